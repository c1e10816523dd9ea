"""Scan-to-map correlation: likelihood field and per-particle window search.

The likelihood field stores, per cell, the distance ``d`` (m) from the cell centre to the centre of
the nearest occupied cell (clamped at ``max_distance_m``) and ``log p = -d^2 / (2 sigma^2)``.
Unknown cells are not obstacles. Lookups outside the field return the clamp value.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .config import CorrelationConfig
from .geometry import wrap_angle
from .grid import OccupancyMap

#: Border (cells) of clamp value around the stored field; bounds the window search shift.
DEFAULT_PAD_CELLS = 32

# tile size (cells) of the likelihood field's local updates
_TILE = 32

# keep the (N, J, S, M) index tensor of the window search below this many elements per chunk
_CHUNK_ELEMENTS = 2_000_000


class LikelihoodField:
    """Distance / log-likelihood field over a map window.

    Parameters
    ----------
    distance_m : numpy.ndarray
        ``(H, W)`` distance to the nearest obstacle (m), already clamped.
    resolution : float
        Cell size (m).
    origin : array_like
        ``(2,)`` world ``(x, y)`` of the corner of cell (0, 0) (m).
    sigma_m : float
        Likelihood std (m).
    max_distance_m : float
        Clamp value (m), also used outside the field.
    pad_cells : int
        Border of clamp value stored around the field.

    Attributes
    ----------
    origin : numpy.ndarray
        ``(2,)`` float64.
    resolution : float
    width, height : int
        Size of the unpadded field.
    pad : int
    """

    def __init__(
        self,
        distance_m: np.ndarray,
        resolution: float,
        origin,
        sigma_m: float,
        max_distance_m: float,
        pad_cells: int = DEFAULT_PAD_CELLS,
    ) -> None:
        d = np.asarray(distance_m, dtype=np.float32)
        self.resolution = float(resolution)
        self.origin = np.asarray(origin, dtype=np.float64).reshape(-1)[:2].copy()
        self.sigma_m = float(sigma_m)
        self.max_distance_m = float(max_distance_m)
        self.height, self.width = d.shape
        self.pad = int(pad_cells)
        p = self.pad
        self._dist = cv2.copyMakeBorder(
            np.minimum(d, np.float32(self.max_distance_m)),
            p,
            p,
            p,
            p,
            cv2.BORDER_CONSTANT,
            value=float(self.max_distance_m),
        )
        self._wp = self._dist.shape[1]
        self._loglik = (self._dist * self._dist) * np.float32(-0.5 / (self.sigma_m**2))
        self._dist_flat = self._dist.reshape(-1)
        self._refresh_prob(None)
        self._loglik_flat = self._loglik.reshape(-1)
        self.min_log_likelihood = -0.5 * (self.max_distance_m / self.sigma_m) ** 2

    def _refresh_prob(self, region) -> None:
        """Recompute the smooth match field ``exp(-d^2 / (2 sigma^2))`` (all or a padded region)."""
        if region is None:
            self._prob = np.exp(self._loglik)
            self._prob_flat = self._prob.reshape(-1)
        else:
            a, b, c, d = region
            self._prob[a:b, c:d] = np.exp(self._loglik[a:b, c:d])

    @property
    def log_likelihood(self) -> np.ndarray:
        """``(H, W)`` float32 log-likelihood (view, unpadded)."""
        p = self.pad
        return self._loglik[p : p + self.height, p : p + self.width]

    @property
    def distance_m(self) -> np.ndarray:
        """``(H, W)`` float32 clamped obstacle distance (view, unpadded)."""
        p = self.pad
        return self._dist[p : p + self.height, p : p + self.width]

    def _cells(self, xy: np.ndarray, margin: int) -> tuple[np.ndarray, np.ndarray]:
        """Padded integer cell coords of the cells containing ``xy``, clipped into the border."""
        u = np.floor((xy[..., 0] - self.origin[0]) / self.resolution)
        v = np.floor((xy[..., 1] - self.origin[1]) / self.resolution)
        lo = -1 - margin
        cx = np.clip(u, lo, self.width + margin).astype(np.int64) + self.pad
        cy = np.clip(v, lo, self.height + margin).astype(np.int64) + self.pad
        return cx, cy

    def lookup(self, xy: np.ndarray) -> np.ndarray:
        """Nearest-cell log-likelihood at world points ``(..., 2)`` -> ``(...)`` float32."""
        xy = np.asarray(xy, dtype=np.float64)
        cx, cy = self._cells(xy, 0)
        return self._loglik_flat[cy * self._wp + cx]

    def distance_bilinear(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bilinearly interpolated distance and its gradient at world points (see :meth:`_bilinear`)."""
        return self._bilinear(self._dist_flat, xy)

    def match_bilinear(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bilinearly interpolated ``exp(-d^2 / (2 sigma^2))`` in ``[0, 1]`` and its gradient (1/m)."""
        return self._bilinear(self._prob_flat, xy)

    def _bilinear(self, table: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bilinear interpolation of a padded cell-centre table and its gradient at world points.

        Parameters
        ----------
        xy : numpy.ndarray
            ``(..., 2)`` world points (m).

        Returns
        -------
        d : numpy.ndarray
            ``(...)`` interpolated value.
        grad : numpy.ndarray
            ``(..., 2)`` ``[dd/dx, dd/dy]`` (per m).
        """
        xy = np.asarray(xy, dtype=np.float64)
        res = self.resolution
        u = (xy[..., 0] - self.origin[0]) / res - 0.5 + self.pad
        v = (xy[..., 1] - self.origin[1]) / res - 0.5 + self.pad
        hp, wp = self._dist.shape
        u = np.clip(u, 0.0, wp - 1.001)
        v = np.clip(v, 0.0, hp - 1.001)
        u0 = np.floor(u)
        v0 = np.floor(v)
        fu = u - u0
        fv = v - v0
        i00 = v0.astype(np.int64) * wp + u0.astype(np.int64)
        D = table
        d00 = D[i00]
        d01 = D[i00 + 1]
        d10 = D[i00 + wp]
        d11 = D[i00 + wp + 1]
        top = d00 + fu * (d01 - d00)
        bot = d10 + fu * (d11 - d10)
        d = top + fv * (bot - top)
        gx = ((1.0 - fv) * (d01 - d00) + fv * (d11 - d10)) / res
        gy = (bot - top) / res
        return d, np.stack([gx, gy], axis=-1)


class GridLikelihoodField(LikelihoodField):
    """Likelihood field covering a whole grid, updated in place where obstacles change.

    Because distances are clamped at ``max_distance_m`` (R cells), an obstacle change only
    affects cells within R of it; :meth:`set_obstacles` recomputes the distance transform on the
    bounding box of the changed cells grown by R (source grown by 2R), which is exact.

    Parameters
    ----------
    height, width : int
        Grid size (cells).
    resolution : float
        Cell size (m).
    origin : array_like
        ``(2,)`` world position of cell (0, 0)'s corner (m).
    cfg : CorrelationConfig
        ``sigma_m``, ``max_distance_m`` and ``occupied_threshold`` are used.

    Attributes
    ----------
    obstacles : numpy.ndarray
        ``(H, W)`` bool obstacle mask the field currently reflects.
    """

    def __init__(self, height: int, width: int, resolution: float, origin, cfg: CorrelationConfig) -> None:
        super().__init__(
            np.full((height, width), cfg.max_distance_m, dtype=np.float32),
            resolution,
            origin,
            cfg.sigma_m,
            cfg.max_distance_m,
            DEFAULT_PAD_CELLS,
        )
        self.occupied_threshold = int(cfg.occupied_threshold)
        self.obstacles = np.zeros((height, width), dtype=bool)
        self._anchor = self.origin.copy()  # the initial origin; cells keep their place on growth
        self._offset = np.zeros(2, dtype=np.int64)
        self._r = int(math.ceil(self.max_distance_m / self.resolution)) + 1

    def grow(self, add: tuple[int, int, int, int]) -> None:
        """Add ``(top, bottom, left, right)`` obstacle-free rows / columns around the field
        (whole tiles of the grid, :func:`~.grid.growth_plan`): the tables are copied into larger
        ones, the new cells hold the clamp value, and the field is recomputed within ``R`` of the
        obstacles near the old edges (their distances reach into the new cells), so it equals
        the field of the whole obstacle mask computed at once."""
        top, bottom, left, right = (int(v) for v in add)
        if not (top or bottom or left or right):
            return
        h, w, p = self.height, self.width, self.pad
        self.obstacles = np.pad(self.obstacles, ((top, bottom), (left, right)))
        nh, nw = self.obstacles.shape

        def table(old: np.ndarray) -> np.ndarray:  # padded: the border value is the clamp's
            out = np.full((nh + 2 * p, nw + 2 * p), old[0, 0], dtype=old.dtype)
            out[p + top : p + top + h, p + left : p + left + w] = old[p : p + h, p : p + w]
            return out

        self._dist, self._loglik, self._prob = table(self._dist), table(self._loglik), table(self._prob)
        self._dist_flat = self._dist.reshape(-1)
        self._loglik_flat = self._loglik.reshape(-1)
        self._prob_flat = self._prob.reshape(-1)
        self._wp = self._dist.shape[1]
        self.height, self.width = nh, nw
        self._offset = self._offset + np.array([left, top], np.int64)
        self.origin = self._anchor - self.resolution * self._offset.astype(np.float64)
        # obstacles within R of an old edge that now has cells beyond it
        r = self._r
        bands = []
        if top:
            bands.append((top, min(top + r, top + h), left, left + w))
        if bottom:
            bands.append((max(top + h - r, top), top + h, left, left + w))
        if left:
            bands.append((top, top + h, left, min(left + r, left + w)))
        if right:
            bands.append((top, top + h, max(left + w - r, left), left + w))
        rr, cc = [], []
        for a0, a1, b0, b1 in bands:
            br, bc = np.nonzero(self.obstacles[a0:a1, b0:b1])
            rr.append(br + a0)
            cc.append(bc + b0)
        rows, cols = np.concatenate(rr), np.concatenate(cc)
        if rows.size:
            self._recompute_cells(rows, cols)

    def set_obstacles(self, flat_idx: np.ndarray, is_obstacle: np.ndarray) -> int:
        """Set the obstacle state of cells and update the field around the changes.

        Parameters
        ----------
        flat_idx : numpy.ndarray
            int flat indices ``row * width + col`` (repeats allowed if their values agree).
        is_obstacle : numpy.ndarray
            bool, same shape.

        Returns
        -------
        int
            Number of (index entries of) cells whose state changed.
        """
        idx = np.asarray(flat_idx, dtype=np.int64).reshape(-1)
        val = np.asarray(is_obstacle, dtype=bool).reshape(-1)
        flat = self.obstacles.reshape(-1)
        changed = flat[idx] != val
        if not changed.any():
            return 0
        ci = idx[changed]
        flat[ci] = val[changed]
        rows = ci // self.width
        self._recompute_cells(rows, ci - rows * self.width)
        return int(ci.size)

    def set_obstacle_block(self, row0: int, col0: int, is_obstacle: np.ndarray) -> int:
        """Set the obstacle state of the rectangle of cells starting at ``(row0, col0)``
        (``is_obstacle``: ``(h, w)`` bool, inside the grid) and update the field around the
        changes; like :meth:`set_obstacles` without flat index arrays. Returns the cells changed."""
        block = np.asarray(is_obstacle, dtype=bool)
        h, w = block.shape
        view = self.obstacles[row0 : row0 + h, col0 : col0 + w]
        changed = view != block
        if not changed.any():
            return 0
        view[...] = block
        rows, cols = np.nonzero(changed)
        self._recompute_cells(rows + row0, cols + col0)
        return int(rows.size)

    def update_from_occupancy(self, occupancy_int8: np.ndarray) -> int:
        """Bring the field up to date with a full int8 map of the same size (diff, then local update).

        Returns
        -------
        int
            Number of cells whose obstacle state changed.
        """
        occ = np.asarray(occupancy_int8)
        if occ.shape != self.obstacles.shape:
            raise ValueError(f"occupancy shape {occ.shape} != field shape {self.obstacles.shape}")
        mask = occ >= self.occupied_threshold
        ci = np.flatnonzero(mask != self.obstacles)
        if ci.size == 0:
            return 0
        return self.set_obstacles(ci, mask.reshape(-1)[ci])

    def _recompute_cells(self, rows: np.ndarray, cols: np.ndarray) -> None:
        """Update the field around changed cells, tile by tile.

        A scan's changes lie along its far endpoints, so their bounding box is mostly untouched
        map; the distance transform (linear in area) runs instead on each horizontal run of
        ``_TILE``-cell tiles that hold a change (exact: see :meth:`_recompute`).
        """
        t = _TILE
        ntc = (self.width + t - 1) // t
        key = np.unique((rows // t) * ntc + cols // t)
        tr, tc = key // ntc, key % ntc
        brk = np.flatnonzero((np.diff(tr) != 0) | (np.diff(tc) != 1)) + 1
        for a, b in zip(np.r_[0, brk], np.r_[brk, key.size]):
            r0, c0 = int(tr[a]) * t, int(tc[a]) * t
            self._recompute(r0, min(r0 + t, self.height), c0, min((int(tc[b - 1]) + 1) * t, self.width))

    def _recompute(self, r0: int, r1: int, c0: int, c1: int) -> None:
        """Recompute the field for cells within ``R`` of the rectangle (exact: the distance
        transform runs on the rectangle grown by ``2R``, and distances are clamped at ``R``)."""
        r = self._r
        h, w = self.height, self.width
        # output region: cells within r of the change; source region: within 2r
        o0, o1, p0, p1 = max(r0 - r, 0), min(r1 + r, h), max(c0 - r, 0), min(c1 + r, w)
        s0, s1, q0, q1 = max(r0 - 2 * r, 0), min(r1 + 2 * r, h), max(c0 - 2 * r, 0), min(c1 + 2 * r, w)
        m = self.obstacles[s0:s1, q0:q1]
        if m.any():
            src = np.where(m, np.uint8(0), np.uint8(255))
            d = cv2.distanceTransform(src, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * np.float32(self.resolution)
            d = np.minimum(d[o0 - s0 : o1 - s0, p0 - q0 : p1 - q0], np.float32(self.max_distance_m))
        else:
            d = np.float32(self.max_distance_m)
        p = self.pad
        self._dist[p + o0 : p + o1, p + p0 : p + p1] = d
        dd = self._dist[p + o0 : p + o1, p + p0 : p + p1]
        self._loglik[p + o0 : p + o1, p + p0 : p + p1] = (dd * dd) * np.float32(-0.5 / (self.sigma_m**2))
        self._refresh_prob((p + o0, p + o1, p + p0, p + p1))


def _field_from_obstacle_mask(
    mask: np.ndarray, resolution: float, origin, sigma_m: float, max_distance_m: float, pad_cells: int
) -> LikelihoodField:
    m = np.asarray(mask, dtype=bool)
    if m.ndim != 2:
        raise ValueError(f"mask must be 2-D, got shape {m.shape}")
    if not m.any():
        dist = np.full(m.shape, max_distance_m, dtype=np.float32)
    else:
        src = np.where(m, np.uint8(0), np.uint8(255))
        dist = cv2.distanceTransform(src, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * np.float32(resolution)
    return LikelihoodField(dist, resolution, origin, sigma_m, max_distance_m, pad_cells)


def build_likelihood_field(
    occupancy_int8: np.ndarray,
    resolution: float,
    sigma_m: float,
    occupied_threshold: int = 65,
    origin=(0.0, 0.0),
    max_distance_m: float | None = None,
    pad_cells: int = DEFAULT_PAD_CELLS,
) -> LikelihoodField:
    """Likelihood field of an int8 occupancy grid (exact Euclidean distance transform).

    Parameters
    ----------
    occupancy_int8 : numpy.ndarray
        ``(H, W)`` int8, -1 unknown, 0..100 (nav_msgs/OccupancyGrid data reshaped).
    resolution : float
        Cell size (m).
    sigma_m : float
        Likelihood std (m).
    occupied_threshold : int
        Cells with value ``>= occupied_threshold`` are obstacles.
    origin : array_like
        ``(2,)`` world position of cell (0, 0)'s corner (m).
    max_distance_m : float, optional
        Distance clamp (m); default ``4 * sigma_m``.
    pad_cells : int
        Clamp-valued border kept around the field.

    Returns
    -------
    LikelihoodField
        ``.log_likelihood`` is the ``(H, W)`` float32 field.
    """
    occ = np.asarray(occupancy_int8)
    if not 1 <= occupied_threshold <= 100:
        raise ValueError(f"occupied_threshold must be in [1, 100], got {occupied_threshold!r}")
    if not sigma_m > 0:
        raise ValueError(f"sigma_m must be > 0, got {sigma_m!r}")
    mdist = 4.0 * sigma_m if max_distance_m is None else float(max_distance_m)
    return _field_from_obstacle_mask(occ >= occupied_threshold, resolution, origin, sigma_m, mdist, pad_cells)


def build_likelihood_field_from_map(occ_map: OccupancyMap, cfg: CorrelationConfig) -> LikelihoodField:
    """Likelihood field of an :class:`OccupancyMap` with the parameters of ``cfg``."""
    return build_likelihood_field(
        occ_map.data,
        occ_map.resolution,
        cfg.sigma_m,
        cfg.occupied_threshold,
        occ_map.origin,
        cfg.max_distance_m,
    )


def build_likelihood_field_from_mask(
    obstacle_mask: np.ndarray, resolution: float, origin, cfg: CorrelationConfig
) -> LikelihoodField:
    """Likelihood field from a bool obstacle mask ``(H, W)`` (e.g. ``LogOddsGrid.occupied_mask``)."""
    return _field_from_obstacle_mask(
        obstacle_mask, resolution, origin, cfg.sigma_m, cfg.max_distance_m, DEFAULT_PAD_CELLS
    )


def _offsets(half: float, step: float) -> np.ndarray:
    k = int(math.floor(half / step + 1e-9))
    return np.arange(-k, k + 1, dtype=np.float64) * step


# cv2.remap turns float maps into 16-bit fixed-point cell coordinates and asserts that the table
# and its maps (output) have fewer than SHRT_MAX rows and columns: tables up to this size only,
# and at most this many candidate poses (rows) or scan points (columns) per call
_REMAP_MAX_CELLS = 32000


def _use_remap(field: LikelihoodField, points: int = 0) -> bool:
    """Whether OpenCV's remap can do the window search's nearest-cell lookups (both padded
    sides and the number of points < 32000): many points in one C call instead of numpy index
    arithmetic. The candidate poses (the map's rows) are chunked to fit (:func:`window_search`)."""
    return max(max(field._dist.shape), points) < _REMAP_MAX_CELLS


def _points_in_table(poses: np.ndarray, pts: np.ndarray, field: LikelihoodField, dtype=np.float64):
    """The points seen from every pose: rotated ``rx, ry`` ``(N, M)`` (robot frame) and their
    continuous coordinates ``u, v`` in the padded table (cell ``k`` spans ``[k - 0.5, k + 0.5)``),
    in ``dtype``; the large pose part is formed in float64 and rounded once."""
    c = np.cos(poses[:, 2:3]).astype(dtype, copy=False)
    s = np.sin(poses[:, 2:3]).astype(dtype, copy=False)
    px, py = pts[:, 0].astype(dtype, copy=False), pts[:, 1].astype(dtype, copy=False)
    # rx = c px - s py, ry = s px + c py, u = rx inv + (..), v alike, in place (fewer (N, M) temporaries)
    tmp, rx, ry, res, off = s * py, c * px, s * px, field.resolution, field.pad - 0.5
    rx -= tmp
    ry += np.multiply(c, py, out=tmp)
    u = np.multiply(rx, inv := dtype(1.0 / res), out=tmp)
    u += ((poses[:, 0:1] - field.origin[0]) / res + off).astype(dtype, copy=False)
    v = ry * inv
    v += ((poses[:, 1:2] - field.origin[1]) / res + off).astype(dtype, copy=False)
    return u, v, rx, ry


def _window_scores_remap(
    cand: np.ndarray, pts: np.ndarray, field: LikelihoodField, sx: np.ndarray, sy: np.ndarray
) -> np.ndarray:
    """``(K, S)`` summed nearest-cell log-likelihood of every candidate pose ``(K, 3)`` at every
    whole-cell shift (dy-major (dy, dx) order), one remap per shift."""
    u, v, _, _ = _points_in_table(cand, pts, field)
    u, v = u.astype(np.float32), v.astype(np.float32)  # remap's maps; its rounding picks the cell
    out, k = np.empty((cand.shape[0], sx.size * sy.size)), 0
    table, clamp = field._loglik, float(field.min_log_likelihood)
    uu, vv, vals = np.empty_like(u), np.empty_like(v), np.empty(u.shape, table.dtype)  # reused per shift
    for dy in sy:
        np.add(v, np.float32(dy), out=vv)
        for dx in sx:
            np.add(u, np.float32(dx), out=uu)
            cv2.remap(table, uu, vv, cv2.INTER_NEAREST, dst=vals, borderMode=cv2.BORDER_CONSTANT, borderValue=clamp)
            out[:, k] = vals.sum(axis=1, dtype=np.float64)
            k += 1
    return out


def window_search(
    poses: np.ndarray, points: np.ndarray, field: LikelihoodField, cfg: CorrelationConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Exhaustive (x, y, yaw) window search around every pose with nearest-cell lookups.

    Translations are whole-cell shifts (``step_xy_m`` rounded to >= 1 cell), so every rotated
    point set is looked up once per shift: one OpenCV nearest remap per shift, or integer index
    arithmetic on fields too large for remap (the same cells up to float32 rounding at cell edges).

    Parameters
    ----------
    poses : numpy.ndarray
        ``(N, 3)`` poses.
    points : numpy.ndarray
        ``(M, 2)`` scan endpoints in the robot frame of the poses.
    field : LikelihoodField
    cfg : CorrelationConfig

    Returns
    -------
    best_poses : numpy.ndarray
        ``(N, 3)``.
    scores : numpy.ndarray
        ``(N,)`` summed log-likelihood at the best candidate.
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    n = poses.shape[0]
    res = field.resolution
    sc = max(1, int(round(cfg.step_xy_m / res)))
    kx = int(math.floor(cfg.search_x_m / (sc * res) + 1e-9))
    ky = int(math.floor(cfg.search_y_m / (sc * res) + 1e-9))
    max_shift = sc * max(kx, ky)
    if 2 * max_shift + 1 > field.pad:
        raise ValueError(
            f"search window of {max_shift} cells needs pad_cells >= {2 * max_shift + 1}, field has {field.pad}"
        )
    yaws = _offsets(cfg.search_yaw_rad, cfg.step_yaw_rad)
    sx = np.arange(-kx, kx + 1) * sc
    sy = np.arange(-ky, ky + 1) * sc
    # int32 indices halve the memory traffic of the (n, J, S, M) gather where the table allows
    idx_t = np.int32 if field._loglik_flat.size < 2**31 - 1 else np.int64
    offs = (sy[:, None] * field._wp + sx[None, :]).reshape(-1).astype(idx_t)  # (S,) row-major (dy, dx)
    penalty = _prior_penalty(sx * res, sy * res, yaws, cfg)  # (J, S) or None
    n_yaw, n_shift, m = yaws.size, offs.size, pts.shape[0]
    best_poses = np.empty_like(poses)
    best_scores = np.empty(n)
    remap = _use_remap(field, m)
    # remap: one row per candidate (particle x yaw) and remap takes < SHRT_MAX rows; the index
    # tensor of the numpy path is (n, J, S, M): bound either by chunks of particles (each
    # particle's scores do not depend on the chunking: the same results for any chunk size)
    chunk = max(1, (_REMAP_MAX_CELLS - 1) // n_yaw) if remap else max(1, _CHUNK_ELEMENTS // max(1, n_yaw * n_shift * m))
    table = field._loglik_flat
    for i0 in range(0, n, chunk):  # chunks of particles (not one particle at a time)
        p = poses[i0 : i0 + chunk]
        if remap:
            cand = np.repeat(p, n_yaw, axis=0)
            cand[:, 2] += np.tile(yaws, p.shape[0])
            sc_all = _window_scores_remap(cand, pts, field, sx, sy).reshape(p.shape[0], n_yaw, n_shift)
        else:
            th = p[:, 2:3] + yaws[None, :]  # (n, J)
            c = np.cos(th)[..., None]
            s = np.sin(th)[..., None]
            wx = p[:, 0, None, None] + c * pts[:, 0] - s * pts[:, 1]  # (n, J, M)
            wy = p[:, 1, None, None] + s * pts[:, 0] + c * pts[:, 1]
            cx, cy = field._cells(np.stack([wx, wy], axis=-1), max_shift)
            base = (cy * field._wp + cx).astype(idx_t)
            sc_all = table[base[:, :, None, :] + offs[None, None, :, None]].sum(axis=-1, dtype=np.float64)
        if penalty is not None:
            sc_all -= penalty[None]
        flat = sc_all.reshape(p.shape[0], -1)
        k = np.argmax(flat, axis=1)
        j, sidx = np.divmod(k, n_shift)
        iy, ix = np.divmod(sidx, sx.size)
        best_poses[i0 : i0 + chunk, 0] = p[:, 0] + sx[ix] * res
        best_poses[i0 : i0 + chunk, 1] = p[:, 1] + sy[iy] * res
        best_poses[i0 : i0 + chunk, 2] = p[:, 2] + yaws[j]
        best_scores[i0 : i0 + chunk] = flat[np.arange(p.shape[0]), k]
    best_poses[:, 2] = wrap_angle(best_poses[:, 2])
    return best_poses, best_scores


def _prior_penalty(dx: np.ndarray, dy: np.ndarray, dyaw: np.ndarray, cfg: CorrelationConfig):
    """``(J, S)`` motion-prior cost of the window candidates (``S`` = dy-major (dy, dx) grid), or
    None when ``cfg`` has no prior."""
    if not (cfg.prior_sigma_xy_m > 0 or cfg.prior_sigma_yaw_rad > 0):
        return None
    t = np.zeros((dy.size, dx.size))
    if cfg.prior_sigma_xy_m > 0:
        t = (dy[:, None] ** 2 + dx[None, :] ** 2) * (0.5 / cfg.prior_sigma_xy_m**2)
    r = np.zeros(dyaw.size)
    if cfg.prior_sigma_yaw_rad > 0:
        r = dyaw**2 * (0.5 / cfg.prior_sigma_yaw_rad**2)
    return r[:, None] + t.reshape(1, -1)


def _prior_cost(poses: np.ndarray, predicted: np.ndarray, cfg: CorrelationConfig) -> np.ndarray:
    """``(N,)`` motion-prior cost of ``poses`` relative to ``predicted`` (0 without a prior)."""
    c = np.zeros(poses.shape[0])
    if cfg.prior_sigma_xy_m > 0:
        c += ((poses[:, 0] - predicted[:, 0]) ** 2 + (poses[:, 1] - predicted[:, 1]) ** 2) * (
            0.5 / cfg.prior_sigma_xy_m**2
        )
    if cfg.prior_sigma_yaw_rad > 0:
        dth = wrap_angle(poses[:, 2] - predicted[:, 2])
        c += dth**2 * (0.5 / cfg.prior_sigma_yaw_rad**2)
    return c


def _cost(
    poses: np.ndarray, pts: np.ndarray, field: LikelihoodField, residual: str = "likelihood", precision: str = "float64"
):
    """Residuals ``(N, M)``, their gradients ``gx, gy`` (1/m) and the rotated points ``rx, ry``.

    ``residual='distance'``: the bilinear obstacle distance; ``'likelihood'``: ``1 - M`` with
    ``M`` the bilinear ``exp(-d^2 / (2 sigma^2))``. (OpenCV's remap would interpolate faster,
    but its bilinear weights are quantised to 1/32 cell, and Gauss-Newton on a finite-difference
    gradient of it stopped centimetres short: measured, not used.)
    """
    if residual == "distance":
        return _bilinear_at(poses, pts, field, field._dist_flat, True, precision)
    val, gx, gy, rx, ry = _bilinear_at(poses, pts, field, field._prob_flat, True, precision)
    return 1.0 - val, -gx, -gy, rx, ry  # r = 1 - M, dr = -dM


def _bilinear_at(
    poses: np.ndarray,
    pts: np.ndarray,
    field: LikelihoodField,
    table: np.ndarray,
    gradient: bool,
    precision: str = "float64",
):
    """Bilinear ``table`` values ``(N, M)`` at the points seen from every pose and
    (``gradient``) the exact gradient of the interpolant (1/m) with the rotated points:
    ``val, gx, gy, rx, ry``. Inlined (no ``(..., 2)`` stacking): the refinement calls this with
    small arrays, where numpy's per-call overhead dominates. ``precision='float32'`` (the table's
    own type) is ~25 % faster; in float32 the refinement converged differently enough to halve the
    wall agreement of the intel_910 segment test's map (0.85 -> 0.36), hence float64 by default."""
    dtype = np.float32 if precision == "float32" else np.float64
    u, v, rx, ry = _points_in_table(poses, pts, field, dtype)
    inv = dtype(1.0 / field.resolution)
    hp, wp = field._dist.shape
    np.clip(u, 0.0, wp - 1.001, out=u)
    np.clip(v, 0.0, hp - 1.001, out=v)
    u0 = np.floor(u)
    v0 = np.floor(v)
    fu = u - u0
    fv = v - v0
    idx_t = np.int32 if table.size < 2**31 - wp - 1 else np.intp
    i00 = v0.astype(idx_t) * idx_t(wp) + u0.astype(idx_t)
    d00 = table[i00]
    a0 = table[i00 + 1] - d00
    d10 = table[i00 + wp]
    a1 = table[i00 + (wp + 1)] - d10
    top = d00 + fu * a0
    e = d10 + fu * a1 - top
    val = top + fv * e
    if not gradient:
        return val
    return val, (a0 + fv * (a1 - a0)) * inv, e * inv, rx, ry


def match_cost(poses: np.ndarray, pts: np.ndarray, field: LikelihoodField) -> np.ndarray:
    """``(N,)`` ``sum (1 - M)^2`` (bilinear match likelihood ``M``, float32) of the points seen from every pose."""
    r = 1.0 - _bilinear_at(poses, pts, field, field._prob_flat, False, "float32")
    return _rowdot(r, r)


def _rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(N,)`` float64 row sums of ``a * b`` for ``(N, M)`` arrays (float32 or float64)."""
    return np.einsum("nm,nm->n", a, b, dtype=np.float64)


def refine(
    poses: np.ndarray,
    points: np.ndarray,
    field: LikelihoodField,
    iterations: int,
    residual: str = "likelihood",
    precision: str = "float64",
) -> tuple[np.ndarray, np.ndarray]:
    """Damped Gauss-Newton refinement of ``sum r(p_i)^2`` for every pose (vectorised).

    ``residual='likelihood'``: ``r = 1 - exp(-d^2 / (2 sigma^2))`` (smooth, Hector-style);
    ``residual='distance'``: ``r = d`` (clamped obstacle distance).

    A step is kept only where it lowers the cost; a pose stops at its first rejected or tiny step.

    Parameters
    ----------
    poses : numpy.ndarray
        ``(N, 3)`` start poses.
    points : numpy.ndarray
        ``(M, 2)`` endpoints in the robot frame.
    field : LikelihoodField
    iterations : int
    residual : str
        ``'likelihood'`` or ``'distance'``.

    Returns
    -------
    poses : numpy.ndarray
        ``(N, 3)`` refined poses.
    cost : numpy.ndarray
        ``(N,)`` ``sum r^2`` at the refined poses.
    """
    x = np.array(poses, dtype=np.float64).reshape(-1, 3)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    d, gx, gy, rx, ry = _cost(x, pts, field, residual, precision)
    cost = _rowdot(d, d)
    max_t = 2.0 * field.resolution
    max_r = 0.05
    active = np.arange(x.shape[0])  # poses still moving
    diag = np.arange(3)
    for _ in range(iterations):
        if active.size == 0:
            break
        j3 = gy * rx - gx * ry  # d r / d yaw
        h = np.empty((active.size, 3, 3))  # J J^T from its six distinct sums
        h[:, 0, 0], h[:, 1, 1], h[:, 2, 2] = _rowdot(gx, gx), _rowdot(gy, gy), _rowdot(j3, j3)
        h[:, 0, 1] = h[:, 1, 0] = _rowdot(gx, gy)
        h[:, 0, 2] = h[:, 2, 0] = _rowdot(gx, j3)
        h[:, 1, 2] = h[:, 2, 1] = _rowdot(gy, j3)
        b = np.stack([_rowdot(gx, d), _rowdot(gy, d), _rowdot(j3, d)], axis=1)
        h[:, diag, diag] = h[:, diag, diag] * (1.0 + 1e-3) + 1e-9  # Levenberg damping
        step = -np.linalg.solve(h, b[:, :, None])[..., 0]
        t = np.hypot(step[:, 0], step[:, 1])
        step[:, :2] *= np.minimum(1.0, max_t / np.maximum(t, 1e-12))[:, None]
        np.clip(step[:, 2], -max_r, max_r, out=step[:, 2])
        xn = x[active] + step
        dn, gxn, gyn, rxn, ryn = _cost(xn, pts, field, residual, precision)
        cn = _rowdot(dn, dn)
        better = cn < cost[active]
        acc = active[better]
        x[acc] = xn[better]
        cost[acc] = cn[better]
        moving = better & ((np.hypot(step[:, 0], step[:, 1]) > 1e-4) | (np.abs(step[:, 2]) > 1e-5))
        active = active[moving]
        if moving.all():
            d, gx, gy, rx, ry = dn, gxn, gyn, rxn, ryn
        else:  # the poses still moving all accepted their step: their state is the new one
            d, gx, gy, rx, ry = dn[moving], gxn[moving], gyn[moving], rxn[moving], ryn[moving]
    x[:, 2] = wrap_angle(x[:, 2])
    return x, cost


def _distances(poses: np.ndarray, pts: np.ndarray, field: LikelihoodField, precision: str) -> np.ndarray:
    """``(N, M)`` bilinear obstacle distance of the points at every pose."""
    return _bilinear_at(poses, pts, field, field._dist_flat, False, precision)


def correlate(
    poses: np.ndarray,
    points_sensor: np.ndarray,
    field: LikelihoodField,
    cfg: CorrelationConfig,
    match: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Best pose ``(N, 3)`` and score ``(N,)`` of every particle (``poses``, ``(N, 3)``, map frame)
    in its search window, for scan endpoints ``points_sensor`` ``(M, 2)`` in the frame of the poses
    (a laser offset applied first: ``scan.transform_points``).

    Window search (:func:`window_search`, beams ``::beam_stride``) then Gauss-Newton refinement
    (:func:`refine`, beams ``::refine_beam_stride``); beams longer than ``cfg.range_max_m`` are
    ignored. ``match`` ``(M,)`` bool: the points these two use (default all; the points behind an
    occluding edge, ``correlation.shadow_jump_m``, move no pose). The score, ``-sum d^2 / (2
    sigma^2)`` over every point at the refinement's stride (0 when no beam is usable), weighs the
    particles.
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    pts = np.asarray(points_sensor, dtype=np.float64).reshape(-1, 2)
    near = np.hypot(pts[:, 0], pts[:, 1]) <= cfg.range_max_m
    matched = pts[near] if match is None else pts[near & np.asarray(match, dtype=bool).reshape(-1)]
    pts = pts[near]
    if matched.shape[0] == 0:
        return poses.copy(), np.zeros(poses.shape[0])
    best, _ = window_search(poses, matched[:: cfg.beam_stride], field, cfg)
    it, res = cfg.refine_iterations, cfg.refine_residual
    best, _ = refine(best, matched[:: cfg.refine_beam_stride], field, it, res, cfg.precision)
    refine_pts = pts[:: cfg.refine_beam_stride]
    score = _score(best, poses, refine_pts, field, cfg)
    if cfg.prior_sigma_xy_m > 0 or cfg.prior_sigma_yaw_rad > 0:
        score0 = _score(poses, poses, refine_pts, field, cfg)
        stay = score0 >= score
        best[stay] = poses[stay]
        score = np.where(stay, score0, score)
    if cfg.gain_xy < 1.0 or cfg.gain_yaw < 1.0:
        best, score = _blend(poses, best, refine_pts, field, cfg)
    return best, score


def _blend(
    predicted: np.ndarray, matched: np.ndarray, pts: np.ndarray, field: LikelihoodField, cfg: CorrelationConfig
) -> tuple[np.ndarray, np.ndarray]:
    """The poses a fraction ``cfg.gain_*`` of the way from ``predicted`` to ``matched`` and
    their scores (:func:`_score`)."""
    step = matched - predicted
    step[:, 2] = wrap_angle(step[:, 2])
    out = predicted + step * np.array([cfg.gain_xy, cfg.gain_xy, cfg.gain_yaw])
    out[:, 2] = wrap_angle(out[:, 2])
    return out, _score(out, predicted, pts, field, cfg)


def _score(
    poses: np.ndarray, predicted: np.ndarray, pts: np.ndarray, field: LikelihoodField, cfg: CorrelationConfig
) -> np.ndarray:
    """``(N,)`` the weight update of particles at ``poses``: ``-sum d^2 / (2 sigma^2)`` over the
    points minus the motion prior's cost relative to ``predicted`` (0 without a prior)."""
    d = _distances(poses, pts, field, cfg.precision)
    return -0.5 * _rowdot(d, d) / (cfg.sigma_m**2) - _prior_cost(poses, predicted, cfg)
