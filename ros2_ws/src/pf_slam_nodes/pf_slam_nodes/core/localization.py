"""Localization on a fixed map: where the particles start, and when the set has converged.

Arrays in and out (no ROS, no files). The correlation stage (:class:`~.stages.CorrectionStage`
with :meth:`~.stages.CorrectionStage.set_map`) runs this; the map comes from outside.

**Initialisation.** Candidate poses are drawn from the prior -- uniformly over the map's free
cells with a uniform heading (global: ``localization.global_candidates_per_m2`` per m^2 of free
space, at most ``localization.max_candidates``), or from the Gaussian of an initial pose
(``/initialpose``'s covariance, ``localization.pose_candidates`` of them, those on free cells
kept) -- and scored against a *coarse* likelihood field of the map (``coarse_sigma_m``, wider
than the correlation's, so a candidate a few cells and degrees off the truth still scores well)
with ``coarse_beams`` of the scan's points. The ``init_particles`` best become the particle set
(uniform weights); the correlation stage then matches each of them in its window and weighs them
as usual, and the following corrections (with resampling) decide between the hypotheses left.

**Convergence.** While the set's size is not ``filter.num_particles``, every correction checks
the weighted spread (position std and circular heading std); once both are below
``converged_xy_m`` / ``converged_yaw_rad`` the set is resampled to ``filter.num_particles``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .config import CorrelationConfig, LocalizationConfig
from .correlation import _REMAP_MAX_CELLS, _points_in_table, _use_remap
from .filter import _resample_from_u, normalize_log_weights
from .geometry import wrap_angle
from .likelihood import LikelihoodField, build_likelihood_field

# keep the (chunk, M) point arrays of the coarse scoring below this many elements
_CHUNK_ELEMENTS = 4_000_000


#: occupancy values (0..100) counted as free space (map_server trinary writes 0)
FREE_MAX = 25


def free_mask(occupancy: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: the cells known to be free (occupancy 0..``FREE_MAX``), where a robot
    may stand."""
    occ = np.asarray(occupancy)
    return (occ >= 0) & (occ <= FREE_MAX)


def sample_free_poses(free: np.ndarray, resolution: float, origin, n: int, rng: np.random.Generator) -> np.ndarray:
    """``(n, 3)`` poses uniform over the free cells (uniform within a cell) with uniform heading."""
    idx = np.flatnonzero(np.asarray(free, dtype=bool).reshape(-1))
    if idx.size == 0:
        raise ValueError("the map has no free cell to place particles on")
    w = free.shape[1]
    pick = idx[rng.integers(0, idx.size, size=n)]
    rows, cols = np.divmod(pick, w)
    off = rng.random((n, 2))
    ox, oy = float(origin[0]), float(origin[1])
    out = np.empty((n, 3))
    out[:, 0] = ox + (cols + off[:, 0]) * resolution
    out[:, 1] = oy + (rows + off[:, 1]) * resolution
    out[:, 2] = rng.uniform(-math.pi, math.pi, size=n)
    return out


def sample_gaussian_poses(mean, cov: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``(n, 3)`` poses from ``N(mean, cov)`` (``cov``: ``(3, 3)`` over x, y, yaw; a
    non-positive-definite one is clipped to its non-negative eigenvalues), heading wrapped."""
    m = np.asarray(mean, dtype=np.float64).reshape(3)
    c = np.asarray(cov, dtype=np.float64).reshape(3, 3)
    c = 0.5 * (c + c.T)
    if not np.isfinite(c).all() or not np.isfinite(m).all():
        raise ValueError("initial pose and covariance must be finite")
    vals, vecs = np.linalg.eigh(c)
    root = vecs * np.sqrt(np.clip(vals, 0.0, None))[None, :]
    out = m[None, :] + rng.standard_normal((n, 3)) @ root.T
    out[:, 2] = wrap_angle(out[:, 2])
    return out


def coarse_scores(poses: np.ndarray, points: np.ndarray, field: LikelihoodField) -> np.ndarray:
    """``(N,)`` summed nearest-cell log-likelihood of robot-frame ``points`` ``(M, 2)`` seen from
    every pose ``(N, 3)``: one OpenCV nearest remap per chunk of poses (the same result for any
    chunking); points beyond the field score the clamp value."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    n, m = poses.shape[0], pts.shape[0]
    out = np.zeros(n)
    if m == 0:
        return out
    remap = _use_remap(field, m)
    chunk = max(1, min(_REMAP_MAX_CELLS - 1, _CHUNK_ELEMENTS // m))
    clamp = float(field.min_log_likelihood)
    for i0 in range(0, n, chunk):
        p = poses[i0 : i0 + chunk]
        if remap:
            u, v, _, _ = _points_in_table(p, pts, field, np.float32)
            vals = cv2.remap(field._loglik, u, v, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=clamp)
        else:  # a table too large for remap (32,000 cells or more on a side): index arithmetic
            c, s = np.cos(p[:, 2:3]), np.sin(p[:, 2:3])
            vals = field.lookup(
                np.stack(
                    [p[:, 0:1] + c * pts[:, 0] - s * pts[:, 1], p[:, 1:2] + s * pts[:, 0] + c * pts[:, 1]], axis=-1
                )
            )
        out[i0 : i0 + chunk] = vals.sum(axis=1, dtype=np.float64)
    return out


def spread(particles: np.ndarray, log_weights: np.ndarray) -> tuple[float, float]:
    """Weighted spread of a set: (position std = sqrt of the trace of the xy covariance (m),
    circular heading std ``sqrt(-2 ln R)`` (rad))."""
    p = np.asarray(particles, dtype=np.float64).reshape(-1, 3)
    w = np.exp(normalize_log_weights(log_weights))
    w /= w.sum()
    mx, my = w @ p[:, 0], w @ p[:, 1]
    var = w @ ((p[:, 0] - mx) ** 2 + (p[:, 1] - my) ** 2)
    r = math.hypot(w @ np.cos(p[:, 2]), w @ np.sin(p[:, 2]))
    return math.sqrt(max(var, 0.0)), math.sqrt(-2.0 * math.log(min(max(r, 1e-300), 1.0)))


class Localizer:
    """The fixed map's free space and coarse field, and the initialisation / convergence rules.

    Parameters
    ----------
    occupancy : numpy.ndarray
        ``(H, W)`` int8 map (-1 unknown, 0..100; row 0 = lowest y).
    resolution : float
        Cell size (m).
    origin : array_like
        ``(2,)`` world position of cell (0, 0)'s corner (m).
    corr_cfg : CorrelationConfig
        ``occupied_threshold`` (what is an obstacle).
    cfg : LocalizationConfig
    """

    def __init__(
        self, occupancy: np.ndarray, resolution: float, origin, corr_cfg: CorrelationConfig, cfg: LocalizationConfig
    ) -> None:
        occ = np.asarray(occupancy)
        self.cfg = cfg
        self.resolution = float(resolution)
        self.origin = np.asarray(origin, dtype=np.float64).reshape(-1)[:2].copy()
        self.free = free_mask(occ)
        self.free_area_m2 = float(self.free.sum()) * self.resolution**2
        if self.free_area_m2 <= 0:
            raise ValueError("the map has no free cell (occupancy 0): nowhere to localize")
        self.coarse = build_likelihood_field(
            occ, self.resolution, cfg.coarse_sigma_m, corr_cfg.occupied_threshold, self.origin, 3.0 * cfg.coarse_sigma_m
        )

    @property
    def global_candidates(self) -> int:
        """Candidate poses of a global initialisation: per m^2 of free space, bounded."""
        c = self.cfg
        return int(min(c.max_candidates, max(c.init_particles, round(c.global_candidates_per_m2 * self.free_area_m2))))

    def on_free(self, poses: np.ndarray) -> np.ndarray:
        """``(N,)`` bool: the poses standing on a free cell of the map."""
        cells = np.floor((np.asarray(poses)[:, :2] - self.origin) / self.resolution).astype(np.int64)
        h, w = self.free.shape
        ok = (cells[:, 0] >= 0) & (cells[:, 0] < w) & (cells[:, 1] >= 0) & (cells[:, 1] < h)
        out = np.zeros(ok.shape, dtype=bool)
        out[ok] = self.free[cells[ok, 1], cells[ok, 0]]
        return out

    def candidates(self, rng: np.random.Generator, mean=None, cov=None) -> np.ndarray:
        """Candidate poses from the prior: global (``mean`` None) or ``N(mean, cov)`` (those on
        free cells; all of them if none is)."""
        if mean is None:
            return sample_free_poses(self.free, self.resolution, self.origin, self.global_candidates, rng)
        cand = sample_gaussian_poses(mean, cov, self.cfg.pose_candidates, rng)
        keep = self.on_free(cand)
        return cand[keep] if keep.any() else cand

    def initial_set(self, points: np.ndarray, rng: np.random.Generator, mean=None, cov=None) -> np.ndarray:
        """``(init_particles, 3)`` particles: the best-scoring candidates of the prior against
        the coarse field with ``coarse_beams`` of the robot-frame scan ``points`` ``(M, 2)``
        (without points: random candidates). Ordered by score, best first."""
        cand = self.candidates(rng, mean, cov)
        k = min(self.cfg.init_particles, cand.shape[0])
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if pts.shape[0] == 0:
            return cand[:k].copy()
        stride = max(1, int(math.ceil(pts.shape[0] / self.cfg.coarse_beams)))
        scores = coarse_scores(cand, pts[::stride], self.coarse)
        best = np.argsort(-scores, kind="stable")[:k]
        return cand[best].copy()

    def converged(self, particles: np.ndarray, log_weights: np.ndarray) -> bool:
        """Whether the set's spread is below ``converged_xy_m`` and ``converged_yaw_rad``."""
        sxy, syaw = spread(particles, log_weights)
        return sxy <= self.cfg.converged_xy_m and syaw <= self.cfg.converged_yaw_rad

    @staticmethod
    def reduce(
        particles: np.ndarray, log_weights: np.ndarray, n: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """Resample a set to ``n`` particles (stratified, by weight; uniform weights)."""
        idx = _resample_from_u(log_weights, (np.arange(n) + rng.random(n)) / n)
        return np.asarray(particles)[idx].copy(), np.full(n, -math.log(n))


def initial_cov(cfg: LocalizationConfig) -> np.ndarray:
    """``(3, 3)`` covariance of the parameter-given initial pose (diagonal)."""
    return np.diag([cfg.initial_sigma_xy_m**2, cfg.initial_sigma_xy_m**2, cfg.initial_sigma_yaw_rad**2])


def pending_from_config(cfg: LocalizationConfig) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The initialisation the parameters ask for: ``(mean, cov)`` or ``(None, None)`` (global)."""
    if not cfg.use_initial_pose:
        return None, None
    return np.array([cfg.initial_pose_x_m, cfg.initial_pose_y_m, cfg.initial_pose_yaw_rad]), initial_cov(cfg)


__all__ = [
    "FREE_MAX",
    "Localizer",
    "coarse_scores",
    "free_mask",
    "initial_cov",
    "pending_from_config",
    "sample_free_poses",
    "sample_gaussian_poses",
    "spread",
]
