"""Bring your own bag: any rosbag2 with a LaserScan and an Odometry under its own topic names."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from pf_slam_nodes import cli  # noqa: E402
from pf_slam_nodes.io.bag import bag_info, open_writer, read_bag  # noqa: E402
from pf_slam_nodes.io.evaluation import evaluate  # noqa: E402

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
    rc = cli.main(
        [
            "run",
            str(own_bag),
            "--out",
            str(out),
            "--scan-topic",
            "/front/scan",
            "--odom-topic",
            "/wheel/odom",
            "--snapshot-every",
            "0",
            "--params",
            str(ROOT / "ros2_ws/src/pf_slam_nodes/config/sim_indoor.yaml"),
        ]
    )
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
    ev = evaluate(out / "trajectory.tum", SAMPLE.parent / "ground_truth.tum")
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


def _car_with_imu(path: Path, sign: float) -> Path:
    """The car sample with its FOG re-recorded as sensor_msgs/Imu on /imu/data (one per batch,
    yaw rate = sign * the batch's yaw / its time span), the encoders, scans, mounts and wheel
    geometry as they are."""
    from pf_slam_nodes.io.bag import TYPESTORE
    from pf_slam_nodes.ros import cdr

    car = ROOT / "bags" / "car_sample"
    T = TYPESTORE.types
    vec = T["geometry_msgs/msg/Vector3"]
    with open_writer(path) as bag:
        topics = bag_info(car)["topics"]
        for t in ("/encoders", "/scan", "/tf_static"):
            bag.add_connection(t, topics[t][0])
        bag.add_connection("/imu/data", "sensor_msgs/msg/Imu")
        for key, value in bag_info(car).get("custom_data", {}).items():  # the wheel geometry
            bag.set_custom_data(key, value)
        last = None
        for topic, _msgtype, t, raw in read_bag(car, topics=["/encoders", "/scan", "/tf_static", "/fog"]):
            if topic != "/fog":
                bag.write_raw(topic, t, raw)
                continue
            stamps, dyaw = cdr.fog_batch_yaw(raw)
            end = int(stamps[-1])
            if last is not None:
                rate = sign * float(dyaw.sum()) / ((end - last) / 1e9)
                msg = T["sensor_msgs/msg/Imu"](
                    header=T["std_msgs/msg/Header"](
                        stamp=T["builtin_interfaces/msg/Time"](sec=end // 10**9, nanosec=end % 10**9), frame_id="imu"
                    ),
                    orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.zeros(9),
                    angular_velocity=vec(x=0.0, y=0.0, z=rate),
                    angular_velocity_covariance=np.zeros(9),
                    linear_acceleration=vec(x=0.0, y=0.0, z=0.0),
                    linear_acceleration_covariance=np.zeros(9),
                )
                bag.write_raw("/imu/data", t, TYPESTORE.serialize_cdr(msg, "sensor_msgs/msg/Imu"))
            last = end
    return path


def test_encoders_with_an_imu_gyro(tmp_path, ros_domain):
    """An Imu next to wheel encoders is the gyro (auto-detected): with the FOG's yaw rates the
    car sample is tracked; with the rates negated it is not (so the yaw does come from it)."""
    from pf_slam_nodes.graph import run

    # kaist.yaml without its FOG line: the gyro's format comes from the bag (a file value would win)
    kaist = (ROOT / "ros2_ws/src/pf_slam_nodes/config/kaist.yaml").read_text()
    assert "    fog_format: batch\n" in kaist
    (tmp_path / "car.yaml").write_text(kaist.replace("    fog_format: batch\n", ""))
    ate = {}
    for sign in (1.0, -1.0):
        bag = _car_with_imu(tmp_path / f"car_imu_{sign:+.0f}", sign)
        out = tmp_path / f"run_{sign:+.0f}"
        res = run(
            str(bag),
            out,
            params_file=str(tmp_path / "car.yaml"),
            progress=False,
            domain_id=ros_domain,
            snapshot_every=0,
            record=False,
        )
        assert res.summary["inputs"] == {"scan": "/scan", "encoders": "/encoders", "imu": "/imu/data"}
        assert res.summary["scans_processed"] == 2000
        ev = evaluate(out / "trajectory.tum", ROOT / "bags" / "car_sample_ground_truth.csv")
        assert ev["n_associated"] >= 1990
        ate[sign] = ev["ate"]["rmse"]
    assert ate[1.0] < 0.2 and ate[-1.0] > 1.0, ate
