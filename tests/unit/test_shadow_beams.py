"""correlation.shadow_jump_m: the beams on the far side of an occluding edge are not matched.

Where the background comes out from behind a pillar, the edge of what was seen moves with the
viewpoint; points there pulled the matches along the corridor of the simulated ring floor (a
scale-like drift of 0.2 % with perfect odometry and noise-free ranges)."""

import numpy as np
import pytest
from ring_harness import along_track_drift

from pf_slam_nodes.core.config import CorrelationConfig
from pf_slam_nodes.core.scan import shadow_beams, shadow_neighbours


def test_the_far_side_of_a_range_jump_is_flagged():
    r = np.array([5.0, 5.0, 2.0, 2.0, 5.0, 5.0, np.inf, 5.0, np.nan, 5.0])
    # the pillar (beams 2, 3) stays; the wall beside it, one beam on each side, goes
    assert shadow_beams(r, 0.3, 1).tolist() == [0, 1, 0, 0, 1, 0, 0, 0, 0, 0]
    assert shadow_beams(r, 0.3, 2).tolist() == [1, 1, 0, 0, 1, 1, 0, 0, 0, 0]
    # a jump below the threshold, no return (inf) or no value (NaN) is no edge
    assert not shadow_beams(r, 3.5, 1).any()
    assert not shadow_beams(np.array([5.0, np.inf, 5.0, np.nan]), 0.3, 1).any()
    assert not shadow_beams(r, 0.0, 1).any()  # off


def test_the_neighbourhood_is_an_angle_on_a_dense_scanner():
    deg = np.radians
    one, half, quarter = (deg(np.linspace(-90.0, 90.0, n)) for n in (181, 361, 721))
    angle = 0.0131  # the indoor profile's 0.75 deg
    assert shadow_neighbours(one, 1, angle) == 1  # a 1 deg scanner keeps its one beam ...
    assert shadow_neighbours(half, 1, angle) == 1  # ... and a 0.5 deg one (every CARMEN log)
    assert shadow_neighbours(quarter, 1, angle) == 3  # 0.25 deg: the same angle, three beams
    assert shadow_neighbours(quarter[::-1], 1, angle) == 3  # mirrored (upside-down mount)
    assert shadow_neighbours(deg(np.linspace(-135.0, 135.0, 811)), 1, angle) == 2  # 0.33 deg
    assert shadow_neighbours(quarter, 5, angle) == 5  # never fewer than shadow_beams
    assert shadow_neighbours(quarter, 1, 0.0) == 1  # off: shadow_beams alone
    assert shadow_neighbours(np.zeros(1), 2, angle) == 2


def test_negative_values_are_refused():
    with pytest.raises(ValueError, match="shadow_jump_m"):
        CorrelationConfig(shadow_jump_m=-0.1)
    with pytest.raises(ValueError, match="shadow_beams"):
        CorrelationConfig(shadow_beams=0)
    with pytest.raises(ValueError, match="shadow_angle_rad"):
        CorrelationConfig(shadow_angle_rad=-0.01)


def test_matches_no_longer_run_ahead_along_a_pillared_corridor():
    drift_off, jitter_off = along_track_drift(
        {"correlation.shadow_jump_m": 0.0, "grid.peak_ratio": 0.0, "grid.free_stop_cells": 0}
    )
    drift_on, jitter_on = along_track_drift(
        {"correlation.shadow_jump_m": 0.3, "grid.peak_ratio": 0.0, "grid.free_stop_cells": 0}
    )
    assert drift_off > 0.12 and jitter_off > 0.014  # 90 m of corridor: 0.19 m ahead, 17 mm per scan
    assert abs(drift_on) < 0.08 and jitter_on < 0.011  # 0.04 m, 8 mm


def test_a_dense_scanner_does_not_run_ahead_either():
    # 1081 beams over 270 deg (a 0.25 deg scanner) with 1 cm of range noise: one beam beside an
    # edge is a quarter of the angle it is on the 1 deg laser, and the matches ran ahead again
    dense = np.radians(np.linspace(-135.0, 135.0, 1081))
    drift_beam, _ = along_track_drift({"correlation.shadow_angle_rad": 0.0}, 600, 0.01, dense)
    drift_angle, _ = along_track_drift({}, 600, 0.01, dense)  # the indoor profile's 0.75 deg
    assert drift_beam > 0.15  # 0.21 m ahead over 60 m
    assert abs(drift_angle) < 0.1  # 0.06 m behind


def test_points_left_out_of_the_match_still_weigh_the_particles():
    from pf_slam_nodes.core.config import GridConfig
    from pf_slam_nodes.core.correlation import build_likelihood_field_from_map, correlate
    from pf_slam_nodes.core.grid import LogOddsGrid
    from pf_slam_nodes.core.scan import scan_to_points

    angles = np.radians(np.arange(-90.0, 90.5, 1.0))
    box = np.where(np.abs(np.sin(angles)) > 1e-9, 2.1 / np.maximum(np.abs(np.sin(angles)), 1e-9), np.inf)
    ranges = np.minimum(box, 4.3 / np.maximum(np.cos(angles), 1e-9))  # a room: walls at y = +-2.1, x = 4.3
    grid = LogOddsGrid(GridConfig(resolution_m=0.05, size_x_m=12.0, size_y_m=12.0))
    for _ in range(3):
        grid.integrate_scan(np.zeros(3), ranges, angles)
    cfg = CorrelationConfig()
    field = build_likelihood_field_from_map(grid.to_occupancy_map(), cfg)
    pts = scan_to_points(ranges, angles, 1e-6, 20.0)
    pts[::7] += 0.25  # every 7th point off the walls
    match = np.ones(len(pts), bool)
    match[::7] = False
    start = np.array([[0.04, -0.03, 0.02], [-0.05, 0.02, -0.01]])
    pose_m, score_m = correlate(start.copy(), pts, field, cfg, match)
    pose_k, score_k = correlate(start.copy(), pts[match], field, cfg)
    assert np.allclose(pose_m, pose_k)  # the pose comes from the matched points alone ...
    assert np.abs(pose_m[0] - pose_m[1]).max() < 1e-3  # both starts end at one pose
    assert np.all(score_m < score_k - 1.0)  # ... the score from every point (the off ones cost)
