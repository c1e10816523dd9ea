"""The odometry's translation scale measured between two scans (``correlation.odom_scale``).

A wheel-diameter calibration error scales every odometry increment by the same factor. Two scans
taken ``baseline_m`` apart see the same structure; matching them against each other measures how
far the vehicle really moved between them, independently of the map the filter builds (a match
against that map follows the odometry's own scale wherever the map does, which is along every
street without much along-track structure).

The match is a grid search of the along-track offset (and a small cross-track one) of the
odometry's relative pose, on a *symmetric* cost: the new scan's points on the old scan's
likelihood field plus the old scan's points on the new scan's field. Each one-way cost is biased
where one scan saw structure the other could not (a tilted lidar cuts a building lower from
nearer, a range limit ends a wall): the new scan's points on the old field slide back, the old
scan's points on the new field slide forward; the sum does neither. Only points both scans could
see are used: the new scan's within ``reach_m`` of the old pose, the old scan's ahead of the new
pose and within ``reach_m`` of it (``reach_m``: the match range less ``REACH_MARGIN_M``, so that
the other scan saw that far too). A pair is kept only where the summed cost's profile along the
street has a clear minimum inside the window (its second difference above ``min_curvature``):
streets without along-track structure measure nothing instead of the prediction.

ROS-free, no file I/O, vectorised over the candidate offsets.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass

import cv2
import numpy as np

from .config import CorrelationConfig
from .correlation import match_cost
from .geometry import relative_pose
from .likelihood import LikelihoodField, build_likelihood_field_from_mask
from .scan import transform_points

#: candidate offsets: a coarse pass over the whole window, then a fine one around its best
COARSE_STEP_M = 0.1
FINE_STEP_M = 0.02
CROSS_HALF_M = 0.3
#: points of a scan used: within the match range less this of the other scan's pose (m)
REACH_MARGIN_M = 10.0
#: fewer points in either scan: no pair
MIN_POINTS = 30
#: scans kept for pairing, at most
MAX_PAIR_SCANS = 64
ORIGIN = np.zeros(3)  # relative_pose(p, ORIGIN) is the inverse of p


@dataclass(frozen=True)
class PairScan:
    """One scan kept for pairing: its odometry pose (3,), its points in the vehicle frame (M, 2)
    and their likelihood field (vehicle frame)."""

    odom: np.ndarray
    points: np.ndarray
    field: LikelihoodField


def pair_scan(
    odom: np.ndarray, points: np.ndarray, resolution: float, cfg: CorrelationConfig, fill_m: float = 0.0
) -> PairScan | None:
    """A scan ready for pairing (its field over the points' bounding box), or None if it has fewer
    than ``MIN_POINTS`` points. ``fill_m`` > 0: the points are in beam order and consecutive ones
    at most this far apart (m) are joined by a line in the field, so that a wall is a wall however
    sparsely its beam ends fall (a field of dots with gaps pulls the scans' dense near parts
    together: a bare corridor then measures a short travel)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if pts.shape[0] < MIN_POINTS:
        return None
    margin = cfg.max_distance_m + resolution
    lo = pts.min(axis=0) - margin
    w, h = np.ceil((pts.max(axis=0) + margin - lo) / resolution).astype(int)
    mask = np.zeros((h, w), dtype=np.uint8)
    cells = np.floor((pts - lo) / resolution).astype(np.int64)
    mask[cells[:, 1], cells[:, 0]] = 1
    if fill_m > 0.0:
        near = np.hypot(*np.diff(pts, axis=0).T) <= fill_m
        segs = np.stack([cells[:-1][near], cells[1:][near]], axis=1).astype(np.int32)
        cv2.polylines(mask, list(segs), False, 1)
    field = build_likelihood_field_from_mask(mask.astype(bool), resolution, lo, cfg)
    return PairScan(np.asarray(odom, dtype=np.float64).reshape(3).copy(), pts, field)


def _profile(rel, u, v, along, cross, new_pts, old_pts, old: PairScan, new: PairScan) -> np.ndarray:
    """``(len(along), len(cross))`` symmetric cost of the candidates ``rel + a u + c v``."""
    a, c = np.meshgrid(along, cross, indexing="ij")
    cands = np.repeat(rel[None, :], a.size, axis=0)
    cands[:, :2] += a.reshape(-1, 1) * u + c.reshape(-1, 1) * v
    cost = match_cost(cands, new_pts, old.field)  # new scan on the old field
    cost += match_cost(relative_pose(cands, ORIGIN), old_pts, new.field)  # old on the new: inverse poses
    return cost.reshape(a.shape)


def pair_travel(
    old: PairScan,
    new: PairScan,
    max_error: float,
    min_curvature: float,
    range_max_m: float,
    reach_margin_m: float = REACH_MARGIN_M,
) -> tuple[float, float] | None:
    """``(odometry travel, measured travel)`` between two scans (m, the chord), or None where the
    pair measures nothing: the scans too close, too few points both can see, or no clear minimum
    of the cost along the street within ``+- 2 max_error`` of the travel (at least 0.2 m).
    ``range_max_m``: the range the scans were cut at; each scan's points within that less
    ``reach_margin_m`` of the other's pose are used."""
    rel = relative_pose(old.odom, new.odom)  # the new pose in the old scan's frame, by odometry
    dist = float(math.hypot(rel[0], rel[1]))
    if dist < 1.0:
        return None
    reach = range_max_m - reach_margin_m
    u = rel[:2] / dist
    v = np.array([-u[1], u[0]])
    in_old = transform_points(new.points, rel)
    new_pts = new.points[np.hypot(in_old[:, 0], in_old[:, 1]) <= reach]
    in_new = transform_points(old.points, relative_pose(rel, ORIGIN))
    old_pts = old.points[(in_new[:, 0] >= 1.0) & (np.hypot(in_new[:, 0], in_new[:, 1]) <= reach)]
    if new_pts.shape[0] < MIN_POINTS or old_pts.shape[0] < MIN_POINTS:
        return None
    half = max(0.2, 2.0 * max_error * dist)
    half = COARSE_STEP_M * math.ceil(half / COARSE_STEP_M)
    along = np.arange(-half, half + 1e-9, COARSE_STEP_M)
    cross = np.arange(-CROSS_HALF_M, CROSS_HALF_M + 1e-9, COARSE_STEP_M)
    coarse = _profile(rel, u, v, along, cross, new_pts, old_pts, old, new)
    i, j = np.unravel_index(int(np.argmin(coarse)), coarse.shape)
    if i == 0 or i == along.size - 1:
        return None
    fine_a = along[i] + np.arange(-5, 6) * FINE_STEP_M
    fine_c = cross[j] + np.array([-0.5, 0.0, 0.5]) * COARSE_STEP_M
    prof = _profile(rel, u, v, fine_a, fine_c, new_pts, old_pts, old, new).min(axis=1)
    k = int(np.argmin(prof))
    if k == 0 or k == prof.size - 1:
        return None
    c0, c1, c2 = prof[k - 1], prof[k], prof[k + 1]
    second = c0 - 2.0 * c1 + c2
    if second / FINE_STEP_M**2 <= min_curvature:
        return None
    offset = fine_a[k] + 0.5 * (c0 - c2) / second * FINE_STEP_M
    return dist, dist + float(offset)


class ScalePairs:
    """The recent scans kept for pairing, and the pairing: :meth:`measure` pairs a scan with the
    newest kept one at least ``odom_scale_baseline_m`` of odometry back, then keeps it and forgets
    those no longer needed. Its state is its own (nothing of the filter's), so that it can live in
    a worker process (core/deferred.py)."""

    def __init__(self, resolution: float, cfg: CorrelationConfig) -> None:
        self.resolution = float(resolution)
        self.cfg = cfg
        self.kept: collections.deque[PairScan] = collections.deque()

    def measure(self, odom: np.ndarray, points: np.ndarray) -> tuple[float, float] | None:
        """A scan (its odometry pose (3,), its points in the vehicle frame, all of them): the
        ``(odometry travel, measured travel)`` of its pair (:func:`pair_travel`), or None."""
        cfg = self.cfg
        scan = pair_scan(odom, points, self.resolution, cfg)
        if scan is None:
            return None
        got = None
        far = [math.hypot(*(p.odom[:2] - scan.odom[:2])) >= cfg.odom_scale_baseline_m for p in self.kept]
        if any(far):
            last = len(far) - 1 - far[::-1].index(True)  # the newest kept scan far enough back
            got = pair_travel(self.kept[last], scan, cfg.odom_scale_max, cfg.odom_scale_min_curvature, cfg.range_max_m)
            while len(far) > 1 and far[1]:  # the next one is far enough for the next scan too
                self.kept.popleft()
                far.pop(0)
        self.kept.append(scan)
        while len(self.kept) > MAX_PAIR_SCANS:
            self.kept.popleft()
        return got
