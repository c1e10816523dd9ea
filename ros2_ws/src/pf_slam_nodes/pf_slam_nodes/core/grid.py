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

import cv2
import numpy as np

from .config import GridConfig
from .geometry import compose
from .scan import line_incidence, on_line

#: ``(row_min, row_max, col_min, col_max)``, half-open ``[min, max)``.
Bounds = tuple[int, int, int, int]

# |sensor position| (cells from the initial grid) beyond which a scan is not traced
_MAX_COORD = float(2**40)
# the 4-neighbours of a cell (not the cell): the kernel of LogOddsGrid.matching_patch
_CROSS = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], dtype=np.uint8)


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
        Pass to :func:`pf_slam_nodes.core.likelihood.build_likelihood_field_from_map`.
    """
    arr = np.asarray(data)
    if arr.ndim != 2:
        raise ValueError(f"data must be 2-D (H, W), got shape {arr.shape}")
    if not (math.isfinite(resolution) and resolution > 0):
        raise ValueError(f"resolution must be > 0, got {resolution!r}")
    o = np.asarray(origin, dtype=np.float64).reshape(-1)[:2].copy()
    return OccupancyMap(arr.astype(np.int8, copy=False), float(resolution), o)


def grid_geometry(cfg: GridConfig, center_xy: np.ndarray | None = None) -> tuple[int, int, np.ndarray]:
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


#: Edge (cells) of the tiles a grid grows by.
TILE_CELLS = 256


def growth_plan(
    height: int, width: int, need: Bounds, max_cells: int, tile: int = TILE_CELLS
) -> tuple[int, int, int, int] | None:
    """Cells to add ``(top, bottom, left, right)`` (rows before row 0, rows after the last,
    columns before column 0, after the last) so that the rectangle ``need`` = ``(row_min,
    row_max, col_min, col_max)`` (half-open, in the grid's current cells) fits.

    Each side that must grow grows by whole tiles and by at least a quarter of the grid's
    extent on that axis (amortised: a grid grown over a path of length L is copied O(log L)
    times per axis, so the mean cost per scan does not depend on the map's size). Where that
    would exceed ``max_cells`` cells, only the tiles needed; where even those exceed it, no
    growth (``(0, 0, 0, 0)``). None when ``need`` already fits.
    """
    r0, r1, c0, c1 = need
    want = (max(0, -r0), max(0, r1 - height), max(0, -c0), max(0, c1 - width))
    if not any(want):
        return None

    def tiles(n: int, floor: int) -> int:
        return 0 if n <= 0 else tile * -(-max(n, floor) // tile)

    for quarter in (True, False):
        fh, fw = (height // 4, width // 4) if quarter else (0, 0)
        add = (tiles(want[0], fh), tiles(want[1], fh), tiles(want[2], fw), tiles(want[3], fw))
        if (height + add[0] + add[1]) * (width + add[2] + add[3]) <= max_cells:
            return add
    return (0, 0, 0, 0)


def grow_array(a: np.ndarray, add: tuple[int, int, int, int], fill) -> np.ndarray:
    """``a`` ``(H, W)`` inside a new ``(H + top + bottom, W + left + right)`` array of ``fill``."""
    top, bottom, left, right = add
    h, w = a.shape
    out = np.full((h + top + bottom, w + left + right), fill, dtype=a.dtype)
    out[top : top + h, left : left + w] = a
    return out


class LogOddsGrid:
    """One log-odds occupancy grid updated by ray tracing.

    Parameters
    ----------
    cfg : GridConfig
    center_xy : array_like, optional
        ``(2,)`` world point the grid is centred on when ``cfg.origin_x_m`` is None
        (the reference loop passes the first pose). Default ``(0, 0)``.

    The grid starts at the configured size and grows by whole tiles (:data:`TILE_CELLS`,
    :func:`growth_plan`) where :meth:`integrate_scan` reaches beyond it, up to ``cfg.max_cells``
    cells. Cells keep their place in the world when it grows: the lattice is that of the
    initial grid (``anchor``), and a point's cell is computed relative to it, so a grid that
    never grows computes exactly what a fixed grid does.

    Attributes
    ----------
    log_odds : numpy.ndarray
        ``(H, W)`` float32, 0 = unknown.
    resolution : float
    origin : numpy.ndarray
        ``(2,)`` float64 world ``(x, y)`` of the corner of cell (0, 0).
    anchor : numpy.ndarray
        ``(2,)`` the initial grid's origin; ``offset`` ``(2,)`` int64 ``[col, row]`` of the
        initial grid's cell (0, 0) in the current grid.
    width, height : int
        Columns (x) and rows (y).
    cells_beyond_bound : int
        Traced cells not written because the grid could not grow that far (``max_cells``).
    scans_beyond_bound : int
        Scans that had such cells.
    growths : int
        Times the grid grew.
    """

    def __init__(self, cfg: GridConfig, center_xy: np.ndarray | None = None) -> None:
        self.cfg = cfg
        self.resolution = float(cfg.resolution_m)
        self.height, self.width, self.origin = grid_geometry(cfg, center_xy)
        self.anchor = self.origin.copy()
        self.offset = np.zeros(2, dtype=np.int64)
        self.log_odds = np.zeros((self.height, self.width), dtype=np.float32)
        #: ``(H, W)`` float32 beam ends per cell (``cfg.peak_ratio > 0``, else None)
        self.hits = np.zeros_like(self.log_odds) if cfg.peak_ratio > 0 else None
        self.cells_beyond_bound = 0
        self.scans_beyond_bound = 0
        self.growths = 0
        #: ``(top, bottom, left, right)`` cells the last :meth:`integrate_scan` added, or None
        self.last_growth: tuple[int, int, int, int] | None = None
        self._touched: list[int] | None = None  # [rmin, rmax, cmin, cmax) of written cells
        #: flat indices (row * width + col, may repeat) written by the last :meth:`integrate_scan`
        self.last_touched_idx = np.zeros(0, dtype=np.int64)
        self.last_touched_bounds: Bounds | None = None  # bounds of last_touched_idx

    # ------------------------------------------------------------------ geometry
    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """World points ``(..., 2)`` (m) -> int64 cell indices ``(..., 2)`` as ``[col, row]``."""
        return _world_to_cell(xy, self.anchor, self.resolution) + self.offset

    def cell_to_world(self, cells: np.ndarray) -> np.ndarray:
        """Cell indices ``(..., 2)`` ``[col, row]`` -> world ``(x, y)`` of the cell centres (m)."""
        return self.anchor + (np.asarray(cells, dtype=np.float64) - self.offset + 0.5) * self.resolution

    @property
    def nbytes(self) -> int:
        """Bytes of the grid's arrays."""
        return int(self.log_odds.nbytes) + (0 if self.hits is None else int(self.hits.nbytes))

    def grow(self, add: tuple[int, int, int, int]) -> None:
        """Add ``(top, bottom, left, right)`` unknown rows / columns around the grid."""
        top, bottom, left, right = (int(v) for v in add)
        if not (top or bottom or left or right):
            return
        self.log_odds = grow_array(self.log_odds, (top, bottom, left, right), 0.0)
        if self.hits is not None:
            self.hits = grow_array(self.hits, (top, bottom, left, right), 0.0)
        self.height, self.width = self.log_odds.shape
        self.offset = self.offset + np.array([left, top], dtype=np.int64)
        self.origin = self.anchor - self.resolution * self.offset.astype(np.float64)
        if self._touched is not None:
            t = self._touched
            self._touched = [t[0] + top, t[1] + top, t[2] + left, t[3] + left]
        self.growths += 1

    def in_bounds(self, cells: np.ndarray) -> np.ndarray:
        """Bool ``(...)``: whether cell indices ``(..., 2)`` ``[col, row]`` lie in the grid."""
        c = np.asarray(cells)
        return (c[..., 0] >= 0) & (c[..., 0] < self.width) & (c[..., 1] >= 0) & (c[..., 1] < self.height)

    @property
    def touched_bounds(self) -> Bounds | None:
        """``(row_min, row_max, col_min, col_max)`` (half-open) of all cells written so far, or None."""
        return None if self._touched is None else tuple(self._touched)  # type: ignore[return-value]

    def window_bounds(self, center_xy: np.ndarray, half_size_m: float) -> Bounds | None:
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
        sensor_offset: np.ndarray | None = None,
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
            ``+inf`` is "no return" (free space up to ``range_max_usable_m`` or ``range_max_m``,
            the shorter).

        Returns
        -------
        free_idx : numpy.ndarray
            int64 flat indices (row * width + col) of cells traversed by beams (may repeat).
        hit_idx : numpy.ndarray
            int64 flat indices of beam endpoint cells (may repeat).
        """
        pose, r, a = _scan_arrays(pose, ranges, angles, sensor_offset)
        return self._beams(pose, r, a, range_min_m, range_max_m, flat=True)

    def _beams(
        self,
        pose: np.ndarray,
        r: np.ndarray,
        a: np.ndarray,
        range_min_m: float,
        range_max_m: float,
        flat: bool,
        usable_m: float | None = None,
    ):
        usable = float(self.cfg.range_max_usable_m if usable_m is None else usable_m)
        with np.errstate(invalid="ignore"):
            valid = ~np.isnan(r) & (r >= range_min_m) & (r > 0.0) & ((r <= range_max_m) | (r == np.inf))
            is_hit = valid & np.isfinite(r) & (r <= usable)
        # a beam without return saw nothing up to the sensor's range_max, nothing beyond it
        free_len = np.where(np.isinf(r), min(usable, range_max_m), usable)
        r = np.where(is_hit, r, free_len)[valid]
        a = a[valid]
        is_hit = is_hit[valid]
        cells = self._trace_cells(pose, r, a, is_hit)
        if not flat:
            return cells
        fx, fy, hx, hy = cells
        return self._flat(fx, fy), self._flat(hx, hy)

    def _trace_cells(self, pose: np.ndarray, r: np.ndarray, a: np.ndarray, is_hit: np.ndarray):
        """Cells ``[col, row]`` of the lattice of the initial grid (not clipped to the grid) that
        the valid beams traverse (``fx, fy``) and end in (``hx, hy``)."""
        res = self.resolution
        # continuous cell coordinates (initial grid's lattice) of the sensor and the beam ends
        sx = (pose[0] - self.anchor[0]) / res
        sy = (pose[1] - self.anchor[1]) / res
        if not (abs(sx) < _MAX_COORD and abs(sy) < _MAX_COORD):
            empty = np.zeros(0, dtype=np.int64)  # NaN pose, or too far for any grid: the int
            return empty, empty, empty, empty  # casts below would be undefined for such values
        ang = pose[2] + a
        ex = sx + r * np.cos(ang) / res
        ey = sy + r * np.sin(ang) / res
        # DDA: one sample per cell along the major axis; endpoint included only for no-hit beams
        n = np.maximum(np.ceil(np.maximum(np.abs(ex - sx), np.abs(ey - sy))).astype(np.int64), 1)
        counts = n + (~is_hit).astype(np.int64)
        spare = self.cfg.free_stop_cells  # cells before a hit beam's end its free trace leaves alone
        if self.cfg.graze_margin_m > 0 and is_hit.sum() >= 3:
            spare = np.maximum(spare, self._graze_cells(ex, ey, sx, sy, is_hit))
        if np.any(spare):
            counts = np.where(is_hit, np.maximum(n - spare, 0), counts)
        total = int(counts.sum())
        beam = np.repeat(np.arange(r.size), counts)
        start = np.cumsum(counts) - counts
        k = np.arange(total, dtype=np.int64) - np.repeat(start, counts)
        t = k / n[beam]
        fx = np.floor(sx + t * (ex[beam] - sx)).astype(np.int64)
        fy = np.floor(sy + t * (ey[beam] - sy)).astype(np.int64)
        hx = np.floor(ex[is_hit]).astype(np.int64)
        hy = np.floor(ey[is_hit]).astype(np.int64)
        if self.cfg.surface_fill_m > 0 and is_hit.sum() >= 4:
            lx, ly = self._surface_cells(ex, ey, is_hit)
            hx, hy = np.concatenate([hx, lx]), np.concatenate([hy, ly])
        return fx, fy, hx, hy

    def _surface_cells(self, ex: np.ndarray, ey: np.ndarray, is_hit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cells ``[col, row]`` on the segments between neighbouring beams' ends that lie on one
        smooth surface (``grid.surface_fill_m``): both beams hit, they are neighbours in the scan,
        the segment is at most ``surface_fill_m`` long and each end is collinear with its other
        neighbour (:func:`~.scan.on_line`), so an edge's range jump or clutter is never bridged. The
        segment is sampled every half cell; its end cells are the beams' own hit cells."""
        h = np.flatnonzero(is_hit)
        px, py = ex[h], ey[h]
        line = on_line(px, py)[0]
        tx, ty = np.diff(px), np.diff(py)
        length = np.hypot(tx, ty)
        seg = np.flatnonzero(
            line[:-1]
            & line[1:]
            & (np.diff(h) == 1)
            & (length > 1.0)
            & (length <= self.cfg.surface_fill_m / self.resolution)
        )
        if not seg.size:
            empty = np.zeros(0, dtype=np.int64)
            return empty, empty
        n = np.ceil(2.0 * length[seg]).astype(np.int64)
        j = np.repeat(seg, n)
        k = np.arange(int(n.sum()), dtype=np.int64) - np.repeat(np.cumsum(n) - n, n)
        t = (k + 0.5) / np.repeat(n, n)
        return np.floor(px[j] + t * tx[j]).astype(np.int64), np.floor(py[j] + t * ty[j]).astype(np.int64)

    def _graze_cells(self, ex: np.ndarray, ey: np.ndarray, sx: float, sy: float, is_hit: np.ndarray) -> np.ndarray:
        """Per beam, the cells before its end that its free trace leaves alone (``grid.graze_margin_m``).

        A beam that meets a surface at incidence ``a`` runs within one cell of that surface for its
        last ``1 / sin(a)`` cells and would clear the surface's own cells there: the walls and
        pillars that later rays graze fade from the map (a long corridor loses the walls ahead of
        the robot and the matches slide back). The surface is the line to the previous and to the
        next hit beam's end where the three ends lie on one line (within 5 degrees: a range jump at an
        edge, or clutter, is no surface); ``floor(1 / sin(a)) - 1`` cells are skipped (0 up to 30 degrees from the
        normal), at most ``graze_margin_m``."""
        h = np.flatnonzero(is_hit)
        _, inv_sin, _ = line_incidence(ex[h], ey[h], sx, sy)
        cells = np.floor(np.minimum(inv_sin, self.cfg.graze_margin_m / self.resolution + 1.0)).astype(np.int64) - 1
        out = np.zeros(is_hit.size, dtype=np.int64)
        out[h] = np.maximum(cells, 0)
        return out

    def _flat(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Flat indices of the lattice cells ``x, y`` inside the current grid (others dropped)."""
        x = x + self.offset[0]
        y = y + self.offset[1]
        ok = (x >= 0) & (x < self.width) & (y >= 0) & (y < self.height)
        return y[ok] * self.width + x[ok]

    def integrate_scan(
        self,
        pose: np.ndarray,
        ranges: np.ndarray,
        angles: np.ndarray,
        sensor_offset: np.ndarray | None = None,
        range_min_m: float = 0.0,
        range_max_m: float = math.inf,
        usable_m: float | None = None,
    ) -> None:
        """Integrate one scan taken at ``pose`` (see :meth:`trace_scan` for the parameters;
        ``usable_m``: this scan's ``range_max_usable_m`` if not the configured one).

        Each cell is updated at most once per scan: traversed cells get ``log_odds_miss``, beam
        endpoint cells get ``log_odds_hit`` (a hit wins over a traversal by another beam); beams
        longer than ``range_max_usable_m`` mark free space up to ``range_max_usable_m`` and no
        hit, beams without return (``+inf``) up to ``min(range_max_usable_m, range_max_m)``;
        finite beams beyond ``range_max_m`` are ignored. Values are clipped to ``[clip_min,
        clip_max]``; cells outside the grid are never written.
        """
        pose, r, a = _scan_arrays(pose, ranges, angles, sensor_offset)
        fx, fy, hx, hy = self._beams(pose, r, a, range_min_m, range_max_m, False, usable_m)
        self.last_growth = None
        if fx.size or hx.size:
            xs = np.concatenate([fx, hx]) + self.offset[0]
            ys = np.concatenate([fy, hy]) + self.offset[1]
            need = (int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1)
            add = growth_plan(self.height, self.width, need, int(self.cfg.max_cells))
            if add is not None and any(add):
                self.grow(add)
                self.last_growth = add
        free_idx, hit_idx = self._flat(fx, fy), self._flat(hx, hy)
        dropped = fx.size + hx.size - free_idx.size - hit_idx.size
        if dropped:
            self.cells_beyond_bound += int(dropped)
            self.scans_beyond_bound += 1
        flat = self.log_odds.reshape(-1)
        cfg = self.cfg
        hit_before = flat[hit_idx]
        # fancy-index assignment writes repeated indices once -> one update per cell per scan
        flat[free_idx] = np.maximum(flat[free_idx] + np.float32(cfg.log_odds_miss), np.float32(cfg.clip_min))
        flat[hit_idx] = np.minimum(hit_before + np.float32(cfg.log_odds_hit), np.float32(cfg.clip_max))
        if self.hits is not None and hit_idx.size:
            cells, count = np.unique(hit_idx, return_counts=True)
            self.hits.reshape(-1)[cells] += count.astype(np.float32)
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
    def matching_patch(self, occ: np.ndarray, bounds: Bounds) -> tuple[np.ndarray, Bounds]:
        """The scan matcher's view of the cells ``bounds`` that a change touched, from ``occ``, the
        grid's ``(H, W)`` int8 occupancy: a copy of the block and its bounds. With ``cfg.peak_ratio``
        the block grows by one cell (a cell's beam ends decide whether its neighbours are peaks),
        and a cell with fewer beam ends than ``peak_ratio`` times those of its 4-neighbour with the
        most is no surface to match (its value becomes at most 0)."""
        r0, r1, c0, c1 = bounds
        if self.hits is None:
            return np.array(occ[r0:r1, c0:c1], dtype=np.int8, copy=True), bounds
        r0, r1, c0, c1 = max(r0 - 1, 0), min(r1 + 1, self.height), max(c0 - 1, 0), min(c1 + 1, self.width)
        a0, a1, b0, b1 = max(r0 - 1, 0), min(r1 + 1, self.height), max(c0 - 1, 0), min(c1 + 1, self.width)
        hits = self.hits[a0:a1, b0:b1]
        most = cv2.dilate(hits, _CROSS, borderType=cv2.BORDER_CONSTANT, borderValue=0.0)
        low = (hits < np.float32(self.cfg.peak_ratio) * most)[r0 - a0 : r1 - a0, c0 - b0 : c1 - b0]
        out = np.array(occ[r0:r1, c0:c1], dtype=np.int8, copy=True)
        np.minimum(out, 0, out=out, where=low)
        return out, (r0, r1, c0, c1)

    def _crop(self, bounds: Bounds | None) -> np.ndarray:
        if bounds is None:
            return self.log_odds
        r0, r1, c0, c1 = bounds
        return self.log_odds[r0:r1, c0:c1]

    def occupancy(self, bounds: Bounds | None = None) -> np.ndarray:
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

    def occupied_mask(self, occupied_threshold: int, bounds: Bounds | None = None) -> np.ndarray:
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

    def bounds_origin(self, bounds: Bounds | None) -> np.ndarray:
        """World ``(x, y)`` of the corner of the first cell of ``bounds`` (m)."""
        if bounds is None:
            return self.origin.copy()
        return self.anchor + self.resolution * (np.array([bounds[2], bounds[0]], dtype=np.int64) - self.offset).astype(
            np.float64
        )

    def to_occupancy_map(self, bounds: Bounds | None = None) -> OccupancyMap:
        """The (cropped) grid as an :class:`OccupancyMap` (what a ROS subscriber would get)."""
        return OccupancyMap(self.occupancy(bounds), self.resolution, self.bounds_origin(bounds))


def _scan_arrays(pose, ranges, angles, sensor_offset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sensor's pose (the vehicle pose composed with `sensor_offset`) and the scan as float64
    arrays; ValueError if ranges and angles differ in length."""
    pose = np.asarray(pose, dtype=np.float64).reshape(3)
    if sensor_offset is not None:
        pose = compose(pose, np.asarray(sensor_offset, dtype=np.float64).reshape(3))
    r = np.asarray(ranges, dtype=np.float64).reshape(-1)
    a = np.asarray(angles, dtype=np.float64).reshape(-1)
    if r.shape != a.shape:
        raise ValueError(f"ranges and angles must have the same length, got {r.shape} and {a.shape}")
    return pose, r, a
