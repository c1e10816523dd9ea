"""Motion models (prediction step); the SE(2) pose algebra they use is :mod:`.geometry`.

Poses are float64 ``[x, y, theta]`` (m, m, rad), single ``(3,)`` or batched ``(N, 3)``.
Angles returned by these functions are wrapped to ``[-pi, pi)``.
"""

from __future__ import annotations

import math

import numpy as np

from .config import DiffDriveConfig, OdometryMotionConfig

# the SE(2) pose algebra lives in geometry.py; re-exported here, where the motion models use it
from .geometry import _wrap, compose, relative_pose, wrap_angle  # noqa: F401


def sample_odometry_motion(
    poses: np.ndarray,
    delta: np.ndarray,
    cfg: OdometryMotionConfig,
    rng: np.random.Generator,
    sigma_theta_rad: float | None = None,
) -> np.ndarray:
    """Propagate particles by a noisy odometry increment.

    Each particle gets its own perturbed increment (see :class:`OdometryMotionConfig`), composed
    onto it. With all noise parameters zero the result equals ``compose(poses, delta)`` exactly.

    Parameters
    ----------
    poses : numpy.ndarray
        ``(N, 3)`` particle poses.
    delta : numpy.ndarray
        ``(3,)`` odometry increment ``relative_pose(odom_prev, odom_now)``.
    cfg : OdometryMotionConfig
    rng : numpy.random.Generator
    sigma_theta_rad : float, optional
        Replaces ``sigma_theta_per_m * |t| + sigma_theta_min_rad`` (the heading's own uncertainty
        over the increment, e.g. a calibrated gyro's: ``cfg.gyro_noise_scale``); the turning term
        stays.

    Returns
    -------
    numpy.ndarray
        ``(N, 3)`` predicted poses.
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    delta = np.asarray(delta, dtype=np.float64).reshape(3)
    n = poses.shape[0]
    trans = float(np.hypot(delta[0], delta[1]))
    rot = abs(float(wrap_angle(delta[2])))
    s_xy = cfg.sigma_xy_per_m * trans + cfg.sigma_xy_per_rad * rot + cfg.sigma_xy_min_m
    if sigma_theta_rad is None:
        s_th = cfg.sigma_theta_per_m * trans + cfg.sigma_theta_per_rad * rot + cfg.sigma_theta_min_rad
    else:
        s_th = cfg.sigma_theta_per_rad * rot + float(sigma_theta_rad)
    noise = rng.standard_normal((n, 3)) * np.array([s_xy, s_xy, s_th])
    return compose(poses, delta[None, :] + noise)


def wheel_odometry(
    d_left_rad: np.ndarray | float,
    d_right_rad: np.ndarray | float,
    left_diameter_m: float,
    right_diameter_m: float,
    wheel_base_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Distance and yaw change of a differential-drive robot from wheel rotation increments.

    Parameters
    ----------
    d_left_rad, d_right_rad : array_like
        Wheel rotation increments per step (rad), same shape.
    left_diameter_m, right_diameter_m : float
        Wheel diameters (m).
    wheel_base_m : float
        Distance between the wheel contact points (m).

    Returns
    -------
    distance_m : numpy.ndarray
        Distance travelled by the axle midpoint per step (m).
    dyaw_rad : numpy.ndarray
        Yaw change per step (rad), positive = counter-clockwise.
    """
    if not wheel_base_m > 0:
        raise ValueError(f"wheel_base_m must be > 0, got {wheel_base_m!r}")
    dl = np.asarray(d_left_rad, dtype=np.float64) * (0.5 * left_diameter_m)
    dr = np.asarray(d_right_rad, dtype=np.float64) * (0.5 * right_diameter_m)
    return 0.5 * (dl + dr), (dr - dl) / wheel_base_m


def integrate_diff_drive(poses: np.ndarray, distance_m: np.ndarray, dyaw_rad: np.ndarray) -> np.ndarray:
    """Noise-free midpoint integration of one differential-drive step.

    ``x += d cos(theta + dyaw/2)``, ``y += d sin(theta + dyaw/2)``, ``theta += dyaw``
    (second-order / midpoint rule; equals the exact arc up to O(d * dyaw^2)).

    Parameters
    ----------
    poses : numpy.ndarray
        ``(N, 3)`` or ``(3,)``.
    distance_m, dyaw_rad : array_like
        Scalars or ``(N,)``.

    Returns
    -------
    numpy.ndarray
        Poses after the step, same shape as ``poses``.
    """
    poses = np.asarray(poses, dtype=np.float64)
    d = np.asarray(distance_m, dtype=np.float64)
    w = np.asarray(dyaw_rad, dtype=np.float64)
    if poses.shape == (3,) and d.ndim == w.ndim == 0:  # one step: scalar math (per encoder message)
        x, y, th = poses.tolist()
        d, w = float(d), float(w)
        heading = th + 0.5 * w
        return np.array([x + d * math.cos(heading), y + d * math.sin(heading), _wrap(th + w)])
    heading = poses[..., 2] + 0.5 * w
    x = poses[..., 0] + d * np.cos(heading)
    y = poses[..., 1] + d * np.sin(heading)
    th = wrap_angle(poses[..., 2] + w)
    return np.stack(np.broadcast_arrays(x, y, th), axis=-1)


def sample_diff_drive(
    poses: np.ndarray,
    distance_m: float,
    dyaw_rad: float,
    cfg: DiffDriveConfig,
    rng: np.random.Generator,
) -> np.ndarray:
    """Propagate particles by one noisy differential-drive step (midpoint integration).

    ``dyaw_rad`` may come from the wheels (:func:`wheel_odometry`) or from a gyro. Noise is
    described in :class:`DiffDriveConfig`; with zero noise the result equals
    :func:`integrate_diff_drive` (midpoint rule) exactly.

    Parameters
    ----------
    poses : numpy.ndarray
        ``(N, 3)`` particle poses.
    distance_m : float
        Distance travelled this step (m).
    dyaw_rad : float
        Yaw change this step (rad).
    cfg : DiffDriveConfig
    rng : numpy.random.Generator

    Returns
    -------
    numpy.ndarray
        ``(N, 3)`` predicted poses.
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    n = poses.shape[0]
    d = float(distance_m)
    w = float(dyaw_rad)
    s_d = cfg.sigma_v * abs(d) + cfg.sigma_v_min_m
    s_w = cfg.sigma_omega * abs(w) + cfg.sigma_omega_per_m * abs(d) + cfg.sigma_omega_min_rad
    noise = rng.standard_normal((n, 2))
    return integrate_diff_drive(poses, d + s_d * noise[:, 0], w + s_w * noise[:, 1])
