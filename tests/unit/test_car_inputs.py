"""The car's inputs in the core: gyro increments summed per encoder step; the tilted lidar."""

import math

import numpy as np
import pytest

from pf_slam_nodes.core.config import LaserConfig
from pf_slam_nodes.core.odometry import GyroBuffer
from pf_slam_nodes.core.scan import planar_scan

# the real Vehicle2Lidar.txt of the KAIST car (R row-major, T)
KAIST_LIDAR = (
    0.00130201,
    0.796097,
    0.605167,
    0.999999,
    -0.000419027,
    -0.00160026,
    -0.00102038,
    0.605169,
    -0.796097,
    0.8349,
    -0.0126869,
    1.76416,
)


def test_gyro_sums_increments_in_half_open_intervals():
    g = GyroBuffer()
    g.add(np.arange(1, 11) * 1_000_000, np.full(10, 0.01))  # 1..10 ms
    assert g.yaw_between(0, 10_000_000) == pytest.approx(0.10)
    assert g.yaw_between(3_000_000, 5_000_000) == pytest.approx(0.02)  # samples at 4 and 5 ms
    g.add([5_000_000, 11_000_000], [1.0, 0.5])  # a stamp going back is dropped and counted
    assert g.out_of_order == 1 and g.last_stamp == 11_000_000
    assert g.yaw_between(10_000_000, 11_000_000) == pytest.approx(0.5)


def test_gyro_sums_do_not_depend_on_the_batching():
    """The same 1 kHz samples in messages of 1, 10, 37 or 1000 give the same encoder-step yaw,
    bit for bit (`--fog-batch` must not change the trajectory of a chaotic filter), also after
    trimming."""
    rng = np.random.default_rng(4)
    stamps = np.cumsum(rng.integers(900_000, 1_100_000, 5000))
    dyaw = rng.normal(0.0, 1e-4, 5000) + 3e-7
    steps = np.arange(stamps[0], stamps[-1], 10_000_000)  # 100 Hz encoder steps
    results = []
    for batch in (1, 10, 37, 1000):
        g, got = GyroBuffer(), []
        for i in range(0, len(stamps), batch):
            g.add(stamps[i : i + batch], dyaw[i : i + batch])
            while len(got) + 1 < len(steps) and steps[len(got) + 1] <= g.last_stamp:
                t0, t1 = steps[len(got)], steps[len(got) + 1]
                got.append(g.yaw_between(t0, t1))
                g.trim(t0)
        results.append(got)
    assert len(results[0]) == len(steps) - 1
    for other in results[1:]:
        assert other == results[0]


def test_planar_laser_is_unchanged_but_gated():
    r = np.array([0.5, 3.0, np.inf, 90.0])
    a = np.linspace(-1, 1, 4)
    r2, a2, off = planar_scan(r, a, LaserConfig(min_range_m=1.0, max_range_m=80.0), np.array([0.1, 0, 0]))
    assert np.isnan(r2[0]) and r2[1] == 3.0 and np.isinf(r2[2]) and np.isinf(r2[3])
    np.testing.assert_array_equal(a2, a)
    np.testing.assert_array_equal(off, [0.1, 0, 0])


def test_tilted_lidar_projection_and_ground_gate():
    cfg = LaserConfig(extrinsic=KAIST_LIDAR, min_range_m=2.0, max_range_m=75.0, min_height_m=0.5)
    rot = np.array(KAIST_LIDAR[:9]).reshape(3, 3)
    t = np.array(KAIST_LIDAR[9:])
    a = np.deg2rad(np.array([0.0, 90.0, 180.0, -5.0]))
    r = np.array([10.0, 10.0, 1.0, 10.0])
    r2, a2, off = planar_scan(r, a, cfg, np.zeros(3))
    np.testing.assert_allclose(off, [t[0], t[1], 0.0])
    # beam at 90 deg: points forward and up (z = 1.76 + 0.605 * 10 m): kept, 7.96 m ahead
    p = rot @ [0.0, 10.0, 0.0] + t
    assert p[2] > 7 and r2[1] == pytest.approx(math.hypot(p[0] - t[0], p[1] - t[1]))
    assert a2[1] == pytest.approx(math.atan2(p[1] - t[1], p[0] - t[0]))
    assert np.isnan(r2[2])  # 1 m: closer than 2 m
    q = rot @ [10 * math.cos(a[3]), 10 * math.sin(a[3]), 0] + t  # -5 deg: slightly downward
    assert (np.isnan(r2[3])) == (q[2] < 0.5)


def test_laser_config_validates():
    with pytest.raises(ValueError, match="extrinsic"):
        LaserConfig(extrinsic=(1.0,) * 11)
    with pytest.raises(ValueError, match="orthonormal"):
        LaserConfig(extrinsic=(2.0, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0))
