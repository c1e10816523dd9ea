"""Property-based tests (hypothesis) of the core's invariants, for any input the filter may meet.

Weights stay normalised and finite whatever the correlation scores (``-inf``, ``+inf``, NaN,
1e308); resampling only returns indices in ``[0, N)``; the grid's log-odds never leave
``[clip_min, clip_max]``; ray tracing never writes outside the grid.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from pf_slam_nodes.core.config import GridConfig
from pf_slam_nodes.core.filter import (
    n_eff,
    normalize_log_weights,
    stratified_resample,
    systematic_resample,
    update_log_weights,
)
from pf_slam_nodes.core.grid import LogOddsGrid

# derandomize: the same examples on every run (the project's tests are deterministic)
PROPS = settings(
    max_examples=300, deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.too_slow]
)

any_float = st.floats(allow_nan=True, allow_infinity=True, width=64)
scores = hnp.arrays(np.float64, st.integers(1, 64), elements=any_float)


def _check_normalised(lw: np.ndarray, n: int) -> None:
    assert lw.shape == (n,) and lw.dtype == np.float64
    assert not np.isnan(lw).any() and not np.isposinf(lw).any()
    w = np.exp(lw)
    assert np.isfinite(w).all() and (w >= 0).all()
    assert math.isclose(w.sum(), 1.0, rel_tol=1e-9)


@PROPS
@given(scores)
def test_normalize_any_scores(lw):
    _check_normalised(normalize_log_weights(lw), lw.size)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # 1e308 / 1e-300 = inf, inf - inf = NaN: handled
@PROPS
@given(
    st.integers(1, 64).flatmap(
        lambda n: st.tuples(
            hnp.arrays(np.float64, n, elements=any_float),
            hnp.arrays(np.float64, n, elements=any_float),
            st.floats(1e-300, 1e300),
        )
    )
)
def test_update_any_prior_scores_temperature(args):
    lw, ls, temp = args
    out = update_log_weights(lw, ls, temperature=temp)
    _check_normalised(out, lw.size)
    assert 1.0 <= n_eff(out) <= lw.size


class _Draws:
    """An rng whose uniform draws hypothesis picks (0 and the largest float below 1 included)."""

    def __init__(self, u: list[float]) -> None:
        self.u = np.array(u)

    def random(self, size=None):
        return self.u[0] if size is None else np.resize(self.u, size)


rngs = st.one_of(
    st.integers(0, 2**32 - 1).map(np.random.default_rng),
    st.lists(
        st.sampled_from([0.0, 0.5, float(np.nextafter(1.0, 0.0))]) | st.floats(0.0, 1.0, exclude_max=True), min_size=1
    ).map(_Draws),
)


@PROPS
@given(scores, rngs, st.sampled_from([stratified_resample, systematic_resample]))
# found by this test: u = (1 + r) / 2 rounded to 1.0 drew the zero-weight last particle
@example(np.array([746.0, 0.0]), _Draws([float(np.nextafter(1.0, 0.0))]), stratified_resample)
def test_resample_indices_in_range(lw, rng, method):
    idx = method(lw, rng)
    assert idx.shape == (lw.size,) and idx.dtype == np.int64
    assert idx.min() >= 0 and idx.max() < lw.size
    # only particles with weight can be drawn (all may be drawn when none has any)
    w = np.exp(normalize_log_weights(lw))
    assert (w[idx] > 0).all()


finite = st.floats(-1e6, 1e6, allow_nan=False)
coord = st.one_of(finite, st.sampled_from([1e300, -1e300, 1e18, -1e18, math.nan, math.inf]))
ranges = st.one_of(st.floats(-10.0, 1e6), st.sampled_from([math.inf, -math.inf, math.nan, 0.0, 1e300]))


@st.composite
def scans(draw):
    b = draw(st.integers(1, 40))
    r = np.array(draw(st.lists(ranges, min_size=b, max_size=b)), dtype=np.float64)
    a = np.array(draw(st.lists(st.floats(-10.0, 10.0), min_size=b, max_size=b)), dtype=np.float64)
    pose = np.array([draw(coord), draw(coord), draw(st.floats(-100.0, 100.0))])
    return pose, r, a


def _grid(res, hit, miss, clip, usable):
    cfg = GridConfig(
        resolution_m=res,
        size_x_m=4.0,
        size_y_m=3.0,
        origin_x_m=-2.0,
        origin_y_m=-1.0,
        log_odds_hit=hit,
        log_odds_miss=-miss,
        clip_min=-clip,
        clip_max=clip,
        range_max_usable_m=usable,
    )
    return LogOddsGrid(cfg)


grids = st.builds(
    _grid,
    st.sampled_from([0.05, 0.1, 0.37]),
    st.floats(0.01, 3.0),
    st.floats(0.01, 3.0),
    st.floats(0.5, 10.0),
    st.floats(0.1, 30.0),
)


@PROPS
@given(grids, st.lists(scans(), min_size=1, max_size=6))
def test_grid_stays_in_clip_bounds_and_inside(g, scan_list):
    for pose, r, a in scan_list:
        h, w = g.log_odds.shape
        free, hit = g.trace_scan(pose, r, a)
        for idx in (free, hit):
            assert idx.dtype == np.int64
            assert ((idx >= 0) & (idx < h * w)).all()
        before, off = g.log_odds.copy(), g.offset.copy()
        g.integrate_scan(pose, r, a)
        lo = g.log_odds
        h, w = lo.shape  # the grid may have grown by whole tiles: the old cells kept their place
        dc, dr = g.offset - off
        assert (h - before.shape[0]) % 256 == 0 and (w - before.shape[1]) % 256 == 0
        kept = lo.copy()
        kept.reshape(-1)[g.last_touched_idx] = np.nan  # cells this scan wrote
        old = kept[dr : dr + before.shape[0], dc : dc + before.shape[1]]
        same = np.isnan(old) | (old == before)
        assert same.all()  # every other old cell is where and what it was
        assert np.count_nonzero(np.nan_to_num(kept, nan=0.0)) == np.count_nonzero(np.nan_to_num(old, nan=0.0))
        assert np.isfinite(lo).all()
        assert lo.min() >= np.float32(g.cfg.clip_min) and lo.max() <= np.float32(g.cfg.clip_max)
        if g.last_touched_bounds is not None:
            r0, r1, c0, c1 = g.last_touched_bounds
            assert 0 <= r0 < r1 <= h and 0 <= c0 < c1 <= w
    # the cells written are exactly those the traces named (nothing else changed)
    written = np.flatnonzero(g.log_odds.reshape(-1))
    if written.size:
        tb = g.touched_bounds
        rows, cols = written // w, written % w
        assert tb[0] <= rows.min() and rows.max() < tb[1] and tb[2] <= cols.min() and cols.max() < tb[3]


@PROPS
@given(grids, scans())
def test_scan_in_the_grid_writes_only_traced_cells(g, scan):
    g = LogOddsGrid(dataclasses.replace(g.cfg, max_cells=0))  # fixed: trace_scan names the cells
    pose, r, a = scan
    pose[:2] = np.clip(pose[:2], [-2.0, -1.0], [1.99, 1.99])  # sensor inside the grid
    free, hit = g.trace_scan(pose, r, a)
    g.integrate_scan(pose, r, a)
    changed = set(np.flatnonzero(g.log_odds.reshape(-1)).tolist())
    assert changed <= set(free.tolist()) | set(hit.tolist())
