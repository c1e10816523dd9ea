"""correlation.recover_search_m: a set that slid off the map beyond the window's reach is shifted
back once consecutive wide searches agree, and never on one correction alone."""

import math

import numpy as np
import pytest
from test_core_correlation_slam import RES, raycast, world  # noqa: E402

from pf_slam_nodes.core.config import CorrelationConfig
from pf_slam_nodes.core.correlation import build_likelihood_field, correlate
from pf_slam_nodes.core.motion import compose, relative_pose
from pf_slam_nodes.core.recovery import Recovery
from pf_slam_nodes.core.scan import beam_angles, scan_to_points

TRUE = np.array([6.1, 5.2, 0.4])


def _setup(offset):
    occ = world()
    ang = beam_angles(-math.pi / 2, math.pi / 180, 181)
    pts = scan_to_points(raycast(occ, TRUE, ang), ang, 0.1, 19.0)
    # a window of +-0.1 m without the refinement: offsets of 0.5 m are out of the local match's reach
    cfg = CorrelationConfig(
        search_x_m=0.1, search_y_m=0.1, search_yaw_rad=0.1, refine_iterations=0, recover_search_m=0.7
    )
    field = build_likelihood_field(occ, RES, cfg.sigma_m, cfg.occupied_threshold, (0.0, 0.0), cfg.max_distance_m)
    rng = np.random.default_rng(0)
    start = compose(TRUE, np.array(offset))
    predicted = np.vstack([start, start + rng.normal(0, [0.02, 0.02, 0.005], (9, 3))])
    return predicted, pts, field, cfg


def _err(poses, scores):
    e = relative_pose(TRUE, poses[int(np.argmax(scores))])
    return math.hypot(e[0], e[1]), abs(e[2])


def test_agreeing_wide_searches_bring_the_set_back():
    predicted, pts, field, cfg = _setup((0.5, -0.3, 0.03))
    local, scores = correlate(predicted, pts, field, cfg)
    assert _err(local, scores)[0] > 0.3  # beyond the window: the local match cannot fix it
    rec = Recovery()
    for n in range(cfg.recover_corrections - 1):
        out, s = rec.correct(n, predicted, local, scores, pts, field, cfg)
        assert out is local and rec.fired == 0  # one correction (or two) never moves the set
    out, s = rec.correct(cfg.recover_corrections - 1, predicted, local, scores, pts, field, cfg)
    d, a = _err(out, s)
    assert rec.fired == 1 and d < 0.05 and a < 0.03  # the window's steps (no refinement here)
    assert s.max() > scores.max() and rec.last["correction"] == cfg.recover_corrections - 1


def test_corrections_that_are_not_consecutive_or_disagree_move_nothing():
    rec = Recovery()
    predicted, pts, field, cfg = _setup((0.5, -0.3, 0.03))
    local, scores = correlate(predicted, pts, field, cfg)
    for n in (0, 2, 4, 6):  # every other correction finds the shift: never three in a row
        assert rec.correct(n, predicted, local, scores, pts, field, cfg)[0] is local
    other = _setup((-0.5, 0.35, -0.03))[0]
    local2, scores2 = correlate(other, pts, field, cfg)
    for n in range(10, 16):  # consecutive, but the shifts alternate between two directions
        p, loc, sc = (predicted, local, scores) if n % 2 else (other, local2, scores2)
        assert rec.correct(n, p, loc, sc, pts, field, cfg)[0] is loc
    assert rec.fired == 0


def test_a_set_on_the_map_is_left_alone():
    predicted, pts, field, cfg = _setup((0.05, 0.03, 0.01))
    local, scores = correlate(predicted, pts, field, cfg)
    rec = Recovery()
    for n in range(6):
        assert rec.correct(n, predicted, local, scores, pts, field, cfg)[0] is local
    assert rec.fired == 0


def test_a_poor_fit_where_the_wide_window_agrees_is_not_refined(monkeypatch):
    """A scan that fits badly where the set is right (clutter the map does not hold): the wide
    window's best cell is the best particle itself, so its refinement, which could only find the
    local match again, is skipped, and nothing moves."""
    import pf_slam_nodes.core.recovery as recovery

    predicted, pts, field, cfg = _setup((0.0, 0.0, 0.0))
    rng = np.random.default_rng(1)
    clutter = np.column_stack([rng.uniform(0.5, 3.0, 60), rng.uniform(-3.0, 3.0, 60)])
    pts = np.vstack([pts, clutter])
    local, scores = correlate(predicted, pts, field, cfg)
    assert scores.max() < -cfg.recover_min_gain and _err(local, scores)[0] < 0.05
    calls = []
    monkeypatch.setattr(recovery, "correlate", lambda *a: calls.append(1) or correlate(*a))
    rec = Recovery()
    for n in range(4):
        assert rec.correct(n, predicted, local, scores, pts, field, cfg)[0] is local
    assert calls == [] and rec.fired == 0


@pytest.mark.parametrize("bad", [{"recover_search_m": -0.1}, {"recover_corrections": 0}, {"recover_min_gain": 0.0}])
def test_recover_parameters_are_checked(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        CorrelationConfig(**bad)
