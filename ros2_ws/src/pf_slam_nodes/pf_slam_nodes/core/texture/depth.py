"""RGB-D floor texture (THOR's Kinect v2): the depth-mode stage beside the stereo texturer.

Per depth + RGB pair (:meth:`DepthTexturer.process`):

1. **Depth -> 3-D**: every ``depth_stride``-th depth pixel (row and column) with a valid depth
   (``depth_min_m`` .. ``depth_max_m``; 0 = invalid) is back-projected with the depth camera's
   ``K``: ``P_d = Z [(u - cx) / fx, (v - cy) / fy, 1]`` (optical frame: x right, y down, z ahead).
2. **-> RGB pixel**: ``P_rgb = R P_d + T`` (the depth camera in the RGB camera, metres), projected
   with the RGB camera's ``K``; points outside the RGB image are dropped. The colour is the RGB
   pixel's (nearest), so the 1920 x 1080 image is only indexed, never resampled.
3. **-> base frame**: ``p_b = R_bc P_rgb + t_bc`` with the RGB camera's mount at the image stamp
   (on a humanoid: base_link -> head from /tf, interpolated, then head -> kinect ->
   kinect_rgb_optical from /tf_static).
4. **Ground**: a plane fitted by RANSAC + least squares (:func:`.ground.fit_ground_plane`) to the
   points near the kinematic floor (``z = floor_height_m`` in the base frame, 0 for base_link on
   the ground); a fit tilted more than ``plane_max_tilt_deg`` or more than
   ``plane_max_offset_m`` from the kinematic floor height is rejected (``plane_fitted`` False,
   the kinematic floor is used). Points within ``height_tol_m`` of the plane and within
   ``max_lateral_m`` / ``depth_max_m`` of the robot are floor; they are dropped onto the plane
   (``x, y``) and moved into the world with the 2D pose at the image stamp.
5. **Accumulation**: :class:`~.map.TextureMap` (running mean per cell), the same as stereo.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from .config import TextureConfig
from .ground import Plane, fit_ground_plane


@dataclasses.dataclass(frozen=True)
class DepthCamera:
    """An RGB-D camera: the two intrinsic matrices and the depth camera's pose in the RGB one.

    ``k_depth``, ``k_rgb``: (3, 3); ``rot``, ``t``: ``P_rgb = rot @ P_depth + t`` (m);
    ``rgb_size``: (width, height) of the colour image.
    """

    k_depth: np.ndarray
    k_rgb: np.ndarray
    rot: np.ndarray
    t: np.ndarray
    rgb_size: tuple[int, int]

    def __post_init__(self) -> None:
        for name in ("k_depth", "k_rgb"):
            k = np.asarray(getattr(self, name), dtype=np.float64).reshape(3, 3)
            if not (np.isfinite(k).all() and k[0, 0] > 0 and k[1, 1] > 0):
                raise ValueError(f"RGB-D camera: {name} needs positive focal lengths, got {k.tolist()}")
            object.__setattr__(self, name, k)
        rot = np.asarray(self.rot, dtype=np.float64).reshape(3, 3)
        if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-3):
            raise ValueError(f"RGB-D camera: depth -> RGB rotation is not orthonormal: {rot.tolist()}")
        object.__setattr__(self, "rot", rot)
        object.__setattr__(self, "t", np.asarray(self.t, dtype=np.float64).reshape(3))


@dataclasses.dataclass
class DepthFrameResult:
    """What one depth + RGB pair gave: floor samples ``xy_world`` (N, 2) (m; empty without a
    pose), ``xy_base`` (N, 2), ``rgb`` (N, 3) uint8, the ``plane`` used (base frame),
    ``plane_fitted``, ``floor_offset_m`` (the fitted plane's height at the base origin minus
    the kinematic floor height; NaN without a fit) and ``timings_ms``."""

    xy_world: np.ndarray
    xy_base: np.ndarray
    rgb: np.ndarray
    plane: Plane
    plane_fitted: bool
    floor_offset_m: float
    points: int
    timings_ms: dict


class DepthTexturer:
    """Turns depth + RGB pairs into coloured floor samples (see the module docstring).

    Parameters
    ----------
    camera : DepthCamera
    cfg : TextureConfig
        Uses ``depth_stride``, ``depth_min_m``, ``depth_max_m``, ``max_lateral_m``,
        ``height_tol_m``, ``plane_fit``, ``ransac_*``, ``plane_max_tilt_deg``,
        ``plane_max_offset_m``, ``seed``.
    floor_height_m : float
        The kinematic floor's height in the base frame (0: base_link on the ground).
    """

    def __init__(self, camera: DepthCamera, cfg: TextureConfig | None = None, floor_height_m: float = 0.0) -> None:
        self.camera = camera
        self.cfg = cfg or TextureConfig()
        self.floor = float(floor_height_m)
        self.rng = np.random.default_rng(self.cfg.seed)
        self._rays: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def _grid(self, h: int, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, unit-depth rays (3, M)) of the subsampled depth pixels (cached)."""
        key = (h, w)
        if key not in self._rays:
            s = self.cfg.depth_stride
            rows, cols = np.meshgrid(np.arange(s // 2, h, s), np.arange(s // 2, w, s), indexing="ij")
            rows, cols = rows.ravel(), cols.ravel()
            k = self.camera.k_depth
            rays = np.stack([(cols - k[0, 2]) / k[0, 0], (rows - k[1, 2]) / k[1, 1], np.ones(rows.size)])
            self._rays[key] = (rows, cols, rays)
        return self._rays[key]

    def ground_plane(self, p: np.ndarray) -> tuple[Plane, bool]:
        """The floor of one pair's base-frame points ``(N, 3)``: the RANSAC fit near the
        kinematic floor, checked against it (else the kinematic floor, False)."""
        cfg = self.cfg
        nominal = Plane(np.array([0.0, 0.0, 1.0]), -self.floor)
        if not cfg.plane_fit:
            return nominal, False
        near = np.abs(p[:, 2] - self.floor) < cfg.plane_max_offset_m + cfg.ransac_tol_m
        plane, _ = fit_ground_plane(
            p[near], cfg.ransac_iterations, cfg.ransac_tol_m, cfg.ransac_max_points, cfg.plane_max_tilt_deg, self.rng
        )
        if (
            plane is None
            or plane.tilt_deg > cfg.plane_max_tilt_deg
            or abs(-plane.c / plane.normal[2] - self.floor) > cfg.plane_max_offset_m
        ):
            return nominal, False
        return plane, True

    def process(
        self,
        depth_mm: np.ndarray,
        rgb: np.ndarray,
        base_from_rgb: tuple[np.ndarray, np.ndarray],
        pose: np.ndarray | None = None,
        rgb_from_depth: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> DepthFrameResult:
        """One pair -> floor samples.

        Parameters
        ----------
        depth_mm : (H, W) uint16
            Depth (mm, 0 = invalid), as ``16UC1``.
        rgb : (h, w, 3) uint8
            The colour image (RGB order).
        base_from_rgb : (R (3, 3), t (3,))
            The RGB camera's optical frame in the base frame at the image stamp.
        pose : (3,), optional
            The base's 2D pose ``(x, y, theta)`` in the world at the stamp.
        rgb_from_depth : (R (3, 3), t (3,)), optional
            The depth camera (at the depth image's stamp) in the RGB camera (at the colour
            image's stamp), when the two are not taken at once and the head moves between them
            (THOR: RGB 15 ms after depth); ``base_from_rgb`` is then the RGB camera's at its own
            stamp. Default: the camera's fixed ``P_rgb = R P_depth + T``.
        """
        cfg, cam = self.cfg, self.camera
        t0 = time.perf_counter()
        d = np.asarray(depth_mm)
        rows, cols, rays = self._grid(*d.shape[:2])
        z = d[rows, cols].astype(np.float64) * 1e-3
        ok = (z >= cfg.depth_min_m) & (z <= cfg.depth_max_m)
        p_d = rays[:, ok] * z[ok]
        r_cd, t_cd = (
            (cam.rot, cam.t) if rgb_from_depth is None else (np.asarray(a, dtype=np.float64) for a in rgb_from_depth)
        )
        p_c = r_cd @ p_d + np.reshape(t_cd, (3, 1))  # the RGB camera's optical frame
        kr = cam.k_rgb
        h, w = rgb.shape[:2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.rint(kr[0, 0] * p_c[0] / p_c[2] + kr[0, 2])
            v = np.rint(kr[1, 1] * p_c[1] / p_c[2] + kr[1, 2])
            inside = (p_c[2] > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        u, v, p_c = u[inside].astype(np.int64), v[inside].astype(np.int64), p_c[:, inside]
        r_bc, t_bc = (np.asarray(a, dtype=np.float64) for a in base_from_rgb)
        p_b = (r_bc @ p_c + t_bc.reshape(3, 1)).T  # (N, 3) base frame
        t1 = time.perf_counter()
        plane, fitted = self.ground_plane(p_b)
        hgt = plane.height_of(p_b)
        floor = (np.abs(hgt) < cfg.height_tol_m) & (np.abs(p_b[:, 1]) <= cfg.max_lateral_m)
        q = p_b[floor] - hgt[floor, None] * plane.normal[None, :]  # onto the plane
        xy_b = q[:, :2]
        colours = np.asarray(rgb)[v[floor], u[floor]][:, :3].astype(np.uint8)
        if pose is not None:
            x, y, th = (float(a) for a in np.asarray(pose, dtype=np.float64).reshape(3))
            c, s = math.cos(th), math.sin(th)
            xy_w = np.column_stack([x + c * xy_b[:, 0] - s * xy_b[:, 1], y + s * xy_b[:, 0] + c * xy_b[:, 1]])
        else:
            xy_w = np.zeros((0, 2))
        offset = (-plane.c / plane.normal[2] - self.floor) if fitted else float("nan")
        t2 = time.perf_counter()
        return DepthFrameResult(
            xy_w,
            xy_b,
            colours,
            plane,
            fitted,
            float(offset),
            int(p_b.shape[0]),
            {"points": 1e3 * (t1 - t0), "ground": 1e3 * (t2 - t1), "total": 1e3 * (t2 - t0)},
        )
