"""Scan geometry, log-odds grid and ray tracing."""

import math

import numpy as np

from pf_slam_nodes.core.config import GridConfig
from pf_slam_nodes.core.grid import LogOddsGrid, from_occupancy
from pf_slam_nodes.core.scan import (
    beam_angles,
    grazing_samples,
    scan_to_points,
    transform_points,
    transform_points_batch,
)

L4 = math.log(4.0)


def small_grid(**kw):
    d = dict(
        resolution_m=1.0,
        size_x_m=10.0,
        size_y_m=10.0,
        origin_x_m=0.0,
        origin_y_m=0.0,
        range_max_usable_m=20.0,
        log_odds_hit=L4,
        log_odds_miss=-L4,
    )
    d.update(kw)
    return LogOddsGrid(GridConfig(**d))


def test_beam_angles_and_points():
    a = beam_angles(-math.pi / 2, math.pi / 2, 3)
    np.testing.assert_allclose(a, [-math.pi / 2, 0, math.pi / 2])
    pts = scan_to_points(np.array([1.0, np.inf, np.nan, 0.05, 2.0, 90.0]), np.zeros(6), 0.1, 80.0)
    np.testing.assert_allclose(pts, [[1.0, 0.0], [2.0, 0.0]])
    assert scan_to_points(np.arange(1.0, 7.0), np.zeros(6), 0.1, 80.0, stride=2).shape == (3, 2)


def test_transform_points():
    p = np.array([[1.0, 0.0]])
    np.testing.assert_allclose(transform_points(p, np.array([1.0, 1.0, math.pi / 2])), [[1.0, 2.0]], atol=1e-12)
    b = transform_points_batch(p, np.array([[0, 0, 0], [1.0, 1.0, math.pi / 2]]))
    assert b.shape == (2, 1, 2)
    np.testing.assert_allclose(b[1], [[1.0, 2.0]], atol=1e-12)


def test_ray_marks_expected_free_and_hit_cells():
    g = small_grid()
    # sensor at the centre of cell (col 1, row 5), beam along +x hitting a wall at x = 6.5 (col 6)
    g.integrate_scan(np.array([1.5, 5.5, 0.0]), np.array([5.0]), np.array([0.0]))
    lo = g.log_odds
    expect = np.zeros_like(lo)
    expect[5, 1:6] = -L4
    expect[5, 6] = L4
    np.testing.assert_allclose(lo, expect, atol=1e-6)
    occ = g.occupancy()
    assert occ[5, 6] == 80 and occ[5, 3] == 20 and occ[0, 0] == -1


def test_diagonal_ray_and_no_return():
    g = small_grid()
    g.integrate_scan(np.array([0.5, 0.5, math.pi / 4]), np.array([4 * math.sqrt(2)]), np.array([0.0]))
    lo = g.log_odds
    for k in range(4):
        assert lo[k, k] == np.float32(-L4)
    assert lo[4, 4] == np.float32(L4)
    assert np.count_nonzero(lo) == 5
    g2 = small_grid(range_max_usable_m=3.0)
    g2.integrate_scan(np.array([0.5, 0.5, 0.0]), np.array([np.inf]), np.array([0.0]))
    np.testing.assert_allclose(g2.log_odds[0, :4], -L4)  # free up to 3 m, endpoint cell free, no hit
    assert np.count_nonzero(g2.log_odds) == 4 and g2.log_odds.max() == 0


def test_no_return_clears_only_up_to_the_sensor_range():
    """A beam without return saw free space up to the scan's range_max, not up to the grid's
    (longer) usable range: a wall beyond the sensor's reach must survive such beams."""
    g = small_grid(range_max_usable_m=20.0)
    g.integrate_scan(np.array([0.5, 0.5, 0.0]), np.array([7.0]), np.array([0.0]))  # wall in col 7
    for _ in range(5):
        g.integrate_scan(np.array([0.5, 0.5, 0.0]), np.array([np.inf]), np.array([0.0]), range_max_m=4.0)
    lo = g.log_odds
    assert lo[0, 7] == np.float32(L4)  # the wall: untouched by the 4 m no-return beams
    assert np.all(lo[0, :5] < -L4)  # within 4 m: cleared by every beam
    assert np.all(lo[0, 5:7] == np.float32(-L4))  # beyond 4 m: by the beam with the return only


def test_hit_wins_over_free_in_same_scan_and_clipping():
    g = small_grid(clip_max=2.0, clip_min=-3.0)
    pose = np.array([0.5, 5.5, 0.0])
    for _ in range(5):
        g.integrate_scan(pose, np.array([3.0, 6.0]), np.array([0.0, 0.0]))
    assert g.log_odds[5, 3] == np.float32(2.0)  # hit by beam 0, traversed by beam 1, clipped
    assert g.log_odds[5, 1] == np.float32(-3.0)  # clipped
    assert g.log_odds.max() <= 2.0 and g.log_odds.min() >= -3.0


def test_no_write_outside_grid():
    """A grid bounded at its initial size (max_cells) never writes beyond it, and counts what it
    could not write."""
    g = small_grid(max_cells=100)
    ang = np.linspace(-math.pi, math.pi, 73)
    g.integrate_scan(np.array([8.5, 8.5, 0.3]), np.full(73, 50.0), ang)  # rays leave the grid
    g.integrate_scan(np.array([-5.0, -5.0, 0.0]), np.array([200.0]), np.array([0.5]))  # sensor outside
    assert g.log_odds.shape == (10, 10)
    assert np.count_nonzero(g.log_odds) > 0
    big = LogOddsGrid(
        GridConfig(
            resolution_m=1.0,
            size_x_m=12,
            size_y_m=12,
            origin_x_m=-1.0,
            origin_y_m=-1.0,
            range_max_usable_m=20.0,
            log_odds_hit=L4,
            log_odds_miss=-L4,
            max_cells=144,
        )
    )
    big.integrate_scan(np.array([8.5, 8.5, 0.3]), np.full(73, 50.0), ang)
    # the 10x10 grid equals the interior of a larger grid: nothing was wrapped or clipped into it
    inner = big.log_odds[1:11, 1:11]
    assert g.scans_beyond_bound == 2 and g.cells_beyond_bound > 0 and g.growths == 0
    g1 = small_grid(max_cells=100)
    g1.integrate_scan(np.array([8.5, 8.5, 0.3]), np.full(73, 50.0), ang)
    np.testing.assert_array_equal(g1.log_odds, inner)


def test_world_to_cell_and_centre_origin():
    g = LogOddsGrid(GridConfig(resolution_m=0.05, size_x_m=10.0, size_y_m=4.0), center_xy=np.array([1.0, 2.0]))
    assert (g.width, g.height) == (200, 80)
    np.testing.assert_allclose(g.origin, [-4.0, 0.0])
    c = g.world_to_cell(np.array([[1.0, 2.0], [-4.0, 0.0], [-4.01, 0.0]]))
    np.testing.assert_array_equal(c, [[100, 40], [0, 0], [-1, 0]])
    np.testing.assert_array_equal(g.in_bounds(c), [True, True, False])


def test_occupied_mask_matches_occupancy_and_from_occupancy():
    g = small_grid()
    g.log_odds[:] = np.linspace(-3, 3, 100, dtype=np.float32).reshape(10, 10)
    g.log_odds[0, 0] = 0.0
    occ = g.occupancy()
    np.testing.assert_array_equal(g.occupied_mask(65), occ >= 65)
    m = from_occupancy(occ, 1.0, (0.0, 0.0, 0.0))
    assert (m.width, m.height) == (10, 10) and m.data.dtype == np.int8


def test_sparse_scan_range_raises_the_cut_only_for_scans_with_few_near_returns():
    from pf_slam_nodes.core.scan import sparse_scan_range

    near = np.array([3.0, 5.0, 8.0, np.inf, 12.0, 30.0, 40.0, np.nan])
    assert sparse_scan_range(near, 20.0, 80.0, 0.25) == 20.0  # 4 of 8 within 20 m
    assert sparse_scan_range(near, 20.0, 80.0, 0.0) == 20.0  # off
    far = np.array([3.0, np.inf, 55.0, 30.0, 90.0, 45.0, np.inf, np.inf])
    assert sparse_scan_range(far, 20.0, 80.0, 0.25) == 30.0  # the 2nd nearest of 8 (a quarter)
    assert sparse_scan_range(far, 20.0, 80.0, 0.5) == 55.0  # 4 returns wanted, 90 m is no return
    assert sparse_scan_range(np.array([np.inf, 50.0, np.inf, np.inf]), 20.0, 80.0, 0.75) == 50.0  # all returns
    assert sparse_scan_range(np.full(4, np.inf), 20.0, 80.0, 0.25) == 20.0


def test_mapping_stage_maps_the_far_returns_of_a_sparse_scan():
    """A scan whose returns are all beyond range_max_usable_m maps its nearest quarter as hits
    with grid.min_return_fraction, and none without."""
    from pf_slam_nodes.core.config import FilterConfig
    from pf_slam_nodes.core.stages import MappingStage

    ranges = np.array([25.0, 26.0, 27.0, 28.0, np.inf, np.inf, np.inf, np.inf])
    angles = np.linspace(-0.2, 0.2, 8)
    hits = {}
    for frac in (0.0, 0.25):
        cfg = GridConfig(resolution_m=0.5, size_x_m=80.0, size_y_m=80.0, min_return_fraction=frac)
        m = MappingStage(FilterConfig(), cfg)
        m.integrate(np.zeros(3), ranges, angles, 0.1, 30.0)
        hits[frac] = int(np.count_nonzero(m.grid.log_odds > 0))
    assert hits[0.0] == 0 and hits[0.25] == 2


def test_grazing_samples_are_the_sparse_far_returns_of_a_wall_seen_along_it():
    """A wall 1.2 m to the left, beams every degree: the returns more than 1 m apart where the
    beams meet it more than 70 deg from its normal (far along it) are grazing samples; the near
    ones (dense, head-on) are not, nor is a return whose neighbours lie on two surfaces."""
    a = beam_angles(math.radians(5.0), math.radians(1.0), 80)  # 5 .. 84 deg
    pts = np.stack([1.2 / np.tan(a), np.full(a.size, 1.2)], axis=1)
    g = grazing_samples(pts, 1.0)
    span = np.zeros(a.size)
    span[1:-1] = np.hypot(*(pts[2:] - pts[:-2]).T)
    incidence = np.degrees(math.pi / 2 - a)  # from the wall's normal
    np.testing.assert_array_equal(g[1:-1], ((span > 1.0) & (incidence > 70.0))[1:-1])
    assert g[1:-1].any() and not g[-20:].any() and not g[0] and not g[-1]
    bent = pts.copy()
    bent[11:, 1] += 3.0  # from beam 11 on, another surface 3 m further out
    assert not grazing_samples(bent, 1.0)[10:12].any()
