"""Seeded 2D indoor simulator: an office floor, a smooth drive, a laser and drifting odometry.

Writes the project's own small sample (``make run`` replays ``bags/sample_indoor``)::

    python -m pf_slam_tools.sim.indoor --out bags --seed 0 --duration 60

* **World** -- a 20 m x 15 m office floor of wall segments: outer walls, a 2 m wide east-west
  corridor, three rooms south of it and two north of it (1.2 m door gaps, one door between the
  two south-west rooms), boxes and pillars (one rotated) in every room and two cabinets flush
  with the corridor walls, so scan matching is well conditioned everywhere.
* **Drive** -- a clockwise loop at ~0.5 m/s (corridor -> room B -> room A -> corridor) of
  straight legs joined by circular arcs, with one ~3 s stop; after one lap (~21 m) the robot
  drives on through the start region (loop closure). The seed perturbs the corners, arc radii,
  cruise speed and the time and length of the stop.
* **Laser** -- 10 Hz, 181 beams over 180 deg (``angle_min = -pi/2``, ``pi/180`` increment),
  ``range_max`` 20 m, Gaussian range noise (0.01 m), ~1 % dropouts; a missing return
  (dropout or nothing within ``range_max``) is ``+inf``. Mounted at the base origin.
* **Odometry** -- differential-drive wheel odometry integrated from the true motion with a wheel
  scale error of 1-2 %, a left/right scale mismatch (heading drift 0.3-0.6 deg/m) and random wheel
  slip, published as ``nav_msgs/Odometry`` (default 20 Hz; every scan stamp has one).

Frames: the ground truth (``ground_truth.tum``, ``ground_truth_map.yaml``) is expressed in the
frame of the robot's true starting pose, which is where a SLAM ``map`` frame starts, and
``odom`` starts at the same identity pose; so ``|odom - ground truth|`` is the dead-reckoning
drift and a SLAM trajectory compares to the ground truth without alignment.
All bag stamps are ``EPOCH_NS + k * period``; the output is byte-identical for a given seed.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pf_slam_nodes.core.geometry import rpy_to_matrix, rpy_to_quat
from pf_slam_nodes.io.bag import BagError, laser_scan, odometry, open_writer, tf_static
from pf_slam_nodes.io.mapfile import write_map
from pf_slam_nodes.io.trajectory import write_tum

from .paths import pose_on_path

__all__ = [
    "ANGLE_INCREMENT_RAD",
    "ANGLE_MIN_RAD",
    "EPOCH_NS",
    "IndoorWorld",
    "N_BEAMS",
    "RANGE_MAX_M",
    "SimResult",
    "beam_angles",
    "build_parser",
    "distance_to_segments",
    "main",
    "office_world",
    "plan_drive",
    "rasterise_world",
    "ray_cast",
    "simulate_indoor",
    "simulate_odometry",
    "mount_pose",
    "simulate_scans",
]

#: Record / header time of the first message (2023-11-14T22:13:20Z).
EPOCH_NS = 1_700_000_000 * 1_000_000_000
#: Internal integration rate of the drive and the odometry (Hz).
SIM_RATE_HZ = 100
SCAN_RATE_HZ = 10
N_BEAMS = 181
ANGLE_MIN_RAD = -0.5 * math.pi
ANGLE_INCREMENT_RAD = math.pi / 180.0
RANGE_MIN_M = 0.1
RANGE_MAX_M = 20.0
RANGE_SIGMA_M = 0.01
DROPOUT_PROB = 0.01
WHEEL_BASE_M = 0.4
MAP_RESOLUTION_M = 0.05

BAG_NAME = "sample_indoor"
GROUND_TRUTH_NAME = "ground_truth.tum"
MAP_NAME = "ground_truth_map"
SCAN_TOPIC, ODOM_TOPIC, TF_STATIC_TOPIC = "/scan", "/odom", "/tf_static"
LASER_FRAME, BASE_FRAME, ODOM_FRAME = "laser", "base_link", "odom"

# --------------------------------------------------------------------------------------------
# world (floor-plan coordinates, metres; shifted to the start frame by ``office_world``)

_FLOOR_W_M, _FLOOR_H_M = 20.0, 15.0
_DOOR_W_M = 1.2
#: ``(axis, fixed coordinate, from, to, door centres)``: 'h' runs along x at y = fixed.
_WALLS: tuple[tuple[str, float, float, float, tuple[float, ...]], ...] = (
    ("h", 0.0, 0.0, 20.0, ()),  # south outer wall
    ("h", 15.0, 0.0, 20.0, ()),  # north outer wall
    ("v", 0.0, 0.0, 15.0, ()),  # west outer wall
    ("v", 20.0, 0.0, 15.0, ()),  # east outer wall
    ("h", 6.5, 0.0, 20.0, (3.0, 10.0, 17.0)),  # corridor south wall: doors to rooms A, B, C
    ("h", 8.5, 0.0, 20.0, (5.0, 15.0)),  # corridor north wall: doors to rooms D, E
    ("v", 7.0, 0.0, 6.5, (3.0,)),  # room A | room B, with a door
    ("v", 13.0, 0.0, 6.5, ()),  # room B | room C
    ("v", 9.0, 8.5, 15.0, ()),  # room D | room E
    ("v", 14.5, 11.5, 15.0, ()),  # partition in room E
)
#: Boxes and pillars ``(cx, cy, length_x, width_y, yaw_deg)``.
_BOXES: tuple[tuple[float, float, float, float, float], ...] = (
    (1.2, 1.0, 1.2, 0.8, 0.0),  # A: desk
    (0.35, 4.6, 0.6, 1.6, 0.0),  # A: cabinet on the west wall
    (5.6, 5.4, 0.4, 0.4, 0.0),  # A: pillar
    (8.6, 1.1, 1.0, 0.6, 30.0),  # B: crate, rotated
    (11.8, 1.8, 0.4, 0.4, 0.0),  # B: pillar
    (12.2, 5.2, 0.8, 1.2, 0.0),  # B: shelf
    (16.5, 3.0, 2.0, 1.0, 0.0),  # C: table
    (4.5, 12.0, 2.0, 1.0, 0.0),  # D: table
    (7.5, 10.5, 0.4, 0.4, 0.0),  # D: pillar
    (17.5, 10.5, 1.0, 1.0, 15.0),  # E: crate, rotated
    (7.0, 8.35, 0.8, 0.3, 0.0),  # corridor: cabinet on the north wall
    (13.5, 6.65, 0.6, 0.3, 0.0),  # corridor: cabinet on the south wall
)
#: True starting pose in floor-plan coordinates (heading east along the corridor).
_START_XY = (4.5, 7.5)
#: Loop corners (floor-plan) visited clockwise from the start, and their arc radii (m).
_CORNERS = ((10.0, 7.5), (10.2, 3.2), (3.2, 2.7), (3.0, 7.5))
_RADII = (0.9, 0.9, 0.9, 0.9)


@dataclass(frozen=True)
class IndoorWorld:
    """Static geometry, in the start frame (the robot's true starting pose is the origin).

    Attributes
    ----------
    segments : np.ndarray
        ``(M, 4)`` float64 wall segments ``[x0, y0, x1, y1]`` (m), box outlines included.
    boxes : np.ndarray
        ``(Q, 5)`` float64 solid boxes ``[cx, cy, length_x, width_y, yaw]`` (m, rad).
    bounds : np.ndarray
        ``(4,)`` ``[xmin, ymin, xmax, ymax]`` of the outer walls (m).
    """

    segments: np.ndarray
    boxes: np.ndarray
    bounds: np.ndarray


def _box_corners(boxes: np.ndarray) -> np.ndarray:
    """``(Q, 5)`` boxes -> ``(Q, 4, 2)`` corners, counter-clockwise."""
    half = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=np.float64) * 0.5
    local = half[None] * boxes[:, None, 2:4]
    c, s = np.cos(boxes[:, 4])[:, None], np.sin(boxes[:, 4])[:, None]
    x = boxes[:, None, 0] + c * local[..., 0] - s * local[..., 1]
    y = boxes[:, None, 1] + s * local[..., 0] + c * local[..., 1]
    return np.stack([x, y], axis=-1)


def office_world() -> IndoorWorld:
    """The office floor of this module, in the start frame."""
    segs: list[tuple[float, float, float, float]] = []
    for axis, fixed, lo, hi, doors in _WALLS:
        cuts = sorted(doors)
        starts = [lo] + [c + 0.5 * _DOOR_W_M for c in cuts]
        ends = [c - 0.5 * _DOOR_W_M for c in cuts] + [hi]
        for a, b in zip(starts, ends):
            segs.append((a, fixed, b, fixed) if axis == "h" else (fixed, a, fixed, b))
    boxes = np.array(_BOXES, dtype=np.float64)
    boxes[:, 4] = np.deg2rad(boxes[:, 4])
    corners = _box_corners(boxes)
    box_segs = np.concatenate([corners, np.roll(corners, -1, axis=1)], axis=-1).reshape(-1, 4)
    shift = np.array(_START_XY * 2)
    segments = np.concatenate([np.array(segs), box_segs]) - shift
    boxes[:, :2] -= shift[:2]
    bounds = np.array([0.0, 0.0, _FLOOR_W_M, _FLOOR_H_M]) - shift
    return IndoorWorld(segments=segments, boxes=boxes, bounds=bounds)


# --------------------------------------------------------------------------------------------
# geometry


def beam_angles() -> np.ndarray:
    """``(N_BEAMS,)`` beam angles of the simulated laser (rad), ``-pi/2 .. pi/2``."""
    return ANGLE_MIN_RAD + ANGLE_INCREMENT_RAD * np.arange(N_BEAMS, dtype=np.float64)


def ray_cast(
    poses: np.ndarray, angles: np.ndarray, segments: np.ndarray, range_max_m: float, chunk: int = 64
) -> np.ndarray:
    """Noise-free ranges of beams against wall segments (beams x segments, vectorised).

    Parameters
    ----------
    poses : np.ndarray
        ``(K, 3)`` or ``(3,)`` sensor poses ``[x, y, theta]`` (m, m, rad).
    angles : np.ndarray
        ``(B,)`` beam angles in the sensor frame (rad).
    segments : np.ndarray
        ``(M, 4)`` segments ``[x0, y0, x1, y1]`` (m).
    range_max_m : float
        Hits farther than this are no return.
    chunk : int
        Poses processed per array operation (bounds memory at ``chunk * B * M``).

    Returns
    -------
    np.ndarray
        ``(K, B)`` (or ``(B,)`` for a single pose) float64 distance to the first segment hit
        (m); ``+inf`` where nothing is hit within ``range_max_m``.
    """
    p = np.asarray(poses, dtype=np.float64)
    single = p.ndim == 1
    p = p.reshape(-1, 3)
    a = np.asarray(angles, dtype=np.float64).ravel()
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    e = seg[:, 2:] - seg[:, :2]  # (M, 2)
    out = np.full((len(p), len(a)), np.inf)
    for k0 in range(0, len(p), chunk):
        pk = p[k0 : k0 + chunk]
        th = pk[:, 2:3] + a[None]  # (k, B)
        dx, dy = np.cos(th)[..., None], np.sin(th)[..., None]  # (k, B, 1)
        wx = seg[None, :, 0] - pk[:, 0:1]  # (k, M)
        wy = seg[None, :, 1] - pk[:, 1:2]
        denom = dx * e[:, 1] - dy * e[:, 0]  # (k, B, M) cross(d, e)
        num_t = (wx * e[:, 1] - wy * e[:, 0])[:, None, :]  # cross(w, e)
        num_u = wx[:, None, :] * dy - wy[:, None, :] * dx  # cross(w, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num_t / denom
            u = num_u / denom
        hit = (denom != 0.0) & (t > 1e-9) & (u >= 0.0) & (u <= 1.0)
        r = np.where(hit, t, np.inf).min(axis=-1)
        r[r > range_max_m] = np.inf
        out[k0 : k0 + chunk] = r
    return out[0] if single else out


def distance_to_segments(points: np.ndarray, segments: np.ndarray, chunk: int = 16384) -> np.ndarray:
    """Distance from each point to the nearest segment.

    Parameters
    ----------
    points : np.ndarray
        ``(P, 2)`` points (m).
    segments : np.ndarray
        ``(M, 4)`` segments ``[x0, y0, x1, y1]`` (m).

    Returns
    -------
    np.ndarray
        ``(P,)`` float64 distances (m).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    a, e = seg[:, :2], seg[:, 2:] - seg[:, :2]
    ee = np.maximum((e * e).sum(axis=1), 1e-300)
    out = np.empty(len(pts))
    for i in range(0, len(pts), chunk):
        w = pts[i : i + chunk, None, :] - a[None]  # (p, M, 2)
        u = np.clip((w * e).sum(axis=-1) / ee, 0.0, 1.0)
        d = w - u[..., None] * e
        out[i : i + chunk] = np.sqrt((d * d).sum(axis=-1).min(axis=1))
    return out


def rasterise_world(
    world: IndoorWorld, resolution_m: float = MAP_RESOLUTION_M, margin_m: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth occupancy grid of ``world``.

    Returns
    -------
    occupancy : np.ndarray
        ``(H, W)`` int8, row 0 = lowest y: 100 within half a cell diagonal of a wall or inside a
        box, 0 elsewhere inside the outer walls, -1 outside.
    origin_xy : np.ndarray
        ``(2,)`` world position of the lower-left corner of cell ``(0, 0)`` (m).
    """
    xmin, ymin, xmax, ymax = world.bounds
    origin = np.array([xmin - margin_m, ymin - margin_m])
    w = int(round((xmax - xmin + 2 * margin_m) / resolution_m))
    h = int(round((ymax - ymin + 2 * margin_m) / resolution_m))
    gx = origin[0] + (np.arange(w) + 0.5) * resolution_m
    gy = origin[1] + (np.arange(h) + 0.5) * resolution_m
    cx, cy = np.meshgrid(gx, gy)  # (H, W), row = y
    inside = (cx > xmin) & (cx < xmax) & (cy > ymin) & (cy < ymax)
    occ = np.where(inside, 0, -1).astype(np.int8)
    pts = np.stack([cx.ravel(), cy.ravel()], axis=1)
    near = distance_to_segments(pts, world.segments).reshape(h, w) <= 0.5 * math.sqrt(2.0) * resolution_m
    for bx, by, lx, wy, yaw in world.boxes:
        c, s = math.cos(yaw), math.sin(yaw)
        lx_ = c * (cx - bx) + s * (cy - by)
        ly_ = -s * (cx - bx) + c * (cy - by)
        near |= (np.abs(lx_) <= 0.5 * lx) & (np.abs(ly_) <= 0.5 * wy)
    occ[near] = 100
    return occ, origin


# --------------------------------------------------------------------------------------------
# drive


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _loop_primitives(corners: np.ndarray, radii: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Closed path start -> corners[0] -> ... -> corners[-1] -> start, corners filleted.

    Returns ``(P, 5)`` constant-curvature pieces ``[x0, y0, theta0, curvature, length]``.
    """
    n = len(corners)
    pieces: list[tuple[float, float, float, float, float]] = []
    pos = start.copy()
    for i in range(n):
        c = corners[i]
        u_in = c - (corners[i - 1] if i > 0 else start)
        u_out = (corners[i + 1] if i + 1 < n else start) - c
        u_in /= np.linalg.norm(u_in)
        u_out /= np.linalg.norm(u_out)
        turn = math.atan2(u_in[0] * u_out[1] - u_in[1] * u_out[0], float(u_in @ u_out))
        d = radii[i] * math.tan(0.5 * abs(turn))
        arc_start, arc_end = c - d * u_in, c + d * u_out
        line_len = float(np.linalg.norm(arc_start - pos))
        if (arc_start - pos) @ u_in < 0.0:
            raise ValueError(f"corner {i}: radius {radii[i]:.3f} m too large for its legs")
        heading = math.atan2(u_in[1], u_in[0])
        pieces.append((pos[0], pos[1], heading, 0.0, line_len))
        pieces.append((arc_start[0], arc_start[1], heading, math.copysign(1.0 / radii[i], turn), radii[i] * abs(turn)))
        pos = arc_end
    u = start - pos
    if u @ (start - corners[-1]) <= 0.0:
        raise ValueError("last corner radius too large for the closing leg")
    pieces.append((pos[0], pos[1], math.atan2(u[1], u[0]), 0.0, float(np.linalg.norm(u))))
    return np.array(pieces, dtype=np.float64)


def _pose_on_path(pieces: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Poses ``(N, 3)`` at arc lengths ``s`` (wrapped around the closed path)."""
    p = pose_on_path(pieces, np.mod(s, pieces[:, 4].sum()))
    p[:, 2] = np.arctan2(np.sin(p[:, 2]), np.cos(p[:, 2]))
    return p


def plan_drive(
    duration_s: float, rng: np.random.Generator, rate_hz: int = SIM_RATE_HZ
) -> tuple[np.ndarray, np.ndarray]:
    """True trajectory of the robot, sampled at ``rate_hz``.

    The loop of ``_CORNERS`` (clockwise, ~21 m, arcs of ~0.9 m radius) is driven at a cruise
    speed of 0.5 m/s (seeded +-6 %, slow +-5 % modulation) from standstill, with one stop of
    ~3 s (smooth 1.5 s ramps) between 22 s and 28 s; the path wraps after one lap.

    Returns
    -------
    t_s : np.ndarray
        ``(N,)`` times since the start (s), ``N = round(duration_s * rate_hz)``.
    poses : np.ndarray
        ``(N, 3)`` ``[x, y, theta]`` in the start frame; ``poses[0] == (0, 0, 0)``.
    """
    corners = np.array(_CORNERS, dtype=np.float64)
    jitter = rng.uniform(-0.1, 0.1, size=corners.shape)
    jitter[[0, -1], 1] = 0.0  # keep the corridor leg through the start on y = 7.5
    corners += jitter
    radii = np.array(_RADII) + rng.uniform(-0.1, 0.05, size=len(_RADII))
    v_cruise = 0.5 * (1.0 + rng.uniform(-0.06, 0.06))
    mod_period_s, mod_phase = rng.uniform(12.0, 20.0), rng.uniform(0.0, 2 * math.pi)
    t_stop, hold_s = rng.uniform(22.0, 28.0), rng.uniform(2.5, 3.5)
    ramp_s = 1.5

    start = np.array(_START_XY, dtype=np.float64)
    pieces = _loop_primitives(corners - start, radii, np.zeros(2))
    n = int(round(duration_s * rate_hz))
    t = np.arange(n, dtype=np.float64) / rate_hz
    speed = v_cruise * (1.0 + 0.05 * np.sin(2 * math.pi * t / mod_period_s + mod_phase))
    speed *= _smoothstep(t / ramp_s)
    speed *= 1.0 - _smoothstep((t - t_stop) / ramp_s) + _smoothstep((t - t_stop - ramp_s - hold_s) / ramp_s)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) / rate_hz)])
    return t, _pose_on_path(pieces, s)


# --------------------------------------------------------------------------------------------
# sensors


def simulate_odometry(
    poses: np.ndarray, rng: np.random.Generator, wheel_base_m: float = WHEEL_BASE_M, slip_sigma: float = 0.003
) -> np.ndarray:
    """Wheel odometry integrated from the true motion, with systematic and random errors.

    The true increments ``(ds, dtheta)`` between consecutive poses become left / right wheel
    travels, which are scaled by ``1 -+ m / 2 + e`` (``|e|`` ~ U(1 %, 2 %) common scale error,
    ``|m|`` ~ U(0.2 %, 0.4 %) left/right mismatch, i.e. a heading drift of ``m / wheel_base``
    = 0.3-0.6 deg/m) plus slip ``N(0, slip_sigma^2 |travel|)``, then re-integrated (midpoint).
    ``m`` takes the sign opposite to ``e``: on the clockwise loop of ``plan_drive`` the heading
    errors of both then add instead of cancelling, so every seed drifts visibly (~0.5-2 m).

    Parameters
    ----------
    poses : np.ndarray
        ``(N, 3)`` true poses at a fixed rate.

    Returns
    -------
    np.ndarray
        ``(N, 3)`` odometry poses, starting at the identity.
    """
    p = np.asarray(poses, dtype=np.float64)
    dth = np.diff(p[:, 2])
    dth = np.arctan2(np.sin(dth), np.cos(dth))
    dxy = np.diff(p[:, :2], axis=0)
    mid = p[:-1, 2] + 0.5 * dth
    ds = dxy[:, 0] * np.cos(mid) + dxy[:, 1] * np.sin(mid)
    scale = rng.choice([-1.0, 1.0]) * rng.uniform(0.01, 0.02)
    mismatch = -math.copysign(rng.uniform(0.002, 0.004), scale)
    left = ds - 0.5 * wheel_base_m * dth
    right = ds + 0.5 * wheel_base_m * dth
    left = left * (1.0 + scale - 0.5 * mismatch) + rng.normal(size=len(ds)) * slip_sigma * np.sqrt(np.abs(left))
    right = right * (1.0 + scale + 0.5 * mismatch) + rng.normal(size=len(ds)) * slip_sigma * np.sqrt(np.abs(right))
    ds_o = 0.5 * (left + right)
    dth_o = (right - left) / wheel_base_m
    th = np.concatenate([[0.0], np.cumsum(dth_o)])
    mid_o = th[:-1] + 0.5 * dth_o
    x = np.concatenate([[0.0], np.cumsum(ds_o * np.cos(mid_o))])
    y = np.concatenate([[0.0], np.cumsum(ds_o * np.sin(mid_o))])
    return np.stack([x, y, np.arctan2(np.sin(th), np.cos(th))], axis=1)


def mount_pose(chain: Sequence[tuple[str, str, Sequence[float], Sequence[float]]]) -> tuple[np.ndarray, np.ndarray]:
    """``(R (3, 3), t (3,))`` of the last frame of a chain of static transforms
    ``(parent, child, (x, y, z), (roll, pitch, yaw) rad)`` in the first parent (each child the
    next one's parent)."""
    rot, t = np.eye(3), np.zeros(3)
    for k, (parent, _child, xyz, rpy) in enumerate(chain):
        if k and parent != chain[k - 1][1]:
            raise ValueError(f"mount chain: {parent!r} is not the previous child {chain[k - 1][1]!r}")
        r = rpy_to_matrix(np.degrees(np.asarray(rpy, dtype=np.float64)))
        t = t + rot @ np.asarray(xyz, dtype=np.float64)
        rot = rot @ r
    return rot, t


def simulate_scans(
    poses: np.ndarray,
    segments: np.ndarray,
    rng: np.random.Generator,
    mount: tuple[np.ndarray, np.ndarray] | None = None,
    range_sigma_m: float = RANGE_SIGMA_M,
    angles: np.ndarray | None = None,
    range_max: float = RANGE_MAX_M,
) -> np.ndarray:
    """Laser ranges at ``poses``: ray cast, ``N(0, range_sigma_m^2)`` noise, dropouts.

    ``mount``: the laser's ``(R, t)`` in the base frame (its scan plane horizontal: upright or
    upside down, which mirrors the beams); default at the base origin. ``angles``, ``range_max``:
    another laser's beams (rad) and range (m); default the simulator's (:func:`beam_angles`).

    Returns
    -------
    np.ndarray
        ``(K, B)`` float32 ranges (m); ``+inf`` = no return (nothing within ``range_max``, a
        noisy range beyond it, or a dropout with probability ``DROPOUT_PROB``).
    """
    angles = beam_angles() if angles is None else np.asarray(angles, dtype=np.float64)
    if mount is not None:
        rot, t = (np.asarray(v, dtype=np.float64) for v in mount)
        if abs(abs(rot[2, 2]) - 1.0) > 1e-9:
            raise ValueError(f"the simulated laser must scan a horizontal plane, got R = {rot.tolist()}")
        p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
        poses = np.stack(
            [p[:, 0] + c * t[0] - s * t[1], p[:, 1] + s * t[0] + c * t[1], p[:, 2] + math.atan2(rot[1, 0], rot[0, 0])],
            axis=-1,
        )
        angles = math.copysign(1.0, rot[2, 2]) * angles
    r = ray_cast(poses, angles, segments, range_max).reshape(-1, angles.size)
    r = r + range_sigma_m * rng.normal(size=r.shape)
    r[rng.random(size=r.shape) < DROPOUT_PROB] = np.inf
    r[r > range_max] = np.inf
    return r.astype(np.float32)


# --------------------------------------------------------------------------------------------
# sample


@dataclass(frozen=True)
class SimResult:
    """What ``simulate_indoor`` wrote.

    ``odom_drift_m`` is the final dead-reckoning position error (odometry vs ground truth at
    the last scan); ``path_length_m`` the distance driven.
    """

    bag_path: Path
    ground_truth_path: Path
    map_yaml_path: Path
    seed: int
    duration_s: float
    n_scans: int
    n_odom: int
    path_length_m: float
    odom_drift_m: float


def simulate_indoor(
    out_dir: str | os.PathLike,
    seed: int = 0,
    duration_s: float = 60.0,
    odom_rate_hz: int = 20,
    overwrite: bool = False,
    storage: str = "mcap",
    laser_mount: Sequence[tuple[str, str, Sequence[float], Sequence[float]]] | None = None,
) -> SimResult:
    """Simulate the office drive and write the sample bag, ground truth and map.

    Writes ``out_dir/sample_indoor`` (rosbag2: ``/scan`` ``sensor_msgs/LaserScan`` frame
    ``laser`` at 10 Hz, ``/odom`` ``nav_msgs/Odometry`` ``odom -> base_link`` at
    ``odom_rate_hz``, ``/tf_static`` ``base_link -> laser`` identity), ``out_dir/
    ground_truth.tum`` (true pose at every scan stamp) and ``out_dir/ground_truth_map.pgm``
    / ``.yaml`` (the walls at 0.05 m). At equal stamps the odometry precedes the scan.

    Parameters
    ----------
    out_dir : str or PathLike
        Output directory (created if missing).
    seed : int
        Seeds the drive, the odometry errors and the laser noise (independent streams).
    duration_s : float
        Simulated time (s); ``round(duration_s * 10)`` scans.
    odom_rate_hz : int
        A multiple of 10 dividing 100 (10, 20, 50 or 100).
    overwrite : bool
        Replace an existing ``sample_indoor`` bag (else ``BagError``).
    laser_mount : sequence of (parent, child, (x, y, z), (roll, pitch, yaw) rad), optional
        The laser's mount as a chain of static transforms from ``base_link`` (written to
        ``/tf_static`` as given; the scans are in the last child's frame and simulated from that
        pose). Its scan plane must be horizontal (roll 0 or 180 deg, pitch 0). Default:
        ``base_link -> laser`` identity.
    """
    if not (isinstance(duration_s, (int, float)) and 0.1 <= duration_s <= 3600.0):
        raise ValueError(f"duration_s must be in [0.1, 3600] s, got {duration_s!r}")
    if odom_rate_hz not in (10, 20, 50, 100):
        raise ValueError(f"odom_rate_hz must be 10, 20, 50 or 100, got {odom_rate_hz!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    bag_path = out / BAG_NAME
    if bag_path.exists() and overwrite:
        if not (bag_path.is_dir() and (bag_path / "metadata.yaml").is_file()):
            raise BagError(f"{bag_path}: exists and is not a rosbag2 directory; not removing it")
        shutil.rmtree(bag_path)

    drive_rng, odom_rng, laser_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(3))
    world = office_world()
    n_scans = int(round(duration_s * SCAN_RATE_HZ))
    scan_step = SIM_RATE_HZ // SCAN_RATE_HZ
    odom_step = SIM_RATE_HZ // odom_rate_hz
    t_s, truth = plan_drive(n_scans / SCAN_RATE_HZ, drive_rng)
    odom = simulate_odometry(truth, odom_rng)
    scan_idx = np.arange(0, len(t_s), scan_step)
    chain = list(laser_mount) if laser_mount else [(BASE_FRAME, LASER_FRAME, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))]
    if chain[0][0] != BASE_FRAME:
        raise ValueError(f"laser_mount must start at {BASE_FRAME!r}, got {chain[0][0]!r}")
    mount = mount_pose(chain) if laser_mount else None
    laser_frame = chain[-1][1]
    ranges = simulate_scans(truth[scan_idx], world.segments, laser_rng, mount)
    stamps_ns = EPOCH_NS + np.arange(len(t_s), dtype=np.int64) * (1_000_000_000 // SIM_RATE_HZ)
    transforms = [(parent, child, tuple(float(v) for v in xyz), rpy_to_quat(rpy)) for parent, child, xyz, rpy in chain]
    n_odom = write_sim_bag(
        bag_path,
        storage,
        stamps_ns,
        odom,
        ranges,
        odom_step,
        scan_step,
        transforms,
        laser_frame,
        f"indoor seed={int(seed)} duration_s={n_scans / SCAN_RATE_HZ:g} odom_rate_hz={odom_rate_hz}",
    )

    gt_path = out / GROUND_TRUTH_NAME
    write_tum(gt_path, stamps_ns[scan_idx] / 1e9, truth[scan_idx])
    occ, origin = rasterise_world(world, MAP_RESOLUTION_M)
    map_yaml = write_map(out, occ, MAP_RESOLUTION_M, origin, name=MAP_NAME)
    last = scan_idx[-1]
    return SimResult(
        bag_path=bag_path,
        ground_truth_path=gt_path,
        map_yaml_path=Path(map_yaml),
        seed=int(seed),
        duration_s=n_scans / SCAN_RATE_HZ,
        n_scans=len(scan_idx),
        n_odom=n_odom,
        path_length_m=float(np.hypot(*np.diff(truth[:, :2], axis=0).T).sum()),
        odom_drift_m=float(np.hypot(*(odom[last, :2] - truth[last, :2]))),
    )


def write_sim_bag(
    bag_path: Path,
    storage: str,
    stamps_ns: np.ndarray,
    odom: np.ndarray,
    ranges: np.ndarray,
    odom_step: int,
    scan_step: int,
    transforms: list,
    laser_frame: str,
    sim_tag: str,
) -> int:
    """A simulated drive as a rosbag2: /tf_static (`transforms`: (parent, child, xyz, quat)),
    /odom every `odom_step`-th sample of `odom` (twist from its differences), /scan every
    `scan_step`-th (`ranges` one row per scan); custom data ``pf_slam.sim`` = `sim_tag`.
    Returns the number of /odom messages."""
    dt = 1.0 / SIM_RATE_HZ
    dth = np.diff(odom[:, 2])
    twist_w = np.concatenate([[0.0], np.arctan2(np.sin(dth), np.cos(dth)) / dt])
    twist_v = np.concatenate([[0.0], np.hypot(*np.diff(odom[:, :2], axis=0).T) / dt])
    n_odom = 0
    with open_writer(bag_path, storage=storage) as bag:
        bag.add_connection(TF_STATIC_TOPIC, "tf2_msgs/msg/TFMessage")
        bag.add_connection(ODOM_TOPIC, "nav_msgs/msg/Odometry")
        bag.add_connection(SCAN_TOPIC, "sensor_msgs/msg/LaserScan")
        bag.set_custom_data("pf_slam.sim", sim_tag)
        t0 = int(stamps_ns[0])
        bag.write(TF_STATIC_TOPIC, t0, tf_static(t0, transforms))
        for i in range(len(stamps_ns)):
            stamp = int(stamps_ns[i])
            if i % odom_step == 0:
                bag.write(ODOM_TOPIC, stamp, odometry(stamp, ODOM_FRAME, BASE_FRAME, odom[i], (twist_v[i], twist_w[i])))
                n_odom += 1
            if i % scan_step == 0:
                bag.write(
                    SCAN_TOPIC,
                    stamp,
                    laser_scan(
                        stamp,
                        laser_frame,
                        ANGLE_MIN_RAD,
                        ANGLE_INCREMENT_RAD,
                        ranges[i // scan_step],
                        RANGE_MIN_M,
                        RANGE_MAX_M,
                        scan_time=1.0 / SCAN_RATE_HZ,
                    ),
                )
    return n_odom


# --------------------------------------------------------------------------------------------
# command line


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the simulator's options to ``parser`` (for ``pf-slam simulate-indoor``)."""
    parser.add_argument("--out", default="bags", help="output directory (default: bags)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("--duration", type=float, default=60.0, help="simulated seconds (default: 60)")
    parser.add_argument(
        "--odom-rate", type=int, default=20, choices=(10, 20, 50, 100), help="odometry rate in Hz (default: 20)"
    )
    parser.add_argument("--force", action="store_true", help="replace an existing sample_indoor bag in --out")
    return parser


def build_parser() -> argparse.ArgumentParser:
    """Stand-alone parser of ``python -m pf_slam_tools.sim.indoor``."""
    return add_arguments(
        argparse.ArgumentParser(
            prog="python -m pf_slam_tools.sim.indoor",
            description="Write the seeded indoor sample bag, its ground truth and map.",
        )
    )


def run_args(args: argparse.Namespace) -> int:
    """Run the simulator from parsed ``add_arguments`` options; prints a summary."""
    try:
        res = simulate_indoor(
            args.out, seed=args.seed, duration_s=args.duration, odom_rate_hz=args.odom_rate, overwrite=args.force
        )
    except (BagError, ValueError) as exc:
        print(f"simulate-indoor: error: {exc}", file=sys.stderr)
        return 2
    size = sum(f.stat().st_size for f in res.bag_path.iterdir() if f.is_file())
    print(
        f"{res.bag_path}: {res.n_scans} scans, {res.n_odom} odometry messages, "
        f"{res.duration_s:g} s, {size} bytes\n"
        f"{res.ground_truth_path}\n{res.map_yaml_path}\n"
        f"path {res.path_length_m:.1f} m, dead-reckoning drift at the end "
        f"{res.odom_drift_m:.2f} m"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m pf_slam_tools.sim.indoor --out DIR --seed N --duration S``."""
    return run_args(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
