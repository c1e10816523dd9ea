"""Likelihood field for scan-to-map correlation.

The likelihood field stores, per cell, the distance ``d`` (m) from the cell centre to the centre of
the nearest occupied cell (clamped at ``max_distance_m``) and ``log p = -d^2 / (2 sigma^2)``.
Unknown cells are not obstacles. Lookups outside the field return the clamp value.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .config import CorrelationConfig
from .grid import OccupancyMap

#: Border (cells) of clamp value around the stored field; bounds the window search shift.
DEFAULT_PAD_CELLS = 32

# tile size (cells) of the likelihood field's local updates
_TILE = 32


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
