"""The map without a size: the grid and the likelihood field grow by whole tiles where scans
reach, memory follows the explored box, the field stays equal to a dense recompute."""

import math
import time

import numpy as np

from pf_slam_nodes.core import config as cfg
from pf_slam_nodes.core.correlation import build_likelihood_field_from_mask
from pf_slam_nodes.core.grid import TILE_CELLS, LogOddsGrid, growth_plan
from pf_slam_nodes.core.stages import CorrectionStage, MappingStage

ANG = np.linspace(-math.pi / 2, math.pi / 2, 181)


def corridor_scan(pose, half_width=2.0, pillar_every=6.0):
    """Ranges in an east-west corridor |y| < half_width with 0.4 m pillars on its walls every
    ``pillar_every`` m (a feature-rich straight corridor of any length)."""
    th = pose[2] + ANG
    c, s = np.cos(th), np.sin(th)
    with np.errstate(divide="ignore", invalid="ignore"):
        ty = np.where(s > 0, (half_width - pose[1]) / s, (-half_width - pose[1]) / s)
        ty = np.where(np.abs(s) < 1e-9, np.inf, ty)
        hx = pose[0] + ty * c
        # pillars: the wall steps in by 0.4 m over 0.4 m every pillar_every m
        on_pillar = np.mod(np.nan_to_num(hx, posinf=0.5), pillar_every) < 0.4
        ty2 = np.where(s > 0, (half_width - 0.4 - pose[1]) / s, (-half_width + 0.4 - pose[1]) / s)
    r = np.where(on_pillar, ty2, ty)
    r = np.where((r > 0) & (r < 15.0), r, np.inf)
    return r


def test_growth_plan_tiles_quarter_and_bound():
    assert growth_plan(100, 100, (0, 100, 0, 100), 10**9) is None
    # one cell beyond the right edge: a whole tile (the quarter of 100 is less)
    assert growth_plan(100, 100, (0, 100, 0, 101), 10**9) == (0, 0, 0, TILE_CELLS)
    # a big grid grows by at least a quarter of its extent (amortised)
    assert growth_plan(4000, 4000, (-1, 10, 0, 10), 10**9) == (1024, 0, 0, 0)
    # the bound: only the tiles needed, or nothing
    assert growth_plan(4000, 4000, (-1, 10, 0, 10), 4256 * 4000) == (256, 0, 0, 0)
    assert growth_plan(4000, 4000, (-1, 10, 0, 10), 4000 * 4000) == (0, 0, 0, 0)


def test_tiles_only_where_scans_touch_and_memory_follows_the_explored_box():
    """A 400 m corridor driven east from a 10 m grid: the grid grows along x by tiles, stays one
    or two tiles high, and its memory is within 1.6x the explored bounding box (+ a tile border)."""
    g = LogOddsGrid(cfg.GridConfig(size_x_m=10.0, size_y_m=10.0, range_max_usable_m=15.0), np.zeros(2))
    assert g.log_odds.shape == (200, 200)
    for x in np.arange(0.0, 400.0, 0.5):
        g.integrate_scan(np.array([x, 0.0, 0.0]), corridor_scan(np.array([x, 0.0, 0.0])), ANG)
    r0, r1, c0, c1 = g.touched_bounds
    explored = (r1 - r0) * (c1 - c0)
    assert (c1 - c0) * g.resolution > 410.0 and (r1 - r0) * g.resolution < 6.0  # the corridor only
    assert g.height <= 200 + 2 * TILE_CELLS  # never grew across the corridor beyond a tile
    assert (g.width - 200) % TILE_CELLS == 0 and (g.height - 200) % TILE_CELLS == 0
    padded = (r1 - r0 + 2 * TILE_CELLS) * (c1 - c0 + 2 * TILE_CELLS)
    assert g.log_odds.size <= 1.6 * padded, (g.log_odds.shape, explored)
    # a fixed 100 m grid would have lost everything beyond x = 50 m: here the far end is mapped
    occ = g.occupancy()
    for y in (2.0, -2.0):  # both walls between x = 390 and 398 m: occupied along most of it
        a, b = g.world_to_cell(np.array([[390.0, y], [398.0, y]]))
        band = occ[a[1] - 1 : a[1] + 2, a[0] : b[0]] >= 65
        assert band.any(axis=0).mean() > 0.6  # (a pillar steps the wall in at 390 m)
    assert g.growths < 20  # amortised: ~log growth, not one per scan


def test_a_scan_far_outside_integrates_where_it_is():
    """A scan 500 m south-west of a 10 m grid lands where it is in the world: its endpoints are
    occupied, its beams free, and the first scan's cells are untouched by the growth."""
    g = LogOddsGrid(
        cfg.GridConfig(size_x_m=10.0, size_y_m=10.0, range_max_usable_m=20.0, log_odds_hit=2.0), np.zeros(2)
    )
    g.integrate_scan(np.zeros(3), np.full(181, 3.0), ANG)
    first = g.occupancy(g.touched_bounds)
    first_origin = g.bounds_origin(g.touched_bounds)
    pose = np.array([-500.0, -420.0, 0.7])
    r = np.full(181, 4.0)
    g.integrate_scan(pose, r, ANG)
    assert g.offset[0] > 0 and g.offset[1] > 0  # grew on the negative side
    ends = pose[:2] + 4.0 * np.stack([np.cos(pose[2] + ANG), np.sin(pose[2] + ANG)], axis=1)
    cells = g.world_to_cell(ends)
    assert (g.occupancy()[cells[:, 1], cells[:, 0]] >= 65).all()
    mid = g.world_to_cell(pose[:2] + 2.0 * np.array([math.cos(pose[2]), math.sin(pose[2])]))
    assert g.occupancy()[mid[1], mid[0]] < 50
    # the first scan's cells: same values at the same world place
    c = g.world_to_cell(first_origin + 0.5 * g.resolution)
    np.testing.assert_array_equal(g.occupancy()[c[1] : c[1] + first.shape[0], c[0] : c[0] + first.shape[1]], first)
    np.testing.assert_allclose(g.cell_to_world(g.world_to_cell(ends)), ends, atol=g.resolution)


def test_growing_grid_equals_a_big_fixed_grid():
    """Where both have cells, the growing grid's cells are those of a fixed 200 m grid with the
    same origin (the growing one also has the cells west and south of that origin), bit for bit."""
    small = LogOddsGrid(cfg.GridConfig(size_x_m=10.0, size_y_m=10.0, origin_x_m=-5.0, origin_y_m=-5.0))
    big = LogOddsGrid(
        cfg.GridConfig(size_x_m=200.0, size_y_m=200.0, origin_x_m=-5.0, origin_y_m=-5.0, max_cells=4000 * 4000)
    )  # fixed
    rng = np.random.default_rng(3)
    for k in range(60):
        pose = np.array([k * 2.0, k * 1.1, rng.uniform(-3, 3)])
        r = rng.uniform(0.5, 25.0, 181)
        r[rng.random(181) < 0.1] = np.inf
        small.integrate_scan(pose, r, ANG)
        big.integrate_scan(pose, r, ANG)
    dc, dr = small.offset
    assert dc > 0 and dr > 0 and small.growths > 0
    mine = small.log_odds[dr:, dc:]
    h, w = min(mine.shape[0], big.height), min(mine.shape[1], big.width)
    np.testing.assert_array_equal(mine[:h, :w], big.log_odds[:h, :w])
    assert not big.log_odds[h:].any() and not big.log_odds[:, w:].any()
    assert np.count_nonzero(mine[:h, :w]) > 10000 and small.log_odds[:dr].any()


def test_bound_stops_growth_and_counts():
    g = LogOddsGrid(cfg.GridConfig(size_x_m=10.0, size_y_m=10.0, max_cells=300 * 300), np.zeros(2))
    g.integrate_scan(np.array([1e6, 1e6, 0.0]), np.full(181, 3.0), ANG)
    assert g.log_odds.shape == (200, 200) and g.scans_beyond_bound == 1 and g.cells_beyond_bound > 0
    assert not g.log_odds.any()
    g.integrate_scan(np.array([np.nan, 0.0, 0.0]), np.full(181, 3.0), ANG)  # NaN pose: nothing
    assert not g.log_odds.any()


def _drive(size_m, steps, max_cells=100_000_000):
    f, c, r = cfg.FilterConfig(), cfg.CorrelationConfig(), cfg.ResampleConfig()
    g = cfg.GridConfig(size_x_m=size_m, size_y_m=size_m, range_max_usable_m=15.0, max_cells=max_cells)
    mapper, corr = MappingStage(f, g), CorrectionStage(f, g, c, r)
    times = []
    for x in steps:
        # a corridor that turns north at x = 60 m: growth along both axes, on both sides of y
        pose = np.array([x, 0.0, 0.0]) if x < 60 else np.array([60.0, x - 60.0, math.pi / 2])
        local = pose.copy()
        if x >= 60:  # the corridor scan in the robot's frame along its own axis
            local = np.array([pose[1], 60.0 - pose[0], 0.0])
        ranges = corridor_scan(local)
        corr.pose = pose
        t0 = time.perf_counter()
        corr.apply_patch(mapper.integrate(pose, ranges, ANG, 0.0, 15.0))
        times.append(time.perf_counter() - t0)
    return mapper, corr, np.array(times)


def test_field_equals_a_dense_recompute_after_growth():
    mapper, corr, _ = _drive(8.0, np.arange(0.0, 120.0, 0.4))
    f = corr.field
    g = mapper.grid
    assert (f.height, f.width) != (160, 160)  # grew
    # the field's obstacles are the mapper's, at the same world place
    occ, res, origin = g.occupancy(), g.resolution, g.origin
    c0, r0 = np.rint((origin - f.origin) / res).astype(int)
    obst = np.zeros((f.height, f.width), bool)
    a0, b0 = max(r0, 0), max(c0, 0)
    a1, b1 = min(r0 + occ.shape[0], f.height), min(c0 + occ.shape[1], f.width)
    obst[a0:a1, b0:b1] = occ[a0 - r0 : a1 - r0, b0 - c0 : b1 - c0] >= corr.corr_cfg.occupied_threshold
    np.testing.assert_array_equal(f.obstacles, obst)
    dense = build_likelihood_field_from_mask(f.obstacles, f.resolution, f.origin, corr.corr_cfg)
    np.testing.assert_array_equal(f.distance_m, dense.distance_m)
    np.testing.assert_array_equal(f.log_likelihood, dense.log_likelihood)
    assert f.obstacles.any()


def test_per_scan_cost_does_not_follow_the_map_size(capsys):
    """A benchmark number, printed (no timing assert): integrate + patch + field update per scan
    early in a drive (small map) and late (a map 10x larger), from a 8 m grid and from a 400 m one."""
    steps = np.arange(0.0, 160.0, 0.4)
    out = []
    for size in (8.0, 400.0):
        mapper, corr, t = _drive(size, steps)
        n = len(t) // 5
        out.append(
            (size, 1e3 * np.median(t[5:n]), 1e3 * np.median(t[-n:]), mapper.grid.log_odds.shape, mapper.grid.growths)
        )
    with capsys.disabled():
        for size, early, late, shape, growths in out:
            print(
                f"\n[growmap bench] initial {size:g} m: median ms/scan (map+field) first fifth "
                f"{early:.2f}, last fifth {late:.2f}; final grid {shape}, growths {growths}"
            )
    assert out[0][3][0] * out[0][3][1] < out[1][3][0] * out[1][3][1]  # the grown grid is the smaller
