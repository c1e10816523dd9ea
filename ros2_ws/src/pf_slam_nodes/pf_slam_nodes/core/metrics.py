"""Trajectory accuracy metrics for planar SLAM (pure numpy).

* ATE (absolute trajectory error): RMSE etc. of position differences after the least-squares
  SE(2) alignment of the estimate onto the ground truth (Umeyama 1991 without scale).
* RPE (relative pose error) over a fixed index step (Sturm et al. 2012, in SE(2)).
* Relations error (Kümmerle et al. 2009, "On measuring the accuracy of SLAM algorithms"):
  for each ground-truth relation ``(t1, t2, delta*)``, the estimated relative pose
  ``delta = pose(t1)^-1 * pose(t2)`` is compared with the true one through the error transform
  ``e = delta*^-1 * delta``; translational error ``||e.xy||`` (m), rotational ``|wrap(e.theta)|``
  (deg). Reported as mean and (population) standard deviation over the matched relations.
  No global alignment is needed: relations are frame-independent.

Poses are ``(K, 3)`` ``[x, y, theta]`` arrays (m, m, rad); stamps are seconds (float64).
"""

from __future__ import annotations

import math

import numpy as np

from .geometry import relative_pose, wrap_angle

__all__ = [
    "RELATION_MAX_DT",
    "align_se2",
    "apply_se2",
    "associate",
    "ate",
    "format_evaluation",
    "match_stamps",
    "relations_error",
    "relative_se2",
    "rpe",
    "trajectory_errors",
    "wrap_angle",
]

#: Default stamp tolerance (s) for matching relation stamps to trajectory stamps.
#: The relation stamps of intel_910.relations and intel_2726.relations are exact copies of
#: scan stamps (the rounded ``gfs`` stamps of intel_2726.clf are never relation stamps), so
#: they match with any tolerance >= 0 (37/37 and 90/90). The tolerance must stay tight: the
#: full intel.relations refers to readings of the bursty original log that are only 0.7-5 ms
#: away from other readings, and a 1 ms tolerance already pairs 7 of its relations with the
#: wrong intel_910 scan (97 instead of 90; 91 instead of 37 for intel_2726). 10 us keeps
#: exactly the subset relations (90 / 37) from intel.relations and is 100x the float64 /
#: 9-decimal TUM round-off of such stamps (~1e-7 s).
RELATION_MAX_DT = 1e-5


def _poses(p: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(p, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name} must have shape (K, 3), got {a.shape}")
    return a


def relative_se2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^-1 * b`` for ``(K, 3)`` pose arrays: ``b`` expressed in the frame of ``a``
    (:func:`~pf_slam_nodes.core.geometry.relative_pose`, the motion model's)."""
    return relative_pose(a, b)


def apply_se2(theta: float, t: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Apply the rigid transform ``(theta, t)`` to ``(K, 3)`` poses (or ``(K, 2)`` points)."""
    p = np.asarray(poses, dtype=np.float64)
    c, s = math.cos(theta), math.sin(theta)
    out = p.copy()
    out[:, 0] = c * p[:, 0] - s * p[:, 1] + t[0]
    out[:, 1] = s * p[:, 0] + c * p[:, 1] + t[1]
    if p.shape[1] > 2:
        out[:, 2] = wrap_angle(p[:, 2] + theta)
    return out


def align_se2(est_xy: np.ndarray, gt_xy: np.ndarray) -> tuple[float, np.ndarray]:
    """Rigid 2D alignment minimising ``sum ||R(theta) est + t - gt||^2`` (Umeyama, no scale).

    Parameters
    ----------
    est_xy, gt_xy : np.ndarray
        ``(K, 2)`` corresponding positions, ``K >= 1``.

    Returns
    -------
    theta : float
        Rotation (rad).
    t : np.ndarray
        ``(2,)`` translation (m). ``gt ~= R(theta) @ est + t``.
    """
    e = np.asarray(est_xy, dtype=np.float64)[:, :2]
    g = np.asarray(gt_xy, dtype=np.float64)[:, :2]
    if e.shape != g.shape or len(e) == 0:
        raise ValueError(f"est_xy {e.shape} and gt_xy {g.shape} must be equal, non-empty")
    me, mg = e.mean(axis=0), g.mean(axis=0)
    ec, gc = e - me, g - mg
    # For 2D, the SVD solution reduces to the angle of sum(conj(e) * g) in complex form.
    num = float(np.sum(ec[:, 0] * gc[:, 1] - ec[:, 1] * gc[:, 0]))
    den = float(np.sum(ec[:, 0] * gc[:, 0] + ec[:, 1] * gc[:, 1]))
    theta = math.atan2(num, den) if (num != 0.0 or den != 0.0) else 0.0
    c, s = math.cos(theta), math.sin(theta)
    t = mg - np.array([c * me[0] - s * me[1], s * me[0] + c * me[1]])
    return theta, t


def match_stamps(query: np.ndarray, stamps: np.ndarray, max_dt: float) -> np.ndarray:
    """For each query time, the index of the nearest entry of ``stamps``, or -1 if none is
    within ``max_dt`` (s). ``stamps`` need not be sorted; ties go to the earlier index."""
    q = np.asarray(query, dtype=np.float64).ravel()
    s = np.asarray(stamps, dtype=np.float64).ravel()
    out = np.full(q.shape, -1, dtype=np.int64)
    if len(s) == 0 or len(q) == 0:
        return out
    order = np.argsort(s, kind="stable")
    ss = s[order]
    hi = np.clip(np.searchsorted(ss, q, side="left"), 0, len(ss) - 1)
    lo = np.clip(hi - 1, 0, len(ss) - 1)
    d_hi, d_lo = np.abs(ss[hi] - q), np.abs(ss[lo] - q)
    best = np.where(d_lo <= d_hi, lo, hi)
    dt = np.minimum(d_lo, d_hi)
    ok = dt <= max_dt
    out[ok] = order[best[ok]]
    return out


def associate(est_stamps: np.ndarray, gt_stamps: np.ndarray, max_dt: float = 0.02) -> np.ndarray:
    """One-to-one nearest-time association.

    Returns
    -------
    np.ndarray
        ``(M, 2)`` int64 index pairs ``[i_est, i_gt]`` with ``|t_est - t_gt| <= max_dt``, each
        index used at most once (closest pairs win), sorted by ``i_est``.
    """
    e = np.asarray(est_stamps, dtype=np.float64).ravel()
    g = np.asarray(gt_stamps, dtype=np.float64).ravel()
    j = match_stamps(e, g, max_dt)
    i = np.flatnonzero(j >= 0)
    j = j[i]
    if len(i) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    dt = np.abs(e[i] - g[j])
    order = np.lexsort((i, dt))
    _, first = np.unique(j[order], return_index=True)
    keep = order[first]
    pairs = np.column_stack([i[keep], j[keep]]).astype(np.int64)
    return pairs[np.argsort(pairs[:, 0], kind="stable")]


def _stats(x: np.ndarray) -> dict:
    if len(x) == 0:
        nan = float("nan")
        return {"rmse": nan, "mean": nan, "median": nan, "std": nan, "max": nan}
    return {
        "rmse": float(np.sqrt(np.mean(x * x))),
        "mean": float(np.mean(x)),
        "median": float(np.median(x)),
        "std": float(np.std(x)),
        "max": float(np.max(x)),
    }


def ate(est: np.ndarray, gt: np.ndarray) -> dict:
    """Absolute trajectory error of associated poses, after SE(2) alignment of est onto gt.

    Parameters
    ----------
    est, gt : np.ndarray
        ``(K, 3)`` associated poses (row k of each is the same instant).

    Returns
    -------
    dict
        ``rmse``, ``mean``, ``median``, ``std``, ``max`` position error (m); ``rot_rmse_deg``
        heading error after alignment; ``n``; ``align_theta`` (rad) and ``align_t`` (m) of
        the alignment.
    """
    e, g = _poses(est, "est"), _poses(gt, "gt")
    if e.shape != g.shape:
        raise ValueError(f"est {e.shape} and gt {g.shape} must have the same shape")
    if len(e) == 0:
        raise ValueError("ate needs at least one associated pose")
    theta, t = align_se2(e[:, :2], g[:, :2])
    a = apply_se2(theta, t, e)
    err = np.hypot(a[:, 0] - g[:, 0], a[:, 1] - g[:, 1])
    rot = np.degrees(np.abs(wrap_angle(a[:, 2] - g[:, 2])))
    out = _stats(err)
    out.update(
        rot_rmse_deg=float(np.sqrt(np.mean(rot * rot))),
        n=int(len(e)),
        align_theta=float(theta),
        align_t=[float(t[0]), float(t[1])],
    )
    return out


def rpe(est: np.ndarray, gt: np.ndarray, delta: int = 1) -> dict:
    """Relative pose error between poses ``delta`` indices apart.

    Returns
    -------
    dict
        ``trans_rmse``, ``trans_mean`` (m), ``rot_rmse_deg``, ``rot_mean_deg`` (deg), ``n``.
    """
    e, g = _poses(est, "est"), _poses(gt, "gt")
    if e.shape != g.shape:
        raise ValueError(f"est {e.shape} and gt {g.shape} must have the same shape")
    if delta < 1:
        raise ValueError(f"delta must be >= 1, got {delta}")
    n = len(e) - delta
    if n <= 0:
        nan = float("nan")
        return {"trans_rmse": nan, "trans_mean": nan, "rot_rmse_deg": nan, "rot_mean_deg": nan, "n": 0}
    d_est = relative_se2(e[:-delta], e[delta:])
    d_gt = relative_se2(g[:-delta], g[delta:])
    err = relative_se2(d_gt, d_est)
    tr = np.hypot(err[:, 0], err[:, 1])
    rot = np.degrees(np.abs(err[:, 2]))
    return {
        "trans_rmse": float(np.sqrt(np.mean(tr * tr))),
        "trans_mean": float(tr.mean()),
        "rot_rmse_deg": float(np.sqrt(np.mean(rot * rot))),
        "rot_mean_deg": float(rot.mean()),
        "n": int(n),
    }


def relations_error(
    est_stamps: np.ndarray,
    est_poses: np.ndarray,
    rel_stamps: np.ndarray,
    rel_delta: np.ndarray,
    max_dt: float = RELATION_MAX_DT,
) -> dict:
    """Kümmerle et al. (2009) relation-based error of a trajectory.

    Parameters
    ----------
    est_stamps : np.ndarray
        ``(K,)`` trajectory times (s).
    est_poses : np.ndarray
        ``(K, 3)`` estimated poses.
    rel_stamps : np.ndarray
        ``(R, 2)`` relation times ``[t1, t2]`` (s).
    rel_delta : np.ndarray
        ``(R, 3)`` true pose at ``t2`` in the frame of the pose at ``t1``.
    max_dt : float
        A relation is used only when both its times have a trajectory pose within ``max_dt``.

    Returns
    -------
    dict
        ``trans_mean``, ``trans_std``, ``trans_max`` (m), ``rot_mean_deg``, ``rot_std_deg``,
        ``rot_max_deg`` (deg), ``trans_sq_mean`` (m^2), ``rot_sq_mean_deg`` (deg^2),
        ``n_used``, ``n_total``. Means are NaN when no relation could be matched.
    """
    p = _poses(est_poses, "est_poses")
    rs = np.asarray(rel_stamps, dtype=np.float64).reshape(-1, 2)
    rd = _poses(rel_delta, "rel_delta")
    if len(rs) != len(rd):
        raise ValueError(f"rel_stamps has {len(rs)} rows but rel_delta has {len(rd)}")
    i1 = match_stamps(rs[:, 0], est_stamps, max_dt)
    i2 = match_stamps(rs[:, 1], est_stamps, max_dt)
    ok = (i1 >= 0) & (i2 >= 0)
    est_rel = relative_se2(p[i1[ok]], p[i2[ok]])
    err = relative_se2(rd[ok], est_rel)  # delta*^-1 * delta
    tr = np.hypot(err[:, 0], err[:, 1])
    rot = np.degrees(np.abs(err[:, 2]))
    nan = float("nan")
    n = int(ok.sum())

    def m(x: np.ndarray, f) -> float:
        return float(f(x)) if n else nan

    return {
        "trans_mean": m(tr, np.mean),
        "trans_std": m(tr, np.std),
        "trans_max": m(tr, np.max),
        "rot_mean_deg": m(rot, np.mean),
        "rot_std_deg": m(rot, np.std),
        "rot_max_deg": m(rot, np.max),
        "trans_sq_mean": m(tr * tr, np.mean),
        "rot_sq_mean_deg": m(rot * rot, np.mean),
        "n_used": n,
        "n_total": int(len(rs)),
    }


def trajectory_errors(
    t_est: np.ndarray, p_est: np.ndarray, t_gt: np.ndarray, p_gt: np.ndarray, max_dt: float = 0.02, rpe_delta: int = 1
) -> dict:
    """ATE and RPE of an estimate against a reference trajectory, after the one-to-one
    nearest-time association within ``max_dt`` (s).

    Returns ``n_gt``, ``n_associated``, ``max_dt`` and, when a pose could be associated,
    ``ate`` (see :func:`ate`) and ``rpe`` (see :func:`rpe`).
    """
    pairs = associate(t_est, t_gt, max_dt=max_dt)
    out: dict = dict(n_gt=int(len(t_gt)), n_associated=int(len(pairs)), max_dt=float(max_dt))
    if len(pairs):
        e, g = p_est[pairs[:, 0]], p_gt[pairs[:, 1]]
        out["ate"] = ate(e, g)
        out["rpe"] = rpe(e, g, delta=rpe_delta)
    return out


def map_f1(
    est_occ: np.ndarray,
    est_res: float,
    est_origin,
    gt_occ: np.ndarray,
    gt_res: float,
    gt_origin,
    tolerance_m: float = 0.3,
    occupied: int = 65,
) -> dict:
    """Occupied-cell precision / recall / F1 of an estimated map against a ground-truth map.

    Both maps are ``(H, W)`` int8 nav_msgs/OccupancyGrid values (-1 unknown, 0..100), row 0 =
    lowest y, ``origin`` = world ``(x, y)`` of the lower-left corner, in the same world frame
    (the SLAM map frame is the odometry frame at the first scan; the simulator's world frame is
    the vehicle's true start pose: the same frame). A cell is occupied at ``>= occupied``.

    A lidar sees the outline of an obstacle, not its inside, so the reference cells are the
    *edge* cells of the ground truth (occupied with a free 4-neighbour), and only the edges the
    run observed count for recall: those within ``tolerance_m`` of a cell the estimate knows
    (not -1). precision = estimated occupied cells within ``tolerance_m`` of a ground-truth
    occupied cell / estimated occupied cells; recall = observed edge cells within
    ``tolerance_m`` of an estimated occupied cell / observed edge cells.
    """
    import cv2  # distance transforms; cv2 is a dependency of the project

    gt = np.asarray(gt_occ)
    g_occ = gt >= occupied
    free = gt == 0
    nb_free = np.zeros_like(free)
    nb_free[1:, :] |= free[:-1, :]
    nb_free[:-1, :] |= free[1:, :]
    nb_free[:, 1:] |= free[:, :-1]
    nb_free[:, :-1] |= free[:, 1:]
    g_edge = g_occ & nb_free
    # the estimate resampled onto the ground-truth grid (nearest cell centre)
    est = np.asarray(est_occ)
    h, w = gt.shape
    ys, xs = np.mgrid[0:h, 0:w]
    wx = np.asarray(gt_origin, float)[0] + (xs + 0.5) * gt_res
    wy = np.asarray(gt_origin, float)[1] + (ys + 0.5) * gt_res
    ec = np.floor((wx - np.asarray(est_origin, float)[0]) / est_res).astype(np.int64)
    er = np.floor((wy - np.asarray(est_origin, float)[1]) / est_res).astype(np.int64)
    inside = (ec >= 0) & (ec < est.shape[1]) & (er >= 0) & (er < est.shape[0])
    e = np.full(gt.shape, -1, dtype=np.int16)
    e[inside] = est[er[inside], ec[inside]]
    e_occ = e >= occupied
    e_known = e >= 0

    def dist_to(mask: np.ndarray) -> np.ndarray:
        if not mask.any():
            return np.full(mask.shape, np.inf, dtype=np.float32)
        return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 5) * gt_res

    tol = float(tolerance_m)
    d_gt = dist_to(g_occ)
    d_est = dist_to(e_occ)
    d_known = dist_to(e_known)
    tp_est = int(np.count_nonzero(e_occ & (d_gt <= tol)))
    n_est = int(np.count_nonzero(e_occ))
    observed_edges = g_edge & (d_known <= tol)
    n_ref = int(np.count_nonzero(observed_edges))
    tp_ref = int(np.count_nonzero(observed_edges & (d_est <= tol)))
    precision = tp_est / n_est if n_est else 0.0
    recall = tp_ref / n_ref if n_ref else 0.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return {
        "precision": precision,
        "recall": recall,
        "f1": f1,
        "tolerance_m": tol,
        "est_occupied_cells": n_est,
        "observed_edge_cells": n_ref,
    }


def format_evaluation(res: dict) -> str:
    """Human-readable lines for ``pf-slam eval`` (of :func:`pf_slam_nodes.io.evaluation.evaluate`)."""
    lines = [f"estimate: {res['est']} ({res['n_est']} poses)"] if "est" in res else []
    if "gt" in res:
        lines.append(
            f"reference: {res['gt']} ({res['n_gt']} poses), associated "
            f"{res['n_associated']} within {res['max_dt'] * 1e3:.0f} ms"
        )
        if "ate" in res:
            a, r = res["ate"], res["rpe"]
            lines.append(
                f"ATE  rmse {a['rmse']:.4f} m  mean {a['mean']:.4f}  median "
                f"{a['median']:.4f}  max {a['max']:.4f}  (heading rmse "
                f"{a['rot_rmse_deg']:.2f} deg)"
            )
            lines.append(
                f"RPE  trans rmse {r['trans_rmse']:.4f} m  mean {r['trans_mean']:.4f}"
                f"  rot mean {r['rot_mean_deg']:.3f} deg  (n={r['n']})"
            )
        else:
            lines.append("ATE/RPE: no pose could be associated")
    if "map" in res:
        m = res["map"]
        lines.append(
            f"map ({res['map_gt']}): occupied-cell F1 {m['f1']:.3f}  precision "
            f"{m['precision']:.3f}  recall {m['recall']:.3f}  (tolerance "
            f"{m['tolerance_m']:.2f} m, {m['est_occupied_cells']} occupied cells, "
            f"{m['observed_edge_cells']} observed edge cells)"
        )
    if "relations" in res:
        q = res["relations"]
        lines.append(f"relations ({res['relations_file']}): used {q['n_used']}/{q['n_total']}")
        lines.append(
            f"  translational {q['trans_mean']:.4f} +- {q['trans_std']:.4f} m   "
            f"rotational {q['rot_mean_deg']:.3f} +- {q['rot_std_deg']:.3f} deg"
        )
    return "\n".join(lines)
