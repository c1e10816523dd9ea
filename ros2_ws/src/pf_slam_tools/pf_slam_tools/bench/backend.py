"""A light loop-closure back end on top of the filter (an experiment of the worlds bench, not used
by the graph): keyframes, scan-to-submap loop matches, an SE(2) pose graph, the trajectory bent
onto the optimised keyframes. Measured in docs/architecture.md ("Seeds and worlds"): it did not win.

The filter matches every scan against the one map it builds, so its error is a random walk of
small match errors that nothing pulls back once the robot is beyond the search window of the
place it saw before (measured: the corrected-pose buildings drift 0.2-0.4 m ATE even with
perfect odometry). This back end runs on the filter's corrected poses and scans:

1. keyframes every ``keyframe_m`` of travel (or ``keyframe_rad`` of turning);
2. for each keyframe, the nearest earlier keyframe within ``search_radius_m`` that lies at least
   ``min_loop_travel_m`` of travel back is a loop candidate; the keyframe's scan is matched
   against a submap of the scans of the candidate's neighbours (``submap_keyframes`` each side),
   exhaustively in a ``window_m`` x ``window_rad`` window, then finer; the match is kept when
   its score (mean beam likelihood) reaches ``min_score`` and is ``min_margin`` above the best
   match at least ``ambiguity_m`` away (a corridor of identical doors has several);
3. Gauss-Newton on the pose graph (odometry edges = the filter's relative poses between
   consecutive keyframes, loop edges = the matches, Cauchy-weighted), first keyframe fixed;
4. every pose is moved with its keyframe (pose' = keyframe' (+) (keyframe^-1 (+) pose)).

Pure numpy + OpenCV (distance transform of the submap).
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from pf_slam_nodes.core.geometry import compose, relative_pose, wrap_angle


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    keyframe_m: float = 1.0
    keyframe_rad: float = 0.5
    max_keyframes: int = 1200
    search_radius_m: float = 5.0
    min_loop_travel_m: float = 20.0
    submap_keyframes: int = 6
    window_m: float = 1.2
    window_rad: float = 0.3
    resolution_m: float = 0.05
    sigma_m: float = 0.1
    max_range_m: float = 20.0
    min_score: float = 0.55
    min_margin: float = 0.05
    ambiguity_m: float = 1.0
    loop_every: int = 2
    odom_sigma_xy_m: float = 0.02
    odom_sigma_xy_per_m: float = 0.02
    odom_sigma_rad: float = 0.005
    odom_sigma_rad_per_m: float = 0.005
    loop_sigma_xy_m: float = 0.05
    loop_sigma_rad: float = 0.01
    cauchy_c: float = 1.0
    iterations: int = 15


def keyframes(poses: np.ndarray, cfg: LoopConfig) -> np.ndarray:
    """Indices of the keyframes along ``poses`` (K, 3): the first, then every ``keyframe_m`` of
    travel or ``keyframe_rad`` of turning (spacing widened so there are at most ``max_keyframes``)."""
    p = np.asarray(poses, dtype=np.float64)
    step = np.hypot(*np.diff(p[:, :2], axis=0).T)
    length = float(step.sum())
    dist = max(cfg.keyframe_m, length / max(cfg.max_keyframes - 1, 1))
    out, acc, th0 = [0], 0.0, p[0, 2]
    for k in range(1, len(p)):
        acc += step[k - 1]
        if acc >= dist or abs(wrap_angle(p[k, 2] - th0)) >= cfg.keyframe_rad:
            out.append(k)
            acc, th0 = 0.0, p[k, 2]
    return np.array(out, dtype=np.int64)


def _world(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.stack([pose[0] + c * points[:, 0] - s * points[:, 1], pose[1] + s * points[:, 0] + c * points[:, 1]], 1)


class _Submap:
    """Likelihood ``exp(-d^2 / 2 sigma^2)`` of a set of world points, on a local grid."""

    def __init__(self, pts: np.ndarray, cfg: LoopConfig, margin: float) -> None:
        self.res = cfg.resolution_m
        self.origin = pts.min(axis=0) - margin
        size = np.ceil((pts.max(axis=0) + margin - self.origin) / self.res).astype(int) + 1
        occ = np.full((size[1], size[0]), 255, np.uint8)
        c = np.floor((pts - self.origin) / self.res).astype(int)
        occ[c[:, 1], c[:, 0]] = 0
        d = cv2.distanceTransform(occ, cv2.DIST_L2, 5) * self.res
        self.like = np.exp(-0.5 * (d / cfg.sigma_m) ** 2).astype(np.float32)

    def score(self, pts: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """Mean likelihood of ``pts`` (robot frame, (P, 2)) at each of ``poses`` (C, 3)."""
        c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
        x = poses[:, 0:1] + c * pts[None, :, 0] - s * pts[None, :, 1]
        y = poses[:, 1:2] + s * pts[None, :, 0] + c * pts[None, :, 1]
        ix = np.floor((x - self.origin[0]) / self.res).astype(np.int64)
        iy = np.floor((y - self.origin[1]) / self.res).astype(np.int64)
        h, w = self.like.shape
        ok = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
        v = np.where(ok, self.like[np.clip(iy, 0, h - 1), np.clip(ix, 0, w - 1)], 0.0)
        return v.mean(axis=1)


def _grid(center: np.ndarray, half_xy: float, step_xy: float, half_th: float, step_th: float) -> np.ndarray:
    n = int(round(half_xy / step_xy))
    m = int(round(half_th / step_th))
    dx = np.arange(-n, n + 1) * step_xy
    dt = np.arange(-m, m + 1) * step_th
    gx, gy, gt = np.meshgrid(dx, dx, dt, indexing="ij")
    return center + np.stack([gx.ravel(), gy.ravel(), gt.ravel()], 1)


def match_loop(
    scan: np.ndarray, guess: np.ndarray, submap: _Submap, cfg: LoopConfig
) -> tuple[np.ndarray, float] | None:
    """Best world pose of ``scan`` (robot-frame points) near ``guess`` in ``submap``, with its
    score; None when it is too weak or ambiguous."""
    pts = scan[::2] if len(scan) > 120 else scan
    cand = _grid(guess, cfg.window_m, 0.1, cfg.window_rad, 0.025)
    sc = submap.score(pts, cand)
    best = int(np.argmax(sc))
    far = np.hypot(cand[:, 0] - cand[best, 0], cand[:, 1] - cand[best, 1]) >= cfg.ambiguity_m
    rival = float(sc[far].max()) if far.any() else 0.0
    fine = _grid(cand[best], 0.1, 0.02, 0.03, 0.005)
    fs = submap.score(scan, fine)
    k = int(np.argmax(fs))
    s = float(fs[k])
    if s < cfg.min_score or float(sc[best]) - rival < cfg.min_margin:
        return None
    return fine[k], s


def _edge_error(xi: np.ndarray, xj: np.ndarray, z: np.ndarray):
    """Error of edge i->j with measurement z and its Jacobians (3x3 each)."""
    c, s = math.cos(xi[2]), math.sin(xi[2])
    dx, dy = xj[0] - xi[0], xj[1] - xi[1]
    rt = np.array([[c, s], [-s, c]])
    t = rt @ np.array([dx, dy])
    cz, sz = math.cos(z[2]), math.sin(z[2])
    rz = np.array([[cz, sz], [-sz, cz]])
    e = np.empty(3)
    e[:2] = rz @ (t - z[:2])
    e[2] = wrap_angle(xj[2] - xi[2] - z[2])
    drt = np.array([[-s, c], [-c, -s]])
    a = np.zeros((3, 3))
    a[:2, :2] = -rz @ rt
    a[:2, 2] = rz @ (drt @ np.array([dx, dy]))
    a[2, 2] = -1.0
    b = np.zeros((3, 3))
    b[:2, :2] = rz @ rt
    b[2, 2] = 1.0
    return e, a, b


def optimise(nodes: np.ndarray, edges: list, cfg: LoopConfig) -> np.ndarray:
    """Gauss-Newton on the SE(2) pose graph; ``edges`` = (i, j, z (3,), info (3, 3), robust)."""
    x = nodes.copy()
    n = len(x)
    for _ in range(cfg.iterations):
        h = np.zeros((3 * n, 3 * n))
        g = np.zeros(3 * n)
        for i, j, z, info, robust in edges:
            e, a, b = _edge_error(x[i], x[j], z)
            w = 1.0
            if robust:
                chi2 = float(e @ info @ e)
                w = 1.0 / (1.0 + chi2 / cfg.cauchy_c**2)
            om = w * info
            si, sj = slice(3 * i, 3 * i + 3), slice(3 * j, 3 * j + 3)
            h[si, si] += a.T @ om @ a
            h[si, sj] += a.T @ om @ b
            h[sj, si] += b.T @ om @ a
            h[sj, sj] += b.T @ om @ b
            g[si] += a.T @ om @ e
            g[sj] += b.T @ om @ e
        h[:3, :3] += np.eye(3) * 1e9  # the first keyframe fixed
        dx = np.linalg.solve(h, -g)
        x += dx.reshape(-1, 3)
        x[:, 2] = wrap_angle(x[:, 2])
        if np.abs(dx).max() < 1e-5:
            break
    return x


@dataclasses.dataclass
class LoopResult:
    poses: np.ndarray  # (K, 3) every pose, moved with its keyframe
    keyframes: np.ndarray  # keyframe indices
    loops: list  # (i, j, z, score) accepted loop edges (keyframe numbers)


def close_loops(poses: np.ndarray, scans: list, cfg: LoopConfig = LoopConfig()) -> LoopResult:
    """Run the back end on a trajectory. ``poses`` (K, 3) the filter's poses, ``scans`` K arrays
    (P_k, 2) of robot-frame scan points (may be empty for a scan not to be used)."""
    p = np.asarray(poses, dtype=np.float64)
    kf = keyframes(p, cfg)
    kp = p[kf]
    pts = []
    for k in kf:
        s = np.asarray(scans[k], dtype=np.float64).reshape(-1, 2)
        s = s[np.hypot(s[:, 0], s[:, 1]) <= cfg.max_range_m]
        pts.append(s)
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(kp[:, :2], axis=0).T))])
    edges = []
    for a in range(len(kf) - 1):
        z = relative_pose(kp[a], kp[a + 1])
        d = math.hypot(z[0], z[1])
        sxy = cfg.odom_sigma_xy_m + cfg.odom_sigma_xy_per_m * d
        sth = cfg.odom_sigma_rad + cfg.odom_sigma_rad_per_m * d
        edges.append((a, a + 1, z, np.diag([1 / sxy**2, 1 / sxy**2, 1 / sth**2]), False))
    loops = []
    info_loop = np.diag([1 / cfg.loop_sigma_xy_m**2] * 2 + [1 / cfg.loop_sigma_rad**2])
    for a in range(0, len(kf), cfg.loop_every):
        if len(pts[a]) < 20:
            continue
        back = np.where(travel[a] - travel >= cfg.min_loop_travel_m)[0]
        if not len(back):
            continue
        d = np.hypot(kp[back, 0] - kp[a, 0], kp[back, 1] - kp[a, 1])
        if d.min() > cfg.search_radius_m:
            continue
        b = int(back[np.argmin(d)])
        lo, hi = max(0, b - cfg.submap_keyframes), min(len(kf), b + cfg.submap_keyframes + 1)
        hi = min(hi, int(back[-1]) + 1)
        world = np.concatenate([_world(pts[c], kp[c]) for c in range(lo, hi)])
        if len(world) < 50:
            continue
        sub = _Submap(world, cfg, cfg.window_m + cfg.max_range_m * 0 + 1.0)
        m = match_loop(pts[a], kp[a], sub, cfg)
        if m is None:
            continue
        pose, score = m
        z = relative_pose(kp[b], pose)  # measured pose of a in b's frame (b's pose as the filter has it)
        edges.append((b, a, z, info_loop, True))
        loops.append((a, b, z, score))
    if not loops:
        return LoopResult(p.copy(), kf, loops)
    opt = optimise(kp, edges, cfg)
    owner = np.searchsorted(kf, np.arange(len(p)), side="right") - 1
    rel = relative_pose(kp[owner], p)
    out = compose(opt[owner], rel)
    return LoopResult(out, kf, loops)
