"""Laser scan geometry: beam angles, endpoints, frame transforms."""

from __future__ import annotations

import numpy as np


def beam_angles(angle_min: float, angle_increment: float, n: int) -> np.ndarray:
    """Angles of ``n`` beams, ``angle_min + i * angle_increment`` (sensor_msgs/LaserScan).

    Parameters
    ----------
    angle_min : float
        Angle of the first beam (rad).
    angle_increment : float
        Angle between consecutive beams (rad).
    n : int
        Number of beams.

    Returns
    -------
    numpy.ndarray
        ``(n,)`` float64 angles (rad).
    """
    return float(angle_min) + float(angle_increment) * np.arange(int(n), dtype=np.float64)


def valid_beams(ranges: np.ndarray, range_min: float, range_max: float) -> np.ndarray:
    """Mask of finite beams with ``range_min <= r <= range_max``.

    Parameters
    ----------
    ranges : numpy.ndarray
        ``(B,)`` ranges (m); inf/NaN allowed.

    Returns
    -------
    numpy.ndarray
        ``(B,)`` bool.
    """
    r = np.asarray(ranges, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.isfinite(r) & (r >= range_min) & (r <= range_max)


def scan_to_points(
    ranges: np.ndarray,
    angles: np.ndarray,
    range_min: float,
    range_max: float,
    stride: int = 1,
) -> np.ndarray:
    """Beam endpoints in the sensor frame for valid beams.

    Parameters
    ----------
    ranges : numpy.ndarray
        ``(B,)`` ranges (m). inf, NaN, ``< range_min`` and ``> range_max`` are dropped.
    angles : numpy.ndarray
        ``(B,)`` beam angles (rad).
    range_min, range_max : float
        Valid range interval (m), inclusive.
    stride : int
        Keep every ``stride``-th beam (applied before the validity filter).

    Returns
    -------
    numpy.ndarray
        ``(M, 2)`` float64 endpoints ``[x, y]`` (m), M <= ceil(B / stride).
    """
    r = np.asarray(ranges, dtype=np.float64)[::stride]
    a = np.asarray(angles, dtype=np.float64)[::stride]
    if r.shape != a.shape:
        raise ValueError(f"ranges and angles must have the same length, got {r.shape} and {a.shape}")
    m = valid_beams(r, range_min, range_max)
    r = r[m]
    a = a[m]
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=-1)


def transform_points(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Map points from the frame of ``pose`` into the parent frame.

    Parameters
    ----------
    points : numpy.ndarray
        ``(M, 2)`` points in the local frame.
    pose : numpy.ndarray
        ``(3,)`` pose of the local frame in the parent frame.

    Returns
    -------
    numpy.ndarray
        ``(M, 2)`` float64 points in the parent frame.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    x, y, th = (float(v) for v in np.asarray(pose, dtype=np.float64).reshape(3))
    c, s = np.cos(th), np.sin(th)
    out = np.empty_like(p)
    out[:, 0] = x + c * p[:, 0] - s * p[:, 1]
    out[:, 1] = y + s * p[:, 0] + c * p[:, 1]
    return out


def transform_points_batch(points: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Map one point set through many poses.

    Parameters
    ----------
    points : numpy.ndarray
        ``(M, 2)`` points in the local frame.
    poses : numpy.ndarray
        ``(N, 3)`` poses.

    Returns
    -------
    numpy.ndarray
        ``(N, M, 2)`` float64 points in the parent frame.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    q = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    c = np.cos(q[:, 2])[:, None]
    s = np.sin(q[:, 2])[:, None]
    out = np.empty((q.shape[0], p.shape[0], 2))
    out[..., 0] = q[:, 0:1] + c * p[None, :, 0] - s * p[None, :, 1]
    out[..., 1] = q[:, 1:2] + s * p[None, :, 0] + c * p[None, :, 1]
    return out
