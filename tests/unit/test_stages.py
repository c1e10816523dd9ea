"""Stages as the graph runs them: map patches keep the correlator's field equal to a full rebuild."""

import numpy as np
from conftest import box_ranges

from pf_slam_nodes.core import config as cfg
from pf_slam_nodes.core.correlation import GridLikelihoodField
from pf_slam_nodes.core.stages import CorrectionStage, MappingStage, PredictionStage


def _box_scan(pose, n=181, fov=np.pi):
    """Ranges from `pose` inside a ~6 m x 4 m box; walls on cell centres of the 0.05 m grid."""
    ang = np.linspace(-fov / 2, fov / 2, n)
    return box_ranges(pose, ang, (-2.975, 3.025), (-1.975, 2.025)), ang


def test_patches_reproduce_the_mappers_obstacles():
    f, g, c, r = (
        cfg.FilterConfig(),
        cfg.GridConfig(size_x_m=10, size_y_m=10),
        cfg.CorrelationConfig(),
        cfg.ResampleConfig(),
    )
    mapper, corr = MappingStage(f, g), CorrectionStage(f, g, c, r)
    for pose in ([0, 0, 0], [0.3, 0.1, 0.2], [-0.5, 0.2, 1.5]):
        ranges, ang = _box_scan(np.array(pose, float))
        corr.pose = np.array(pose, float)
        corr.apply_patch(mapper.integrate(np.array(pose, float), ranges, ang, 0.0, 10.0))
    full = mapper.grid.occupancy() >= c.occupied_threshold
    np.testing.assert_array_equal(corr.field.obstacles, full)
    rebuilt = GridLikelihoodField(mapper.grid.height, mapper.grid.width, mapper.grid.resolution, mapper.grid.origin, c)
    rebuilt.update_from_occupancy(mapper.grid.occupancy())
    np.testing.assert_array_equal(corr.field.log_likelihood, rebuilt.log_likelihood)


def test_prediction_gate_and_first_scan():
    p = PredictionStage(cfg.FilterConfig(num_particles=4, min_travel_m=0.5), cfg.OdometryMotionConfig())
    update, delta = p.predict(np.array([1.0, 2.0, 0.3]))
    assert update and np.all(p.particles == [1.0, 2.0, 0.3])
    update, delta = p.predict(np.array([1.2, 2.0, 0.3]))
    assert not update and np.all(p.particles == [1.0, 2.0, 0.3])
    np.testing.assert_allclose(delta[0], 0.2 * np.cos(0.3))
    update, _ = p.predict(np.array([2.0, 2.0, 0.3]))
    assert update and not np.all(p.particles == [1.0, 2.0, 0.3])


def test_correction_recovers_pose_offset_and_keeps_n():
    f, g, c, r = (
        cfg.FilterConfig(num_particles=10),
        cfg.GridConfig(size_x_m=10, size_y_m=10),
        cfg.CorrelationConfig(),
        cfg.ResampleConfig(),
    )
    mapper, corr = MappingStage(f, g), CorrectionStage(f, g, c, r)
    true = np.array([0.2, -0.1, 0.1])
    ranges, ang = _box_scan(true, n=360, fov=2 * np.pi * 359 / 360)
    first = corr.correct(np.tile(true, (10, 1)), np.full(10, -np.log(10)), ranges, ang)
    assert not first.matched
    corr.apply_patch(mapper.integrate(first.pose, ranges, ang, 0.0, 10.0))
    guess = np.tile(true + [0.08, -0.06, 0.03], (10, 1))
    res = corr.correct(guess, np.full(10, -np.log(10)), ranges, ang)
    assert res.matched and res.particles.shape == (10, 3)
    np.testing.assert_allclose(res.pose, true, atol=0.02)


def test_a_sparse_scan_is_matched_on_its_far_returns():
    """In a 50 m x 50 m hall every return lies beyond the 20 m cut: without
    grid.min_return_fraction the scan has nothing to match and the offset stays; with it the scan
    maps and matches its nearest quarter and the correction recovers the pose."""
    true = np.array([0.3, -0.2, 0.05])
    ang = np.linspace(-np.pi, np.pi, 1440, endpoint=False)  # 0.1 m apart on the walls
    # walls on cell centres of the grid (centred on the first pose); the nearest quarter: all four
    ranges = box_ranges(true, ang, (-24.95, 24.95), (-24.95, 24.95))
    assert ranges.min() > 20.0
    err = {}
    for frac in (0.0, 0.25):
        f = cfg.FilterConfig(num_particles=10)
        g = cfg.GridConfig(resolution_m=0.1, size_x_m=80, size_y_m=80, min_return_fraction=frac)
        c = cfg.CorrelationConfig(step_xy_m=0.1)
        mapper, corr = MappingStage(f, g), CorrectionStage(f, g, c, cfg.ResampleConfig())
        first = corr.correct(np.tile(true, (10, 1)), np.full(10, -np.log(10)), ranges, ang, 0.0, 80.0)
        corr.apply_patch(mapper.integrate(first.pose, ranges, ang, 0.0, 80.0))
        guess = np.tile(true + [0.12, -0.08, 0.005], (10, 1))  # 0.005 rad: 0.12 m at 25 m
        res = corr.correct(guess, np.full(10, -np.log(10)), ranges, ang, 0.0, 80.0)
        err[frac] = float(np.hypot(*(res.pose[:2] - true[:2])))
        if frac == 0.0:
            assert not res.matched and np.count_nonzero(mapper.grid.log_odds > 0) == 0
    assert err[0.0] > 0.13 and err[0.25] < 0.03
