"""Sensors of the car simulator: 3D lidar ray casting, stereo rendering, encoders and FOG.

Frames: world = start frame (x east, y north, z up, ground ``z = 0``); vehicle frame = x
forward, y left, z up, origin on the ground midway between the rear wheels (the point whose
motion the encoders measure); sensor -> vehicle by ``R``, ``T`` of ``Vehicle2<Sensor>.txt``
(``p_vehicle = R @ p_sensor + T``). The car is flat on flat ground (no roll, pitch or bounce).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from pf_slam_tools.sim.car_params import PARAM_FILES, extrinsic, yaml_matrix
from pf_slam_tools.sim.car_world import KIND_BUILDING, KIND_CAR, KIND_CROWN, CarWorld

__all__ = [
    "IMAGE_H",
    "IMAGE_W",
    "LIDAR_ANGLES_RAD",
    "LIDAR_MAX_M",
    "N_LIDAR_BEAMS",
    "STEREO_BASELINE_M",
    "camera_pose",
    "lidar_directions",
    "lidar_ranges",
    "ray_boxes",
    "render_rgb",
    "rgb_to_bayer",
    "fog_deltas",
    "encoder_counts",
]

# ---- calibration (from the param texts) ----------------------------------------------------
R_LIDAR, T_LIDAR = extrinsic("Lidar")
R_STEREO, T_STEREO = extrinsic("Stereo")
N_LIDAR_BEAMS = 286
LIDAR_START_DEG, LIDAR_STEP_DEG, LIDAR_MAX_M = -5.0, 0.666, 80.0
LIDAR_ANGLES_RAD = np.deg2rad(LIDAR_START_DEG + LIDAR_STEP_DEG * np.arange(N_LIDAR_BEAMS))
P_LEFT = yaml_matrix("left_camera.yaml", "projection_matrix")
P_RIGHT = yaml_matrix("right_camera.yaml", "projection_matrix")
#: Baseline of the rectified pair, ``-P_right[0, 3] / f`` (0.4751492 m; ``stereo_param.txt``
#: says 0.4751436 m): the images are rendered so that ``disparity = f * STEREO_BASELINE_M / Z``.
STEREO_BASELINE_M = float(-P_RIGHT[0, 3] / P_RIGHT[0, 0])
IMAGE_W, IMAGE_H = 1280, 560
_ENC = {
    k.strip(): float(v)
    for k, v in (
        ln.split(":") for ln in PARAM_FILES["EncoderParameter.txt"].splitlines() if ":" in ln and "stored" not in ln
    )
}
ENCODER_TICKS = int(_ENC["Encoder resolution"])
WHEEL_D_LEFT_M = _ENC["Encoder left wheel diameter"]
WHEEL_D_RIGHT_M = _ENC["Encoder right wheel diameter"]
WHEEL_BASE_M = _ENC["Encoder wheel base"]

LIDAR_SIGMA_M = 0.025
LIDAR_DROPOUT = 0.01


def _rz(theta: np.ndarray) -> np.ndarray:
    """``(N, 3, 3)`` rotations about z."""
    c, s = np.cos(theta), np.sin(theta)
    r = np.zeros(np.shape(theta) + (3, 3))
    r[..., 0, 0], r[..., 0, 1], r[..., 1, 0], r[..., 1, 1], r[..., 2, 2] = c, -s, s, c, 1.0
    return r


def ray_boxes(
    origins: np.ndarray,
    dirs: np.ndarray,
    boxes: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest hit of rays with axis-aligned boxes (slab method, rays x boxes vectorised).

    Parameters
    ----------
    origins, dirs : np.ndarray
        ``(N, 3)`` ray origins and directions (need not be unit: ``t`` is in units of
        ``|dir|``). ``origins`` may be ``(3,)`` (shared).
    boxes : np.ndarray
        ``(M, 3)`` ... ``(M, 6)`` ``[xmin, ymin, zmin, xmax, ymax, zmax]``.

    Returns
    -------
    t : ``(N,)`` ray parameter of the entry point (``inf`` = no hit in front of the origin);
    index : ``(N,)`` int box index (-1 = none); axis : ``(N,)`` int8 axis of the entered face.
    """
    o = np.asarray(origins)
    d = np.asarray(dirs).reshape(-1, 3)
    o = np.broadcast_to(o.reshape(-1, 3), d.shape) if o.ndim == 1 else o.reshape(-1, 3)
    n = len(d)
    if len(boxes) == 0:
        return np.full(n, np.inf), np.full(n, -1), np.zeros(n, np.int8)
    tn = tf = axis = None
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(3):
            inv = 1.0 / d[:, k : k + 1]
            t1 = (boxes[None, :, k] - o[:, k : k + 1]) * inv  # (N, M)
            t2 = (boxes[None, :, k + 3] - o[:, k : k + 1]) * inv
            lo_k, hi_k = np.fmin(t1, t2), np.fmax(t1, t2)
            if tn is None:
                tn, tf, axis = lo_k, hi_k, np.zeros(lo_k.shape, np.int8)
            else:
                axis = np.where(lo_k > tn, np.int8(k), axis)
                tn, tf = np.fmax(tn, lo_k), np.fmin(tf, hi_k)
    tn = np.where((tf >= tn) & (tn > 1e-6), tn, np.inf)
    idx = tn.argmin(axis=1)
    rows = np.arange(n)
    t = tn[rows, idx]
    ax = axis[rows, idx]
    idx = np.where(np.isfinite(t), idx, -1)
    return t, idx, ax


def _ray_box_image(
    o: np.ndarray,
    inv: np.ndarray,
    box: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One box against a block of pixel rays: ``inv`` ``(h, w, 3)`` = 1 / direction.

    Returns the entry ``t`` (``inf`` = miss) and the axis of the entered face, ``(h, w)``.
    """
    tn = tf = axis = None
    with np.errstate(invalid="ignore"):
        for k in range(3):
            t1 = (box[k] - o[k]) * inv[..., k]
            t2 = (box[k + 3] - o[k]) * inv[..., k]
            lo_k, hi_k = np.fmin(t1, t2), np.fmax(t1, t2)
            if tn is None:
                tn, tf, axis = lo_k, hi_k, np.zeros(lo_k.shape, np.int8)
            else:
                axis[lo_k > tn] = k
                tn, tf = np.fmax(tn, lo_k), np.fmin(tf, hi_k)
    return np.where((tf >= tn) & (tn > 1e-4), tn, np.inf), axis


# ---- lidar ---------------------------------------------------------------------------------


def lidar_directions() -> np.ndarray:
    """``(286, 3)`` unit beam directions in the vehicle frame: ``R @ [cos a, sin a, 0]``."""
    a = LIDAR_ANGLES_RAD
    return np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1) @ R_LIDAR.T


def lidar_ranges(poses: np.ndarray, boxes: np.ndarray, chunk: int = 10) -> np.ndarray:
    """Noise-free LMS511 ranges at vehicle poses: ground plane and boxes, 3D.

    Parameters
    ----------
    poses : np.ndarray
        ``(K, 3)`` vehicle poses ``[x, y, theta]`` (world frame).
    boxes : np.ndarray
        ``(M, 6)`` world boxes.
    chunk : int
        Scans cast together; per chunk only the boxes within range that cross the tilted scan
        plane in front of the sensor are tested.

    Returns
    -------
    np.ndarray
        ``(K, 286)`` ranges (m); ``inf`` where nothing is hit within ``LIDAR_MAX_M``.
    """
    p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    dirs_v = lidar_directions()
    out = np.full((len(p), N_LIDAR_BEAMS), np.inf)
    lo, hi = boxes[:, :3], boxes[:, 3:]
    for k0 in range(0, len(p), chunk):
        pk = p[k0 : k0 + chunk]
        rot = _rz(pk[:, 2])  # (k, 3, 3)
        org = pk[:, None, :].copy()
        org[..., 2] = 0.0
        org = org[:, 0] + rot @ T_LIDAR  # (k, 3)
        normal = rot @ R_LIDAR[:, 2]  # scan-plane normal
        fan_y = rot @ R_LIDAR[:, 1]  # the 90 deg beam
        # cull: boxes crossing the scan plane, in front of the sensor, within range
        cand = np.zeros(len(boxes), dtype=bool)
        for j in range(len(pk)):
            nlo, nhi = normal[j] * lo, normal[j] * hi
            smin = np.minimum(nlo, nhi).sum(1) - normal[j] @ org[j]
            smax = np.maximum(nlo, nhi).sum(1) - normal[j] @ org[j]
            flo, fhi = fan_y[j] * lo, fan_y[j] * hi
            fmax = np.maximum(flo, fhi).sum(1) - fan_y[j] @ org[j]
            dx = np.maximum(np.maximum(lo[:, 0] - org[j, 0], org[j, 0] - hi[:, 0]), 0.0)
            dy = np.maximum(np.maximum(lo[:, 1] - org[j, 1], org[j, 1] - hi[:, 1]), 0.0)
            cand |= (smin <= 0.0) & (smax >= 0.0) & (fmax > -8.0) & (dx * dx + dy * dy < LIDAR_MAX_M**2)
        dirs = np.einsum("kij,bj->kbi", rot, dirs_v)  # (k, B, 3)
        o = np.repeat(org, N_LIDAR_BEAMS, axis=0)
        d = dirs.reshape(-1, 3)
        t, _, _ = ray_boxes(o, d, boxes[cand])
        with np.errstate(divide="ignore"):
            tg = np.where(d[:, 2] < 0.0, -o[:, 2] / d[:, 2], np.inf)
        r = np.minimum(t, tg)
        r[r > LIDAR_MAX_M] = np.inf
        out[k0 : k0 + chunk] = r.reshape(len(pk), N_LIDAR_BEAMS)
    return out


# ---- stereo --------------------------------------------------------------------------------


def camera_pose(pose: np.ndarray, right: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``(R_world_cam (3, 3), centre (3,))`` of the (rectified) left or right camera.

    The rectified left camera frame is taken to be the frame of ``Vehicle2Stereo.txt``
    (x right, y down, z forward); the right camera is ``STEREO_BASELINE_M`` along its +x.
    """
    rot = _rz(np.asarray(pose[2], dtype=np.float64))
    r_wc = rot @ R_STEREO
    c = np.array([pose[0], pose[1], 0.0]) + rot @ T_STEREO
    if right:
        c = c + r_wc[:, 0] * STEREO_BASELINE_M
    return r_wc, c


#: The 12 edges of a box as pairs of corner indices (corner = 4 ix + 2 iy + iz).
_EDGES = np.array([(i, i | bit) for i in range(8) for bit in (4, 2, 1) if not i & bit])
_PIX_DIRS: np.ndarray | None = None


def _pixel_dirs() -> np.ndarray:
    """``(H, W, 3)`` float32 camera-frame rays ``[(u - cx) / f, (v - cy) / f, 1]``."""
    global _PIX_DIRS
    if _PIX_DIRS is None:
        f, cx, cy = P_LEFT[0, 0], P_LEFT[0, 2], P_LEFT[1, 2]
        u, v = np.meshgrid(np.arange(IMAGE_W, dtype=np.float64), np.arange(IMAGE_H))
        _PIX_DIRS = np.stack([(u - cx) / f, (v - cy) / f, np.ones_like(u)], axis=-1).astype(np.float32)
    return _PIX_DIRS


def _hash_noise(a: np.ndarray, b: np.ndarray, cell_m: float) -> np.ndarray:
    """Value noise (unit sigma, bilinear between hashed lattice values) at surface coordinates
    ``a``, ``b`` (m) with lattice spacing ``cell_m``: deterministic and not periodic."""
    x = np.asarray(a, dtype=np.float64) / cell_m
    y = np.asarray(b, dtype=np.float64) / cell_m
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0).astype(np.float32), (y - y0).astype(np.float32)
    i, j = x0.astype(np.int64), y0.astype(np.int64)

    def h(ii: np.ndarray, jj: np.ndarray) -> np.ndarray:
        v = (ii * 374761393 + jj * 668265263) & 0xFFFFFFFF
        v = ((v ^ (v >> 13)) * 1274126177) & 0xFFFFFFFF
        v ^= v >> 16
        return ((v & 0xFFFF).astype(np.float32) / 65535.0 - 0.5) * 3.4641016

    top = h(i, j) * (1 - fx) + h(i + 1, j) * fx
    bot = h(i, j + 1) * (1 - fx) + h(i + 1, j + 1) * fx
    return top * (1 - fy) + bot * fy


#: Procedural ground detail not stored in the floor texture: ``(cell m, sigma)`` layers.
GRAIN_LAYERS = ((0.1, 5.0), (0.03, 4.0))
SKY_TOP, SKY_HORIZON = np.array([95.0, 140.0, 205.0]), np.array([215.0, 225.0, 235.0])


def render_rgb(
    pose: np.ndarray,
    world: CarWorld,
    right: bool = False,
    render_range_m: float = 250.0,
    grain: bool = True,
    depth: np.ndarray | None = None,
) -> np.ndarray:
    """Ray-cast one rectified camera image at vehicle pose ``pose``.

    Per pixel: the ground plane (floor texture, bilinear, plus the ``GRAIN_LAYERS`` of
    procedural detail not stored in the texture unless ``grain`` is False), the boxes
    (facades with windows, cars with a dark glass band, poles, trees; flat shading per face)
    and the sky above.
    Vectorised over pixels; boxes are tested only inside their projected bounding rectangle.

    If ``depth`` (``(560, 1280)`` float) is given it receives the camera-z depth of every
    pixel (m; ``inf`` = sky).

    Returns
    -------
    np.ndarray
        ``(560, 1280, 3)`` uint8 RGB.
    """
    r_wc, c = camera_pose(np.asarray(pose, dtype=np.float64), right)
    dc = _pixel_dirs()
    dw = (dc.reshape(-1, 3) @ r_wc.T.astype(np.float32)).reshape(IMAGE_H, IMAGE_W, 3)
    cz = np.float32(c[2])
    with np.errstate(divide="ignore"):
        zbuf = np.where(dw[..., 2] < 0, -cz / dw[..., 2], np.inf).astype(np.float32)
        inv = 1.0 / dw
    ident = np.full((IMAGE_H, IMAGE_W), -1, dtype=np.int32)  # -1 ground / sky
    axis = np.zeros((IMAGE_H, IMAGE_W), dtype=np.int8)
    # candidate boxes: project the corners
    b = world.boxes
    corners = np.stack(np.meshgrid([0, 3], [1, 4], [2, 5], indexing="ij"), -1).reshape(-1, 3)
    pts = b[:, corners]  # (M, 8, 3)
    cam = (pts - c) @ r_wc  # (M, 8, 3) camera frame
    zc = cam[..., 2]
    dist = np.hypot(np.clip(c[0], b[:, 0], b[:, 3]) - c[0], np.clip(c[1], b[:, 1], b[:, 4]) - c[1])
    f, cx, cy = P_LEFT[0, 0], P_LEFT[0, 2], P_LEFT[1, 2]
    cf = c.astype(np.float32)
    near = 0.05
    for m in np.flatnonzero((zc.max(1) > near) & (dist < render_range_m)):
        q = cam[m]
        if zc[m].min() <= near:  # clip the box at the near plane
            za, zb = q[_EDGES[:, 0], 2], q[_EDGES[:, 1], 2]
            cut = (za - near) * (zb - near) < 0.0
            w = ((near - za[cut]) / (zb[cut] - za[cut]))[:, None]
            q = np.concatenate([q[q[:, 2] > near], q[_EDGES[cut, 0]] * (1 - w) + q[_EDGES[cut, 1]] * w])
        u = f * q[:, 0] / q[:, 2] + cx
        v = f * q[:, 1] / q[:, 2] + cy
        u0, u1 = max(int(u.min()), 0), min(int(u.max()) + 2, IMAGE_W)
        v0, v1 = max(int(v.min()), 0), min(int(v.max()) + 2, IMAGE_H)
        if u0 >= u1 or v0 >= v1:
            continue
        t, ax = _ray_box_image(cf, inv[v0:v1, u0:u1], b[m].astype(np.float32))
        zs = zbuf[v0:v1, u0:u1]
        closer = t < zs
        zs[closer] = t[closer]
        ident[v0:v1, u0:u1][closer] = m
        axis[v0:v1, u0:u1][closer] = ax[closer]
    hit = np.isfinite(zbuf)
    if depth is not None:
        depth[...] = zbuf
    p = cf + dw * np.where(hit, zbuf, 0.0)[..., None]  # hit points (world)
    img = np.empty((IMAGE_H, IMAGE_W, 3), dtype=np.float32)
    # sky
    sky = ~hit
    ds = dw[sky]
    w_sky = np.clip(ds[:, 2] / np.linalg.norm(ds, axis=-1) / 0.5, 0.0, 1.0)[:, None]
    img[sky] = SKY_HORIZON * (1 - w_sky) + SKY_TOP * w_sky
    # ground
    gnd = hit & (ident < 0)
    if gnd.any():
        res, org = world.texture_res_m, world.texture_origin
        mx = ((p[..., 0] - org[0]) / res - 0.5).astype(np.float32)
        my = ((p[..., 1] - org[1]) / res - 0.5).astype(np.float32)
        tex = cv2.remap(
            world.texture, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(90, 95, 75)
        ).astype(np.float32)
        img[gnd] = tex[gnd]
        if grain:
            gx, gy = p[..., 0][gnd], p[..., 1][gnd]
            img[gnd] += sum(sig * _hash_noise(gx, gy, cell) for cell, sig in GRAIN_LAYERS)[:, None]
    # boxes
    obj = hit & (ident >= 0)
    if obj.any():
        ids = ident[obj]
        ax = axis[obj]
        q = p[obj]
        kinds = world.kinds[ids]
        base = world.colours[ids].copy()
        along = np.where(ax == 0, q[:, 1], q[:, 0])
        z = q[:, 2]
        bx = b[ids]
        # buildings: a grid of windows (3.5 m storeys, 3.2 m bays) from 1 m up
        bld = kinds == KIND_BUILDING
        fa, fz = np.mod(along, 3.2) / 3.2, np.mod(z, 3.5) / 3.5
        win = bld & (ax != 2) & (fa > 0.25) & (fa < 0.75) & (fz > 0.3) & (fz < 0.8) & (z > 1.0)
        base[win] = (55.0, 65.0, 80.0)
        # cars: dark glass band on the upper part
        car = kinds == KIND_CAR
        glass = car & (ax != 2) & (z > bx[:, 2] + 0.6 * (bx[:, 5] - bx[:, 2]))
        base[glass] *= 0.3
        shade = np.where(ax == 0, 0.85, np.where(ax == 1, 0.7, 1.0)).astype(np.float32)
        amp = np.where(kinds == KIND_CROWN, 30.0, np.where(bld, 10.0, 4.0)).astype(np.float32)
        detail = _hash_noise(along, z, 0.08)
        img[obj] = base * shade[:, None] + (amp * detail)[:, None]
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def rgb_to_bayer(rgb: np.ndarray) -> np.ndarray:
    """``(H, W, 3)`` RGB -> ``(H, W)`` Bayer mosaic that ``cv2.COLOR_BAYER_BG2BGR`` decodes.

    Red on even rows / even columns, blue on odd rows / odd columns, green elsewhere (checked
    against OpenCV's decoder).
    """
    m = rgb[..., 1].copy()
    m[0::2, 0::2] = rgb[0::2, 0::2, 0]
    m[1::2, 1::2] = rgb[1::2, 1::2, 2]
    return m


# ---- encoders and FOG ----------------------------------------------------------------------


def wheel_travel(s: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """True left / right wheel travel (m) for arc length ``s`` and unwrapped heading."""
    dth = theta - theta[0]
    return s - 0.5 * WHEEL_BASE_M * dth, s + 0.5 * WHEEL_BASE_M * dth


def encoder_counts(
    s: np.ndarray,
    theta: np.ndarray,
    d_true_m: tuple[float, float],
    offsets: tuple[float, float],
    slip_sigma: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """``(N, 2)`` int64 cumulative left / right counts at the samples of ``s`` / ``theta``.

    Wheel angle = travel / (d_true / 2) plus a slip random walk (``slip_sigma`` rad per
    sqrt(rad) of rotation); counts = ``floor(angle * ENCODER_TICKS / 2 pi) + offset``.
    """
    out = []
    for travel, d, off in zip(wheel_travel(s, theta), d_true_m, offsets):
        ang = travel / (0.5 * d)
        dang = np.diff(ang, prepend=ang[0])
        slip = np.cumsum(rng.normal(size=len(ang)) * slip_sigma * np.sqrt(np.abs(dang)))
        out.append(np.floor((ang + slip) * ENCODER_TICKS / (2 * math.pi)).astype(np.int64) + int(off))
    return np.stack(out, axis=1)


def fog_deltas(
    theta_prev: np.ndarray, theta: np.ndarray, bias: float, sigma: float, sigma_rp: float, rng: np.random.Generator
) -> np.ndarray:
    """``(N, 3)`` ``[delta_roll, delta_pitch, delta_yaw]`` (rad per sample)."""
    n = len(theta)
    dyaw = (theta - theta_prev) + bias + sigma * rng.normal(size=n)
    return np.stack([sigma_rp * rng.normal(size=n), sigma_rp * rng.normal(size=n), dyaw], axis=1)
