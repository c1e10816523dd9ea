"""The per-scan fast paths agree with the general code they shortcut."""

import math

import numpy as np
import pytest

from pf_slam_nodes.core.config import FilterConfig, GridConfig, LaserConfig
from pf_slam_nodes.core.metrics import map_f1
from pf_slam_nodes.core.motion import compose, integrate_diff_drive, relative_pose, wheel_odometry
from pf_slam_nodes.core.odometry import GyroBuffer, WheelOdometryIntegrator
from pf_slam_nodes.core.stages import MappingStage


def test_scalar_compose_and_relative_pose_match_the_batched_form():
    rng = np.random.default_rng(0)
    a = rng.uniform(-5, 5, (50, 3))
    b = rng.uniform(-5, 5, (50, 3))
    batch_c, batch_r = compose(a, b), relative_pose(a, b)
    for i in range(50):
        np.testing.assert_allclose(compose(a[i], b[i]), batch_c[i], atol=1e-12)
        np.testing.assert_allclose(relative_pose(a[i], b[i]), batch_r[i], atol=1e-12)
        np.testing.assert_allclose(compose(a[i], relative_pose(a[i], b[i]))[:2], b[i, :2], atol=1e-9)


def test_wheel_integrator_scalar_step_matches_wheel_odometry_and_midpoint_rule():
    w = WheelOdometryIntegrator(0.62, 0.63, 1.5)
    pose = np.zeros(3)
    rng = np.random.default_rng(1)
    left = right = 0.0
    w.step(left, right)
    for _ in range(200):
        dl, dr = rng.uniform(0, 0.2, 2)
        left, right = left + dl, right + dr
        got = w.step(left, right)
        d, dyaw = wheel_odometry(dl, dr, 0.62, 0.63, 1.5)
        pose = integrate_diff_drive(pose, d, dyaw)
        np.testing.assert_allclose(got, pose, atol=1e-9)


def test_gyro_buffer_grows_and_trims_without_changing_sums():
    g = GyroBuffer()
    stamps = np.arange(1, 30001, dtype=np.int64) * 1_000_000  # 30 s at 1 kHz
    dy = np.sin(np.arange(stamps.size) * 1e-3) * 1e-4
    cum = np.concatenate([[0.0], np.cumsum(dy)])
    for k in range(0, stamps.size, 10):  # batches of 10, as FogBatch
        g.add(stamps[k : k + 10], dy[k : k + 10])
        if k % 5000 == 0 and k:
            g.trim(int(stamps[k - 12000])) if k >= 12000 else None
    assert g.last_stamp == stamps[-1]
    t0, t1 = int(stamps[20000]), int(stamps[25000])
    assert g.yaw_between(t0, t1) == pytest.approx(cum[25001] - cum[20001], abs=1e-12)
    g.add(stamps[:5], dy[:5])  # old stamps: dropped and counted
    assert g.out_of_order == 5


def test_mapping_stage_keeps_the_exported_occupancy_current():
    ms = MappingStage(FilterConfig(), GridConfig(size_x_m=40.0, size_y_m=40.0), LaserConfig())
    angles = np.linspace(-math.pi / 2, math.pi / 2, 181)
    for k in range(5):
        ms.integrate(np.array([0.5 * k, 0.1 * k, 0.05 * k]), np.full(181, 4.0 + k), angles, 0.0, 30.0)
        occ, _, _ = ms.map_occupancy()
        np.testing.assert_array_equal(occ, ms.grid.occupancy(ms.grid.touched_bounds))


def test_map_f1_perfect_shifted_and_empty():
    gt = np.zeros((60, 60), np.int8)
    gt[20:40, 20:40] = 100  # a building; its outline is what a lidar sees
    est = np.full_like(gt, -1)
    est[15:45, 15:45] = 0
    est[20, 20:40] = est[39, 20:40] = 100
    est[20:40, 20] = est[20:40, 39] = 100
    perfect = map_f1(est, 0.2, (0.0, 0.0), gt, 0.2, (0.0, 0.0))
    assert perfect["precision"] == 1.0 and perfect["recall"] == 1.0 and perfect["f1"] == 1.0
    shifted = map_f1(est, 0.2, (1.0, 0.0), gt, 0.2, (0.0, 0.0))  # the map 1 m off
    assert shifted["f1"] < 0.6
    none = map_f1(np.full_like(gt, -1), 0.2, (0.0, 0.0), gt, 0.2, (0.0, 0.0))
    assert none["f1"] == 0.0 and none["observed_edge_cells"] == 0


def test_filter_config_pose_estimate_is_checked():
    assert FilterConfig(pose_estimate="mean").pose_estimate == "mean"
    with pytest.raises(ValueError, match="pose_estimate"):
        FilterConfig(pose_estimate="median")


def test_pose_estimates_best_and_mean():
    """The best particle, or the weighted mean (yaw on the circle): with two hypotheses 3 m
    apart the mean lands between them."""
    from pf_slam_nodes.core.stages import pose_estimate

    particles = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.02], [-0.1, 0.0, -0.02], [3.0, 0.0, 0.5], [3.1, 0.0, 0.5]])
    log_w = np.log(np.array([0.3, 0.2, 0.2, 0.15, 0.15]))
    np.testing.assert_array_equal(pose_estimate(particles, log_w, FilterConfig()), particles[0])
    mean = pose_estimate(particles, log_w, FilterConfig(pose_estimate="mean"))
    yaw = math.atan2(
        0.2 * math.sin(0.02) - 0.2 * math.sin(0.02) + 0.3 * math.sin(0.5),
        0.3 + 0.4 * math.cos(0.02) + 0.3 * math.cos(0.5),
    )
    np.testing.assert_allclose(mean, [0.915, 0.0, yaw], atol=1e-12)
    np.testing.assert_allclose(
        pose_estimate(particles[[3, 3]], np.log([0.5, 0.5]), FilterConfig(pose_estimate="mean")),
        particles[3],
        atol=1e-12,
    )


def test_odometry_peek_consumes_nothing():
    from pf_slam_nodes.core.odometry import OdometryBuffer

    for sync in ("exact", "interpolate"):
        b = OdometryBuffer(sync)
        for k in range(5):
            b.add(100 * k, np.array([k, 0.0, 0.0]))
        for t in (200, 200, 250, 400):
            want = b.peek(t, final=True)
            again = b.peek(t, final=True)
            got = b.lookup(t, final=True)
            np.testing.assert_array_equal(want, again)
            np.testing.assert_array_equal(want, got)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_points_in_table_in_place_equals_the_plain_formula(dtype):
    """The window search's point transform works in place (fewer large temporaries): the same
    arithmetic, so the same bits as the plain expression, in both precisions."""
    from pf_slam_nodes.core.config import CorrelationConfig
    from pf_slam_nodes.core.correlation import GridLikelihoodField, _points_in_table

    rng = np.random.default_rng(3)
    field = GridLikelihoodField(200, 300, 0.05, (-7.3, -4.1), CorrelationConfig())
    poses = np.column_stack([rng.uniform(-3, 3, 500), rng.uniform(-2, 2, 500), rng.uniform(-4, 4, 500)])
    pts = rng.uniform(-20, 20, (540, 2))[::2]  # a strided view, as the beam stride gives
    u, v, rx, ry = _points_in_table(poses, pts, field, dtype)
    c = np.cos(poses[:, 2:3]).astype(dtype)
    s = np.sin(poses[:, 2:3]).astype(dtype)
    px, py = pts[:, 0].astype(dtype), pts[:, 1].astype(dtype)
    ex, ey = c * px - s * py, s * px + c * py
    off = field.pad - 0.5
    eu = ex * dtype(1 / 0.05) + ((poses[:, 0:1] - field.origin[0]) / 0.05 + off).astype(dtype)
    ev = ey * dtype(1 / 0.05) + ((poses[:, 1:2] - field.origin[1]) / 0.05 + off).astype(dtype)
    for got, want in ((u, eu), (v, ev), (rx, ex), (ry, ey)):
        assert got.dtype == dtype and np.array_equal(got, want)


def test_keep_freed_memory_is_accepted_by_glibc():
    """pf-slam run raises glibc's malloc thresholds (runner/memory.py); on Linux/glibc both
    settings are accepted, and numpy's large temporaries still work."""
    import platform

    from pf_slam_nodes.runner.memory import keep_freed_memory

    ok = keep_freed_memory()
    if platform.system() == "Linux" and platform.libc_ver()[0] == "glibc":
        assert ok
    a = np.ones((900, 300))
    assert float((a * 2.0 - a).sum()) == 900 * 300
