"""Stages 1-6 per stereo pair (:class:`StereoTexturer`, :class:`FrameResult`), and the pose of
a pair (:func:`interpolate_poses`)."""

from __future__ import annotations

import dataclasses
import math
import time

import cv2
import numpy as np

from .config import _SGBM_MODES, TextureConfig
from .ground import Plane, _dot3, fit_ground_plane
from .images import debayer, detect_rectified, grey
from .map import TextureMap
from .rig import StereoRig

# --------------------------------------------------------------------------------------------
# pose of a pair


def interpolate_poses(stamps: np.ndarray, poses: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Poses ``(x, y, theta)`` at ``query`` times, linear between the two neighbours.

    ``stamps`` (K,) increasing (any time unit; int64 ns works), ``poses`` (K, 3); theta is
    unwrapped before interpolating and wrapped to (-pi, pi] after. Queries outside
    ``[stamps[0], stamps[-1]]`` get NaN rows.
    """
    st = np.asarray(stamps)
    ps = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    q = np.atleast_1d(np.asarray(query))
    out = np.full((len(q), 3), np.nan)
    if len(st) == 0:
        return out
    ok = (q >= st[0]) & (q <= st[-1])
    if not ok.any():
        return out
    i = np.clip(np.searchsorted(st, q[ok], side="right") - 1, 0, max(len(st) - 2, 0))
    j = np.minimum(i + 1, len(st) - 1)
    span = (st[j] - st[i]).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(span > 0, (q[ok] - st[i]).astype(np.float64) / span, 0.0)
    th = np.unwrap(ps[:, 2])
    out[ok, 0] = ps[i, 0] + w * (ps[j, 0] - ps[i, 0])
    out[ok, 1] = ps[i, 1] + w * (ps[j, 1] - ps[i, 1])
    t = th[i] + w * (th[j] - th[i])
    out[ok, 2] = np.arctan2(np.sin(t), np.cos(t))
    return out


# --------------------------------------------------------------------------------------------
# per-pair processing


@dataclasses.dataclass
class FrameResult:
    """What one stereo pair gave.

    Attributes
    ----------
    xy_world : (N, 2)
        World positions of the ground samples (m; empty without a pose): the pixel samples,
        then the ``n_fill`` gap-filling samples (cell centres).
    xy_vehicle : (N - n_fill, 2)
        The pixel samples in the vehicle frame (m; also without a pose).
    rgb : (N, 3) uint8
        The colours of ``xy_world`` (of ``xy_vehicle`` without a pose).
    plane : Plane
        Road plane used (vehicle frame).
    plane_fitted : bool
        False: the fit failed or was rejected; the nominal plane was used.
    rectified_here : bool
        The pair was rectified by this frame's processing.
    disparity : (h, w) float32
        Disparity (full-resolution px, NaN invalid) at the downscaled resolution of the
        processed rows; pixel ``(i, j)`` covers full-resolution rows
        ``first_row + k i .. + k - 1`` and columns ``k j .. + k - 1`` (``k = downscale``).
    first_row : int
        First full-resolution row processed.
    valid_fraction : float
        Valid disparity fraction over the processed rows.
    timings_ms : dict
        ``'debayer'``, ``'rectify'``, ``'disparity'``, ``'ground'``, ``'total'`` (ms).
    n_fill : int
        Samples (the last ones) from gap filling.
    """

    xy_world: np.ndarray
    xy_vehicle: np.ndarray
    rgb: np.ndarray
    plane: Plane
    plane_fitted: bool
    rectified_here: bool
    disparity: np.ndarray
    first_row: int
    valid_fraction: float
    timings_ms: dict
    n_fill: int = 0


_DEMOSAIC_MARGIN = 8  # rows above the first processed one demosaiced with it (even: Bayer phase)


class StereoTexturer:
    """Turns stereo pairs into coloured ground samples (see the module docstring).

    Parameters
    ----------
    rig : StereoRig
    cfg : TextureConfig
    """

    def __init__(self, rig: StereoRig, cfg: TextureConfig | None = None) -> None:
        self.rig = rig
        self.cfg = cfg or TextureConfig()
        self.rng = np.random.default_rng(self.cfg.seed)
        self._rectify: bool | None = {"yes": True, "no": False}.get(self.cfg.rectify)
        k = self.cfg.downscale
        nd = self.cfg.num_disparities // k
        bs = self.cfg.block_size
        self._pad = nd
        self._sgbm = cv2.StereoSGBM_create(
            minDisparity=0,
            numDisparities=nd,
            blockSize=bs,
            P1=int(round(self.cfg.p1 * bs * bs)),
            P2=int(round(self.cfg.p2 * bs * bs)),
            disp12MaxDiff=self.cfg.disp12_max_diff,
            uniquenessRatio=self.cfg.uniqueness_ratio,
            speckleWindowSize=self.cfg.speckle_window,
            speckleRange=self.cfg.speckle_range,
            preFilterCap=self.cfg.pre_filter_cap,
            mode=_SGBM_MODES[self.cfg.sgbm_mode],
        )
        self._clahe = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 8))
        self.first_row = self._first_row()
        self._stride_cache: dict[tuple[int, int], np.ndarray] = {}
        self._sample_cache: dict[tuple[int, int, bool], tuple[np.ndarray, ...]] = {}

    @property
    def rectify(self) -> bool | None:
        """Whether pairs are rectified here (None: ``'auto'`` has not decided yet)."""
        return self._rectify

    def _first_row(self) -> int:
        """First full-resolution row that can see the ground within ``max_range_m``
        (nominal plane, rectified camera), minus ``row_margin_px``; a multiple of downscale."""
        cfg, rig = self.cfg, self.rig
        r_vc, t = rig.rect_to_vehicle(True)
        p = np.array([t[0] + cfg.max_range_m, t[1], 0.0])  # ground straight ahead
        q = r_vc.T @ (p - t)
        v = rig.cy + rig.fy * q[1] / q[2] if q[2] > 0 else 0.0
        v0 = int(math.floor(v)) - cfg.row_margin_px
        v0 = min(max(v0, 0), rig.height - 8 * cfg.downscale)
        return v0 - v0 % cfg.downscale

    # ---------------------------------------------------------------- stages
    def prepare(
        self,
        left: np.ndarray,
        right: np.ndarray,
        encoding: str = "bayer_rggb8",
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, dict]:
        """Demosaic + rectify the processed rows (``first_row:``).

        Returns ``(left_rgb, left_grey, right_grey, valid, timings)``: the left colour image
        (``demosaic`` method), the grey images for matching (OpenCV's Bayer-to-grey, the same
        for both cameras), ``valid`` (bool) marking rectified pixels from inside the raw image
        (None when not rectified here), and ``timings`` (ms, plus ``'rectified_here'``).
        """
        t0 = time.perf_counter()
        for img in (left, right):
            if img.shape[:2] != (self.rig.height, self.rig.width):
                raise ValueError(
                    f"image is {img.shape[1]} x {img.shape[0]}, the calibration {self.rig.width} x {self.rig.height}"
                )
        # images that need no rectification: only the processed rows (and a margin for the
        # demosaicing neighbourhood, even to keep the Bayer phase) are demosaiced
        crop = max(self.first_row - _DEMOSAIC_MARGIN, 0) if self._rectify is False else 0
        lrgb = debayer(left[crop:], encoding, self.cfg.demosaic)
        lg, rg = grey(left[crop:], encoding), grey(right[crop:], encoding)
        t1 = time.perf_counter()
        if self._rectify is None:
            already = detect_rectified(lg, rg, self.rig)
            self._rectify = None if already is None else not already
        rect = True if self._rectify is None else self._rectify
        v0 = self.first_row
        valid = None
        if rect:
            outs = []
            for side, img in (("left", lrgb), ("left", lg), ("right", rg)):
                mx, my = self.rig.rectify_maps(side)
                outs.append(cv2.remap(img, mx[v0:], my[v0:], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT))
            lrgb, lg, rg = outs
            valid = self.rig.rectified_valid("left")[v0:]
        else:
            lrgb, lg, rg = lrgb[v0 - crop :], lg[v0 - crop :], rg[v0 - crop :]
        t2 = time.perf_counter()
        return lrgb, lg, rg, valid, {"debayer": 1e3 * (t1 - t0), "rectify": 1e3 * (t2 - t1), "rectified_here": rect}

    def disparity(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """SGBM disparity of (cropped) rectified grey (or RGB) images.

        Returns ``(h // k, w // k)`` float32 disparity in full-resolution px (NaN = invalid),
        ``k = downscale``.
        """
        k = self.cfg.downscale
        gl = left if left.ndim == 2 else cv2.cvtColor(left, cv2.COLOR_RGB2GRAY)
        gr = right if right.ndim == 2 else cv2.cvtColor(right, cv2.COLOR_RGB2GRAY)
        if self.cfg.prefilter == "clahe":
            gl, gr = self._clahe.apply(gl), self._clahe.apply(gr)
        elif self.cfg.prefilter == "equalize":
            gl, gr = cv2.equalizeHist(gl), cv2.equalizeHist(gr)
        h, w = gl.shape
        h, w = h - h % k, w - w % k
        if k > 1:
            gl = cv2.resize(gl[:h, :w], (w // k, h // k), interpolation=cv2.INTER_AREA)
            gr = cv2.resize(gr[:h, :w], (w // k, h // k), interpolation=cv2.INTER_AREA)
        pad = self._pad
        gl = cv2.copyMakeBorder(gl, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0)
        gr = cv2.copyMakeBorder(gr, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0)
        raw = self._sgbm.compute(gl, gr)[:, pad:]
        disp = raw.astype(np.float32) * np.float32(k / 16.0)
        disp[raw <= 0] = np.nan
        return disp

    def _grid_rays(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Separable rectified-camera ray components ``(ry (h, 1), rx (1, w))`` float32 of
        full-resolution pixel rows / columns (``ray = [rx, ry, 1]``)."""
        rig = self.rig
        ry = ((np.asarray(rows, np.float64) - rig.cy) / rig.fy).astype(np.float32)[:, None]
        rx = ((np.asarray(cols, np.float64) - rig.cx) / rig.f).astype(np.float32)[None, :]
        return ry, rx

    def point_grid(self, disp: np.ndarray, rectified_here: bool) -> np.ndarray:
        """Vehicle-frame points ``(h, w, 3)`` float32 of a disparity image (NaN = invalid).

        Pixel ``(i, j)`` of ``disp`` is the mean of full-resolution pixels
        ``first_row + k i .. + k - 1``, ``k j .. + k - 1``: its centre is
        ``(k j + (k - 1) / 2, first_row + k i + (k - 1) / 2)``.
        """
        k = self.cfg.downscale
        h, w = disp.shape
        ry, rx = self._grid_rays(self.first_row + k * np.arange(h) + 0.5 * (k - 1), k * np.arange(w) + 0.5 * (k - 1))
        d = disp - np.float32(self.rig.cx_offset)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(d > 0, np.float32(self.rig.f * self.rig.baseline_m) / d, np.nan).astype(np.float32)
        r_vc, t = self.rig.rect_to_vehicle(rectified_here)
        r = r_vc.astype(np.float32)
        out = np.empty((h, w, 3), np.float32)
        for i in range(3):
            out[..., i] = (r[i, 0] * rx + r[i, 1] * ry + r[i, 2]) * z + np.float32(t[i])
        return out

    def points(self, disp: np.ndarray, rectified_here: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vehicle-frame points of the valid disparities: ``(p (N, 3) float64, rows (N,),
        cols (N,))``, rows / columns indexing ``disp``."""
        g = self.point_grid(disp, rectified_here)
        rr, cc = np.nonzero(np.isfinite(g[..., 2]))
        return g[rr, cc].astype(np.float64), rr, cc

    def _in_box(self, p: np.ndarray) -> np.ndarray:
        """Bool ``(...)``: vehicle-frame points ``(..., >=2)`` inside the range box."""
        return self._in_box_xy(p[..., 0], p[..., 1])

    def _in_box_xy(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bool: vehicle-frame ``x``, ``y`` (m, any shape) inside the range box."""
        t = self.rig.t_vehicle_cam
        ahead = x - np.float32(t[0])
        with np.errstate(invalid="ignore"):
            return (
                (ahead >= self.cfg.min_range_m)
                & (ahead <= self.cfg.max_range_m)
                & (np.abs(y - np.float32(t[1])) <= self.cfg.max_lateral_m)
            )

    def ground_plane(self, p: np.ndarray, preselected: bool = False) -> tuple[Plane, bool]:
        """Road plane of one pair's vehicle-frame points (nominal plane on failure);
        ``preselected``: ``p`` holds only the candidates already (in the range box, near the
        nominal ground)."""
        cfg = self.cfg
        nominal = Plane.nominal()
        if not cfg.plane_fit:
            return nominal, False
        if not preselected:
            p = p[self._in_box(p) & (np.abs(p[:, 2]) < cfg.plane_max_offset_m + cfg.ransac_tol_m)]
        plane, _ = fit_ground_plane(
            p, cfg.ransac_iterations, cfg.ransac_tol_m, cfg.ransac_max_points, cfg.plane_max_tilt_deg, self.rng
        )
        if plane is None or plane.tilt_deg > cfg.plane_max_tilt_deg or abs(plane.c) > cfg.plane_max_offset_m:
            return nominal, False
        return plane, True

    def _stride_mask(self, h: int, w: int) -> np.ndarray:
        """Bool ``(h, w)`` (rows from ``first_row``): the pixels sampled for splatting.

        Near the car a cell holds hundreds of pixels (5 m ahead: 2 cm along x 6 mm across at
        the KAIST rig). Rows are kept every ``floor(cell_m / (n fp_row))``-th row and columns
        every ``floor(cell_m / (n fp_col))``-th column (``n = cell_samples``; ``fp_row`` the
        along-track ground footprint of a pixel in that row on the nominal plane, ``fp_col`` the
        across-track one), both clipped to ``1 .. pixel_stride_max``: each cell still gets about
        ``n x n`` samples where the image has more.
        """
        key = (h, w)
        m = self._stride_cache.get(key)
        if m is None:
            rig, cfg = self.rig, self.cfg
            v = self.first_row + np.arange(h, dtype=np.float64)
            cam_h = max(float(rig.t_vehicle_cam[2]), 1e-3)
            n = float(cfg.cell_samples)

            def stride_of(fp: np.ndarray) -> np.ndarray:
                with np.errstate(divide="ignore", invalid="ignore"):
                    st = np.where(np.isfinite(fp), np.floor(cfg.cell_m / (n * fp)), 1.0)
                return np.clip(np.nan_to_num(st, nan=1.0), 1, cfg.pixel_stride_max).astype(np.int64)

            with np.errstate(divide="ignore", invalid="ignore"):
                z = np.where(v > rig.cy + 1.0, rig.fy * cam_h / (v - rig.cy), np.inf)
            s_row, s_col = stride_of(z * z / (rig.fy * cam_h)), stride_of(z / rig.f)
            rows = (np.arange(h) % s_row) == 0
            cols = (np.arange(w)[None, :] % s_col[:, None]) == 0
            m = rows[:, None] & cols
            self._stride_cache[key] = m
        return m

    def _samples(
        self, hf: int, wf: int, ds_shape: tuple[int, int], rect: bool, valid: np.ndarray | None
    ) -> tuple[np.ndarray, ...]:
        """The full-resolution pixels splatted when their disparity pixel is ground (cached per
        image geometry): ``(fi, di, q0, q1, q2)``, row-major: flat pixel indices in the processed
        rows (``hf x wf``), flat indices of their disparity pixels (``ds_shape``), and their
        vehicle-frame ray components (float32) for the ray-plane intersection. Pixels of the
        stride pattern (:meth:`_stride_mask`), inside the disparity image's coverage and, when
        rectified here, from inside the raw image."""
        key = (hf, wf, bool(rect))
        out = self._sample_cache.get(key)
        if out is None:
            k = self.cfg.downscale
            h, w = ds_shape
            m = self._stride_mask(hf, wf).copy()
            m[h * k :] = False
            m[:, w * k :] = False
            if valid is not None:
                m &= valid
            ri, ci = np.nonzero(m)
            r_vc, _ = self.rig.rect_to_vehicle(rect)
            r = r_vc.astype(np.float32)
            ry, rx = self._grid_rays(self.first_row + ri, ci)
            ry, rx = ry[:, 0], rx[0]
            q = [r[i, 0] * rx + r[i, 1] * ry + r[i, 2] for i in range(3)]
            out = (ri * wf + ci, (ri // k) * w + ci // k, *q)
            self._sample_cache[key] = out
        return out

    def process(
        self,
        left: np.ndarray,
        right: np.ndarray,
        pose: np.ndarray | None = None,
        encoding: str = "bayer_rggb8",
        cells: tuple[np.ndarray, float] | None = None,
    ) -> FrameResult:
        """One stereo pair -> coloured ground samples.

        Parameters
        ----------
        left, right : numpy.ndarray
            Raw images (``encoding``).
        pose : (3,), optional
            Vehicle pose ``(x, y, theta)`` (m, rad) in the world at the images' stamp;
            ``xy_world`` is empty without it.
        cells : (anchor_xy (2,), cell_m), optional
            The texture grid: with ``fill_gaps``, its cells in view that no ground pixel fell
            in get one sample at their centre (see :meth:`_fill`).
        """
        cfg, rig = self.cfg, self.rig
        t0 = time.perf_counter()
        lrgb, lg, rg, valid, tm = self.prepare(left, right, encoding)
        rect = bool(tm.pop("rectified_here"))
        t1 = time.perf_counter()
        disp = self.disparity(lg, rg)
        k = cfg.downscale
        if valid is not None:  # no disparity where the rectified left image has no data
            vk = valid[: disp.shape[0] * k : k, : disp.shape[1] * k : k]
            disp[~vk[: disp.shape[0], : disp.shape[1]]] = np.nan
        t2 = time.perf_counter()
        grid = self.point_grid(disp, rect)
        # the plane fit's candidates picked on the float32 grid (same points, same order as
        # ground_plane's own selection from all finite points)
        with np.errstate(invalid="ignore"):
            near = self._in_box(grid) & (np.abs(grid[..., 2]) < np.float32(cfg.plane_max_offset_m + cfg.ransac_tol_m))
        plane, fitted = self.ground_plane(grid[near].astype(np.float64), preselected=True)
        n32 = plane.normal.astype(np.float32)
        t = rig.t_vehicle_cam.astype(np.float32)
        with np.errstate(invalid="ignore"):
            hgt = _dot3(grid, n32) + np.float32(plane.c)
            ground_ds = (np.abs(hgt) < cfg.height_tol_m) & self._in_box(grid)
            if cfg.obstacle_margin_px > 0:  # block matching fattens objects over the ground
                m = 2 * cfg.obstacle_margin_px + 1
                above = cv2.dilate((hgt > cfg.height_tol_m).astype(np.uint8), np.ones((m, m), np.uint8))
                ground_ds &= above == 0
        # full-resolution ground pixels: the sampled pixels (stride pattern, valid) of ground
        # disparity pixels; their rays are precomputed (_samples)
        hf, wf = lrgb.shape[:2]
        fi, di, q0, q1, q2 = self._samples(hf, wf, disp.shape, rect, valid)
        sel = np.flatnonzero(ground_ds.ravel()[di])
        fi = fi[sel]
        if cfg.snap_to_plane:  # ray-plane intersection of the sampled pixels only
            q = (q0[sel], q1[sel], q2[sel])  # vehicle rays
            nq = n32[0] * q[0] + n32[1] * q[1] + n32[2] * q[2]
            with np.errstate(divide="ignore", invalid="ignore"):
                sc = -np.float32(float(plane.normal @ rig.t_vehicle_cam) + plane.c) / nq
                px = t[0] + sc * q[0]
                py = t[1] + sc * q[1]
                keep = (sc > 0) & self._in_box_xy(px, py)
            fi = fi[keep]
            xy_v = np.stack([px[keep], py[keep]], axis=-1).astype(np.float64)
        else:  # each full-resolution pixel takes the stereo point of its disparity pixel
            xy_v = grid[..., :2].reshape(-1, 2)[di[sel]].astype(np.float64)
        rgb = lrgb.reshape(-1, 3)[fi]
        n_fill = 0
        if pose is not None:
            x, y, th = (float(a) for a in np.asarray(pose, dtype=np.float64).reshape(3))
            c, s_ = math.cos(th), math.sin(th)
            xy_w = np.column_stack([x + c * xy_v[:, 0] - s_ * xy_v[:, 1], y + s_ * xy_v[:, 0] + c * xy_v[:, 1]])
            if cells is not None and cfg.fill_gaps:
                fxy, frgb = self._fill(np.array([x, y, th]), cells, xy_w, (ground_ds, valid), lrgb, plane, rect)
                n_fill = len(fxy)
                if n_fill:
                    xy_w = np.concatenate([xy_w, fxy])
                    rgb = np.concatenate([rgb, frgb])
        else:
            xy_w = np.zeros((0, 2))
        t3 = time.perf_counter()
        tm.update(disparity=1e3 * (t2 - t1), ground=1e3 * (t3 - t2), total=1e3 * (t3 - t0))
        n_proc = disp.size if valid is None else max(int(valid[::k, ::k].sum()), 1)
        return FrameResult(
            xy_w,
            xy_v,
            rgb,
            plane,
            fitted,
            rect,
            disp,
            self.first_row,
            float(np.isfinite(disp).sum() / max(n_proc, 1)),
            tm,
            n_fill,
        )

    def _fill(
        self,
        pose: np.ndarray,
        cells: tuple[np.ndarray, float],
        xy_w: np.ndarray,
        ground: tuple[np.ndarray, np.ndarray | None],
        lrgb: np.ndarray,
        plane: Plane,
        rect: bool,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Gap filling: the cells of the frame's range box that no ground pixel fell in, whose
        centre projects onto a ground pixel, get the bilinear colour at that projection.

        Far away an image row spans more than a cell (0.33 m at 20 m for the KAIST rig), so
        pixel splatting alone leaves stripes; near, a cell holds many pixels and is left to
        them (area average). ``ground``: ``(ground mask at the disparity resolution, valid
        rectified pixels or None)``. Returns ``(xy (M, 2) cell centres, rgb (M, 3))``.
        """
        cfg, rig = self.cfg, self.rig
        anchor, cm = np.asarray(cells[0], dtype=np.float64).reshape(2), float(cells[1])
        x, y, th = pose
        c, s = math.cos(th), math.sin(th)
        t = rig.t_vehicle_cam
        bx = t[0] + np.array([cfg.min_range_m, cfg.min_range_m, cfg.max_range_m, cfg.max_range_m])
        by = t[1] + np.array([-1.0, 1.0, -1.0, 1.0]) * cfg.max_lateral_m
        wx, wy = x + c * bx - s * by, y + s * bx + c * by
        i0, j0 = np.floor((np.array([wx.min(), wy.min()]) - anchor) / cm).astype(np.int64)
        i1, j1 = np.floor((np.array([wx.max(), wy.max()]) - anchor) / cm).astype(np.int64) + 1
        ni, nj = int(i1 - i0), int(j1 - j0)
        if ni <= 0 or nj <= 0 or ni * nj > 4_000_000:
            return np.zeros((0, 2)), np.zeros((0, 3), np.uint8)
        hit = np.zeros((nj, ni), dtype=bool)
        if len(xy_w):  # per axis: numpy's (N, 2) broadcasts and column picks are slow
            hx = np.floor((xy_w[:, 0] - anchor[0]) / cm).astype(np.int64) - i0
            hy = np.floor((xy_w[:, 1] - anchor[1]) / cm).astype(np.int64) - j0
            ok = (hx >= 0) & (hx < ni) & (hy >= 0) & (hy < nj)
            hit.ravel()[hy[ok] * ni + hx[ok]] = True
        gx = anchor[0] + (np.arange(i0, i1) + 0.5) * cm
        gy = anchor[1] + (np.arange(j0, j1) + 0.5) * cm
        dx, dy = gx[None, :] - x, gy[:, None] - y
        vx = (c * dx + s * dy).astype(np.float32)  # vehicle frame
        vy = (-s * dx + c * dy).astype(np.float32)
        cand = ~hit & self._in_box_xy(vx, vy)
        vx, vy = vx[cand], vy[cand]
        n = plane.normal
        vz = -(n[0] * vx + n[1] * vy + plane.c) / n[2]
        r_vc, _ = rig.rect_to_vehicle(rect)
        r = r_vc.astype(np.float32)
        px, py, pz = vx - np.float32(t[0]), vy - np.float32(t[1]), vz - np.float32(t[2])
        qx = r[0, 0] * px + r[1, 0] * py + r[2, 0] * pz  # camera frame: r^T p
        qy = r[0, 1] * px + r[1, 1] * py + r[2, 1] * pz
        qz = r[0, 2] * px + r[1, 2] * py + r[2, 2] * pz
        with np.errstate(divide="ignore", invalid="ignore"):
            u = rig.cx + rig.f * qx / qz
            v = rig.cy + rig.fy * qy / qz - self.first_row
        g_ds, valid = ground
        k = cfg.downscale
        h, w = g_ds.shape[0] * k, g_ds.shape[1] * k  # the full-resolution pixels it covers
        ok = (qz > 0) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
        ui, vi = np.rint(u[ok]).astype(np.int64), np.rint(v[ok]).astype(np.int64)
        good = g_ds[vi // k, ui // k]
        if valid is not None:
            good &= valid[vi, ui]
        idx = np.flatnonzero(cand.ravel())[np.flatnonzero(ok)[good]]
        if not idx.size:
            return np.zeros((0, 2)), np.zeros((0, 3), np.uint8)
        mu = u[ok][good].astype(np.float32).reshape(-1, 1)
        mv = v[ok][good].astype(np.float32).reshape(-1, 1)
        col = cv2.remap(lrgb, mu, mv, cv2.INTER_LINEAR).reshape(-1, 3)
        jj, ii = np.divmod(idx, ni)
        return np.column_stack([gx[ii], gy[jj]]), col

    def integrate(
        self, texmap: TextureMap, left: np.ndarray, right: np.ndarray, pose: np.ndarray, encoding: str = "bayer_rggb8"
    ) -> FrameResult:
        """:meth:`process` one pair at ``pose`` (gap filling on ``texmap``'s cells) and add
        its samples to ``texmap``."""
        res = self.process(left, right, pose, encoding, cells=(texmap.anchor, texmap.cell_m))
        texmap.add(res.xy_world, res.rgb)
        return res
