"""Converters: real logs -> rosbag2 -> read back with rosbags; one /scan per scan line."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import DATA

from pf_slam_nodes.io.bag import BagError, bag_info, deserialize, read_bag, stamp_ns_of
from pf_slam_nodes.io.carmen import read_carmen
from pf_slam_nodes.io.convert import convert_carmen, convert_mines, laser_offset
from pf_slam_nodes.io.mines import read_mines

needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"{DATA} not available")


def _messages(bag, topic):
    return [(t, deserialize(raw, mt)) for tp, mt, t, raw in read_bag(bag, topics=[topic])]


@needs_data
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_carmen_intel_2726_round_trip(tmp_path, storage):
    clf = DATA / "carmen" / "intel_2726.clf"
    out = tmp_path / "intel"
    rep = convert_carmen(clf, out, storage=storage)
    log = read_carmen(clf)
    assert rep.counts == {"/tf_static": 1, "/odom": 2726, "/scan": 2726}
    assert rep.retimed == 81  # 55 repeats + 26 steps back
    info = bag_info(out)
    assert info["topics"]["/scan"] == ("sensor_msgs/msg/LaserScan", 2726)
    assert info["storage"] == storage
    scans = _messages(out, "/scan")
    assert len(scans) == len(log.scans)
    rec = np.array([t for t, _ in scans])
    assert np.all(np.diff(rec) > 0)  # record time strictly increasing
    hdr = np.array([stamp_ns_of(m) for _, m in scans])
    np.testing.assert_array_equal(hdr, [s.stamp_ns for s in log.scans])  # header = log time
    assert np.count_nonzero(rec != hdr) == 81
    for (_, m), s in zip(scans, log.scans):
        np.testing.assert_array_equal(m.ranges, s.ranges)
        assert m.header.frame_id == "laser"
    assert scans[0][1].angle_increment == pytest.approx(np.pi / 180)
    odoms = _messages(out, "/odom")
    assert [stamp_ns_of(m) for _, m in odoms] == list(hdr)
    assert odoms[5][1].pose.pose.position.x == pytest.approx(log.scans[5].odom_pose[0])
    # each /odom comes right before its /scan in the replay order
    order = [tp for tp, *_ in read_bag(out)]
    assert order[0] == "/tf_static" and order[1:5] == ["/odom", "/scan", "/odom", "/scan"]
    tf = _messages(out, "/tf_static")[0][1].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("base_link", "laser")
    assert tf.transform.translation.x == 0.0 and tf.transform.rotation.w == 1.0
    with pytest.raises(BagError, match="refusing to overwrite"):
        convert_carmen(clf, out, storage=storage)


@needs_data
def test_carmen_mit_csail(tmp_path):
    rep = convert_carmen(DATA / "carmen" / "mit-csail.clf", tmp_path / "mit")
    assert rep.counts["/scan"] == 1988 and rep.retimed == 0
    _, m = _messages(tmp_path / "mit", "/scan")[0]
    assert len(m.ranges) == 361 and np.isposinf(m.ranges[24])
    assert m.angle_max == pytest.approx(np.pi / 2, abs=1e-6)


def test_carmen_with_odom_lines(tmp_path):
    clf = tmp_path / "o.clf"
    clf.write_text(
        "ODOM 0 0 0 0.1 0.0 0 10.0 h 0\n"
        "FLASER 4 1 2 3 4 0.2 0.0 0.1 0.0 0.0 0.1 10.05 h 0\n"
        "ODOM 0.01 0 0 0.1 0.0 0 10.1 h 0\n"
        "ODOM 0.02 0 0 0.1 0.0 0 10.1 h 0\n"
    )
    rep = convert_carmen(clf, tmp_path / "b")
    assert rep.counts == {"/tf_static": 1, "/odom": 3, "/scan": 1}
    assert rep.retimed == 1
    order = [(tp, t) for tp, _, t, _ in read_bag(tmp_path / "b")]
    assert [tp for tp, _ in order] == ["/tf_static", "/odom", "/scan", "/odom", "/odom"]
    assert order[-1][1] == order[-2][1] + 1000
    tf = _messages(tmp_path / "b", "/tf_static")[0][1].transforms[0].transform
    assert tf.translation.x == pytest.approx(0.2 * np.cos(0.1))
    assert tf.translation.y == pytest.approx(-0.2 * np.sin(0.1))
    assert tf.rotation.z == pytest.approx(0.0)


def test_carmen_without_scans(tmp_path):
    clf = tmp_path / "e.clf"
    clf.write_text("# nothing\nPARAM a b c 0\n")
    with pytest.raises(ValueError, match="no usable laser scan"):
        convert_carmen(clf, tmp_path / "b")
    assert not (tmp_path / "b").exists()


def test_laser_offset():
    x, y, yaw = laser_offset(np.array([1.0, 1.0, np.pi / 2]), np.array([1.0, 0.0, np.pi / 2]))
    assert (x, y, yaw) == pytest.approx((1.0, 0.0, 0.0))


@needs_data
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_mines_round_trip(tmp_path, storage):
    dat = DATA / "mines" / "exp1.dat"
    out = tmp_path / "mines"
    rep = convert_mines(dat, out, storage=storage)
    log = read_mines(dat)
    assert rep.counts == {"/tf_static": 1, "/encoders": 756, "/scan": 756}
    assert rep.retimed == 0
    info = bag_info(out)
    assert info["custom_data"]["pf_slam.ticks_per_rev"] == "2000"
    assert float(info["custom_data"]["pf_slam.wheel_radius_m"]) == 0.077
    scans = _messages(out, "/scan")
    enc = _messages(out, "/encoders")
    assert len(scans) == len(enc) == 756
    for i, ((t, m), (te, e)) in enumerate(zip(scans, enc)):
        assert t == te == log.stamps_us[i] * 1000 == stamp_ns_of(m) == stamp_ns_of(e)
        np.testing.assert_array_equal(m.ranges, log.ranges[i])
    e = enc[-1][1]
    assert list(e.name) == ["left_wheel", "right_wheel"]
    np.testing.assert_allclose(e.position, [211786 * 2 * np.pi / 2000, 210289 * 2 * np.pi / 2000])
    m = scans[0][1]
    assert (m.range_min, m.range_max) == (pytest.approx(0.02), pytest.approx(5.6))
    assert m.angle_min == pytest.approx(log.angle_min)
