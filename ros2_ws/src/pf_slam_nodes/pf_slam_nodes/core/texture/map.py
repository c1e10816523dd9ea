"""Stage 7: the texture accumulator (:class:`TextureMap`, tiled running-mean RGB per world cell)
and the images made from it (north-up BGR for a PNG, overlay with the occupancy grid)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .config import TextureConfig

# --------------------------------------------------------------------------------------------
# the accumulator


class TextureMap:
    """Running-mean RGB per world cell, in tiles allocated on demand.

    Cell ``(i, j)`` (column i along x, row j along y) covers
    ``[anchor_x + i * cell_m, + cell_m) x [anchor_y + j * cell_m, + cell_m)``; tiles are
    ``tile_cells`` x ``tile_cells`` cells. Memory: 16 bytes per cell of an allocated tile.

    Parameters
    ----------
    cell_m : float
        Cell size (m).
    tile_cells : int
        Tile edge (cells).
    max_tiles : int
        Tiles allocated at most; samples in further tiles are dropped (``samples_dropped``).
    anchor_xy : (2,)
        World corner of cell ``(0, 0)`` (m): align it with the map whose geometry the
        texture will be rendered in (``/map``'s origin) to avoid resampling shifts.
    """

    def __init__(
        self,
        cell_m: float = 0.1,
        tile_cells: int = 128,
        max_tiles: int = 1024,
        anchor_xy: tuple[float, float] | np.ndarray = (0.0, 0.0),
    ) -> None:
        if not cell_m > 0 or tile_cells < 1 or max_tiles < 1:
            raise ValueError(f"bad texture map geometry: cell {cell_m}, tile {tile_cells}, max tiles {max_tiles}")
        self.cell_m = float(cell_m)
        self.tile_cells = int(tile_cells)
        self.max_tiles = int(max_tiles)
        self.anchor = np.asarray(anchor_xy, dtype=np.float64).reshape(2).copy()
        #: (tx, ty) -> (mean (T, T, 3) float32, count (T, T) float32); row = y, column = x
        self.tiles: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        #: (tx, ty) -> how many times the tile was changed (:class:`IncrementalRender` redraws
        #: only the changed ones)
        self.versions: dict[tuple[int, int], int] = {}
        self.samples_added = 0
        self.samples_dropped = 0
        self.cells_covered = 0  # cells with at least one sample

    @classmethod
    def from_config(
        cls,
        cfg: TextureConfig,
        anchor_xy: tuple[float, float] | np.ndarray = (0.0, 0.0),
    ) -> TextureMap:
        return cls(cfg.cell_m, cfg.tile_cells, cfg.max_tiles, anchor_xy)

    @property
    def memory_bytes(self) -> int:
        return 16 * self.tile_cells**2 * len(self.tiles)

    def cells_of(self, xy: np.ndarray) -> np.ndarray:
        """World ``(N, 2)`` (m) -> int64 cell indices ``(N, 2)`` ``[i (x), j (y)]``."""
        return np.floor((np.asarray(xy, dtype=np.float64) - self.anchor) / self.cell_m).astype(np.int64)

    def empty_like(self) -> TextureMap:
        """An empty map of the same geometry (cell, tiles, anchor)."""
        return TextureMap(self.cell_m, self.tile_cells, self.max_tiles, self.anchor)

    def copy(self) -> TextureMap:
        """An independent copy (tiles and counters)."""
        out = self.empty_like()
        out.tiles = {k: (m.copy(), c.copy()) for k, (m, c) in self.tiles.items()}
        out.versions = dict(self.versions)
        out.samples_added, out.samples_dropped = self.samples_added, self.samples_dropped
        out.cells_covered = self.cells_covered
        return out

    def add(self, xy: np.ndarray, rgb: np.ndarray, weights: np.ndarray | None = None) -> int:
        """Add samples: world points ``(N, 2)`` (m) with colours ``(N, 3)`` (0..255).

        Every sample weighs 1 (or ``weights`` (N,): a sample standing for that many): a cell's
        colour is the mean of all samples that fell in it (``mean += (sum - n mean) / (count +
        n)`` per cell and call). Returns the number of samples added (the rest needed a tile
        beyond ``max_tiles``).
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        col = np.asarray(rgb, dtype=np.float32).reshape(-1, 3)
        wt = None if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
        if len(xy) != len(col) or (wt is not None and len(wt) != len(xy)):
            raise ValueError(f"{len(xy)} points but {len(col)} colours, {'no' if wt is None else len(wt)} weights")
        ok = np.isfinite(xy[:, 0]) & np.isfinite(xy[:, 1])
        if wt is not None:
            ok &= wt > 0
        if not ok.all():
            xy, col = xy[ok], col[ok]
            wt = None if wt is None else wt[ok]
        if not len(xy):
            return 0
        t = self.tile_cells
        # cell indices per axis (1-D: numpy's reductions over axis 0 of (N, 2) are slow)
        cx = np.floor((xy[:, 0] - self.anchor[0]) / self.cell_m).astype(np.int64)
        cy = np.floor((xy[:, 1] - self.anchor[1]) / self.cell_m).astype(np.int64)
        lo = np.array([cx.min(), cy.min()])
        hi = np.array([cx.max(), cy.max()])
        gw, gh = (hi - lo + 1).tolist()
        ntx, nty = (np.floor_divide(hi, t) - np.floor_divide(lo, t) + 1).tolist()
        if ntx * nty > 64:  # scattered input: one call per group of nearby samples
            tx0, ty0 = np.floor_divide(cx, t), np.floor_divide(cy, t)
            key = (tx0 - tx0.min()) // 8 * (nty // 8 + 1) + (ty0 - ty0.min()) // 8
            order = np.argsort(key, kind="stable")
            ks = key[order]
            cuts = np.flatnonzero(ks[1:] != ks[:-1]) + 1
            return sum(self.add(xy[g], col[g], None if wt is None else wt[g]) for g in np.split(order, cuts))
        # per-cell sample counts and colour sums over the batch's bounding box, then the
        # touched cells tile by tile
        flat = (cy - lo[1]) * gw + (cx - lo[0])
        n = np.bincount(flat, weights=wt, minlength=gw * gh)
        hit = np.flatnonzero(n)
        nt_all = n[hit]
        if wt is not None:
            col = col * wt[:, None].astype(np.float32)
        ss_all = np.stack(
            [np.bincount(flat, weights=np.ascontiguousarray(col[:, ch]), minlength=gw * gh)[hit] for ch in range(3)],
            axis=-1,
        )
        ci = hit % gw + lo[0]  # global cell indices of the touched cells
        cj = hit // gw + lo[1]
        tx, ty = np.floor_divide(ci, t), np.floor_divide(cj, t)
        tkey = (ty - ty.min()) * (int(tx.max() - tx.min()) + 1) + (tx - tx.min())
        order = np.argsort(tkey, kind="stable")
        tks = tkey[order]
        cuts = np.flatnonzero(tks[1:] != tks[:-1]) + 1
        added = 0
        for g in np.split(order, cuts):
            tk = (int(tx[g[0]]), int(ty[g[0]]))
            nt = nt_all[g].astype(np.float64)
            n_here = int(nt_all[g].sum())
            tile = self.tiles.get(tk)
            if tile is None:
                if len(self.tiles) >= self.max_tiles:
                    self.samples_dropped += n_here
                    continue
                tile = (np.zeros((t, t, 3), np.float32), np.zeros((t, t), np.float32))
                self.tiles[tk] = tile
            mean, count = tile
            jj, ii = cj[g] - tk[1] * t, ci[g] - tk[0] * t
            c_old = count[jj, ii]
            self.cells_covered += int(np.count_nonzero(c_old == 0))
            c_new = c_old + nt
            m = mean[jj, ii]
            mean[jj, ii] = m + ((ss_all[g] - nt[:, None] * m) / c_new[:, None]).astype(np.float32)
            count[jj, ii] = c_new
            self.versions[tk] = self.versions.get(tk, 0) + 1
            added += n_here
        self.samples_added += added
        return added

    def covered_bounds(self) -> tuple[float, float, float, float] | None:
        """World ``(xmin, ymin, xmax, ymax)`` of the allocated tiles (m), or None."""
        if not self.tiles:
            return None
        k = np.array(list(self.tiles), dtype=np.int64)
        ext = self.tile_cells * self.cell_m
        lo = self.anchor + k.min(axis=0) * ext
        hi = self.anchor + (k.max(axis=0) + 1) * ext
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    def cell_count(self) -> int:
        """Cells with at least one sample."""
        return self.cells_covered

    def render(
        self,
        origin_xy: tuple[float, float] | np.ndarray,
        resolution: float,
        width: int,
        height: int,
        into: tuple[np.ndarray, np.ndarray] | None = None,
        only: tuple[set, tuple[int, int, int, int]] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The texture in a map geometry (``OccupancyGrid`` layout, row 0 = lowest y).

        An output cell coarser than 1.5 texture cells is the sample-weighted mean of the
        texture cells whose centres fall in it; a finer (or similar) one takes the texture cell
        containing its centre (exact when the grids are aligned). Work memory is per block of
        256 x 256 output cells; only the output itself (4 bytes per cell) is whole.

        ``into``: ``(rgb, covered)`` of this geometry to draw in (default: new, empty);
        ``only``: ``(tiles, (c0, r0, c1, r1))``: draw only the output blocks that one of these
        tile keys meets or that are not wholly inside that cell rectangle (each such block is
        drawn whole, from all its tiles); the rest of ``into`` is kept (see
        :class:`IncrementalRender`).

        Returns
        -------
        rgb : (height, width, 3) uint8
            Observed cells never ``(0, 0, 0)`` (clamped to 1); unobserved cells 0.
        covered : (height, width) bool
        """
        w, h = int(width), int(height)
        if w <= 0 or h <= 0 or not resolution > 0:
            raise ValueError(f"bad render geometry {w} x {h} at {resolution!r} m")
        o = np.asarray(origin_xy, dtype=np.float64).reshape(-1)[:2]
        res = float(resolution)
        t, cm = self.tile_cells, self.cell_m
        ext = t * cm
        coarse = res >= 1.5 * cm
        if into is None:
            rgb, covered = np.zeros((h, w, 3), np.uint8), np.zeros((h, w), bool)
        else:
            rgb, covered = into
            if rgb.shape != (h, w, 3) or covered.shape != (h, w):
                raise ValueError(f"render into {rgb.shape} / {covered.shape}, the geometry is {w} x {h}")
        blk = 256 if only is None else 64
        # output cell range each tile can write, and the output blocks it meets
        jobs: dict[tuple[int, int], list] = {}
        for key in self.tiles:
            corner = self.anchor + np.array(key, dtype=np.float64) * ext
            if coarse:  # cells containing the texture cell centres
                lo = np.floor((corner + 0.5 * cm - o) / res).astype(np.int64)
                hi = np.floor((corner + ext - 0.5 * cm - o) / res).astype(np.int64) + 1
            else:  # cells whose centres lie in the tile
                lo = np.ceil((corner - o) / res - 0.5).astype(np.int64)
                hi = np.ceil((corner + ext - o) / res - 0.5).astype(np.int64)
            lo = np.maximum(lo, 0)
            hi = np.minimum(hi, [w, h])
            if (lo >= hi).any():
                continue
            for by in range(int(lo[1]) // blk, (int(hi[1]) - 1) // blk + 1):
                for bx in range(int(lo[0]) // blk, (int(hi[0]) - 1) // blk + 1):
                    jobs.setdefault((bx, by), []).append((key, corner))
        for (bx, by), tiles in jobs.items():
            c0, r0 = bx * blk, by * blk
            c1, r1 = min(c0 + blk, w), min(r0 + blk, h)
            if only is not None:
                changed, (k0, q0, k1, q1) = only
                inside = k0 <= c0 and c1 <= k1 and q0 <= r0 and r1 <= q1
                if inside and not any(key in changed for key, _ in tiles):
                    continue
            bw, bh = c1 - c0, r1 - r0
            if coarse:
                sums = np.zeros((bh * bw, 3), np.float64)
                cnts = np.zeros(bh * bw, np.float64)
            else:
                mean_b = np.zeros((bh, bw, 3), np.float32)
                cnt_b = np.zeros((bh, bw), np.float32)
            for key, corner in tiles:
                mean, count = self.tiles[key]
                if coarse:
                    jj, ii = np.nonzero(count > 0)
                    oc = np.floor((corner[0] + (ii + 0.5) * cm - o[0]) / res).astype(np.int64) - c0
                    orow = np.floor((corner[1] + (jj + 0.5) * cm - o[1]) / res).astype(np.int64) - r0
                    ok = (oc >= 0) & (oc < bw) & (orow >= 0) & (orow < bh)
                    if not ok.any():
                        continue
                    fl = orow[ok] * bw + oc[ok]
                    cw = count[jj[ok], ii[ok]].astype(np.float64)
                    cnts += np.bincount(fl, weights=cw, minlength=bh * bw)
                    m = mean[jj[ok], ii[ok]]
                    for ch in range(3):
                        sums[:, ch] += np.bincount(fl, weights=m[:, ch] * cw, minlength=bh * bw)
                else:
                    xs = o[0] + (np.arange(c0, c1) + 0.5) * res
                    ys = o[1] + (np.arange(r0, r1) + 0.5) * res
                    ii = np.floor((xs - corner[0]) / cm).astype(np.int64)
                    jj = np.floor((ys - corner[1]) / cm).astype(np.int64)
                    ci = np.flatnonzero((ii >= 0) & (ii < t))
                    ri = np.flatnonzero((jj >= 0) & (jj < t))
                    if not ci.size or not ri.size:
                        continue
                    sel = np.ix_(ri, ci)
                    mean_b[sel] = mean[jj[ri][:, None], ii[ci][None, :]]
                    cnt_b[sel] = count[jj[ri][:, None], ii[ci][None, :]]
            if coarse:
                cov_b = (cnts > 0).reshape(bh, bw)
                mean_b = (sums / np.maximum(cnts, 1e-12)[:, None]).reshape(bh, bw, 3)
            else:
                cov_b = cnt_b > 0
            out = np.clip(np.rint(mean_b), 0, 255).astype(np.uint8)
            out[cov_b] = np.maximum(out[cov_b], 1)
            out[~cov_b] = 0
            rgb[r0:r1, c0:c1] = out
            covered[r0:r1, c0:c1] = cov_b
        return rgb, covered

    def render_native(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """``(rgb, covered, origin_xy)`` over the allocated tiles at ``cell_m``, or None."""
        b = self.covered_bounds()
        if b is None:
            return None
        n = np.rint((np.array(b[2:]) - np.array(b[:2])) / self.cell_m).astype(int)
        rgb, cov = self.render(b[:2], self.cell_m, int(n[0]), int(n[1]))
        return rgb, cov, np.array(b[:2])


class _Drawn(NamedTuple):
    """What :class:`IncrementalRender` drew last: of which map, in which geometry, from which tiles."""

    texmap: TextureMap
    origin: np.ndarray
    resolution: float
    rgb: np.ndarray
    covered: np.ndarray
    versions: dict


class IncrementalRender:
    """A :class:`TextureMap` rendered in a map geometry again and again (the texture node's
    periodic image): each call draws only the output blocks whose tiles changed since the
    previous call (:attr:`TextureMap.versions`) and those newly in view; the rest is copied
    from the previous image, shifted when the map grew by whole cells. Another map object, a
    new resolution or an origin moved by a fraction of a cell: drawn whole.

    The result is the same as :meth:`TextureMap.render`'s; each call returns new arrays, which
    the next call reads (do not modify them).
    """

    def __init__(self) -> None:
        self._last: _Drawn | None = None

    def render(
        self,
        texmap: TextureMap,
        origin_xy: tuple[float, float] | np.ndarray,
        resolution: float,
        width: int,
        height: int,
    ) -> tuple[np.ndarray, np.ndarray]:
        o = np.asarray(origin_xy, dtype=np.float64).reshape(-1)[:2].copy()
        res, w, h = float(resolution), int(width), int(height)
        last, only = self._last, None
        rgb, cov = np.zeros((h, w, 3), np.uint8), np.zeros((h, w), bool)
        if last is not None and last.texmap is texmap and last.resolution == res:
            shift = (last.origin - o) / res  # the previous image's cell (0, 0) in this one
            di = np.rint(shift)
            if np.abs(shift - di).max() < 1e-3:  # /map's resolution is a float32
                dc, dr = int(di[0]), int(di[1])
                prgb, pcov = last.rgb, last.covered
                ph, pw = pcov.shape
                c0, c1 = max(dc, 0), min(dc + pw, w)
                r0, r1 = max(dr, 0), min(dr + ph, h)
                if c0 < c1 and r0 < r1:
                    rgb[r0:r1, c0:c1] = prgb[r0 - dr : r1 - dr, c0 - dc : c1 - dc]
                    cov[r0:r1, c0:c1] = pcov[r0 - dr : r1 - dr, c0 - dc : c1 - dc]
                    changed = {k for k, v in texmap.versions.items() if last.versions.get(k) != v}
                    only = (changed, (c0, r0, c1, r1))
        texmap.render(o, res, w, h, into=(rgb, cov), only=only)
        self._last = _Drawn(texmap, o, res, rgb, cov, dict(texmap.versions))
        return rgb, cov


# --------------------------------------------------------------------------------------------
# output images


def north_up_bgr(rgb: np.ndarray) -> np.ndarray:
    """``OccupancyGrid``-layout RGB (row 0 = lowest y) -> BGR for ``cv2.imwrite``, north up."""
    return np.ascontiguousarray(np.asarray(rgb)[::-1, :, ::-1])


def overlay_occupancy(
    rgb: np.ndarray, covered: np.ndarray, occupancy: np.ndarray, occupied_threshold: int = 65, free_threshold: int = 25
) -> np.ndarray:
    """Texture + occupancy in one RGB image (same geometry, ``OccupancyGrid`` layout).

    Occupied cells (``>= occupied_threshold``) are drawn red (255, 0, 0) over everything;
    textured cells show their colour; untextured free cells are light grey (200), unknown ones
    dark grey (90).
    """
    occ = np.asarray(occupancy)
    if occ.shape != rgb.shape[:2]:
        raise ValueError(f"occupancy {occ.shape} and texture {rgb.shape[:2]} differ")
    out = np.full(rgb.shape, 90, dtype=np.uint8)
    out[(occ >= 0) & (occ <= free_threshold)] = 200
    out[covered] = rgb[covered]
    out[occ >= occupied_threshold] = (255, 0, 0)
    return out
