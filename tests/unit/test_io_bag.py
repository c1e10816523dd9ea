"""Bag writer/reader helpers and message builders (rosbags, no ROS install)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from pf_slam_nodes.core.geometry import yaw_to_quat
from pf_slam_nodes.io.bag import (
    TYPESTORE,
    BagError,
    bag_info,
    clock,
    deserialize,
    joint_state_wheels,
    laser_scan,
    make_header,
    odometry,
    open_writer,
    read_bag,
    stamp_ns_of,
    tf_static,
)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_write_read_both_storages(tmp_path, storage):
    out = tmp_path / "bag"
    ranges = np.array([1.0, np.inf, 2.5], dtype=np.float32)
    with open_writer(out, storage=storage) as bag:
        bag.add_connection("/tf_static", "tf2_msgs/msg/TFMessage")
        bag.add_connection("/scan", "sensor_msgs/msg/LaserScan")
        bag.add_connection("/odom", "nav_msgs/msg/Odometry")
        bag.add_connection("/clock", "rosgraph_msgs/msg/Clock")
        bag.set_custom_data("k", "v")
        bag.write("/tf_static", 5, tf_static(5, [("base_link", "laser", (0.1, 0, 0.2), yaw_to_quat(0.5))]))
        for i in range(3):
            t = 1_000_000_000 + i * 100_000_000
            bag.write("/odom", t, odometry(t, pose=(i, 0.0, 0.1), twist=(0.5, 0.1)))
            bag.write("/scan", t, laser_scan(t, "laser", -1.0, 0.5, ranges, 0.0, 10.0))
        bag.write("/clock", t + 1, clock(t + 1))
        assert bag.counts == {"/tf_static": 1, "/scan": 3, "/odom": 3, "/clock": 1}
    info = bag_info(out)
    assert info["storage"] == storage
    assert info["topics"]["/scan"] == ("sensor_msgs/msg/LaserScan", 3)
    assert info["start_ns"] == 5 and info["end_ns"] == 1_200_000_001
    assert info["duration_ns"] == 1_200_000_001 - 5
    assert info["message_count"] == 8 and info["custom_data"] == {"k": "v"}
    msgs = list(read_bag(out))
    assert [m[0] for m in msgs] == ["/tf_static"] + ["/odom", "/scan"] * 3 + ["/clock"]
    stamps = [m[2] for m in msgs]
    assert stamps == sorted(stamps)
    scan = deserialize(msgs[2][3], msgs[2][1])
    assert scan.header.frame_id == "laser" and stamp_ns_of(scan) == 1_000_000_000
    np.testing.assert_array_equal(scan.ranges, ranges)
    assert scan.angle_max == pytest.approx(0.0)
    odom = deserialize(msgs[1][3], msgs[1][1])
    assert odom.child_frame_id == "base_link" and odom.header.frame_id == "odom"
    assert 2 * math.atan2(odom.pose.pose.orientation.z, odom.pose.pose.orientation.w) == pytest.approx(0.1)
    assert odom.twist.twist.linear.x == 0.5 and odom.twist.twist.angular.z == 0.1
    tf = deserialize(msgs[0][3], msgs[0][1]).transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("base_link", "laser")
    assert tf.transform.translation.z == pytest.approx(0.2)
    assert [m[0] for m in read_bag(out, topics=["/scan"])] == ["/scan"] * 3
    assert list(read_bag(out, topics=["/nothing"])) == []
    # tf_static is recorded latched (transient local) for ros2 bag play
    with Reader(out) as r:
        conn = next(c for c in r.connections if c.topic == "/tf_static")
        assert conn.ext.offered_qos_profiles[0].durability.name == "TRANSIENT_LOCAL"


def test_refuses_overwrite_and_bad_use(tmp_path):
    out = tmp_path / "bag"
    with open_writer(out) as bag:
        bag.add_connection("/scan", "sensor_msgs/msg/LaserScan")
        with pytest.raises(BagError, match="not added"):
            bag.write("/odom", 1, clock(1))
        with pytest.raises(BagError, match="carries"):
            bag.write("/scan", 1, clock(1))
        with pytest.raises(BagError, match="already added"):
            bag.add_connection("/scan", "sensor_msgs/msg/LaserScan")
        with pytest.raises(BagError, match="unknown message type"):
            bag.add_connection("/x", "no_pkg/msg/Nope")
    with pytest.raises(BagError, match="refusing to overwrite"):
        with open_writer(out):
            pass
    with pytest.raises(ValueError, match="storage"):
        with open_writer(tmp_path / "b2", storage="zip"):
            pass


def test_read_errors_name_the_path(tmp_path):
    with pytest.raises(BagError, match="no such file"):
        read_bag(tmp_path / "missing")
    (tmp_path / "emptydir").mkdir()
    with pytest.raises(BagError, match="emptydir.*no metadata.yaml"):
        bag_info(tmp_path / "emptydir")
    txt = tmp_path / "notes.txt"
    txt.write_text("hello")
    with pytest.raises(BagError, match="notes.txt"):
        read_bag(txt)
    fake = tmp_path / "fake.mcap"
    fake.write_bytes(b"not an mcap file at all" * 10)
    with pytest.raises(BagError, match="fake.mcap"):
        list(read_bag(fake))
    # a real bag with its data file truncated
    out = tmp_path / "trunc"
    with open_writer(out) as bag:
        bag.add_connection("/clock", "rosgraph_msgs/msg/Clock")
        for i in range(200):
            bag.write("/clock", i, clock(i))
    data = next(out.glob("*.mcap"))
    data.write_bytes(data.read_bytes()[:200])
    with pytest.raises(BagError, match="trunc"):
        list(read_bag(out))
    bad_yaml = tmp_path / "badyaml"
    bad_yaml.mkdir()
    (bad_yaml / "metadata.yaml").write_text("rosbag2_bagfile_information: [")
    with pytest.raises(BagError, match="badyaml"):
        bag_info(bad_yaml)


def test_builders():
    h = make_header(1_500_000_123, "map")
    assert (h.stamp.sec, h.stamp.nanosec, h.frame_id) == (1, 500_000_123, "map")
    js = joint_state_wheels(7, 1.5, -2.0)
    assert list(js.name) == ["left_wheel", "right_wheel"]
    np.testing.assert_array_equal(js.position, [1.5, -2.0])
    raw = TYPESTORE.serialize_cdr(js, "sensor_msgs/msg/JointState")
    assert list(deserialize(raw, "sensor_msgs/msg/JointState").position) == [1.5, -2.0]
    assert clock(3_000_000_001).clock.nanosec == 1
    tf = tf_static(0, [("a", "b", (0, 0, 0), (0, 0, 0, 2.0))])
    assert tf.transforms[0].transform.rotation.w == 1.0
    with pytest.raises(ValueError):
        tf_static(0, [("a", "b", (0, 0, 0), (0, 0, 0, 0))])
    with pytest.raises(ValueError):
        make_header(-1, "x")


def test_writer_creates_missing_parent_directories(tmp_path):
    """`pf-slam convert carmen LOG bags_local/x` in a fresh clone (no bags_local yet) works."""
    out = tmp_path / "not" / "yet" / "bag"
    with open_writer(out) as w:
        w.add_connection("/chatter", "std_msgs/msg/String")
    assert (out / "metadata.yaml").is_file()
