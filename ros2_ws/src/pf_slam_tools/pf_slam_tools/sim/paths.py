"""Paths made of straight and circular pieces, shared by the simulators."""

from __future__ import annotations

import numpy as np


def pose_on_path(pieces: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Poses ``(N, 3)`` (theta unwrapped) at arc lengths ``s`` along an open piece path."""
    s = np.atleast_1d(np.asarray(s, dtype=np.float64))
    s0 = np.concatenate([[0.0], np.cumsum(pieces[:, 4])[:-1]])
    i = np.clip(np.searchsorted(s0, s, side="right") - 1, 0, len(pieces) - 1)
    x0, y0, th0, kappa = (pieces[i, j] for j in range(4))
    ds = s - s0[i]
    th = th0 + kappa * ds
    straight = kappa == 0.0
    k = np.where(straight, 1.0, kappa)
    x = np.where(straight, x0 + ds * np.cos(th0), x0 + (np.sin(th) - np.sin(th0)) / k)
    y = np.where(straight, y0 + ds * np.sin(th0), y0 - (np.cos(th) - np.cos(th0)) / k)
    return np.stack([x, y, th], axis=1)


# --------------------------------------------------------------------------------------------
# world
