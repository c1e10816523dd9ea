"""grid.graze_margin_m: a wall that later rays graze stays in the map; a beam that meets a
surface head-on still clears up to its end."""

import numpy as np

from pf_slam_nodes.core.config import GridConfig
from pf_slam_nodes.core.grid import LogOddsGrid

WALL_Y = 1.02  # inside the cell row [1.00, 1.05): a beam grazing it from below crosses that row


def _grid(margin):
    return LogOddsGrid(
        GridConfig(
            resolution_m=0.05, size_x_m=40.0, size_y_m=10.0, origin_x_m=-20.0, origin_y_m=-5.0, graze_margin_m=margin
        )
    )


def _scan_at_wall(pose, angles):
    """Ranges from ``pose`` (x, y, 0) to the wall y = WALL_Y, x in [0, 10] (inf elsewhere)."""
    s = np.sin(angles)
    r = np.where(s > 1e-6, (WALL_Y - pose[1]) / np.maximum(s, 1e-6), np.inf)
    x = pose[0] + r * np.cos(angles)
    return np.where((x >= 0) & (x <= 10), r, np.inf)


def _wall_kept(margin, grazing_scans=30):
    g = _grid(margin)
    a = np.radians(np.arange(-90, 90.5, 0.5))
    for x in np.arange(0.5, 10, 1.0):  # build the wall from below, head-on
        p = np.array([x, 0.0, 0.0])
        g.integrate_scan(p, _scan_at_wall(p, a), a)

    def wall():
        c = g.world_to_cell(np.stack([np.arange(1.0, 9.0, 0.05) + 0.025, np.full(160, WALL_Y)], axis=1))
        return (g.log_odds[c[:, 1], c[:, 0]] > 0).mean()

    before = wall()
    p = np.array([-3.0, 0.5, 0.0])  # then along it, grazing (3-15 degrees)
    ag = np.radians(np.arange(3.0, 15.0, 0.25))
    for _ in range(grazing_scans):
        g.integrate_scan(p, _scan_at_wall(p, ag), ag)
    return before, wall()


def test_a_grazed_wall_fades_without_the_margin_and_stays_with_it():
    before0, after0 = _wall_kept(0.0)
    before1, after1 = _wall_kept(0.5)
    assert before0 == before1 > 0.95
    assert after0 < 0.7 * before0  # the seeds' map: grazing rays erase the wall
    assert after1 > 0.9 * before1  # with the margin it stays


def test_head_on_beams_still_clear_up_to_their_end():
    # an obstacle seen head-on, then gone: the margin does not protect it
    for margin in (0.0, 0.5):
        g = _grid(margin)
        a = np.radians(np.arange(-10, 10.5, 0.5))
        p = np.array([0.0, 0.0, 0.0])
        g.integrate_scan(p, np.full(a.size, 3.0) / np.cos(a), a)  # a wall at x = 3
        g.integrate_scan(p, np.full(a.size, 3.0) / np.cos(a), a)

        def cell():
            c = g.world_to_cell(np.array([[3.01, 0.01]]))[0]
            return g.log_odds[c[1], c[0]]

        assert cell() > 0
        for _ in range(10):  # gone: beams to x = 6
            g.integrate_scan(p, np.full(a.size, 6.0) / np.cos(a), a)
        assert cell() < 0
