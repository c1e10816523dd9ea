"""Weights, N_eff and resampling."""

import numpy as np
import pytest

from pf_slam_nodes.core.filter import (
    n_eff,
    normalize_log_weights,
    stratified_resample,
    systematic_resample,
    update_log_weights,
)


def _lse(x):
    m = x.max()
    return m + np.log(np.exp(x - m).sum())


@pytest.mark.parametrize(
    "lw",
    [
        np.array([1e308, -1e308, 0.0]),
        np.array([-1e6, -1e6 - 1, -2e6]),
        np.array([0.0, -np.inf, -np.inf]),
        np.array([5.0]),
    ],
)
def test_normalize_finite_and_normalised(lw):
    out = normalize_log_weights(lw)
    assert abs(_lse(out)) < 1e-9
    assert np.all(np.isfinite(out) | (out == -np.inf))


def test_normalize_all_minus_inf_is_uniform():
    np.testing.assert_allclose(normalize_log_weights(np.full(4, -np.inf)), np.log(0.25))


def test_update_with_extreme_scores():
    lw = np.log(np.full(5, 0.2))
    out = update_log_weights(lw, np.array([-1e9, 0.0, -3e8, 1e9, -np.inf]), temperature=2.0)
    assert abs(_lse(out)) < 1e-9
    assert np.argmax(out) == 3
    out2 = update_log_weights(lw, np.array([-1.0, -2.0, -3.0, -4.0, -5.0]), temperature=1.0)
    np.testing.assert_allclose(np.exp(out2), np.exp(-np.arange(1, 6)) / np.exp(-np.arange(1, 6)).sum())


def test_n_eff_bounds():
    assert n_eff(np.zeros(10)) == pytest.approx(10.0)
    assert n_eff(np.array([0.0] + [-1e9] * 9)) == pytest.approx(1.0)
    v = n_eff(np.random.default_rng(0).normal(size=100))
    assert 1.0 <= v <= 100.0


@pytest.mark.parametrize("fn", [stratified_resample, systematic_resample])
def test_resampling_keeps_n_and_favours_heavy(fn):
    rng = np.random.default_rng(42)
    n = 100
    lw = np.full(n, -50.0)
    lw[7] = 0.0
    idx = fn(lw, rng)
    assert idx.shape == (n,) and idx.dtype == np.int64
    assert np.all((idx >= 0) & (idx < n))
    assert np.sum(idx == 7) >= 99
    # proportionality: weights 1:3 over many draws
    counts = np.zeros(2)
    for _ in range(200):
        counts += np.bincount(fn(np.log(np.array([0.25, 0.75])), rng), minlength=2)
    assert abs(counts[1] / counts.sum() - 0.75) < 0.03


@pytest.mark.parametrize("fn", [stratified_resample, systematic_resample])
def test_resampling_never_out_of_range(fn):
    rng = np.random.default_rng(5)
    for _ in range(200):
        lw = rng.normal(scale=30, size=17)
        lw[-1] = -np.inf
        idx = fn(lw, rng)
        assert idx.min() >= 0 and idx.max() < 16
