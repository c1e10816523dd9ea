"""Direct CDR reading/writing of the high-rate messages against rclpy's own serialization."""

import array

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState, LaserScan

from pf_slam_interfaces.msg import FogBatch
from pf_slam_nodes.ros import cdr, convert


@pytest.mark.parametrize("names", [[], ["l"], ["left_wheel", "right"]])
def test_joint_state_positions(names):
    m = JointState()
    m.header.stamp.sec, m.header.stamp.nanosec = 1_700_000_000, 123
    m.header.frame_id = "base_link"
    m.name = names
    m.position = [1.5, -2.25]
    m.velocity = [3.0]
    stamp, pos = cdr.joint_state_positions(serialize_message(m))
    assert stamp == 1_700_000_000_000_000_123
    assert pos.tolist() == [1.5, -2.25]


@pytest.mark.parametrize("roll", [[], [0.1, 0.2]])
def test_fog_batch_yaw(roll):
    f = FogBatch()
    f.header.frame_id = "fog"
    f.stamps_ns = array.array("q", [5, 6])
    f.delta_roll = array.array("d", roll)
    f.delta_yaw = array.array("d", [0.5, -0.5])
    stamps, yaw = cdr.fog_batch_yaw(serialize_message(f))
    assert stamps.tolist() == [5, 6] and yaw.tolist() == [0.5, -0.5]


@pytest.mark.parametrize("frame", ["", "f", "fog", "fog_link", "a_much_longer_fog_frame"])
@pytest.mark.parametrize("n", [0, 1, 10])
def test_fog_batch_fast_path_matches_rclpy(frame, n):
    f = FogBatch()
    f.header.stamp.sec, f.header.stamp.nanosec = 1_700_000_000, 5
    f.header.frame_id = frame
    f.stamps_ns = array.array("q", range(100, 100 + n))
    f.delta_roll = array.array("d", [0.1] * n)
    f.delta_pitch = array.array("d", [0.2] * n)
    f.delta_yaw = array.array("d", [0.25 * k for k in range(n)])
    raw = serialize_message(f)
    fast = cdr._fog_batch_fast(raw)
    assert fast is not None  # the layout rclpy writes takes the fast path
    assert fast[0].tolist() == list(f.stamps_ns) and fast[1].tolist() == list(f.delta_yaw)
    for cut in (len(raw) - 8, 20):
        with pytest.raises(ValueError, match="FogBatch"):
            cdr.fog_batch_yaw(raw[:cut]) if n else cdr.fog_batch_yaw(raw[:13])


@pytest.mark.parametrize("frame", ["l", "laser", "lidar_front"])
def test_laser_scan_ranges(frame):
    m = LaserScan()
    m.header.stamp.sec, m.header.stamp.nanosec = 1_700_000_001, 7
    m.header.frame_id = frame
    m.angle_min, m.angle_max, m.angle_increment = -1.5, 1.5, 0.75
    m.range_min, m.range_max = 0.1, 30.0
    m.ranges = [1.0, float("nan"), -2.0, float("inf"), 4.5]
    m.intensities = [1.0, 2.0]
    stamp, angles, ranges = cdr.laser_scan_ranges(serialize_message(m))
    assert stamp == 1_700_000_001_000_000_007 and angles == (-1.5, 1.5, 0.75)
    np.testing.assert_array_equal(ranges, np.array(m.ranges, dtype=np.float32))
    assert cdr.laser_scan_ranges(serialize_message(LaserScan()))[2].size == 0
    stamp2, angles2, limits, ranges2 = cdr.laser_scan_fields(serialize_message(m))
    assert (stamp2, angles2) == (stamp, angles) and limits == (np.float32(0.1), 30.0)
    np.testing.assert_array_equal(ranges2, ranges)


def test_bad_bytes_name_the_type():
    f = FogBatch()
    f.stamps_ns = array.array("q", [5, 6])
    f.delta_yaw = array.array("d", [0.5])
    with pytest.raises(ValueError, match="FogBatch: 2 stamps but 1 delta_yaw"):
        cdr.fog_batch_yaw(serialize_message(f))
    raw = serialize_message(JointState(position=[1.0, 2.0]))
    with pytest.raises(ValueError, match="JointState: truncated"):
        cdr.joint_state_positions(raw[:30])  # cut inside the positions
    with pytest.raises(ValueError, match="LaserScan: truncated"):
        cdr.laser_scan_ranges(serialize_message(LaserScan(ranges=[1.0] * 10))[:60])
    with pytest.raises(ValueError, match="PoseStamped: not a CDR"):
        cdr.pose_stamped_xy_yaw(b"\x01\x02")


@pytest.mark.parametrize("frame", ["m", "map", "mapx", "a_longer_frame"])
def test_pose_stamped_writer_round_trips_through_rclpy(frame):
    pose, stamp = np.array([1.0, -2.0, 2.9]), 1_700_000_000_123_456_789
    raw = cdr.PoseStampedWriter(frame).pack(pose, stamp)
    msg = deserialize_message(raw, PoseStamped)
    ref = convert.pose_stamped(pose, stamp, frame)
    assert msg == ref  # every field (the CDR bytes differ only in padding)
    s, p = cdr.pose_stamped_xy_yaw(serialize_message(ref))
    assert s == stamp and np.allclose(p, pose, atol=1e-12)


@pytest.mark.parametrize("frame", ["m", "map", "mapx", "a_longer_frame"])
@pytest.mark.parametrize("n", [0, 1, 3])
def test_pose_array_writer_round_trips_through_rclpy(frame, n):
    from geometry_msgs.msg import PoseArray

    poses, stamp = np.random.default_rng(n).normal(size=(n, 3)) * [5.0, 5.0, 3.0], 1_700_000_000_123_456_789
    msg = deserialize_message(cdr.PoseArrayWriter(frame).pack(poses, stamp), PoseArray)
    ref = PoseArray(
        header=convert.pose_stamped(np.zeros(3), stamp, frame).header,
        poses=[convert.pose_stamped(p, stamp, frame).pose for p in poses],
    )
    assert msg.header == ref.header and len(msg.poses) == n
    for a, b in zip(msg.poses, ref.poses):
        assert np.allclose(
            [
                a.position.x,
                a.position.y,
                a.position.z,
                a.orientation.x,
                a.orientation.y,
                a.orientation.z,
                a.orientation.w,
            ],
            [
                b.position.x,
                b.position.y,
                b.position.z,
                b.orientation.x,
                b.orientation.y,
                b.orientation.z,
                b.orientation.w,
            ],
            atol=1e-12,
        )


@pytest.mark.parametrize("frame", ["", "m", "map", "mapx", "a_longer_frame"])
@pytest.mark.parametrize("n", [0, 1, 2, 7])
def test_path_bytes_and_reader_agree_with_rclpy(frame, n):
    from nav_msgs.msg import Path

    rng = np.random.default_rng(n + len(frame))
    stamps = rng.integers(-2_000_000_000, 2_000_000_000_000_000_000, n)
    poses = rng.normal(size=(n, 3)) * [50.0, 50.0, 3.0]
    ref = Path(
        header=convert.pose_stamped(np.zeros(3), 1_700_000_000_123_456_789, frame).header,
        poses=[convert.pose_stamped(p, int(t), frame) for t, p in zip(stamps, poses)],
    )
    raw = cdr.path_bytes(stamps, poses, 1_700_000_000_123_456_789, frame)
    assert deserialize_message(raw, Path) == ref  # every field (the bytes differ only in padding)
    assert len(raw) == len(serialize_message(ref))
    t, p = cdr.path_xy_yaw(serialize_message(ref))
    assert t.tolist() == stamps.tolist() and p.shape == (n, 3)
    assert np.allclose(p[:, :2], poses[:, :2], atol=0) and np.allclose(np.cos(p[:, 2] - poses[:, 2]), 1.0)


def test_path_reader_takes_mixed_frame_ids_pose_by_pose():
    from nav_msgs.msg import Path

    ref = Path(
        poses=[convert.pose_stamped(np.array([k, -k, 0.1 * k]), k, f) for k, f in enumerate("a ab abc a".split())]
    )
    t, p = cdr.path_xy_yaw(serialize_message(ref))
    assert t.tolist() == [0, 1, 2, 3] and np.allclose(p, [[k, -k, 0.1 * k] for k in range(4)])
    with pytest.raises(ValueError, match="nav_msgs/Path"):
        cdr.path_xy_yaw(serialize_message(ref)[:-8])


def test_clock_bytes_are_a_clock_message():
    from rosgraph_msgs.msg import Clock

    stamp = 1_318_000_000_123_456_789
    assert convert.stamp_to_ns(deserialize_message(cdr.clock_bytes(stamp), Clock).clock) == stamp


@pytest.mark.parametrize("parent, child", [("odom", "base_link"), ("o", "b"), ("odom_x", "base_footprint1")])
def test_transform_writer_is_a_tf_message(parent, child):
    from tf2_msgs.msg import TFMessage

    pose, stamp = np.array([3.5, -1.25, -2.0]), 1_700_000_001_000_000_007
    raw = cdr.TransformWriter(parent, child).pack(pose, stamp)
    assert deserialize_message(raw, TFMessage) == TFMessage(transforms=[convert.transform(parent, child, pose, stamp)])


@pytest.mark.parametrize("stamp", [0, 1_700_000_000_123_456_789, -5_000_000_001])
def test_with_header_stamp_rewrites_only_the_stamp(stamp):
    """bag_replay's restamp: the header stamp replaced in the bytes, the rest untouched."""
    m = LaserScan()
    m.header.stamp.sec, m.header.stamp.nanosec = 12, 34
    m.header.frame_id = "laser"
    m.ranges = [1.0, 2.0, float("inf")]
    raw = bytes(serialize_message(m))
    out = cdr.with_header_stamp(raw, stamp)
    back = deserialize_message(out, LaserScan)
    assert back.header.stamp.sec * 1_000_000_000 + back.header.stamp.nanosec == stamp
    assert cdr.header_stamp(out) == stamp and len(out) == len(raw) and out[12:] == raw[12:]
    assert list(back.ranges) == [1.0, 2.0, float("inf")] and back.header.frame_id == "laser"
    with pytest.raises(ValueError):
        cdr.with_header_stamp(b"\x00\x01\x00", stamp)


def test_parse_restamp():
    from pf_slam_nodes.nodes.bag_replay import parse_restamp

    assert parse_restamp("") == {}
    assert parse_restamp("/scan=record,/odom=-3000000000") == {"/scan": "record", "/odom": -3_000_000_000}
    with pytest.raises(ValueError, match="restamp"):
        parse_restamp("/odom=3s")


@pytest.mark.parametrize("child", ["", "b", "base_link", "base_footprint"])
def test_odometry_xy_yaw_equals_the_message_fields(child):
    """The predictor reads /odom from the bytes: the same x, y and yaw (bit for bit) as from
    rclpy's message, for child frame names of every alignment; a cut message is a clear error."""
    from nav_msgs.msg import Odometry

    from pf_slam_nodes.core.geometry import quat_to_yaw

    m = Odometry()
    m.header.stamp.sec, m.header.stamp.nanosec = 1_700_000_000, 987_654_321
    m.header.frame_id, m.child_frame_id = "odom", child
    m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z = 1.25, -3.5, 0.7
    q = m.pose.pose.orientation
    q.x, q.y, q.z, q.w = 0.01, -0.02, 0.6, 0.8
    m.pose.covariance[0] = 9.0
    m.twist.twist.linear.x = 4.0
    raw = serialize_message(m)
    stamp, pose = cdr.odometry_xy_yaw(raw)
    assert stamp == 1_700_000_000_987_654_321
    assert pose.tolist() == [1.25, -3.5, float(quat_to_yaw(q.x, q.y, q.z, q.w))]
    with pytest.raises(ValueError, match="Odometry: truncated"):
        cdr.odometry_xy_yaw(raw[:40])
