"""Correlation options for the car: motion prior of the match and skipping unobserved cells."""

import math

import numpy as np
import pytest
from test_core_correlation_slam import raycast, world

from pf_slam_nodes.core.config import CorrelationConfig, FilterConfig, GridConfig, ResampleConfig
from pf_slam_nodes.core.correlation import build_likelihood_field_from_map, correlate
from pf_slam_nodes.core.grid import LogOddsGrid
from pf_slam_nodes.core.motion import compose
from pf_slam_nodes.core.scan import beam_angles, scan_to_points
from pf_slam_nodes.core.stages import CorrectionStage, MappingStage


def test_defaults_off_and_validation():
    cfg = CorrelationConfig()
    assert cfg.skip_unknown is False and cfg.prior_sigma_xy_m == 0.0 and cfg.prior_sigma_yaw_rad == 0.0
    with pytest.raises(ValueError, match="skip_unknown"):
        CorrelationConfig(skip_unknown=1)
    with pytest.raises(ValueError, match="prior_sigma_xy_m"):
        CorrelationConfig(prior_sigma_xy_m=-0.1)
    with pytest.raises(ValueError, match="prior_sigma_yaw_rad"):
        CorrelationConfig(prior_sigma_yaw_rad=float("nan"))


def _scene():
    occ = world()
    true_pose = np.array([6.1, 5.2, 0.4])
    ang = beam_angles(-math.pi / 2, math.pi / 180, 181)
    ranges = raycast(occ, true_pose, ang)
    grid = LogOddsGrid(GridConfig(size_x_m=12.0, size_y_m=10.0, origin_x_m=0.0, origin_y_m=0.0))
    grid.integrate_scan(true_pose, ranges, ang)
    return true_pose, scan_to_points(ranges, ang, 0.1, 19.0), grid


def _offset_start():
    """The scene's true pose and points, a start pose 0.1 m / -0.05 m / 0.02 rad off it
    (``(1, 3)``), the search window ``base`` and the map's likelihood field."""
    true_pose, pts, grid = _scene()
    start = compose(true_pose, np.array([0.1, -0.05, 0.02]))[None]
    base = dict(search_x_m=0.2, search_y_m=0.2, search_yaw_rad=0.1)
    return (
        true_pose,
        pts,
        start,
        base,
        build_likelihood_field_from_map(grid.to_occupancy_map(), CorrelationConfig(**base)),
    )


def _score_in_place(poses, pts, field):
    """The score of particles left where they are (no window, no refinement, no prior)."""
    return correlate(
        poses, pts, field, CorrelationConfig(search_x_m=0, search_y_m=0, search_yaw_rad=0, refine_iterations=0)
    )[1]


def test_motion_prior_keeps_weak_shifts_and_never_scores_below_staying():
    true_pose, pts, start, base, field = _offset_start()
    free, _ = correlate(start, pts, field, CorrelationConfig(**base))
    assert not np.allclose(free, start)  # without a prior the match moves towards the truth
    tight = CorrelationConfig(**base, prior_sigma_xy_m=1e-4, prior_sigma_yaw_rad=1e-5)
    kept, kept_score = correlate(start, pts, field, tight)
    np.testing.assert_array_equal(kept, start)  # any shift costs more than it gains
    stay = _score_in_place(start, pts, field)
    assert kept_score[0] == pytest.approx(stay[0])
    loose = CorrelationConfig(**base, prior_sigma_xy_m=0.5, prior_sigma_yaw_rad=0.5)
    moved, moved_score = correlate(start, pts, field, loose)
    assert moved_score[0] >= stay[0]
    assert math.hypot(*(moved[0, :2] - true_pose[:2])) < math.hypot(*(start[0, :2] - true_pose[:2]))


def test_skip_unknown_drops_points_on_unobserved_cells():
    true_pose, pts, grid = _scene()
    ang = beam_angles(-math.pi / 2, math.pi / 180, 181)
    ranges = raycast(world(), true_pose, ang)
    fcfg = FilterConfig(num_particles=3)
    gcfg = GridConfig(size_x_m=12.0, size_y_m=10.0, origin_x_m=0.0, origin_y_m=0.0)
    corr = CorrectionStage(fcfg, gcfg, CorrelationConfig(skip_unknown=True), ResampleConfig())
    mapper = MappingStage(fcfg, gcfg)
    corr.apply_patch(mapper.integrate(true_pose, ranges, ang, 0.0, 19.0))
    assert corr.known is not None and corr.known.any() and not corr.known.all()
    keep = corr._observed(pts, true_pose)
    assert keep.mean() > 0.9  # the scan's own endpoints were observed
    # the same points seen facing the other way mostly land on cells never observed
    away = corr._observed(pts, compose(true_pose, np.array([0.0, 0.0, math.pi])))
    assert away.sum() < keep.sum()
    # the default stage keeps no mask
    assert CorrectionStage(fcfg, gcfg, CorrelationConfig(), ResampleConfig()).known is None


def test_gains_take_a_fraction_of_the_match_per_axis_and_score_there():
    _, pts, start, base, field = _offset_start()
    full, _ = correlate(start, pts, field, CorrelationConfig(**base))
    half, half_score = correlate(start, pts, field, CorrelationConfig(**base, gain_xy=0.5, gain_yaw=0.0))
    np.testing.assert_allclose(half[0, :2], start[0, :2] + 0.5 * (full[0, :2] - start[0, :2]), atol=1e-12)
    assert half[0, 2] == pytest.approx(start[0, 2])  # gain_yaw 0: the predicted (gyro) yaw is kept
    # the weight update is the score where the particle now is, not at its match
    assert half_score[0] == pytest.approx(_score_in_place(half, pts, field)[0])
    none, _ = correlate(start, pts, field, CorrelationConfig(**base, gain_xy=0.0, gain_yaw=0.0))
    np.testing.assert_allclose(none, start, atol=1e-12)
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="gain_xy"):
            CorrelationConfig(gain_xy=bad)
    with pytest.raises(ValueError, match="gain_yaw"):
        CorrelationConfig(gain_yaw=2.0)
