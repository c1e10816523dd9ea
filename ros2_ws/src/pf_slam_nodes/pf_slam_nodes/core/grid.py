"""Log-odds occupancy grid with vectorised ray tracing.

Conventions (ROS ``nav_msgs/OccupancyGrid``): ``array[row, col]`` with ``row`` along +y and
``col`` along +x; ``origin`` = world ``(x, y)`` of the outer corner of cell ``(0, 0)``; cell
``(row, col)`` covers ``[ox + col*res, ox + (col+1)*res) x [oy + row*res, oy + (row+1)*res)``.
Cell indices returned by :meth:`LogOddsGrid.world_to_cell` are ``[..., 0] = col (x)`` and
``[..., 1] = row (y)``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Optional, Tuple

import numpy as np

from .config import GridConfig
from .geometry import compose

#: ``(row_min, row_max, col_min, col_max)``, half-open ``[min, max)``.
Bounds = Tuple[int, int, int, int]


def _world_to_cell(xy: np.ndarray, origin: np.ndarray, resolution: float) -> np.ndarray:
    xy = np.asarray(xy, dtype=np.float64)
    return np.floor((xy - origin) / resolution).astype(np.int64)


@dataclasses.dataclass(frozen=True)
class OccupancyMap:
    """An int8 occupancy grid as received over ROS (``nav_msgs/OccupancyGrid``).

    Attributes
    ----------
    data : numpy.ndarray
        ``(H, W)`` int8, -1 unknown, 0..100 occupancy probability in percent.
    resolution : float
        Cell size (m).
    origin : numpy.ndarray
        ``(2,)`` world ``(x, y)`` of the corner of cell (0, 0) (m).
    """

    data: np.ndarray
    resolution: float
    origin: np.ndarray

    @property
    def height(self) -> int:
        """Number of rows (y)."""
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        """Number of columns (x)."""
        return int(self.data.shape[1])

    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """World ``(..., 2)`` -> int64 cell indices ``(..., 2)`` as ``[col, row]``."""
        return _world_to_cell(xy, self.origin, self.resolution)


def from_occupancy(data: np.ndarray, resolution: float, origin) -> OccupancyMap:
    """Wrap int8 OccupancyGrid data (e.g. from a ROS message) for correlation.

    Parameters
    ----------
    data : numpy.ndarray
        ``(H, W)`` int8 (a flat message array must be reshaped to ``(height, width)`` first).
    resolution : float
        Cell size (m).
    origin : array_like
        ``(2,)`` (or longer; only x, y are used) world position of cell (0, 0)'s corner (m).
        The map origin's orientation must be identity.

    Returns
    -------
    OccupancyMap
        Pass to :func:`pf_slam_nodes.core.correlation.build_likelihood_field_from_map`.
    """
    arr = np.asarray(data)
    if arr.ndim != 2:
        raise ValueError(f"data must be 2-D (H, W), got shape {arr.shape}")
    if not (math.isfinite(resolution) and resolution > 0):
        raise ValueError(f"resolution must be > 0, got {resolution!r}")
    o = np.asarray(origin, dtype=np.float64).reshape(-1)[:2].copy()
    return OccupancyMap(arr.astype(np.int8, copy=False), float(resolution), o)


def grid_geometry(cfg: GridConfig, center_xy: Optional[np.ndarray] = None) -> tuple[int, int, np.ndarray]:
    """``(height, width, origin_xy)`` of the grid for a config (centred on ``center_xy`` unless
    the config fixes the origin). The correlator uses it to mirror the mapper's grid."""
    res = float(cfg.resolution_m)
    width = int(math.ceil(cfg.size_x_m / res - 1e-9))
    height = int(math.ceil(cfg.size_y_m / res - 1e-9))
    if cfg.origin_x_m is not None:
        origin = np.array([cfg.origin_x_m, cfg.origin_y_m], dtype=np.float64)
    else:
        c = np.zeros(2) if center_xy is None else np.asarray(center_xy, dtype=np.float64).reshape(-1)[:2]
        origin = c - 0.5 * res * np.array([width, height], dtype=np.float64)
    return height, width, origin


def _occupancy_values(log_odds: np.ndarray) -> np.ndarray:
    """float32 log-odds -> nav_msgs/OccupancyGrid int8: -1 where 0 (unknown), else
    ``round(100 / (1 + exp(-l)))``."""
    out = np.rint(100.0 / (1.0 + np.exp(-log_odds, dtype=np.float32))).astype(np.int8)
    out[log_odds == 0] = -1
    return out


class LogOddsGrid:
    """One log-odds occupancy grid updated by ray tracing.

    Parameters
    ----------
    cfg : GridConfig
    center_xy : array_like, optional
        ``(2,)`` world point the grid is centred on when ``cfg.origin_x_m`` is None
        (the reference loop passes the first pose). Default ``(0, 0)``.

    Attributes
    ----------
    log_odds : numpy.ndarray
        ``(H, W)`` float32, 0 = unknown.
    resolution : float
    origin : numpy.ndarray
        ``(2,)`` float64 world ``(x, y)`` of the corner of cell (0, 0).
    width, height : int
        Columns (x) and rows (y).
    """

    def __init__(self, cfg: GridConfig, center_xy: Optional[np.ndarray] = None) -> None:
        self.cfg = cfg
        self.resolution = float(cfg.resolution_m)
        self.height, self.width, self.origin = grid_geometry(cfg, center_xy)
        self.log_odds = np.zeros((self.height, self.width), dtype=np.float32)
        self._touched: Optional[list[int]] = None  # [rmin, rmax, cmin, cmax) of written cells
        #: flat indices (row * width + col, may repeat) written by the last :meth:`integrate_scan`
        self.last_touched_idx = np.zeros(0, dtype=np.int64)
        self.last_touched_bounds: Optional[Bounds] = None  # bounds of last_touched_idx

    # ------------------------------------------------------------------ geometry
    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """World points ``(..., 2)`` (m) -> int64 cell indices ``(..., 2)`` as ``[col, row]``."""
        return _world_to_cell(xy, self.origin, self.resolution)

    def cell_to_world(self, cells: np.ndarray) -> np.ndarray:
        """Cell indices ``(..., 2)`` ``[col, row]`` -> world ``(x, y)`` of the cell centres (m)."""
        return self.origin + (np.asarray(cells, dtype=np.float64) + 0.5) * self.resolution

    def in_bounds(self, cells: np.ndarray) -> np.ndarray:
        """Bool ``(...)``: whether cell indices ``(..., 2)`` ``[col, row]`` lie in the grid."""
        c = np.asarray(cells)
        return (c[..., 0] >= 0) & (c[..., 0] < self.width) & (c[..., 1] >= 0) & (c[..., 1] < self.height)

    @property
    def touched_bounds(self) -> Optional[Bounds]:
        """``(row_min, row_max, col_min, col_max)`` (half-open) of all cells written so far, or None."""
        return None if self._touched is None else tuple(self._touched)  # type: ignore[return-value]

    def window_bounds(self, center_xy: np.ndarray, half_size_m: float) -> Optional[Bounds]:
        """Bounds of the square window around ``center_xy`` intersected with the written area.

        Returns None when the intersection is empty.
        """
        if self._touched is None:
            return None
        c = self.world_to_cell(np.asarray(center_xy, dtype=np.float64)[:2])
        h = int(math.ceil(half_size_m / self.resolution))
        r0 = max(int(c[1]) - h, self._touched[0])
        r1 = min(int(c[1]) + h + 1, self._touched[1])
        c0 = max(int(c[0]) - h, self._touched[2])
        c1 = min(int(c[0]) + h + 1, self._touched[3])
        if r0 >= r1 or c0 >= c1:
            return None
        return (r0, r1, c0, c1)

    # ------------------------------------------------------------------ update
    def trace_scan(
        self,
        pose: np.ndarray,
        ranges: np.ndarray,
        angles: np.ndarray,
        sensor_offset: Optional[np.ndarray] = None,
        range_min_m: float = 0.0,
        range_max_m: float = math.inf,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Flat indices of the free and hit cells of one scan (no grid change).

        Parameters
        ----------
        pose : numpy.ndarray
            ``(3,)`` robot pose in the map frame.
        ranges, angles : numpy.ndarray
            ``(B,)`` ranges (m; inf/NaN allowed) and beam angles (rad) in the sensor frame.
        sensor_offset : numpy.ndarray, optional
            ``(3,)`` sensor pose in the robot frame.
        range_min_m, range_max_m : float
            Sensor limits (the scan's ``range_min`` / ``range_max``): beams outside them, NaN
            or ``-inf`` are ignored (REP 117: not a measurement, neither a hit nor free space);
            ``+inf`` is "no return" (free space up to ``range_max_usable_m``).

        Returns
        -------
        free_idx : numpy.ndarray
            int64 flat indices (row * width + col) of cells traversed by beams (may repeat).
        hit_idx : numpy.ndarray
            int64 flat indices of beam endpoint cells (may repeat).
        """
        pose = np.asarray(pose, dtype=np.float64).reshape(3)
        if sensor_offset is not None:
            pose = compose(pose, np.asarray(sensor_offset, dtype=np.float64).reshape(3))
        r = np.asarray(ranges, dtype=np.float64).reshape(-1)
        a = np.asarray(angles, dtype=np.float64).reshape(-1)
        if r.shape != a.shape:
            raise ValueError(f"ranges and angles must have the same length, got {r.shape} and {a.shape}")
        usable = float(self.cfg.range_max_usable_m)
        with np.errstate(invalid="ignore"):
            valid = ~np.isnan(r) & (r >= range_min_m) & (r > 0.0) & ((r <= range_max_m) | (r == np.inf))
            is_hit = valid & np.isfinite(r) & (r <= usable)
        r = np.where(is_hit, r, usable)[valid]
        a = a[valid]
        is_hit = is_hit[valid]
        res = self.resolution
        # continuous cell coordinates of the sensor and the beam ends
        sx = (pose[0] - self.origin[0]) / res
        sy = (pose[1] - self.origin[1]) / res
        reach = usable / res + 1.0  # no traced beam is longer than range_max_usable_m
        if not (-reach <= sx <= self.width + reach and -reach <= sy <= self.height + reach):
            empty = np.zeros(0, dtype=np.int64)  # NaN pose, or too far to touch the grid: the
            return empty, empty  # int casts below would be undefined for such coordinates
        ang = pose[2] + a
        ex = sx + r * np.cos(ang) / res
        ey = sy + r * np.sin(ang) / res
        # DDA: one sample per cell along the major axis; endpoint included only for no-hit beams
        n = np.maximum(np.ceil(np.maximum(np.abs(ex - sx), np.abs(ey - sy))).astype(np.int64), 1)
        counts = n + (~is_hit).astype(np.int64)
        total = int(counts.sum())
        beam = np.repeat(np.arange(r.size), counts)
        start = np.cumsum(counts) - counts
        k = np.arange(total, dtype=np.int64) - np.repeat(start, counts)
        t = k / n[beam]
        fx = np.floor(sx + t * (ex[beam] - sx)).astype(np.int64)
        fy = np.floor(sy + t * (ey[beam] - sy)).astype(np.int64)
        ok = (fx >= 0) & (fx < self.width) & (fy >= 0) & (fy < self.height)
        free_idx = fy[ok] * self.width + fx[ok]
        hx = np.floor(ex[is_hit]).astype(np.int64)
        hy = np.floor(ey[is_hit]).astype(np.int64)
        okh = (hx >= 0) & (hx < self.width) & (hy >= 0) & (hy < self.height)
        hit_idx = hy[okh] * self.width + hx[okh]
        return free_idx, hit_idx

    def integrate_scan(
        self,
        pose: np.ndarray,
        ranges: np.ndarray,
        angles: np.ndarray,
        sensor_offset: Optional[np.ndarray] = None,
        range_min_m: float = 0.0,
        range_max_m: float = math.inf,
    ) -> None:
        """Integrate one scan taken at ``pose`` (see :meth:`trace_scan` for the parameters).

        Each cell is updated at most once per scan: traversed cells get ``log_odds_miss``, beam
        endpoint cells get ``log_odds_hit`` (a hit wins over a traversal by another beam); beams
        without return (``+inf``) or longer than ``range_max_usable_m`` mark free space up to
        ``range_max_usable_m`` and no hit; finite beams beyond ``range_max_m`` are ignored. Values are clipped to ``[clip_min, clip_max]``; cells
        outside the grid are never written.
        """
        free_idx, hit_idx = self.trace_scan(pose, ranges, angles, sensor_offset, range_min_m, range_max_m)
        flat = self.log_odds.reshape(-1)
        cfg = self.cfg
        hit_before = flat[hit_idx]
        # fancy-index assignment writes repeated indices once -> one update per cell per scan
        flat[free_idx] = np.maximum(flat[free_idx] + np.float32(cfg.log_odds_miss), np.float32(cfg.clip_min))
        flat[hit_idx] = np.minimum(hit_before + np.float32(cfg.log_odds_hit), np.float32(cfg.clip_max))
        allidx = np.concatenate([free_idx, hit_idx])
        self.last_touched_idx = allidx
        self.last_touched_bounds = None
        if allidx.size:
            rows = allidx // self.width
            cols = allidx - rows * self.width
            b = [int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1]
            self.last_touched_bounds = tuple(b)
            if self._touched is None:
                self._touched = b
            else:
                t = self._touched
                self._touched = [min(t[0], b[0]), max(t[1], b[1]), min(t[2], b[2]), max(t[3], b[3])]

    # ------------------------------------------------------------------ export
    def _crop(self, bounds: Optional[Bounds]) -> np.ndarray:
        if bounds is None:
            return self.log_odds
        r0, r1, c0, c1 = bounds
        return self.log_odds[r0:r1, c0:c1]

    def occupancy(self, bounds: Optional[Bounds] = None) -> np.ndarray:
        """nav_msgs/OccupancyGrid data.

        Parameters
        ----------
        bounds : tuple, optional
            ``(row_min, row_max, col_min, col_max)`` crop; default the whole grid.

        Returns
        -------
        numpy.ndarray
            ``(H, W)`` int8: -1 where ``log_odds == 0`` (unknown), else ``round(100 * p)`` with
            ``p = 1 / (1 + exp(-log_odds))``.
        """
        return _occupancy_values(self._crop(bounds))

    def occupancy_at(self, flat_idx: np.ndarray) -> np.ndarray:
        """:meth:`occupancy` values of the cells at flat indices ``(K,)`` -> ``(K,)`` int8."""
        return _occupancy_values(self.log_odds.reshape(-1)[flat_idx])

    @staticmethod
    def occupied_limit(occupied_threshold: int) -> np.float32:
        """Smallest log-odds whose occupancy value rounds to ``>= occupied_threshold``."""
        if not 1 <= occupied_threshold <= 100:
            raise ValueError(f"occupied_threshold must be in [1, 100], got {occupied_threshold!r}")
        p = (occupied_threshold - 0.5) / 100.0
        return np.float32(math.log(p / (1.0 - p))) if p < 1.0 else np.float32(np.inf)

    def occupied_mask(self, occupied_threshold: int, bounds: Optional[Bounds] = None) -> np.ndarray:
        """Bool mask equal to ``occupancy(bounds) >= occupied_threshold``, computed in log-odds.

        Cheaper than :meth:`occupancy` (no exp); identical except for values within float32
        rounding of the rounding boundary.
        """
        limit = self.occupied_limit(occupied_threshold)
        lo = self._crop(bounds)
        return (lo >= limit) & (lo != 0)

    def occupied_at(self, flat_idx: np.ndarray, occupied_threshold: int) -> np.ndarray:
        """:meth:`occupied_mask` evaluated at flat cell indices only."""
        lo = self.log_odds.reshape(-1)[flat_idx]
        return (lo >= self.occupied_limit(occupied_threshold)) & (lo != 0)

    def bounds_origin(self, bounds: Optional[Bounds]) -> np.ndarray:
        """World ``(x, y)`` of the corner of the first cell of ``bounds`` (m)."""
        if bounds is None:
            return self.origin.copy()
        return self.origin + self.resolution * np.array([bounds[2], bounds[0]], dtype=np.float64)

    def to_occupancy_map(self, bounds: Optional[Bounds] = None) -> OccupancyMap:
        """The (cropped) grid as an :class:`OccupancyMap` (what a ROS subscriber would get)."""
        return OccupancyMap(self.occupancy(bounds), self.resolution, self.bounds_origin(bounds))
