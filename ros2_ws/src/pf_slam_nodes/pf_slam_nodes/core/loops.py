"""Loop closure on top of the filter: keyframes, submap-to-submap loop matches, a pose graph.

The filter matches every scan against the one map it builds, so its error is a random walk of
small match errors that nothing pulls back once the robot returns to a place beyond its search
window: the revisit is mapped beside the first visit, offset. :class:`LoopCloser` keeps a pose
graph of keyframes (a corrected scan every ``keyframe_m`` of travel), chained by the filter's
own relative poses, and adds a loop edge where a keyframe's recent surroundings (the scans of
the last ``submap_m`` of travel, as one local map in its frame) match the surroundings of an
earlier keyframe near it (the scans within ``submap_m`` of travel around that one). The graph
is solved (core/posegraph.py) when an accepted loop edge disagrees with the current solution, or
before its corrections are next read (:data:`AGREES_CHI2`); any pose of the run then moves with
the correction of the keyframes around it in time.

A loop match must be exact and unique to be kept. It is searched exhaustively on a coarse
field over a window that grows with the travel since the last closed loop, then its best
candidates are refined on a fine field (Gauss-Newton). A query point scores +1 within
``2 sigma`` of a reference point (an inlier), -1 in the free space the reference's scans saw
(a contradiction: a wall where the earlier visit saw through), 0 where the reference saw
nothing; the best candidate needs ``min_inliers`` (more in a wide search: :func:`min_inliers`),
at most ``max_contradictions``, and must beat every candidate ``ambiguity_m`` or more away by
``min_margin`` (a corridor of identical doors has several). A match can still slide: along a
street or a corridor whose walls fit at every shift the score falls slowly from the best, with
no rival far enough to refuse it; the loop edge then holds across and in yaw as tightly as any,
and along that direction loosely (:func:`loop_information`). The solution drops loop edges that
disagree with the rest (``max_chi2``).

The odometry's scale (``loops.scale_early_travel``): until ``correlation.odom_scale`` has a first
estimate (two scan pairs, tens to hundreds of metres), the filter predicts with the wheels' scale
and, along a street, its matches correct only part of that error, so the whole trajectory after
it is offset by the early stretch's error. Each keyframe carries its odometry pose and the scale
its set was predicted with; the sequential edges before the first scaled keyframe are rescaled
by ``latest scale x odometry travel / filter travel`` over that stretch (what the matches already
corrected is not corrected twice), at every solve, so the final trajectory and map follow the
latest estimate.

Scan pairs (``loops.pair_baseline_m``): the filter's relative poses can be biased along the
direction of travel (a noisy laser's walls pull the matches ahead, the map follows the
odometry's scale along a street), and a closed loop cannot see it: a loop stretched by the same
factor everywhere still closes. At the end of the run each keyframe's scan is matched against the
keyframe ``pair_baseline_m`` of travel back by the symmetric scan-to-scan cost of
core/scanpair.py, which follows neither the map nor the odometry, and each pair that measures its
travel joins the final solve as an edge along the direction of travel.

Frames: the poses given to :meth:`LoopCloser.add` are the filter's in one fixed frame, the *raw*
frame (the stages keep the filter's own frame changes out of it: core/stages.py). The
corrections map raw poses into the optimised frame.

ROS-free and file-free: arrays in, arrays out.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from .config import CorrelationConfig
from .deferred import Offload, inline
from .geometry import compose, relative_pose, wrap_angle
from .loopconfig import LoopClosureConfig
from .posegraph import edge_errors, optimize
from .scan import transform_points, transform_points_batch
from .scanpair import PairScan, pair_scan, pair_travel

#: a match's weakest direction is trusted as much as the others when its score falls by
#: ``min_margin`` or more within ``ambiguity_m / 2`` along it; its std grows as the fall shrinks,
#: up to this factor (a flat ridge: the edge then barely holds along it)
MAX_SLIDE_FACTOR = 30.0

#: a new loop edge that the current solution already satisfies within this chi-square (about one
#: sigma) is added without solving the graph again (the solve waits for one that does not, or for
#: the next read of the corrections): revisits that agree with the filter cost nothing
AGREES_CHI2 = 1.0

#: ``scale_early_travel`` leaves the early travel as it is when the ratio it would apply is
#: farther than this from 1 (the filter's travel there is not the odometry's scaled: a slide, a
#: recovery)
EARLY_SCALE_MAX = 0.03

#: scan pairs (``pair_baseline_m``): the along-track search is +- 2 x this share of the travel (at
#: least 0.2 m), a pair counts where its cost has a clear minimum (second difference per m^2, as
#: ``correlation.odom_scale_min_curvature``), each scan's field reaches this many ``sigma_m`` and
#: joins neighbouring beams' ends up to this far apart (m) by lines
PAIR_MAX_ERROR = 0.03
PAIR_MIN_CURVATURE = 1000.0
PAIR_FIELD_SIGMAS = 6.0
PAIR_FILL_M = 2.0


@dataclasses.dataclass
class LoopEdge:
    ref: int  # keyframe matched against (the earlier place)
    cur: int  # keyframe whose recent surroundings were matched
    z: np.ndarray  # (3,) pose of cur in ref's frame
    score: float
    rival: float
    info: np.ndarray  # (3, 3) information matrix, in z's frame (core/posegraph.py)


def min_inliers(cfg: LoopClosureConfig, window_m: float) -> float:
    """The inlier share a match over a ``window_m`` half-width (and ``cfg.window_rad``) needs:
    ``min_inliers``, plus ``look_elsewhere`` per e-fold of the search volume beyond
    ``look_elsewhere_m`` x ``look_elsewhere_rad`` (the more poses searched, the better the best
    wrong one fits: the outdoor campus, at 10 m / 0.25 rad, matched a place 10.5 m off at 0.50-0.52)."""
    ratio = (window_m / cfg.look_elsewhere_m) ** 2 * (cfg.window_rad / cfg.look_elsewhere_rad)
    return cfg.min_inliers + (cfg.look_elsewhere * math.log(ratio) if ratio > 1.0 else 0.0)


def _voxel(points: np.ndarray, size: float) -> np.ndarray:
    """One point per ``size`` cell (the first in order)."""
    if points.shape[0] == 0:
        return points
    keys = np.floor(points / size).astype(np.int64)
    _, first = np.unique(keys[:, 0] * 2_000_003 + keys[:, 1], return_index=True)
    return points[np.sort(first)]


class _Field:
    """A reference point set on a local grid: the distance to its nearest point, the match
    table ``exp(-d^2 / 2 sigma^2)``, and the free space its scans saw (their polygons, farther
    than ``3 sigma`` from any point)."""

    def __init__(self, pts: np.ndarray, polys: list, res: float, sigma: float, margin: float) -> None:
        self.res = res
        self.origin = pts.min(axis=0) - margin
        w, h = (np.ceil((pts.max(axis=0) + margin - self.origin) / res).astype(np.int64) + 1).tolist()
        occ = np.full((h, w), 255, np.uint8)
        c = np.floor((pts - self.origin) / res).astype(np.int64)
        occ[c[:, 1], c[:, 0]] = 0
        self.dist = cv2.distanceTransform(occ, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * np.float32(res)
        self.like = np.exp(-0.5 * (self.dist / np.float32(sigma)) ** 2)
        seen = np.zeros((h, w), np.uint8)
        cv2.fillPoly(seen, [np.floor((p - self.origin) / res).astype(np.int32) for p in polys], 1)
        self.free = ((seen > 0) & (self.dist > np.float32(3 * sigma))).astype(np.float32)
        self.h, self.w = h, w

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ix = np.floor((xy[..., 0] - self.origin[0]) / self.res).astype(np.int64)
        iy = np.floor((xy[..., 1] - self.origin[1]) / self.res).astype(np.int64)
        return ix, iy

    def lookup(self, table: np.ndarray, xy: np.ndarray, outside: float) -> np.ndarray:
        """Nearest-cell values at world points ``(..., 2)``; ``outside`` beyond the grid."""
        ix, iy = self.cells(xy)
        ok = (ix >= 0) & (ix < self.w) & (iy >= 0) & (iy < self.h)
        out = np.full(ix.shape, outside, np.float32)
        out[ok] = table[iy[ok], ix[ok]]
        return out

    def bilinear(self, table: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``table`` (values at cell centres) interpolated at world points ``(..., 2)`` and its
        gradient (per m); clamped to the grid's edge."""
        u = np.clip((xy[..., 0] - self.origin[0]) / self.res - 0.5, 0.0, self.w - 1.001)
        v = np.clip((xy[..., 1] - self.origin[1]) / self.res - 0.5, 0.0, self.h - 1.001)
        u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        fu, fv = u - u0, v - v0
        d00, d01 = table[v0, u0], table[v0, u0 + 1]
        d10, d11 = table[v0 + 1, u0], table[v0 + 1, u0 + 1]
        top, bot = d00 + fu * (d01 - d00), d10 + fu * (d11 - d10)
        gx = ((1.0 - fv) * (d01 - d00) + fv * (d11 - d10)) / self.res
        return top + fv * (bot - top), gx, (bot - top) / self.res


def match_submaps(
    query: np.ndarray, ref: np.ndarray, ref_polys: list, guess: np.ndarray, window_m: float, cfg: LoopClosureConfig
) -> tuple[np.ndarray, float, float, float, float, tuple[np.ndarray, float]] | None:
    """The pose of the query's frame in the reference's frame within ``window_m`` (and
    ``cfg.window_rad``) of ``guess``: ``(pose (3,), score, inliers, contradictions, rival,
    slide)``, or None when either point set has fewer than 30 points. ``query``, ``ref``:
    ``(M, 2)`` points in their own frames; ``ref_polys``: the reference scans' free-space
    polygons in its frame. ``score`` = inliers - contradictions (shares of the query's points);
    ``rival``: the best score of a candidate ``ambiguity_m`` or more away (-1 if none);
    ``slide``: ``(u, fall)``, the unit direction (reference frame) along which the fit is least
    curved at the pose, and how much the score falls ``ambiguity_m / 2`` along it either way
    (the smaller fall of the two)."""
    if query.shape[0] < 30 or ref.shape[0] < 30:
        return None
    # the fields cover the reference (and a cell or two): a query point beyond them scores 0
    coarse = _Field(ref, ref_polys, cfg.coarse_m, max(cfg.coarse_m, 2 * cfg.sigma_m), 2 * cfg.coarse_m)
    fine = _Field(ref, ref_polys, cfg.resolution_m, cfg.sigma_m, 6 * cfg.sigma_m)
    q = (
        query
        if query.shape[0] <= cfg.max_points
        else query[np.linspace(0, query.shape[0] - 1, cfg.max_points).astype(np.int64)]
    )
    # rotation steps that move the farthest point by about one coarse cell
    dyaw = min(cfg.coarse_m / max(float(np.hypot(q[:, 0], q[:, 1]).max()), 1.0), cfg.window_rad)
    ny = int(math.floor(cfg.window_rad / dyaw + 1e-9))
    yaws = guess[2] + np.arange(-ny, ny + 1) * dyaw
    k = int(math.floor(window_m / cfg.coarse_m + 1e-9))
    sh = np.arange(-k, k + 1)
    # a band of 2k+1 neutral cells around the field: a point beyond it is clipped into the band's
    # middle, so its k shifts either way read 0 (nothing seen there) and stay inside the table
    pad = 2 * k + 1
    table = np.pad(coarse.like - coarse.free, pad)
    hp, wp = table.shape
    c, s = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
    rot = np.stack([guess[0] + c * q[:, 0] - s * q[:, 1], guess[1] + s * q[:, 0] + c * q[:, 1]], axis=-1)
    ix, iy = coarse.cells(rot)  # (R, M)
    base = np.clip(iy + pad, k, hp - 1 - k) * wp + np.clip(ix + pad, k, wp - 1 - k)
    offs = (sh[:, None] * wp + sh[None, :]).ravel()  # (dy, dx), dy-major
    flat = table.ravel()
    scores = np.stack([flat[b[None, :] + offs[:, None]].sum(axis=1) for b in base])  # (R, S)
    best_r = scores.argmax(axis=0)
    grid = scores.max(axis=0).reshape(sh.size, sh.size).astype(np.float32)
    peaks = np.argwhere(grid >= cv2.dilate(grid, np.ones((3, 3), np.uint8)) - 1e-6)
    order = np.argsort(-grid[peaks[:, 0], peaks[:, 1]], kind="stable")[: cfg.candidates]
    cands = np.array(
        [
            [guess[0] + sh[b] * cfg.coarse_m, guess[1] + sh[a] * cfg.coarse_m, yaws[best_r[a * sh.size + b]]]
            for a, b in peaks[order]
        ]
    )
    # the distance clamped at 3 sigma: what the refinement fits and the weakest direction is read on
    clamped = np.minimum(fine.dist, np.float32(3 * cfg.sigma_m))
    poses, score, inl, con = _refine(cands, query, fine, clamped, cfg)
    bi = int(np.argmax(score))
    far = np.hypot(poses[:, 0] - poses[bi, 0], poses[:, 1] - poses[bi, 1]) >= cfg.ambiguity_m
    rival = float(score[far].max()) if far.any() else -1.0
    u = _weakest(poses[bi], query, fine, clamped)
    shifted = poses[bi] + np.array([[u[0], u[1], 0.0], [-u[0], -u[1], 0.0]]) * (0.5 * cfg.ambiguity_m)
    fall = float(score[bi]) - float(_scores(shifted, query, fine, cfg)[0].max())
    return poses[bi], float(score[bi]), float(inl[bi]), float(con[bi]), rival, (u, fall)


def loop_information(cfg: LoopClosureConfig, z: np.ndarray, slide) -> np.ndarray:
    """A loop edge's information matrix (3x3, in ``z``'s frame): ``loop_sigma_xy_m`` and
    ``loop_sigma_rad``, and along the match's weakest direction (``slide``:
    :func:`match_submaps`) the std times ``min_margin / fall`` (at least 1, at most
    :data:`MAX_SLIDE_FACTOR`)."""
    info = np.diag([cfg.loop_sigma_xy_m**-2] * 2 + [cfg.loop_sigma_rad**-2])
    u, fall = slide
    factor = min(max(cfg.min_margin / max(fall, 1e-9), 1.0), MAX_SLIDE_FACTOR)
    c, s = math.cos(z[2]), math.sin(z[2])
    uz = np.array([c * u[0] + s * u[1], -s * u[0] + c * u[1]])  # R_z^T u
    info[:2, :2] += (factor**-2 - 1.0) * cfg.loop_sigma_xy_m**-2 * np.outer(uz, uz)
    return info


class SubmapMatcher:
    """:func:`match_submaps` with its configuration, as an object a worker process can hold
    (core/deferred.py)."""

    def __init__(self, cfg: LoopClosureConfig) -> None:
        self.cfg = cfg

    def match(self, query: np.ndarray, ref: np.ndarray, ref_polys: list, guess: np.ndarray, window_m: float):
        return match_submaps(query, ref, ref_polys, guess, window_m, self.cfg)


def _refine(
    poses: np.ndarray, pts: np.ndarray, field: _Field, dist: np.ndarray, cfg: LoopClosureConfig, iterations: int = 15
):
    """Gauss-Newton on the squared distance ``dist`` (the field's, clamped at ``3 sigma``) from
    every pose; the score, inlier and contradiction shares at the results."""
    x = poses.copy()
    for _ in range(iterations):
        w = transform_points_batch(pts, x)  # (N, M, 2)
        d, ddx, ddy = field.bilinear(dist, w)
        rx, ry = w[..., 0] - x[:, 0:1], w[..., 1] - x[:, 1:2]
        jac = np.stack([ddx, ddy, ddy * rx - ddx * ry], axis=-1)  # (N, M, 3)
        h = np.einsum("nmk,nml->nkl", jac, jac) + np.eye(3) * 1e-6
        step = -np.linalg.solve(h, np.einsum("nmk,nm->nk", jac, d)[..., None])[..., 0]
        step[:, :2] = np.clip(step[:, :2], -cfg.resolution_m, cfg.resolution_m)
        step[:, 2] = np.clip(step[:, 2], -0.01, 0.01)
        x = x + step
        if np.abs(step).max() < 1e-4:
            break
    x[:, 2] = wrap_angle(x[:, 2])
    return (x, *_scores(x, pts, field, cfg))


def _scores(poses: np.ndarray, pts: np.ndarray, field: _Field, cfg: LoopClosureConfig):
    """The score, inlier and contradiction shares of the points at each pose ``(N, 3)``."""
    w = transform_points_batch(pts, poses)
    inl = (field.lookup(field.dist, w, np.inf) <= 2 * cfg.sigma_m).mean(axis=1)
    con = field.lookup(field.free, w, 0.0).mean(axis=1)
    return inl - con, inl, con


def _weakest(pose: np.ndarray, pts: np.ndarray, field: _Field, dist: np.ndarray) -> np.ndarray:
    """The unit translation (reference frame) along which the points' fit to ``dist`` (the
    field's clamped distance, as :func:`_refine` fits it) at ``pose`` is least curved: the
    smaller eigenvector of the distance gradients' 2x2 Gauss-Newton matrix."""
    _, gx, gy = field.bilinear(dist, transform_points_batch(pts, pose[None]))
    g = np.stack([gx[0], gy[0]], axis=1).astype(np.float64)
    return np.linalg.eigh(g.T @ g)[1][:, 0]


def scan_polygon(origin: np.ndarray, ends: np.ndarray, stride: int = 1) -> np.ndarray:
    """A scan's free-space polygon: the sensor's position, then its beams' ends in beam order
    (``ends`` ``(B, 2)``, a no-return beam at the range it cleared), every ``stride``-th."""
    return np.vstack([np.asarray(origin, dtype=np.float64).reshape(1, 2), np.asarray(ends, np.float64)[::stride]])


class LoopCloser:
    """Keyframes, loop matches and the pose graph. Feed it every corrected scan (:meth:`add`);
    read the corrections of any pose (:meth:`corrections`).

    A keyframe's loop match can run beside the caller (``offload``: a worker process,
    core/deferred.py): :meth:`start_keyframe` adds the keyframe and sends its match,
    :meth:`finish_keyframe` takes the answer and closes the loop. Nothing of the graph is read or
    changed in between, so the result is the same as :meth:`add_keyframe`'s, which does both."""

    def __init__(self, cfg: LoopClosureConfig, offload: Offload = inline) -> None:
        self.cfg = cfg
        self.matcher = offload(SubmapMatcher, (cfg,))
        self._open: tuple[int, int, float] | None = None  # (cur, ref, window) of the match sent
        self.stamps: list[float] = []  # keyframes: stamp (the caller's time key) ...
        self.raw: list[np.ndarray] = []  # ... the filter's pose (raw frame) ...
        self.travel: list[float] = []  # ... travel so far (m) ...
        self.points: list[np.ndarray] = []  # ... scan points (own frame, voxel-filtered) ...
        self.polys: list[np.ndarray] = []  # ... free-space polygon (own frame) ...
        self.noise: list[float] = []  # ... and its laser's range noise (m; NaN: not known)
        self.scale = 1.0  # the odometry scale applied to the latest keyframe's set
        # scale_early_travel: the keyframes' odometry poses (None: not given) while no set was scaled;
        # from the first scaled keyframe on, that stretch once: (edges, odometry travel, filter travel)
        self._early_odom: list[np.ndarray | None] | None = [] if cfg.scale_early_travel else None
        self._early: tuple[int, float, float] | None = None
        self.opt = np.zeros((0, 3))  # optimised keyframe poses
        self.mapped = np.zeros((0, 3))  # per keyframe: the correction its scan is mapped with
        self.map_frame = np.zeros(3)  # the correction of the scans mapped since the last rebuild
        self.loops: list[LoopEdge] = []
        self.attempts = 0
        self.rejected = 0  # matches too weak or ambiguous
        self.dropped = 0  # loop edges the solution disagreed with
        self.log: list[tuple] = []  # (cur, ref, pose, score, inliers, contradictions, rival, kept)
        self._travel = 0.0
        self._last: np.ndarray | None = None
        self._last_attempt = -math.inf
        self._last_loop = 0.0
        self._unsolved = False  # loop edges added since the last solve
        self.pairs: list[tuple[int, int, np.ndarray, np.ndarray]] = []  # scan-pair edges (ref, cur, z, info)

    def __len__(self) -> int:
        return len(self.raw)

    def add(
        self,
        stamp: float,
        pose: np.ndarray,
        points: np.ndarray,
        polygon: np.ndarray,
        odom: np.ndarray | None = None,
        scale: float = 1.0,
        noise: float = math.nan,
    ) -> bool:
        """A corrected scan: its stamp (any increasing time key), the filter's pose (raw frame),
        its points and free-space polygon (:func:`scan_polygon`) in its own frame, its odometry
        pose and the odometry scale its set was predicted with (``correlation.odom_scale``; for
        ``scale_early_travel``), its laser's range noise (m; for ``pair_min_noise_m``). True when
        the scan closed a loop (the optimised poses changed)."""
        return self.observe(pose) and self.add_keyframe(stamp, pose, points, polygon, odom, scale, noise)

    def observe(self, pose: np.ndarray) -> bool:
        """A corrected scan's pose (raw frame): True when it is to be a keyframe (then give it
        to :meth:`add_keyframe`; the caller computes its points only then)."""
        cfg = self.cfg
        pose = np.asarray(pose, dtype=np.float64).reshape(3)
        if self._last is not None:
            self._travel += math.hypot(pose[0] - self._last[0], pose[1] - self._last[1])
        self._last = pose
        return not self.raw or (
            self._travel - self.travel[-1] >= cfg.keyframe_m
            or abs(wrap_angle(pose[2] - self.raw[-1][2])) >= cfg.keyframe_rad
        )

    def add_keyframe(
        self,
        stamp: float,
        pose: np.ndarray,
        points: np.ndarray,
        polygon: np.ndarray,
        odom: np.ndarray | None = None,
        scale: float = 1.0,
        noise: float = math.nan,
    ) -> bool:
        """The keyframe :meth:`observe` asked for; True when it closed a loop."""
        self.start_keyframe(stamp, pose, points, polygon, odom, scale, noise)
        return self.finish_keyframe()

    @property
    def waiting(self) -> bool:
        """A loop match was sent and :meth:`finish_keyframe` has not taken it yet."""
        return self._open is not None

    def ready(self) -> bool:
        """:meth:`finish_keyframe` would not wait (no match open, or its answer is here)."""
        return self._open is None or self.matcher.ready()

    def close(self) -> None:
        """Stop the home of the loop matches (a worker process)."""
        self.matcher.close()

    def finish_keyframe(self) -> bool:
        """The answer to the keyframe's loop match, if one was sent (waits for it); True when it
        closed a loop."""
        if self._open is None:
            return False
        k, j, window = self._open
        self._open = None
        return self._close_loop(k, j, window, self.matcher.collect())

    def start_keyframe(
        self,
        stamp: float,
        pose: np.ndarray,
        points: np.ndarray,
        polygon: np.ndarray,
        odom: np.ndarray | None = None,
        scale: float = 1.0,
        noise: float = math.nan,
    ) -> None:
        """The keyframe :meth:`observe` asked for, and its loop match sent if one is due (then
        :meth:`finish_keyframe` before anything else)."""
        assert self._open is None, "finish_keyframe() first"
        cfg = self.cfg
        pose = np.asarray(pose, dtype=np.float64).reshape(3)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= cfg.max_range_m]
        k = len(self.raw)
        self.stamps.append(float(stamp))
        self.raw.append(pose.copy())
        self.travel.append(self._travel)
        self.points.append(_voxel(pts, cfg.resolution_m))
        self.polys.append(np.asarray(polygon, dtype=np.float64).reshape(-1, 2))
        self.noise.append(float(noise))
        if self._early_odom is not None:
            self._early_stretch(odom, float(scale))
        if float(scale) != self.scale:
            self.scale = float(scale)
            self._unsolved = self._unsolved or self._early_edges() > 0  # the early travel follows the new scale
        nxt = pose if k == 0 else compose(self.opt[k - 1], relative_pose(self.raw[k - 1], pose))
        self.opt = np.vstack([self.opt, nxt[None]])
        self.mapped = np.vstack([self.mapped, self.map_frame[None]])
        if self._travel - self._last_attempt >= cfg.loop_every_m:
            self._start_loop(k)

    # ------------------------------------------------------------------ corrections
    def _kf_corrections(self) -> np.ndarray:
        """``(K, 3)`` per keyframe: the transform raw -> optimised (``opt (+) raw^-1``)."""
        if self._unsolved:
            self._solve()
        raw = np.asarray(self.raw)
        return compose(self.opt, relative_pose(raw, np.zeros(3)))

    def corrections(self, stamps: np.ndarray) -> np.ndarray:
        """``(N, 3)`` the raw -> optimised transform at each stamp: the keyframes' interpolated
        in time (before the first keyframe its, after the last the last's)."""
        t = np.asarray(stamps, dtype=np.float64).reshape(-1)
        if not self.raw:
            return np.zeros((t.size, 3))
        corr = self._kf_corrections()
        ks = np.asarray(self.stamps)
        return np.stack(
            [np.interp(t, ks, corr[:, 0]), np.interp(t, ks, corr[:, 1]), np.interp(t, ks, np.unwrap(corr[:, 2]))],
            axis=1,
        )

    def map_shift(self) -> float:
        """How far (m) the keyframes' optimised poses are from where the map has their scans."""
        if not self.raw:
            return 0.0
        if self._unsolved:
            self._solve()
        raw = np.asarray(self.raw)
        d = self.opt[:, :2] - compose(self.mapped, raw)[:, :2]
        return float(np.hypot(d[:, 0], d[:, 1]).max())

    def mark_mapped(self) -> np.ndarray:
        """The map was re-rendered with the current corrections: scans from now on are mapped in
        the optimised frame of the latest keyframe. Returns that frame's correction."""
        self.mapped = self._kf_corrections()
        self.map_frame = self.mapped[-1].copy()
        return self.map_frame

    # ------------------------------------------------------------------ loops
    def _submap(self, center: int, lo_m: float, hi_m: float) -> tuple[np.ndarray, list]:
        """Points and polygons of the keyframes from ``lo_m`` to ``hi_m`` of travel (and
        ``center`` itself) in ``center``'s frame, placed by the optimised poses."""
        t = np.asarray(self.travel)
        lo = min(int(np.searchsorted(t, lo_m)), center)
        hi = max(int(np.searchsorted(t, hi_m, side="right")), center + 1)
        rel = relative_pose(self.opt[center], self.opt[lo:hi])
        pts = [transform_points(self.points[m], rel[m - lo]) for m in range(lo, hi)]
        polys = [transform_points(self.polys[m], rel[m - lo]) for m in range(lo, hi)]
        return _voxel(np.concatenate(pts), self.cfg.resolution_m), polys

    def _start_loop(self, k: int) -> None:
        """Keyframe ``k``'s surroundings against those of the nearest earlier keyframe at least
        ``min_loop_travel_m`` back, if one is near enough: the match is sent."""
        cfg = self.cfg
        t = np.asarray(self.travel)
        back = np.nonzero(t <= t[k] - cfg.min_loop_travel_m)[0]
        if back.size == 0:
            return
        window = min(cfg.window_min_m + cfg.window_per_m * (t[k] - self._last_loop), cfg.window_max_m)
        d = np.hypot(self.opt[back, 0] - self.opt[k, 0], self.opt[back, 1] - self.opt[k, 1])
        if d.min() > window + 0.5 * cfg.submap_m:
            return
        self._last_attempt = t[k]
        j = int(back[np.argmin(d)])
        ref, polys = self._submap(j, t[j] - cfg.submap_m, min(t[j] + cfg.submap_m, t[k] - cfg.min_loop_travel_m))
        query, _ = self._submap(k, t[k] - cfg.submap_m, t[k])
        self.attempts += 1
        self.matcher.submit("match", query, ref, polys, relative_pose(self.opt[j], self.opt[k]), window)
        self._open = (k, j, window)

    def _close_loop(self, k: int, j: int, window: float, m) -> bool:
        """The loop match of keyframe ``k`` against ``j`` (:func:`match_submaps`' answer): kept,
        it is a loop edge; True when the solution changed."""
        cfg = self.cfg
        if m is None:
            return False
        t = self.travel
        pose, score, inl, con, rival, slide = m
        kept = inl >= min_inliers(cfg, window) and con <= cfg.max_contradictions and score - rival >= cfg.min_margin
        self.log.append((k, j, pose, score, inl, con, rival, kept))
        if not kept:
            self.rejected += 1
            return False
        info = loop_information(cfg, pose, slide)
        self.loops.append(LoopEdge(j, k, pose, score, rival, info))
        self._last_loop = t[k]
        e = edge_errors(self.opt, np.array([j]), np.array([k]), pose[None])[0][0]
        if float(e @ info @ e) <= AGREES_CHI2:
            self._unsolved = True
            return False
        self._solve()
        return True

    def _early_stretch(self, odom: np.ndarray | None, scale: float) -> None:
        """``scale_early_travel``: the newest keyframe's odometry pose kept while no set was
        scaled; at the first scaled keyframe, the stretch before it measured once (neither its
        odometry nor the filter's raw travel changes later) and the poses let go."""
        if scale == 1.0:
            self._early_odom.append(None if odom is None else np.asarray(odom, dtype=np.float64).reshape(3).copy())
            return
        odoms, self._early_odom = self._early_odom, None
        m = max(len(odoms) - 1, 0)  # the edges into the keyframes before this one
        if m == 0 or any(o is None for o in odoms):
            return
        raw = np.asarray(self.raw[: m + 1])
        z = relative_pose(raw[:-1], raw[1:])
        d = relative_pose(np.asarray(odoms[:-1]), np.asarray(odoms[1:]))
        self._early = (m, float(np.hypot(d[:, 0], d[:, 1]).sum()), float(np.hypot(z[:, 0], z[:, 1]).sum()))

    def _early_edges(self) -> int:
        """``scale_early_travel``: how many sequential edges (from the first) lie before the
        odometry scale first applied, while the latest scale is not 1; 0 otherwise."""
        return self._early[0] if self._early is not None and self.scale != 1.0 else 0

    def _seq_edges(self, raw: np.ndarray) -> np.ndarray:
        """The sequential edges ``(K-1, 3)``: the filter's relative poses, the early travel
        rescaled (``scale_early_travel``) to the latest scale times the odometry's travel there."""
        z = relative_pose(raw[:-1], raw[1:])
        m = self._early_edges()
        if m == 0:
            return z
        _, odom_travel, travel = self._early
        factor = self.scale * odom_travel / max(travel, 1e-9)
        if travel > 0.0 and abs(factor - 1.0) <= EARLY_SCALE_MAX:
            z[:m, :2] *= factor
        return z

    def add_pair_edges(self) -> int:
        """End of the run (``pair_baseline_m`` > 0): each keyframe's scan matched against the newest
        keyframe at least ``pair_baseline_m`` of travel back (:func:`~.scanpair.pair_travel`: the
        symmetric scan-to-scan cost, at the filter's relative pose); each pair that measures its
        travel is an edge along the direction of travel (std ``pair_sigma_m``; nothing across it or
        in yaw), robust like the loop edges; both keyframes' laser noise at least
        ``pair_min_noise_m``. Solved at the next read of the corrections. Once per
        run; returns the number of pair edges."""
        cfg = self.cfg
        if cfg.pair_baseline_m <= 0.0 or self.pairs or len(self.raw) < 2:
            return len(self.pairs)
        raw, travel = np.asarray(self.raw), np.asarray(self.travel)
        field_cfg = CorrelationConfig(sigma_m=cfg.sigma_m, max_distance_m=PAIR_FIELD_SIGMAS * cfg.sigma_m)
        back = np.searchsorted(travel, travel - cfg.pair_baseline_m, side="right") - 1
        with np.errstate(invalid="ignore"):
            noisy = np.asarray(self.noise) >= cfg.pair_min_noise_m  # NaN: not known, paired only at 0
        noisy |= cfg.pair_min_noise_m <= 0.0
        scans: dict[int, PairScan | None] = {}  # the fields of the keyframes still to be paired

        def scan(m: int) -> PairScan | None:
            if m not in scans:
                scans[m] = pair_scan(raw[m], self.points[m], cfg.resolution_m, field_cfg, PAIR_FILL_M)
            return scans[m]

        for k in range(1, len(raw)):
            ref = int(back[k])
            for m in [m for m in scans if m < ref]:
                del scans[m]
            if ref < 0 or not (noisy[ref] and noisy[k]) or scan(ref) is None or scan(k) is None:
                continue
            got = pair_travel(
                scans[ref],
                scans[k],
                PAIR_MAX_ERROR,
                PAIR_MIN_CURVATURE,
                cfg.max_range_m,
                cfg.pair_reach_margin_m,
            )
            if got is None:
                continue
            dist, measured = got
            z = relative_pose(raw[ref], raw[k])
            u = z[:2] / dist
            z[:2] += (measured - dist) * u
            c, s = math.cos(z[2]), math.sin(z[2])
            uz = np.array([c * u[0] + s * u[1], -s * u[0] + c * u[1]])  # in z's frame, as the edge's error
            info = np.zeros((3, 3))
            info[:2, :2] = np.outer(uz, uz) / cfg.pair_sigma_m**2
            self.pairs.append((ref, k, z, info))
        self._unsolved = self._unsolved or bool(self.pairs)
        return len(self.pairs)

    def _solve(self) -> None:
        self._unsolved = False
        cfg = self.cfg
        raw = np.asarray(self.raw)
        n = raw.shape[0]
        z_seq = self._seq_edges(raw)
        dist = np.hypot(z_seq[:, 0], z_seq[:, 1])
        info_seq = np.zeros((n - 1, 3, 3))
        # along / across the direction of travel (the edge's frame is the earlier keyframe's)
        ux, uy = z_seq[:, 0] / np.maximum(dist, 1e-9), z_seq[:, 1] / np.maximum(dist, 1e-9)
        ux[dist < 1e-9], uy[dist < 1e-9] = 1.0, 0.0
        w_along = (cfg.seq_sigma_xy_m + cfg.seq_sigma_xy_per_m * dist) ** -2
        w_lat = (cfg.seq_sigma_xy_m + cfg.seq_sigma_lateral_per_m * dist) ** -2
        info_seq[:, 0, 0] = w_along * ux * ux + w_lat * uy * uy
        info_seq[:, 1, 1] = w_along * uy * uy + w_lat * ux * ux
        info_seq[:, 0, 1] = info_seq[:, 1, 0] = (w_along - w_lat) * ux * uy
        info_seq[:, 2, 2] = (cfg.seq_sigma_rad + cfg.seq_sigma_rad_per_m * dist) ** -2
        x = self.opt
        for _ in range(3):  # drop the loop edges the solution disagrees with, then solve again
            e, p = self.loops, self.pairs
            i = np.concatenate([np.arange(n - 1), [a.ref for a in e], [q[0] for q in p]]).astype(np.int64)
            j = np.concatenate([np.arange(1, n), [a.cur for a in e], [q[1] for q in p]]).astype(np.int64)
            z = np.vstack([z_seq, *(a.z[None] for a in e), *(q[2][None] for q in p)])
            info = np.concatenate(
                [
                    info_seq,
                    np.array([a.info for a in e]).reshape(-1, 3, 3),
                    np.array([q[3] for q in p]).reshape(-1, 3, 3),
                ]
            )
            robust = np.arange(i.size) >= n - 1
            x, chi2 = optimize(self.opt, i, j, z, info, robust, cfg.cauchy)
            bad = chi2[n - 1 : n - 1 + len(e)] > cfg.max_chi2
            if not bad.any():
                break
            self.dropped += int(bad.sum())
            self.loops = [a for a, b in zip(e, bad) if not b]
        self.opt = x
