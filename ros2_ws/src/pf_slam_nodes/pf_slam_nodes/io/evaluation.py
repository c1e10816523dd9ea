"""``pf-slam eval``: read a trajectory, a reference, relations and maps from files and score them
with :mod:`pf_slam_nodes.core.metrics` (which works on arrays only)."""

from __future__ import annotations

import os

from ..core.metrics import RELATION_MAX_DT, map_f1, relations_error, trajectory_errors
from .mapfile import read_map
from .trajectory import read_relations, read_trajectory

__all__ = ["evaluate"]


def evaluate(
    est_path: str | os.PathLike | None,
    gt_path: str | os.PathLike | None = None,
    relations_path: str | os.PathLike | None = None,
    max_dt: float = 0.02,
    relations_max_dt: float = RELATION_MAX_DT,
    rpe_delta: int = 1,
    map_path: str | os.PathLike | None = None,
    gt_map_path: str | os.PathLike | None = None,
    map_tolerance_m: float = 0.3,
) -> dict:
    """Evaluate a trajectory file against a reference trajectory and/or relations.

    ``est_path`` and ``gt_path`` are TUM or ``t x y theta`` files; a ``gt_path`` ending in
    ``.relations`` is taken as ``relations_path``. ATE/RPE use the one-to-one nearest-time
    association within ``max_dt`` (s); the relations error uses ``relations_max_dt``.

    Returns
    -------
    dict
        ``est`` (path), ``n_est``; with a reference: ``gt``, ``n_gt``, ``n_associated``,
        ``ate`` (see ``ate``), ``rpe`` (see ``rpe``); with relations: ``relations_file``,
        ``relations`` (see ``relations_error``); with a map pair: ``map_est``, ``map_gt``,
        ``map`` (see ``map_f1``).
    """
    if gt_path is not None and str(gt_path).endswith(".relations") and relations_path is None:
        gt_path, relations_path = None, gt_path
    if (map_path is None) != (gt_map_path is None):
        raise ValueError("a map evaluation needs both the map and the ground-truth map (yaml)")
    if gt_path is None and relations_path is None and map_path is None:
        raise ValueError("evaluate needs a reference trajectory (gt_path), relations_path or a map pair")
    out: dict = {}
    if map_path is not None:
        eo, er, eorig = read_map(map_path)
        go, gr, gorig = read_map(gt_map_path)
        out.update(
            map_est=str(map_path),
            map_gt=str(gt_map_path),
            map=map_f1(eo, er, eorig[:2], go, gr, gorig[:2], tolerance_m=map_tolerance_m),
        )
    if est_path is None:
        return out
    t_est, p_est = read_trajectory(est_path)
    out.update(est=str(est_path), n_est=int(len(t_est)))
    if gt_path is not None:
        t_gt, p_gt = read_trajectory(gt_path)
        out["gt"] = str(gt_path)
        out.update(trajectory_errors(t_est, p_est, t_gt, p_gt, max_dt=max_dt, rpe_delta=rpe_delta))
    if relations_path is not None:
        rs, rd = read_relations(relations_path)
        out["relations_file"] = str(relations_path)
        out["relations"] = relations_error(t_est, p_est, rs, rd, max_dt=relations_max_dt)
    return out
