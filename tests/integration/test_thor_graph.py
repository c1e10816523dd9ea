"""THOR through `pf-slam run`: a lidar on a nodding, turning head, odometry from the walk, an
RGB-D floor texture (a synthetic bag written as the THOR contract says: tests/thor_synth.py).

Measured (seed 0, 30 s, 600 scans): ATE 0.051 m, map F1 0.988 with 2 occupied cells farther than
0.3 m from a wall; the same run without floor removal (laser.min_height_m -100): ATE 0.089 m and
14 such cells (floor returns became walls); texture error 1.7 (0..255) on 30 depth pairs.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")

from conftest import config_section  # noqa: E402
from thor_synth import evaluate_run, write_thor_bag  # noqa: E402

from pf_slam_nodes import graph  # noqa: E402
from pf_slam_nodes.core import config as cfg  # noqa: E402
from pf_slam_nodes.core.geometry import quat_to_yaw, wrap_angle  # noqa: E402
from pf_slam_nodes.core.slam import ParticleFilterSlam  # noqa: E402
from pf_slam_nodes.io.bag import bag_info, deserialize, read_bag, stamp_ns_of  # noqa: E402
from pf_slam_nodes.profiles import profile_file  # noqa: E402
from pf_slam_nodes.ros import cdr  # noqa: E402


@pytest.fixture(scope="module")
def thor(tmp_path_factory, module_ros_domain):
    d = tmp_path_factory.mktemp("thor")
    synth = write_thor_bag(d / "bag", duration_s=30.0, seed=0, rgbd_hz=1.0)
    # every RGB-D pair queued (the node skips pairs under load by design; here all 30 are measured)
    res = graph.run(
        str(synth.bag),
        d / "run",
        progress=False,
        domain_id=module_ros_domain,
        overrides={"texture": {"queue_depth": 40, "max_pending_pairs": 40}},
    )
    return synth, d / "run", res, evaluate_run(d / "run", synth)


def test_moving_head_graph(thor):
    synth, out, res, ev = thor
    s = res.summary
    print(ev)
    assert s["profile"]["name"] == "thor" and s["particles"] >= 100
    assert s["complete"] and s["scans_processed"] == synth.scans == 600  # every scan posed
    assert "moving mount" in s["lidar_mount"]["used"]
    # the look-down second: its scans that were due a correction were skipped and counted
    assert 1 <= s["faults"]["scan_mostly_floor"] <= synth.look_down_scans
    assert s["faults"]["mount_out_of_order"] == 0
    assert ev["ate_m"] < 0.08, ev
    assert ev["map_f1"] > 0.95, ev
    # floor returns did not become walls: nearly every occupied cell lies on a wall
    assert ev["false_walls"] <= 6 and ev["precision"] > 0.99, ev


def test_depth_texture_in_the_graph(thor):
    synth, out, res, ev = thor
    t = res.summary["texture"]
    assert t["mode"] == "depth" and t["frames_received"] == 30
    assert t["frames_processed"] == 30 and t["frames_skipped"] == 0
    assert t["plane_fits"] >= 0.8 * t["frames_processed"]
    assert (out / "texture.png").exists()
    assert ev["texture_cells"] > 5000 and ev["texture_error"] < 8.0, ev


def test_stream_loop_equals_graph(thor):
    """The ROS-free loop fed /scan, /odom and /tf in record order gives the graph's trajectory."""
    synth, out, res, _ = thor
    bag = synth.bag
    info = bag_info(bag)
    layers = [graph.load_params(profile_file("thor"))]
    inputs = graph.select_inputs(str(bag), info)
    stamps = graph.inspect_stamps(str(bag), inputs)
    mount = graph.lidar_mount(str(bag), info, inputs)
    layers.insert(0, graph.detect_inputs(str(bag), info, inputs, mount=mount, stamps=stamps))
    pred, corr = graph.node_params(layers, "predictor"), graph.node_params(layers, "correlator")
    laser = config_section(cfg.LaserConfig, corr, "laser")
    assert laser.dynamic_frame == "head" and laser.min_kept_fraction > 0
    slam = ParticleFilterSlam(
        config_section(cfg.FilterConfig, corr, "filter"),
        config_section(cfg.OdometryMotionConfig, pred, "motion"),
        config_section(cfg.GridConfig, corr, "grid"),
        config_section(cfg.CorrelationConfig, corr, "correlation"),
        config_section(cfg.ResampleConfig, corr, "resample"),
        laser,
    )
    slam.open_stream("odom", pred.get("odom_sync", "interpolate"))
    for topic, msgtype, _, raw in read_bag(bag, ["/scan", "/odom", "/tf"]):
        if topic == "/scan":
            stamp, (a_min, a_max, a_inc), (r_min, r_max), ranges = cdr.laser_scan_fields(raw)
            slam.add_scan(stamp, ranges, a_min, a_max, a_inc, r_min, r_max)
        elif topic == "/odom":
            m = deserialize(raw, msgtype)
            q = m.pose.pose.orientation
            slam.add_odometry(
                stamp_ns_of(m),
                np.array([m.pose.pose.position.x, m.pose.pose.position.y, quat_to_yaw(q.x, q.y, q.z, q.w)]),
            )
        else:
            tr = deserialize(raw, msgtype).transforms[0]
            q, t = tr.transform.rotation, tr.transform.translation
            slam.add_mount(stamp_ns_of(tr), (q.x, q.y, q.z, q.w), (t.x, t.y, t.z))
    stream = slam.end_of_stream()
    poses = np.array([p for _, p in stream])
    gp = np.array(res.poses)
    assert np.array_equal(np.array([s for s, _ in stream]), np.array(res.stamps_ns))
    assert np.array_equal(poses[:, :2], gp[:, :2])
    assert np.abs(wrap_angle(poses[:, 2] - gp[:, 2])).max() <= 1e-12
    assert slam.scheduler.faults()["scan_mostly_floor"] == res.summary["faults"]["scan_mostly_floor"]


def test_one_process_per_node_gives_the_same_trajectory(thor, tmp_path, module_ros_domain):
    """The moving mount's samples are waited for on data, never on time: the same poses with
    every node in its own process (the /tf stream then arrives beside the scans, not with them)."""
    synth, out, res, _ = thor
    multi = graph.run(
        str(synth.bag),
        tmp_path / "multi",
        processes="multi",
        progress=False,
        domain_id=module_ros_domain,
        texture=False,
        record=False,
        snapshot_every=0,
    )
    assert multi.summary["faults"]["scan_mostly_floor"] == res.summary["faults"]["scan_mostly_floor"]
    assert (tmp_path / "multi" / "trajectory.tum").read_bytes() == (out / "trajectory.tum").read_bytes()
