"""Scan-to-map correlation: per-particle window search and Gauss-Newton refinement against a
likelihood field (:mod:`.likelihood`)."""

from __future__ import annotations

import math

import cv2
import numpy as np

from .config import CorrelationConfig
from .geometry import wrap_angle
from .likelihood import (
    DEFAULT_PAD_CELLS,
    GridLikelihoodField,
    LikelihoodField,
    build_likelihood_field,
    build_likelihood_field_from_map,
    build_likelihood_field_from_mask,
)
from .scan import grazing_samples

__all__ = [
    "DEFAULT_PAD_CELLS",
    "GridLikelihoodField",
    "LikelihoodField",
    "build_likelihood_field",
    "build_likelihood_field_from_map",
    "build_likelihood_field_from_mask",
    "correlate",
    "match_cost",
    "refine",
    "window_search",
]

# keep the (N, J, S, M) index tensor of the window search below this many elements per chunk
_CHUNK_ELEMENTS = 2_000_000


def _offsets(half: float, step: float) -> np.ndarray:
    k = int(math.floor(half / step + 1e-9))
    return np.arange(-k, k + 1, dtype=np.float64) * step


# cv2.remap turns float maps into 16-bit fixed-point cell coordinates and asserts that the table
# and its maps (output) have fewer than SHRT_MAX rows and columns: tables up to this size only,
# and at most this many candidate poses (rows) or scan points (columns) per call
_REMAP_MAX_CELLS = 32000

# below this many lookups per shift (candidate poses x points) the window search gathers all
# shifts in one numpy index instead: each remap call costs ~10 us, a lookup ~3 ns in remap and
# ~6 ns in numpy, so one particle's wide search (9 yaws x 90 points x 225 shifts: recovery.py)
# takes 1.2 ms instead of 2.3 ms, while the local search of 30 particles stays on remap
_REMAP_MIN_LOOKUPS = 2048


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


def window_reach_m(field: LikelihoodField, step_xy_m: float) -> float:
    """The largest translation (m) a window search at ``step_xy_m`` may reach on ``field``: its
    padding bounds the shifts (``2 * shift + 1 <= pad`` cells, checked by :func:`window_search`)."""
    sc = max(1, int(round(step_xy_m / field.resolution)))
    return ((field.pad - 1) // 2 // sc) * sc * field.resolution


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
    remap = _use_remap(field, m) and n * n_yaw * m >= _REMAP_MIN_LOOKUPS
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


def _offset(poses: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """``(N, 3)`` ``poses - predicted``, the yaw wrapped."""
    e = poses - predicted
    e[:, 2] = wrap_angle(e[:, 2])
    return e


def _prior_cost(poses: np.ndarray, predicted: np.ndarray, cfg: CorrelationConfig) -> np.ndarray:
    """``(N,)`` motion-prior cost of ``poses`` relative to ``predicted`` (0 without a prior)."""
    c = np.zeros(poses.shape[0])
    if cfg.prior_sigma_xy_m <= 0 and cfg.prior_sigma_yaw_rad <= 0:
        return c
    e = _offset(poses, predicted)
    if cfg.prior_sigma_xy_m > 0:
        c += (e[:, 0] ** 2 + e[:, 1] ** 2) * (0.5 / cfg.prior_sigma_xy_m**2)
    if cfg.prior_sigma_yaw_rad > 0:
        c += e[:, 2] ** 2 * (0.5 / cfg.prior_sigma_yaw_rad**2)
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
    prior: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Damped Gauss-Newton refinement of ``sum r(p_i)^2`` for every pose (vectorised), plus a
    motion prior if given.

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
    prior : tuple of numpy.ndarray, optional
        ``(predicted (N, 3), weights (3,))``: the cost gains ``sum_k w_k e_k^2``, ``e`` the pose's
        offset from its predicted pose (x, y, yaw): a least-squares prior that holds the pose
        where the scan's own curvature is weak (along a bare corridor) and yields where it is
        strong (``correlation.refine_prior_xy_m``).

    Returns
    -------
    poses : numpy.ndarray
        ``(N, 3)`` refined poses.
    cost : numpy.ndarray
        ``(N,)`` ``sum r^2`` (and the prior's term) at the refined poses.
    """
    x = np.array(poses, dtype=np.float64).reshape(-1, 3)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    d, gx, gy, rx, ry = _cost(x, pts, field, residual, precision)
    cost = _rowdot(d, d) + _prior_term(x, prior, None)
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
        if prior is not None:
            e = _offset(x[active], prior[0][active])
            if prior[1].ndim == 1:
                h[:, diag, diag] += prior[1]
                b += prior[1] * e
            else:
                h += prior[1][active]
                b += np.einsum("nij,nj->ni", prior[1][active], e)
        h[:, diag, diag] = h[:, diag, diag] * (1.0 + 1e-3) + 1e-9  # Levenberg damping
        step = -np.linalg.solve(h, b[:, :, None])[..., 0]
        t = np.hypot(step[:, 0], step[:, 1])
        step[:, :2] *= np.minimum(1.0, max_t / np.maximum(t, 1e-12))[:, None]
        np.clip(step[:, 2], -max_r, max_r, out=step[:, 2])
        xn = x[active] + step
        dn, gxn, gyn, rxn, ryn = _cost(xn, pts, field, residual, precision)
        cn = _rowdot(dn, dn) + _prior_term(xn, prior, active)
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


def _prior_term(poses: np.ndarray, prior: tuple[np.ndarray, np.ndarray] | None, rows: np.ndarray | None):
    """``(N,)`` the refinement prior's cost ``sum_k w_k e_k^2`` of ``poses`` (the prior's rows
    ``rows``; None: all), or 0 without a prior."""
    if prior is None:
        return 0.0
    e = _offset(poses, prior[0] if rows is None else prior[0][rows])
    if prior[1].ndim == 1:
        return (e * e) @ prior[1]
    w = prior[1] if rows is None else prior[1][rows]
    return np.einsum("ni,nij,nj->n", e, w, e)


def _distances(poses: np.ndarray, pts: np.ndarray, field: LikelihoodField, precision: str) -> np.ndarray:
    """``(N, M)`` bilinear obstacle distance of the points at every pose."""
    return _bilinear_at(poses, pts, field, field._dist_flat, False, precision)


def usable_points(
    points_sensor: np.ndarray, cfg: CorrelationConfig, match: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The points :func:`correlate` scores (those within ``cfg.range_max_m``) and those it
    matches with (of them, the ones ``match`` keeps)."""
    pts = np.asarray(points_sensor, dtype=np.float64).reshape(-1, 2)
    near = np.hypot(pts[:, 0], pts[:, 1]) <= cfg.range_max_m
    matched = pts[near] if match is None else pts[near & np.asarray(match, dtype=bool).reshape(-1)]
    return pts[near], matched


def weighing_points(pts: np.ndarray, cfg: CorrelationConfig) -> np.ndarray:
    """The usable points (``(M, 2)``, scan order) that weigh the particles: all of them, less the
    sparse grazing samples (``cfg.weigh_graze_span_m``) and those within
    ``cfg.weigh_range_margin_m`` of ``cfg.range_max_m``."""
    keep = np.ones(pts.shape[0], dtype=bool)
    if cfg.weigh_graze_span_m > 0:
        keep &= ~grazing_samples(pts, cfg.weigh_graze_span_m)
    if cfg.weigh_range_margin_m > 0:
        keep &= np.hypot(pts[:, 0], pts[:, 1]) <= cfg.range_max_m - cfg.weigh_range_margin_m
    return pts if keep.all() else pts[keep]


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
    sigma^2)`` over the points :func:`weighing_points` keeps at the refinement's stride (0 when no
    beam is usable), weighs the particles.
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    pts, matched = usable_points(points_sensor, cfg, match)
    if matched.shape[0] == 0:
        return poses.copy(), np.zeros(poses.shape[0])
    best, _ = window_search(poses, matched[:: cfg.beam_stride], field, cfg)
    it, res = cfg.refine_iterations, cfg.refine_residual
    prior = weak = None
    if cfg.refine_prior_xy_m > 0 or cfg.refine_prior_yaw_rad > 0:
        w = np.array([_inv_sq(cfg.refine_prior_xy_m)] * 2 + [_inv_sq(cfg.refine_prior_yaw_rad)])
        if cfg.refine_prior_shape == "weak" and w[0] > 0:
            w, weak = _weak_prior(best, matched[:: cfg.refine_beam_stride], field, cfg, w)
        prior = (poses, w)
    best, _ = refine(best, matched[:: cfg.refine_beam_stride], field, it, res, cfg.precision, prior)
    if cfg.degenerate_ratio > 0:
        best = _drop_degenerate(poses, best, matched[:: cfg.refine_beam_stride], field, cfg)
    refine_pts = weighing_points(pts, cfg)[:: cfg.refine_beam_stride]
    scored = _along_weak_to_mean(best, *weak) if weak is not None and cfg.weak_score else best
    score = _score(scored, poses, refine_pts, field, cfg)
    if cfg.prior_sigma_xy_m > 0 or cfg.prior_sigma_yaw_rad > 0:
        score0 = _score(poses, poses, refine_pts, field, cfg)
        stay = score0 >= score
        best[stay] = poses[stay]
        score = np.where(stay, score0, score)
    if cfg.gain_xy < 1.0 or cfg.gain_yaw < 1.0:
        best, score = _blend(poses, best, refine_pts, field, cfg)
    return best, score


#: ``correlation.degenerate_ratio``: a match counts as degenerate only where its strong direction
#: holds at least this share of the points (gradient terms), i.e. the scan lies on the map there.
#: Flagged corridor matches had 0.4-0.98; the sparse scans of the outdoor campus 0.01-0.1.
MATCHED_SHARE = 0.25


def _drop_degenerate(
    predicted: np.ndarray, best: np.ndarray, pts: np.ndarray, field: LikelihoodField, cfg: CorrelationConfig
) -> np.ndarray:
    """``best`` with the shift from ``predicted`` along each match's weak direction removed
    (``cfg.degenerate_ratio``): where the smaller eigenvalue of the points' ``sum g g^T``
    (obstacle-distance gradients at the matched pose) is below ``degenerate_ratio`` times the
    number of points while the larger one is at least :data:`MATCHED_SHARE` times it (the scan
    lies on the map across the weak direction: a corridor), only the part of the shift along
    the larger one's eigenvector is kept. A scan that matches nothing well (open space, a few
    returns, a lost particle) is left as it is."""
    if pts.shape[0] == 0:
        return best
    strong, weak, ang = _gradient_eigen(best, pts, field, cfg.precision)
    m = pts.shape[0]
    bad = (weak < cfg.degenerate_ratio * m) & (strong >= MATCHED_SHARE * m)
    if not bad.any():
        return best
    strong_ang = ang[bad]  # the larger eigenvalue's direction
    vx, vy = np.cos(strong_ang), np.sin(strong_ang)
    dx, dy = best[bad, 0] - predicted[bad, 0], best[bad, 1] - predicted[bad, 1]
    along = dx * vx + dy * vy
    out = best.copy()
    out[bad, 0] = predicted[bad, 0] + along * vx
    out[bad, 1] = predicted[bad, 1] + along * vy
    return out


def _weak_prior(best: np.ndarray, pts: np.ndarray, field: LikelihoodField, cfg: CorrelationConfig, w: np.ndarray):
    """``(N, 3, 3)`` refinement-prior weights (``w``: the isotropic ones, ``(3,)``) that hold each
    match only along its weak direction (``correlation.refine_prior_shape = 'weak'``): the x, y
    weight along the weak eigenvector of the points' ``sum a g g^T`` at ``best`` (``g`` the
    obstacle-distance gradient, ``a = exp(-d^2 / 2 sigma^2)``) is ``w * (1 - weak / strong) *
    min(1, strong / (MATCHED_SHARE * points))``, along the strong one 0; the yaw weight is kept.
    Also returns ``(f, ux, uy)``: that fraction and the weak eigenvector, each ``(N,)``."""
    strong, weak, ang = _gradient_eigen(best, pts, field, cfg.precision, cfg.sigma_m)
    f = (1.0 - weak / np.maximum(strong, 1e-12)) * np.minimum(1.0, strong / (MATCHED_SHARE * pts.shape[0]))
    ux, uy = -np.sin(ang), np.cos(ang)  # the weak eigenvector
    out = np.zeros((best.shape[0], 3, 3))
    out[:, 0, 0] = w[0] * f * ux * ux
    out[:, 1, 1] = w[0] * f * uy * uy
    out[:, 0, 1] = out[:, 1, 0] = w[0] * f * ux * uy
    out[:, 2, 2] = w[2]
    return out, (f, ux, uy)


def _along_weak_to_mean(best: np.ndarray, f: np.ndarray, ux: np.ndarray, uy: np.ndarray) -> np.ndarray:
    """``best`` with each pose moved along its weak direction ``(ux, uy)``, by ``f`` of the way, to
    the set's mean there: the poses the weights are computed at."""
    mean = best[:, :2].mean(axis=0)
    along = (best[:, 0] - mean[0]) * ux + (best[:, 1] - mean[1]) * uy
    out = best.copy()
    out[:, 0] -= f * along * ux
    out[:, 1] -= f * along * uy
    return out


def _gradient_eigen(poses: np.ndarray, pts: np.ndarray, field: LikelihoodField, precision: str, sigma: float = 0.0):
    """``(strong, weak, angle)``, each ``(N,)``: the eigenvalues of the points' ``sum a g g^T``
    (``g`` the obstacle-distance gradient at each pose; ``a = exp(-d^2 / 2 sigma^2)``, or 1 for
    ``sigma`` 0) and the strong eigenvector's direction (rad)."""
    d, gx, gy, _, _ = _bilinear_at(poses, pts, field, field._dist_flat, True, precision)
    agx, agy = gx, gy
    if sigma > 0:
        a = np.exp(-0.5 * (d / sigma) ** 2)
        agx, agy = a * gx, a * gy
    sxx, syy, sxy = _rowdot(agx, gx), _rowdot(agy, gy), _rowdot(agx, gy)
    half_tr, det_part = 0.5 * (sxx + syy), np.hypot(0.5 * (sxx - syy), sxy)
    return half_tr + det_part, half_tr - det_part, 0.5 * np.arctan2(2.0 * sxy, sxx - syy)


def _inv_sq(sigma: float) -> float:
    """``sigma^-2``, 0 for ``sigma`` 0 (no prior on that axis)."""
    return sigma**-2 if sigma > 0 else 0.0


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
