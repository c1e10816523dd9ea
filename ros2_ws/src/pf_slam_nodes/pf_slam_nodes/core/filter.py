"""Particle weights (log domain), effective sample size, resampling."""

from __future__ import annotations

import numpy as np


def normalize_log_weights(log_w: np.ndarray) -> np.ndarray:
    """Normalise log-weights so that ``logsumexp(log_w) == 0``.

    Parameters
    ----------
    log_w : numpy.ndarray
        ``(N,)`` log-weights; ``-inf`` allowed, NaN and ``+inf`` are treated as ``-inf`` and the
        maximum finite weight respectively.

    Returns
    -------
    numpy.ndarray
        ``(N,)`` float64 normalised log-weights (finite for finite input; uniform ``-log N`` when
        every entry is ``-inf``).
    """
    lw = np.asarray(log_w, dtype=np.float64).reshape(-1)
    n = lw.size
    if n == 0:
        raise ValueError("log_w must not be empty")
    lw = np.where(np.isnan(lw), -np.inf, lw)
    if np.isposinf(lw).any():
        lw = np.where(np.isposinf(lw), 0.0, -np.inf)
    m = lw.max()
    if not np.isfinite(m):
        return np.full(n, -np.log(n))
    with np.errstate(over="ignore"):
        shifted = lw - m  # may overflow to -inf for |lw| ~ 1e308: weight 0, as intended
    return shifted - np.log(np.exp(shifted).sum())


def update_log_weights(log_w: np.ndarray, log_scores: np.ndarray, temperature: float = 1.0) -> np.ndarray:
    """Bayes update in the log domain: ``normalize(log_w + log_scores / temperature)``.

    Parameters
    ----------
    log_w : numpy.ndarray
        ``(N,)`` prior log-weights.
    log_scores : numpy.ndarray
        ``(N,)`` measurement log-likelihoods (any finite scale).
    temperature : float
        Softmax temperature (> 0); larger flattens the weights.

    Returns
    -------
    numpy.ndarray
        ``(N,)`` normalised log-weights.
    """
    if not temperature > 0:
        raise ValueError(f"temperature must be > 0, got {temperature!r}")
    lw = np.asarray(log_w, dtype=np.float64).reshape(-1)
    ls = np.asarray(log_scores, dtype=np.float64).reshape(-1)
    if lw.shape != ls.shape:
        raise ValueError(f"log_w and log_scores must have the same shape, got {lw.shape} and {ls.shape}")
    return normalize_log_weights(lw + ls / temperature)


def n_eff(log_w: np.ndarray) -> float:
    """Effective sample size ``1 / sum(w^2)`` of (possibly unnormalised) log-weights, in ``[1, N]``."""
    w = np.exp(normalize_log_weights(log_w))
    w /= w.sum()
    n = w.size
    return float(min(max(1.0 / np.dot(w, w), 1.0), float(n)))


def _resample_from_u(log_w: np.ndarray, u: np.ndarray) -> np.ndarray:
    w = np.exp(normalize_log_weights(log_w))
    c = np.cumsum(w)
    c /= c[-1]
    # (i + r) / N rounds to 1.0 for r just below 1: keep u < 1 so a zero-weight tail is never drawn
    idx = np.searchsorted(c, np.minimum(u, np.nextafter(1.0, 0.0)), side="right")
    return np.minimum(idx, w.size - 1).astype(np.int64)


def stratified_resample(log_w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Stratified resampling: one uniform draw in each stratum ``[i/N, (i+1)/N)``.

    Parameters
    ----------
    log_w : numpy.ndarray
        ``(N,)`` log-weights.
    rng : numpy.random.Generator

    Returns
    -------
    numpy.ndarray
        ``(N,)`` int64 ancestor indices in ``[0, N)``.
    """
    n = np.asarray(log_w).size
    u = (np.arange(n) + rng.random(n)) / n
    return _resample_from_u(log_w, u)


def systematic_resample(log_w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: one uniform offset shared by all strata.

    Parameters
    ----------
    log_w : numpy.ndarray
        ``(N,)`` log-weights.
    rng : numpy.random.Generator

    Returns
    -------
    numpy.ndarray
        ``(N,)`` int64 ancestor indices in ``[0, N)``.
    """
    n = np.asarray(log_w).size
    u = (np.arange(n) + rng.random()) / n
    return _resample_from_u(log_w, u)


def resample(log_w: np.ndarray, method: str, rng: np.random.Generator) -> np.ndarray:
    """Dispatch to :func:`stratified_resample` or :func:`systematic_resample` by name."""
    if method == "stratified":
        return stratified_resample(log_w, rng)
    if method == "systematic":
        return systematic_resample(log_w, rng)
    raise ValueError(f"method must be 'stratified' or 'systematic', got {method!r}")
