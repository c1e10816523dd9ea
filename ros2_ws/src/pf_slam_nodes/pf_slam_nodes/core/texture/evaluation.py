"""Measurements on a real pair (:func:`measure_stereo_pair`) and the comparison of a texture
with a ground-truth floor texture (:func:`visible_ground_mask`, :func:`colour_error`); arrays
in, numbers out."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .config import TextureConfig
from .ground import Plane
from .rig import StereoRig
from .texturer import StereoTexturer

# --------------------------------------------------------------------------------------------
# measurement on one real pair


def road_region_mask(
    rig: StereoRig, ahead_m: tuple[float, float] = (5.0, 15.0), half_width_m: float = 1.75, rectified_here: bool = True
) -> np.ndarray:
    """Bool ``(H, W)`` rectified-image mask of the ego-lane road region.

    The pixels whose ray meets the nominal ground (vehicle ``z = 0``) between ``ahead_m``
    metres ahead of the camera and within ``half_width_m`` of the camera's line (a 3.5 m
    lane), inside the valid rectified area.
    """
    r_vc, t = rig.rect_to_vehicle(rectified_here)
    vv, uu = np.mgrid[0 : rig.height, 0 : rig.width]
    ray = rig.pixel_rays(uu.ravel(), vv.ravel()) @ r_vc.T
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -t[2] / ray[:, 2]
    gx = ray[:, 0] * s
    gy = ray[:, 1] * s
    m = (s > 0) & (gx >= ahead_m[0]) & (gx <= ahead_m[1]) & (np.abs(gy) <= half_width_m)
    m = m.reshape(rig.height, rig.width)
    if rectified_here:
        m &= rig.rectified_valid("left")
    return m


@dataclasses.dataclass
class PairMeasurement:
    """Disparity density and road plane of one stereo pair (:func:`measure_stereo_pair`).

    Attributes
    ----------
    road_density : float
        Valid-disparity fraction over the road region (:func:`road_region_mask`).
    road_inlier_fraction : float
        Fraction of the road region whose stereo point is within ``ransac_tol_m`` of the plane.
    processed_density : float
        Valid-disparity fraction over all processed rows.
    plane : Plane
        Fitted road plane (vehicle frame).
    plane_fitted : bool
    camera_height_m : float
        Distance of the left camera centre from the plane (m).
    normal_vehicle : (3,)
        Plane normal in the vehicle frame.
    normal_camera : (3,)
        The same in the rectified left camera frame (x right, y down, z forward).
    tilt_deg : float
        Angle between the normal and the vehicle z (deg).
    rectified_here : bool
    disparity_ms : float
        Time of the disparity step (ms).
    disparity_full : (H, W) float32
        Disparity at full resolution (nearest), NaN invalid / unprocessed.
    road_mask : (H, W) bool
    """

    road_density: float
    road_inlier_fraction: float
    processed_density: float
    plane: Plane
    plane_fitted: bool
    camera_height_m: float
    normal_vehicle: np.ndarray
    normal_camera: np.ndarray
    tilt_deg: float
    rectified_here: bool
    disparity_ms: float
    disparity_full: np.ndarray
    road_mask: np.ndarray

    def as_dict(self) -> dict:
        return {
            "road_density": round(self.road_density, 4),
            "road_inlier_fraction": round(self.road_inlier_fraction, 4),
            "processed_density": round(self.processed_density, 4),
            "plane_fitted": self.plane_fitted,
            "camera_height_m": round(self.camera_height_m, 4),
            "normal_vehicle": [round(float(v), 5) for v in self.normal_vehicle],
            "normal_camera": [round(float(v), 5) for v in self.normal_camera],
            "tilt_deg": round(self.tilt_deg, 3),
            "rectified_here": self.rectified_here,
            "disparity_ms": round(self.disparity_ms, 1),
        }


def measure_stereo_pair(
    left: np.ndarray,
    right: np.ndarray,
    rig: StereoRig,
    cfg: TextureConfig | None = None,
    encoding: str = "bayer_rggb8",
) -> PairMeasurement:
    """Disparity density on the ego-lane road region and the fitted road plane of one pair."""
    cfg = cfg or TextureConfig()
    tex = StereoTexturer(rig, cfg)
    res = tex.process(left, right, None, encoding)
    k = cfg.downscale
    full = np.full((rig.height, rig.width), np.nan, np.float32)
    up = np.repeat(np.repeat(res.disparity, k, axis=0), k, axis=1)
    full[res.first_row : res.first_row + up.shape[0], : up.shape[1]] = up
    road = road_region_mask(rig, rectified_here=res.rectified_here)
    valid = np.isfinite(full)
    dens = float(valid[road].mean()) if road.any() else 0.0
    # road inliers: stereo point of each road pixel within ransac_tol_m of the plane
    vv, uu = np.nonzero(road & valid)
    z = rig.f * rig.baseline_m / (full[vv, uu].astype(np.float64) - rig.cx_offset)
    r_vc, t = rig.rect_to_vehicle(res.rectified_here)
    p = (rig.pixel_rays(uu, vv) * z[:, None]) @ r_vc.T + t
    inl = float((np.abs(res.plane.height_of(p)) < cfg.ransac_tol_m).sum() / max(road.sum(), 1))
    n = res.plane.normal
    height = float(abs(n @ t + res.plane.c))
    return PairMeasurement(
        dens,
        inl,
        res.valid_fraction,
        res.plane,
        res.plane_fitted,
        height,
        n.copy(),
        r_vc.T @ n,
        res.plane.tilt_deg,
        res.rectified_here,
        res.timings_ms["disparity"],
        full,
        road,
    )


# --------------------------------------------------------------------------------------------
# evaluation against a ground-truth floor texture


def visible_ground_mask(
    poses: np.ndarray,
    rig: StereoRig,
    cfg: TextureConfig,
    resolution: float,
    origin_xy: np.ndarray,
    shape: tuple[int, int],
    rectified_here: bool = False,
) -> np.ndarray:
    """Cells (``OccupancyGrid`` layout) of the ground the left camera saw within the range box.

    A cell counts when its centre (on ``z = 0``) is inside the range box of
    :class:`TextureConfig` for one of ``poses`` (``(K, 3)``, the vehicle at each pair) and
    projects into the left image below ``first_row``. Occlusion is not modelled.
    """
    h, w = shape
    mask = np.zeros((h, w), dtype=bool)
    r_vc, t = rig.rect_to_vehicle(rectified_here)
    v_min = StereoTexturer(rig, cfg).first_row
    reach = math.hypot(cfg.max_range_m + abs(t[0]), cfg.max_lateral_m + abs(t[1]))
    for x, y, th in np.asarray(poses, dtype=np.float64).reshape(-1, 3):
        c0 = max(int((x - reach - origin_xy[0]) / resolution), 0)
        c1 = min(int((x + reach - origin_xy[0]) / resolution) + 1, w)
        r0 = max(int((y - reach - origin_xy[1]) / resolution), 0)
        r1 = min(int((y + reach - origin_xy[1]) / resolution) + 1, h)
        if c0 >= c1 or r0 >= r1:
            continue
        gx = origin_xy[0] + (np.arange(c0, c1) + 0.5) * resolution
        gy = origin_xy[1] + (np.arange(r0, r1) + 0.5) * resolution
        dx = gx[None, :] - x
        dy = gy[:, None] - y
        c, s = math.cos(th), math.sin(th)
        vx = c * dx + s * dy  # vehicle frame
        vy = -s * dx + c * dy
        ahead = vx - t[0]
        box = (ahead >= cfg.min_range_m) & (ahead <= cfg.max_range_m) & (np.abs(vy - t[1]) <= cfg.max_lateral_m)
        pv = np.stack([vx, vy, np.zeros_like(vx)], axis=-1) - t
        q = pv @ r_vc  # camera frame (r_vc^T p)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = rig.cx + rig.f * q[..., 0] / q[..., 2]
            v = rig.cy + rig.fy * q[..., 1] / q[..., 2]
        seen = box & (q[..., 2] > 0) & (u >= 0) & (u <= rig.width - 1) & (v >= v_min) & (v <= rig.height - 1)
        mask[r0:r1, c0:c1] |= seen
    return mask


def colour_error(rgb: np.ndarray, covered: np.ndarray, gt_rgb: np.ndarray, visible: np.ndarray | None = None) -> dict:
    """Compare a texture with the ground truth in the same geometry.

    Returns ``mean_abs_rgb_error`` (mean over the cells both cover and the three channels,
    0..255), ``median_abs_rgb_error``, ``cells_coloured``, and when ``visible`` is given
    ``cells_visible`` and ``coverage`` (= coloured and visible / visible).
    """
    cov = np.asarray(covered, dtype=bool)
    err = np.abs(rgb[cov].astype(np.float64) - gt_rgb[cov].astype(np.float64)).mean(axis=1)
    out = {
        "cells_coloured": int(cov.sum()),
        "mean_abs_rgb_error": float(err.mean()) if err.size else float("nan"),
        "median_abs_rgb_error": float(np.median(err)) if err.size else float("nan"),
    }
    if visible is not None:
        vis = np.asarray(visible, dtype=bool)
        out["cells_visible"] = int(vis.sum())
        out["coverage"] = float((cov & vis).sum() / max(int(vis.sum()), 1))
    return out
