"""grid.surface_fill_m: a scan maps its walls as lines between neighbouring beams' ends, not as
the dots its beams hit, so the next scan no longer scores best where it repeats the last one's
dots; a range jump at an edge is never bridged."""

import dataclasses

import numpy as np
import pytest

from pf_slam_nodes.core.config import CorrelationConfig, GridConfig
from pf_slam_nodes.core.correlation import build_likelihood_field_from_map, correlate
from pf_slam_nodes.core.grid import LogOddsGrid
from pf_slam_nodes.core.scan import scan_to_points

ANGLES = np.radians(np.arange(-90.0, 90.5, 1.0))  # 181 beams, 1 degree apart
HALF_W = 1.23  # corridor half-width: the walls y = +-1.23, off the cell boundaries


def _grid(fill):
    return LogOddsGrid(
        GridConfig(
            resolution_m=0.05, size_x_m=60.0, size_y_m=10.0, origin_x_m=-10.0, origin_y_m=-5.0, surface_fill_m=fill
        )
    )


def _corridor(pose, angles=ANGLES, length=40.0):
    """Ranges from ``pose`` (x, y, 0) to the walls y = +-HALF_W for x in [-10, length] (inf beyond)."""
    s = np.sin(angles)
    with np.errstate(divide="ignore"):
        r = np.where(s > 0, (HALF_W - pose[1]) / s, np.where(s < 0, (-HALF_W - pose[1]) / s, np.inf))
    x = pose[0] + r * np.cos(angles)
    return np.where((x <= length) & (r <= 20.0), r, np.inf)


def _centres(a, b):
    """The 0.05 m cells' centres from ``a`` to ``b`` along one axis."""
    return np.arange(a, b, 0.05) + 0.025


def _hits(g, x, y):
    """Hit (log-odds > 0) at the points ``x, y`` (arrays or scalars, broadcast together)."""
    x, y = np.broadcast_arrays(x, y)
    c = g.world_to_cell(np.stack([x.ravel(), y.ravel()], axis=1))
    return g.log_odds[c[:, 1], c[:, 0]] > 0


def test_a_wall_is_mapped_as_a_line_between_the_beams_ends():
    p = np.zeros(3)
    dots, lines = _grid(0.0), _grid(1.0)
    for g in (dots, lines):
        g.integrate_scan(p, _corridor(p), ANGLES)
    # 1-6 m ahead the beams' ends lie 0.02-0.55 m apart along the wall
    assert _hits(dots, _centres(1.0, 6.0), HALF_W).mean() < 0.45
    assert _hits(lines, _centres(1.0, 6.0), HALF_W).mean() == 1.0
    assert _hits(lines, _centres(1.0, 6.0), -HALF_W).mean() == 1.0
    # segments longer than surface_fill_m stay open: 12-20 m ahead the ends are > 1 m apart
    assert _hits(lines, _centres(12.0, 20.0), HALF_W).mean() < 0.2


def test_an_edge_is_not_bridged():
    # a box face 4 m ahead in front of a wall 6 m ahead, beams 2 degrees apart (ends 0.14-0.21 m
    # apart on each surface): the surfaces become lines, the range jumps between them stay open
    a = np.radians(np.arange(-30.0, 30.5, 2.0))
    r = 6.02 / np.cos(a)
    box = np.abs(4.02 * np.tan(a)) < 0.6
    r = np.where(box, 4.02 / np.cos(a), r)
    lines, dots = _grid(1.0), _grid(0.0)
    for g in (lines, dots):
        g.integrate_scan(np.zeros(3), r, a)
    face, wall = _centres(-0.3, 0.3), _centres(1.3, 3.2)
    assert _hits(lines, 4.02, face).all() and not _hits(dots, 4.02, face).all()
    assert _hits(lines, 6.02, wall).all() and not _hits(dots, 6.02, wall).all()
    # between the box's sides and the wall (x 4.1-5.9) no hit: the jumps are not bridged
    ys = np.linspace(0.45, 1.0, 12)[:, None]
    for side in (-1.0, 1.0):
        assert not _hits(lines, _centres(4.1, 5.9)[None, :], side * ys).any()


def test_the_next_scan_no_longer_sticks_to_the_last_ones_dots():
    # A corridor without any feature along it: nothing in the scans says how far the robot went,
    # so a match should not prefer one position along it. Mapped as dots, the scan taken 0.12 m
    # further on scores best where its points repeat the first scan's dots: at the first pose.
    corr = CorrelationConfig(search_x_m=0.0, search_y_m=0.0, search_yaw_rad=0.0, refine_iterations=0)
    moved = np.array([0.12, 0.0, 0.0])
    pts = scan_to_points(_corridor(moved), ANGLES, 1e-6, 20.0)
    offsets = np.arange(-0.2, 0.205, 0.01)
    cand = np.tile(moved, (offsets.size, 1))
    cand[:, 0] += offsets
    spread = {}
    for fill in (0.0, 1.0):
        g = _grid(fill)
        g.integrate_scan(np.zeros(3), _corridor(np.zeros(3)), ANGLES)
        field = build_likelihood_field_from_map(g.to_occupancy_map(), corr)
        _, scores = correlate(cand.copy(), pts, field, corr)
        spread[fill] = scores.max() - scores[np.argmin(np.abs(offsets))]
        if fill == 0.0:
            assert abs(offsets[int(np.argmax(scores))] + 0.12) < 0.015  # stuck at the first pose
    assert spread[1.0] < 0.3 * spread[0.0]  # 92 -> 24: the far ends, > 1 m apart, are still dots


def test_negative_fill_is_refused():
    with pytest.raises(ValueError, match="surface_fill_m"):
        dataclasses.replace(GridConfig(), surface_fill_m=-0.1)
