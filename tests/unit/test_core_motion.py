"""Motion models and pose algebra."""

import math

import numpy as np

from pf_slam_nodes.core.config import DiffDriveConfig, OdometryMotionConfig
from pf_slam_nodes.core.motion import (
    compose,
    integrate_diff_drive,
    relative_pose,
    sample_diff_drive,
    sample_odometry_motion,
    wheel_odometry,
)

ZERO_ODOM = OdometryMotionConfig(**{k: 0.0 for k in OdometryMotionConfig().to_dict()})
ZERO_DD = DiffDriveConfig(**{k: 0.0 for k in DiffDriveConfig().to_dict()})


def test_compose_hand_values():
    out = compose(np.array([1.0, 2.0, math.pi / 2]), np.array([1.0, 0.5, math.pi / 2]))
    np.testing.assert_allclose(out, [0.5, 3.0, -math.pi], atol=1e-12)


def test_relative_pose_inverts_compose_batched():
    rng = np.random.default_rng(0)
    a = rng.uniform(-5, 5, (20, 3))
    d = rng.uniform(-1, 1, (20, 3))
    b = compose(a, d)
    np.testing.assert_allclose(relative_pose(a, b), d, atol=1e-12)
    assert relative_pose(a[0], b[0]).shape == (3,)


def test_zero_noise_odometry_equals_compose_exactly():
    rng = np.random.default_rng(1)
    poses = rng.uniform(-3, 3, (50, 3))
    delta = np.array([0.3, -0.1, 0.2])
    out = sample_odometry_motion(poses, delta, ZERO_ODOM, rng)
    assert np.array_equal(out, compose(poses, delta))
    np.testing.assert_allclose(sample_odometry_motion(np.zeros((1, 3)), delta, ZERO_ODOM, rng)[0], delta)


def test_odometry_noise_statistics():
    rng = np.random.default_rng(2)
    cfg = OdometryMotionConfig(
        sigma_xy_per_m=0.1,
        sigma_xy_per_rad=0.0,
        sigma_theta_per_m=0.0,
        sigma_theta_per_rad=0.0,
        sigma_xy_min_m=0.0,
        sigma_theta_min_rad=0.01,
    )
    out = sample_odometry_motion(np.zeros((20000, 3)), np.array([1.0, 0.0, 0.0]), cfg, rng)
    np.testing.assert_allclose(out.mean(axis=0), [1.0, 0.0, 0.0], atol=0.005)
    np.testing.assert_allclose(out.std(axis=0), [0.1, 0.1, 0.01], rtol=0.05)


def test_wheel_odometry_hand_values():
    d, w = wheel_odometry(np.array([2.0, 1.0]), np.array([2.0, 3.0]), 0.5, 0.5, 1.0)
    np.testing.assert_allclose(d, [0.5, 0.5])
    np.testing.assert_allclose(w, [0.0, 0.5])


def test_zero_noise_diff_drive_is_midpoint_rule():
    rng = np.random.default_rng(3)
    poses = np.array([[1.0, 1.0, 0.0], [0.0, 0.0, math.pi / 2]])
    out = sample_diff_drive(poses, 1.0, 0.5, ZERO_DD, rng)
    np.testing.assert_array_equal(out, integrate_diff_drive(poses, 1.0, 0.5))
    np.testing.assert_allclose(out[0], [1.0 + math.cos(0.25), 1.0 + math.sin(0.25), 0.5], atol=1e-12)
    np.testing.assert_allclose(out[1], [-math.sin(0.25), math.cos(0.25), math.pi / 2 + 0.5], atol=1e-12)


def test_diff_drive_noise_spreads():
    out = sample_diff_drive(np.zeros((5000, 3)), 1.0, 0.0, DiffDriveConfig(), np.random.default_rng(4))
    assert 0.02 < out[:, 0].std() < 0.08
