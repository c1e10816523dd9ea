"""grid.free_stop_cells: a hit beam's free trace stops short, so noisy beam ends leave a wall
occupied on both sides of its surface.

A beam clears every cell up to the one in front of its end. With noisy ranges, the beams that
overshoot a wall clear the cell that holds its surface, while nothing ever clears the cell
behind it (as seen from where it was mapped): the wall ends up thick on its far side, and the next
scan's points, pulled from the front only, move the match ahead. Stopping each free trace one cell
earlier spares the surface's cell from the overshooting beams as it spares the cell in front from
the short ones: the wall's cells lie on both sides of the surface."""

import numpy as np
import pytest
from ring_harness import along_track_drift

from pf_slam_nodes.core.config import GridConfig
from pf_slam_nodes.core.grid import LogOddsGrid


def _free_cells(stop: int) -> tuple[set, int]:
    """The columns one beam along +x cleared, and the column of its end."""
    g = LogOddsGrid(GridConfig(resolution_m=0.1, size_x_m=4.0, size_y_m=4.0, free_stop_cells=stop))
    pose = np.array([-1.45, 0.05, 0.0])  # mid-cell, beams along +x
    g.integrate_scan(pose, np.array([1.0]), np.zeros(1))
    _, cols = np.nonzero(g.log_odds < 0)
    return {int(c) for c in cols}, int(g.world_to_cell(np.array([-0.45, 0.05]))[0])


def test_the_free_trace_stops_the_given_cells_short():
    free0, end = _free_cells(0)
    free1, _ = _free_cells(1)
    free3, _ = _free_cells(3)
    assert max(free0) == end - 1  # up to the cell in front of the hit
    assert max(free1) == end - 2 and free1 == free0 - {end - 1}
    assert max(free3) == end - 4 and len(free3) == len(free0) - 3


def _neighbour(stop: int, offset: float, side: int) -> float:
    """Log-odds of the cell on ``side`` (-1 in front, +1 behind) of the cell holding a wall 3 m
    ahead whose surface lies ``offset`` from that cell's centre, after 60 beams with 1 cm noise."""
    rng = np.random.default_rng(0)
    g = LogOddsGrid(GridConfig(resolution_m=0.05, size_x_m=8.0, size_y_m=2.0, free_stop_cells=stop))
    col, row = g.world_to_cell(np.array([[3.0, 0.0]]))[0]
    surface = g.cell_to_world(np.array([[col, row]]))[0, 0] + offset
    for _ in range(60):  # one beam per scan: every end counts
        g.integrate_scan(np.zeros(3), np.array([surface + rng.normal(0.0, 0.01)]), np.zeros(1))
    assert g.log_odds[row, col] > 0
    return float(g.log_odds[row, col + side])


def test_a_wall_is_kept_on_both_sides_of_its_surface():
    # a surface 1.5 cm inside a cell's edge: ~7 % of the ends fall in the neighbour across that edge
    behind, front = _neighbour(0, +0.01, +1), _neighbour(0, -0.01, -1)
    assert behind > 0 > front  # without: kept behind (no beam clears it), cleared in front
    behind, front = _neighbour(1, +0.01, +1), _neighbour(1, -0.01, -1)
    assert behind > 0 and front > 0  # with: the wall's cells lie on both sides


def test_refused_values():
    for bad in (-1, 0.5, True):
        with pytest.raises(ValueError, match="free_stop_cells"):
            GridConfig(free_stop_cells=bad)


def test_noisy_ranges_no_longer_pull_the_matches_ahead():
    # the ring floor's first 300 scans (90 m of pillared corridor), ranges with 2 cm noise
    drift_off, _ = along_track_drift({"grid.free_stop_cells": 0}, noise_m=0.02)
    drift_on, jitter_on = along_track_drift({"grid.free_stop_cells": 1}, noise_m=0.02)
    assert drift_off > 0.09  # 0.13 m ahead
    assert abs(drift_on) < 0.04 and jitter_on < 0.022  # 0.00 m, 19 mm per scan
