"""Issue 17.2/17.3 in the core and the bag inspection: the scan's own range limits gate its
ranges (REP 117), bad limits are a counted fault, and every lidar mount in /tf_static (yaw,
offsets, roll/pitch, chains) becomes the parameters that put each return where it is."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pf_slam_nodes.core.config import FilterConfig, GridConfig, LaserConfig
from pf_slam_nodes.core.faults import SCAN_BAD_LIMITS, ScanChecks
from pf_slam_nodes.core.geometry import rpy_to_quat
from pf_slam_nodes.core.grid import LogOddsGrid
from pf_slam_nodes.core.scan import gate_ranges, planar_scan, scan_to_points, transform_points
from pf_slam_nodes.core.stages import MappingStage
from pf_slam_nodes.graph import LidarMount, lidar_mount
from pf_slam_nodes.io.bag import bag_info, laser_scan, open_writer, tf_static
from pf_slam_tools.sim.indoor import beam_angles, distance_to_segments, mount_pose, office_world, ray_cast

PI = math.pi
INC = math.radians(1.0)


# ------------------------------------------------------------------------- 17.3: range limits
def test_gate_ranges_rep117():
    r = np.array([1.0, 15.0, np.inf, np.nan, -np.inf, 0.05, 12.0, 0.1], dtype=np.float32)
    g = gate_ranges(r, 0.1, 12.0)
    assert g[0] == 1.0 and g[6] == 12.0 and g[2] == np.inf  # in range; +inf: no return
    assert np.isnan(g[[1, 3, 4, 5]]).all()  # beyond range_max, NaN, -inf, below range_min: ignored
    assert g[7] == np.float32(0.1)
    assert np.array_equal(gate_ranges(r, 0.1, np.inf)[[0, 1, 2]], [1.0, 15.0, np.inf])  # +inf range_max: no limit
    for lo, hi in ((0.0, 0.0), (0.1, -1.0), (5.0, 2.0), (0.0, np.nan), (np.nan, 10.0), (np.inf, np.inf), (-1.0, 5.0)):
        assert np.isnan(gate_ranges(r, lo, hi)).all(), (lo, hi)


def test_grid_beyond_range_max_is_neither_hit_nor_free_but_inf_is_free():
    """main: a finite return beyond the scan's range_max was traced as free space."""
    g = LogOddsGrid(
        GridConfig(resolution_m=0.1, size_x_m=60.0, size_y_m=60.0, range_max_usable_m=20.0), center_xy=np.zeros(2)
    )
    free, hit = g.trace_scan(np.zeros(3), np.array([15.0]), np.zeros(1), None, 0.1, 12.0)
    assert free.size == 0 and hit.size == 0
    free, hit = g.trace_scan(np.zeros(3), np.array([np.inf]), np.zeros(1), None, 0.1, 12.0)
    assert hit.size == 0 and 119 <= free.size <= 122  # free up to the sensor's range_max (12 m), not 20 m
    free, hit = g.trace_scan(np.zeros(3), np.array([11.0]), np.zeros(1), None, 0.1, 12.0)
    assert hit.size == 1 and free.size >= 109


def test_stages_ignore_returns_beyond_the_scans_range_max():
    m = MappingStage(FilterConfig(), GridConfig(size_x_m=60.0, size_y_m=60.0))
    patch = m.integrate(np.zeros(3), np.array([15.0, 22.0, 13.0]), np.array([0.0, 0.5, 1.0]), 0.1, 12.0)
    assert patch.occupancy.size == 0  # nothing touched
    # a tilted lidar: a 15 m return is projected to < 12 m on the ground plane; still no return
    rot = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(0.9), -math.sin(0.9)], [0.0, math.sin(0.9), math.cos(0.9)]])
    laser = LaserConfig(extrinsic=tuple(rot.reshape(-1)) + (0.0, 0.0, 2.0))
    r, a, _ = planar_scan(np.array([15.0, 10.0]), np.array([0.3, 0.3]), laser, np.zeros(3), 0.1, 12.0)
    assert np.isnan(r[0]) and 0 < r[1] < 10.0


@pytest.mark.parametrize(
    "limits, text",
    [
        ((0.1, 0.0), "range_max 0"),
        ((5.0, 2.0), "range_min 5, range_max 2"),
        ((0.0, float("nan")), "range_max nan"),
        ((-1.0, 5.0), "range_min -1"),
    ],
)
def test_bad_limits_are_a_counted_fault_and_the_scan_not_used(limits, text):
    c = ScanChecks()
    usable, faults = c.check(0, np.full(181, 5.0, np.float32), -PI / 2, PI / 2, INC, *limits)
    assert not usable and [k for k, _ in faults] == [SCAN_BAD_LIMITS] and text in faults[0][1], faults
    assert "posed from odometry" in faults[0][1] and c.counts[SCAN_BAD_LIMITS] == 1
    # good limits, values beyond them: REP 117 no returns, not a fault
    r = np.full(181, 5.0, np.float32)
    r[:20] = 18.0
    assert c.check(1, r, -PI / 2, PI / 2, INC, 0.1, 12.0) == (True, [])


# ------------------------------------------------------------------------- 17.2: mounts
MOUNTS = {
    "yaw180": [("base_link", "laser", (0.0, 0.0, 0.2), (0.0, 0.0, PI))],
    "yaw90_offset": [("base_link", "laser", (0.3, 0.1, 0.2), (0.0, 0.0, PI / 2))],
    "upside_down": [("base_link", "laser", (0.15, -0.05, 0.3), (PI, 0.0, 0.0))],
    "upside_down_yaw": [("base_link", "laser", (0.1, 0.2, 0.3), (PI, 0.0, 0.7))],
    "chain": [
        ("base_link", "shell_link", (0.0, 0.0, 0.09), (0.0, 0.0, 0.0)),
        ("shell_link", "rplidar_link", (-0.04, 0.0, 0.1), (0.0, 0.0, PI / 2)),
    ],
}


@pytest.mark.parametrize("name", MOUNTS)
def test_each_mount_puts_every_return_on_its_wall(name):
    """Ranges cast from the mounted laser, turned into map points as the correlator does with the
    parameters LidarMount gives: every point lies on a wall (to float rounding)."""
    rot, t = mount_pose(MOUNTS[name])
    m = LidarMount("/tf_static", "base_link", MOUNTS[name][-1][1], rot, t)
    p = m.params()
    fcfg = FilterConfig(**{k.split(".")[1]: v for k, v in p.items() if k.startswith("filter.")})
    lcfg = LaserConfig(**({"extrinsic": tuple(p["laser.extrinsic"])} if "laser.extrinsic" in p else {}))
    assert ("laser.extrinsic" in p) == name.startswith("upside_down")
    world = office_world()
    robot = np.array([1.5, 0.2, 0.4])  # in the corridor (the world is in the start frame)
    c, s = math.cos(robot[2]), math.sin(robot[2])
    sensor = np.array(
        [robot[0] + c * t[0] - s * t[1], robot[1] + s * t[0] + c * t[1], robot[2] + math.atan2(rot[1, 0], rot[0, 0])]
    )
    ranges = ray_cast(sensor, math.copysign(1.0, rot[2, 2]) * beam_angles(), world.segments, 20.0)
    r, a, offset = planar_scan(ranges, beam_angles(), lcfg, fcfg.sensor_offset, 0.1, 20.0)
    assert np.array_equal(np.isinf(r), np.isinf(ranges))  # no-returns stay no-returns (free space)
    pts = transform_points(transform_points(scan_to_points(r, a, 0.1, 20.0), offset), robot)
    assert len(pts) > 100
    assert distance_to_segments(pts, world.segments).max() < 1e-9


def _bag(path, transforms, frame="laser", tf=None):
    with open_writer(path) as w:
        w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage")
        w.add_connection("/scan", "sensor_msgs/msg/LaserScan")
        if tf is not None:
            w.add_connection("/tf", "tf2_msgs/msg/TFMessage")
            w.write("/tf", 1, tf_static(1, [tf]))
        w.write("/tf_static", 1, tf_static(1, [(p, c, xyz, rpy_to_quat(rpy)) for p, c, xyz, rpy in transforms]))
        w.write("/scan", 2, laser_scan(2, frame, -PI / 2, INC, np.ones(181), 0.1, 12.0))
    return str(path), bag_info(path)


def test_lidar_mount_composes_a_chain_and_finds_the_base(tmp_path):
    chain = MOUNTS["chain"] + [("base_link", "imu_link", (0.0, 0.0, 0.1), (0.0, 0.0, 0.0))]
    bag, info = _bag(tmp_path / "chain", chain, frame="rplidar_link")
    m = lidar_mount(bag, info, {"scan": "/scan"})
    rot, t = mount_pose(MOUNTS["chain"])
    assert m.source == "/tf_static" and m.chain == ["base_link", "shell_link", "rplidar_link"] and not m.warnings
    np.testing.assert_allclose(m.t, t, atol=1e-12)
    np.testing.assert_allclose(m.rot, rot, atol=1e-12)
    assert m.describe().startswith(
        "lidar mount from /tf_static: base_link -> shell_link -> rplidar_link: x -0.04 y 0.00 z 0.19, yaw 90.0°"
    )
    p = m.params()
    assert p["filter.sensor_offset_yaw_rad"] == pytest.approx(PI / 2) and p[
        "filter.sensor_offset_x_m"
    ] == pytest.approx(-0.04)


def test_lidar_mount_base_from_tf_under_a_common_root(tmp_path):
    """base_footprint -> base_link and base_footprint -> laser, /tf odom -> base_link: the laser
    in base_link = inverse(base_link in base_footprint) * laser in base_footprint."""
    tfs = [
        ("base_footprint", "base_link", (0.0, 0.0, 0.1), (0.0, 0.0, 0.0)),
        ("base_footprint", "laser", (0.2, 0.0, 0.3), (0.0, 0.0, PI / 2)),
    ]
    bag, info = _bag(tmp_path / "fp", tfs, tf=("odom", "base_link", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)))
    m = lidar_mount(bag, info, {"scan": "/scan"})
    assert m.base_frame == "base_link" and m.base_from_tf and not m.warnings
    np.testing.assert_allclose(m.t, [0.2, 0.0, 0.2], atol=1e-12)
    assert m.chain == ["base_link", "base_footprint", "laser"]
    assert m.params()["filter.sensor_offset_yaw_rad"] == pytest.approx(PI / 2)


def test_lidar_mount_missing_frame_and_foreign_root_warn(tmp_path):
    bag, info = _bag(tmp_path / "missing", [("base_link", "imu_link", (0.0, 0.0, 0.1), (0.0, 0.0, 0.0))])
    m = lidar_mount(bag, info, {"scan": "/scan"})
    assert m.source == "parameters" and m.params() == {}
    assert len(m.warnings) == 1 and "'laser'" in m.warnings[0] and "base_link -> imu_link" in m.warnings[0]
    bag, info = _bag(tmp_path / "root", [("chassis", "laser", (0.1, 0.0, 0.0), (0.0, 0.0, PI))])
    m = lidar_mount(bag, info, {"scan": "/scan"})
    assert m.source == "/tf_static" and "hangs off 'chassis', not the robot's base frame 'base_link'" in m.warnings[0]
    assert m.params()["filter.sensor_offset_x_m"] == pytest.approx(0.1)
    m = lidar_mount(bag, info, {"scan": "/scan"}, base_frame="chassis")  # the base_frame parameter
    assert not m.warnings and m.chain == ["chassis", "laser"]
