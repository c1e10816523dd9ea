"""Bring your own bag: any rosbag2 with a LaserScan and an Odometry under its own topic names."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from pf_slam_nodes import cli  # noqa: E402
from pf_slam_nodes.core import metrics  # noqa: E402
from pf_slam_nodes.io.bag import bag_info, open_writer, read_bag  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "bags" / "sample_indoor"
RENAME = {"/scan": "/front/scan", "/odom": "/wheel/odom"}


@pytest.fixture(scope="module")
def own_bag(tmp_path_factory) -> Path:
    """The sample's scans and odometry re-recorded as /front/scan and /wheel/odom, with an
    unrelated topic and no /tf_static (so the graph publishes the laser mount itself)."""
    path = tmp_path_factory.mktemp("own") / "robot_bag"
    with open_writer(path) as bag:
        for old, new in RENAME.items():
            bag.add_connection(new, bag_info(SAMPLE)["topics"][old][0])
        bag.add_connection("/battery", "std_msgs/msg/String")
        from pf_slam_nodes.io.bag import TYPESTORE
        battery = TYPESTORE.serialize_cdr(TYPESTORE.types["std_msgs/msg/String"](data="12.1 V"), "std_msgs/msg/String")
        for topic, _msgtype, t, raw in read_bag(SAMPLE, topics=list(RENAME)):
            bag.write_raw(RENAME[topic], t, raw)
        bag.write_raw("/battery", t, battery)
    return path


def test_own_bag_with_topic_flags(own_bag, tmp_path, ros_domain, capfd):
    out = tmp_path / "run"
    rc = cli.main(["run", str(own_bag), "--out", str(out), "--scan-topic", "/front/scan",
                   "--odom-topic", "/wheel/odom", "--snapshot-every", "0",
                   "--params", str(ROOT / "ros2_ws/src/pf_slam_nodes/config/sim_indoor.yaml")])
    assert rc == 0
    err = capfd.readouterr().err
    # the report names every topic and what it is used for
    lines = {ln.split()[0]: ln for ln in err.splitlines() if ln.startswith("  /")}
    assert "lidar (LaserScan)" in lines["/front/scan"] and "600" in lines["/front/scan"]
    assert "odometry (Odometry)" in lines["/wheel/odom"] and "pairing with scans: exact" in lines["/wheel/odom"]
    assert "not used" in lines["/battery"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["inputs"] == {"scan": "/front/scan", "odom": "/wheel/odom"}
    assert summary["scans_processed"] == 600 and summary["scans_dropped"] == 0
    ev = metrics.evaluate(out / "trajectory.tum", SAMPLE.parent / "ground_truth.tum")
    assert ev["n_associated"] == 600 and ev["ate"]["rmse"] < 0.10, ev["ate"]
    # result.mcap under the bag's own names; the laser mount from the parameters on /tf_static
    from pf_slam_nodes.io.bag import deserialize
    counts: dict[str, int] = {}
    statics = []
    for topic, msgtype, _, raw in read_bag(out / "result.mcap"):
        counts[topic] = counts.get(topic, 0) + 1
        if topic == "/tf_static":
            statics += [(tr.header.frame_id, tr.child_frame_id) for tr in deserialize(raw, msgtype).transforms]
    assert counts["/front/scan"] == counts["/pose"] == 600 and "/scan" not in counts
    assert statics == [("base_link", "laser")]


def test_own_bag_auto_detects_the_only_scan_and_odometry(own_bag):
    from pf_slam_nodes.graph import detect_inputs, select_inputs
    info = bag_info(own_bag)
    inputs = select_inputs(str(own_bag), info)
    assert inputs == {"scan": "/front/scan", "odom": "/wheel/odom"}
    params = detect_inputs(str(own_bag), info, inputs)
    assert params["predictor"]["odometry_source"] == "odom" and params["predictor"]["odom_sync"] == "exact"
    assert params["bag_replay"]["scan_topic"] == "/front/scan"
    assert "mapper" not in params  # no /tf_static in the bag: the mapper publishes the mount
    assert np.isfinite(info["duration_ns"])
