"""Trajectory metrics, incl. the Kümmerle relations error on the real Intel data."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import DATA as SHARED_DATA

from pf_slam_nodes.core.metrics import (
    RELATION_MAX_DT,
    align_se2,
    apply_se2,
    associate,
    ate,
    format_evaluation,
    relations_error,
    relative_se2,
    rpe,
)
from pf_slam_nodes.io.carmen import read_carmen
from pf_slam_nodes.io.evaluation import evaluate
from pf_slam_nodes.io.trajectory import read_relations, read_trajectory, write_tum

DATA = SHARED_DATA / "carmen"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"{DATA} not available")


def _traj(n=50, seed=0):
    rng = np.random.default_rng(seed)
    steps = np.column_stack([rng.uniform(0.0, 0.3, n), np.zeros(n), rng.normal(0, 0.2, n)])
    poses = np.zeros((n, 3))
    for k in range(1, n):
        x, y, th = poses[k - 1]
        poses[k] = [x + steps[k, 0] * math.cos(th), y + steps[k, 0] * math.sin(th), th + steps[k, 2]]
    return poses


def test_align_known_transform():
    gt = _traj()
    theta, t = 0.7, np.array([3.0, -2.0])
    # est = gt moved by the inverse transform: aligning it back must recover (theta, t)
    c, s = math.cos(-theta), math.sin(-theta)
    d = gt[:, :2] - t
    est = gt.copy()
    est[:, 0] = c * d[:, 0] - s * d[:, 1]
    est[:, 1] = s * d[:, 0] + c * d[:, 1]
    est[:, 2] = gt[:, 2] - theta
    th_hat, t_hat = align_se2(est[:, :2], gt[:, :2])
    assert th_hat == pytest.approx(theta) and t_hat == pytest.approx(t)
    res = ate(est, gt)
    assert res["rmse"] < 1e-9 and res["max"] < 1e-9 and res["rot_rmse_deg"] < 1e-6
    assert res["n"] == len(gt)
    np.testing.assert_allclose(apply_se2(th_hat, t_hat, est), gt, atol=1e-9)


def test_ate_hand_computed():
    gt = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    est = gt.copy()
    est[1, 1] = 0.1
    est[2, 1] = -0.1
    # best alignment: theta from the centred cross terms, t re-centres; residuals by hand
    res = ate(est, gt)
    theta, t = align_se2(est[:, :2], gt[:, :2])
    a = apply_se2(theta, t, est)
    err = np.hypot(*(a[:, :2] - gt[:, :2]).T)
    assert res["rmse"] == pytest.approx(np.sqrt(np.mean(err**2)))
    # without rotation the residual would be 0.1 at two points: alignment can only reduce it
    assert res["rmse"] < math.sqrt(2 * 0.01 / 4)


def test_rpe_and_relations_zero_for_perfect():
    gt = _traj()
    r = rpe(gt, gt, delta=3)
    assert r["trans_rmse"] == 0.0 and r["rot_mean_deg"] == 0.0 and r["n"] == len(gt) - 3
    stamps = np.arange(len(gt)) * 0.1 + 1000.0
    i1, i2 = np.arange(0, 40), np.arange(5, 45)
    rel_st = np.column_stack([stamps[i1], stamps[i2]])
    rel_d = relative_se2(gt[i1], gt[i2])
    q = relations_error(stamps, gt, rel_st, rel_d)
    assert q["n_used"] == q["n_total"] == 40
    assert q["trans_mean"] < 1e-12 and q["rot_mean_deg"] < 1e-9
    # a 0.1 rad error at one pose shows up in the relations that use it
    bad = gt.copy()
    bad[10, 2] += 0.1
    q = relations_error(stamps, bad, rel_st, rel_d)
    assert q["rot_max_deg"] == pytest.approx(math.degrees(0.1))


def test_relation_error_definition():
    # true: 1 m forward; estimate: 1 m forward and 0.1 m left, 5 deg left
    est = np.array([[0.0, 0.0, 0.0], [1.0, 0.1, math.radians(5)]])
    q = relations_error(np.array([1.0, 2.0]), est, np.array([[1.0, 2.0]]), np.array([[1.0, 0.0, 0.0]]))
    assert q["trans_mean"] == pytest.approx(0.1) and q["rot_mean_deg"] == pytest.approx(5.0)
    # unmatched stamps are not used
    q = relations_error(np.array([1.0, 2.0]), est, np.array([[1.0, 2.5]]), np.array([[1.0, 0.0, 0.0]]))
    assert q["n_used"] == 0 and math.isnan(q["trans_mean"])


def test_associate():
    est = np.array([0.0, 0.1, 0.2, 0.3, 5.0])
    gt = np.array([0.301, 0.19, 0.105, 0.0])
    pairs = associate(est, gt, max_dt=0.02)
    np.testing.assert_array_equal(pairs, [[0, 3], [1, 2], [2, 1], [3, 0]])
    # one-to-one: two estimates near one reference -> the closer wins
    pairs = associate(np.array([1.0, 1.005]), np.array([1.004]), max_dt=0.02)
    np.testing.assert_array_equal(pairs, [[1, 0]])
    assert associate(np.array([1.0]), np.array([]), 0.1).shape == (0, 2)


@needs_data
@pytest.mark.parametrize("name,n", [("intel_910", 90), ("intel_2726", 37)])
def test_relation_stamps_match_scan_stamps(name, n):
    log = read_carmen(DATA / f"{name}.clf")
    stamps = np.array([s.stamp_s for s in log.scans])
    poses = np.array([s.odom_pose for s in log.scans])
    rs, rd = read_relations(DATA / f"{name}.relations")
    for tol in (0.0, RELATION_MAX_DT):
        assert relations_error(stamps, poses, rs, rd, max_dt=tol)["n_used"] == n
    # the full intel.relations yields exactly the subset at the default tolerance
    rs_all, rd_all = read_relations(DATA / "intel.relations")
    assert relations_error(stamps, poses, rs_all, rd_all)["n_used"] == n


@needs_data
def test_gmapping_reference_relations_error(tmp_path):
    t, p = read_trajectory(DATA / "intel_910_gmapping_reference.txt")
    rs, rd = read_relations(DATA / "intel_910.relations")
    q = relations_error(t, p, rs, rd)
    assert q["n_used"] == 90
    # Kümmerle et al. 2009 report 0.031 +- 0.026 m, 0.4 +- 0.4 deg for GMapping on Intel
    assert q["trans_mean"] == pytest.approx(0.0363, abs=5e-4)
    assert q["trans_std"] == pytest.approx(0.0266, abs=5e-4)
    assert q["rot_mean_deg"] == pytest.approx(0.417, abs=5e-3)
    # the same through a TUM file written and evaluated like `pf-slam eval`
    est = tmp_path / "trajectory.tum"
    write_tum(est, t, p)
    res = evaluate(est, DATA / "intel_910_gmapping_reference.txt", relations_path=DATA / "intel_910.relations")
    assert res["n_associated"] == 910 and res["ate"]["rmse"] < 1e-5
    assert res["relations"]["trans_mean"] == pytest.approx(q["trans_mean"], abs=1e-6)
    assert "relations" in format_evaluation(res)
    res2 = evaluate(est, DATA / "intel_910.relations")  # .relations given as the reference
    assert res2["relations"]["n_used"] == 90 and "ate" not in res2
    with pytest.raises(ValueError):
        evaluate(est)
