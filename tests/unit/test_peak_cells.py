"""grid.peak_ratio: the scan matcher sees a wall at its peak of beam ends, not as a plateau.

With noisy ranges a wall's beam ends spread over two cells; the cell behind it, reached only by
the beams that overshoot, is never crossed by a free ray and stays occupied, while the one in
front is cleared. The two-cell plateau that is left lies behind the wall as seen from where it
was mapped, and the next scan's points, free to sit anywhere on it, pull the match ahead."""

import numpy as np
import pytest
from ring_harness import along_track_drift

from pf_slam_nodes.core.config import GridConfig
from pf_slam_nodes.core.grid import LogOddsGrid


def _grid(ratio: float) -> LogOddsGrid:
    return LogOddsGrid(GridConfig(resolution_m=0.1, size_x_m=1.0, size_y_m=1.0, peak_ratio=ratio))


def test_beam_ends_are_counted_per_cell_and_survive_growth():
    g = _grid(0.5)
    angles = np.radians([-10.0, 0.0, 0.0, 10.0])
    g.integrate_scan(np.zeros(3), np.array([0.3, 0.3, 0.3, np.inf]), angles)
    assert g.hits.sum() == 3 and g.hits.max() == 2  # two beams end in one cell; no return: no hit
    cell = tuple(g.world_to_cell(np.array([0.3, 0.0]))[::-1])
    assert g.hits[cell] == 2
    g.integrate_scan(np.zeros(3), np.array([2.0]), np.zeros(1))  # beyond the grid: it grows
    assert g.growths == 1 and g.hits.shape == g.log_odds.shape
    assert g.hits[tuple(g.world_to_cell(np.array([0.3, 0.0]))[::-1])] == 2
    assert g.hits.sum() == 4
    assert _grid(0.0).hits is None  # off: no counts kept


def test_only_the_peak_of_a_wall_is_matched():
    g = _grid(0.5)
    occ = np.full((10, 10), -1, np.int8)
    occ[0:3, 0:3] = 100
    g.hits[0:4, 0:3] = np.array([[10, 10, 10], [3, 6, 4], [0, 0, 0], [0, 0, 0]], np.float32)
    occ[2, 0:3] = 0
    out, bounds = g.matching_patch(occ, (0, 4, 0, 3))
    assert bounds == (0, 5, 0, 4)  # grown by the cells whose neighbours changed (clipped at the edge)
    # row 1 is the overshoot side of the wall in row 0: its cells under half the wall's count go
    assert out[1, 0:3].tolist() == [0, 100, 0]
    assert out[0, 0:3].tolist() == [100] * 3 and out[2, 0:3].tolist() == [0] * 3 and out[3, 0:3].tolist() == [-1] * 3
    assert occ[1, 0] == 100  # a copy: /map keeps every occupied cell
    # a block's edge cells are judged with their neighbours beyond the block
    out, bounds = g.matching_patch(occ, (1, 2, 0, 3))
    assert bounds == (0, 3, 0, 4) and out[1, 0:3].tolist() == [0, 100, 0]
    off = _grid(0.0)
    out, bounds = off.matching_patch(occ, (0, 4, 0, 3))
    assert bounds == (0, 4, 0, 3) and np.array_equal(out, occ[0:4, 0:3])


def test_refused_values():
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="peak_ratio"):
            GridConfig(peak_ratio=bad)


def test_noisy_ranges_no_longer_pull_the_matches_ahead():
    # the ring floor's first 300 scans (90 m of pillared corridor), ranges with 2 cm noise
    drift_off, jitter_off = along_track_drift({"grid.peak_ratio": 0.0, "grid.free_stop_cells": 0}, noise_m=0.02)
    drift_on, jitter_on = along_track_drift({"grid.peak_ratio": 0.5, "grid.free_stop_cells": 0}, noise_m=0.02)
    assert drift_off > 0.09 and jitter_off > 0.015  # 0.13 m ahead, 17 mm per scan
    assert abs(drift_on) < 0.04 and jitter_on < 0.014  # 0.00 m, 12 mm


def test_the_published_map_keeps_every_cell_the_correlator_sees_the_peaks():
    from pf_slam_nodes.core.config import FilterConfig
    from pf_slam_nodes.core.stages import MappingStage

    angles = np.radians(np.arange(-60.0, 60.5, 1.0))
    wall = 3.0 / np.cos(angles)  # a wall 3 m ahead, seen from 20 poses along x
    maps, patches = {}, {}
    for ratio in (0.0, 0.5):
        stage = MappingStage(
            FilterConfig(), GridConfig(resolution_m=0.05, size_x_m=10.0, size_y_m=10.0, peak_ratio=ratio)
        )
        rng = np.random.default_rng(1)
        for k in range(20):
            patch = stage.integrate(
                np.array([0.01 * k, 0.0, 0.0]), wall - 0.01 * k + rng.normal(0, 0.02, wall.size), angles, 0.0, 20.0
            )
        maps[ratio] = stage.map_occupancy()[0]
        patches[ratio] = patch.occupancy
    assert np.array_equal(maps[0.0], maps[0.5])  # /map does not change
    wall_off, wall_on = ((patches[r] >= 65).sum() for r in (0.0, 0.5))
    assert wall_on < 0.8 * wall_off  # the matcher's wall is thinner: 276 cells of 381
