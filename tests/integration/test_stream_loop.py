"""The ROS-free loop fed the input streams (core/slam.py ParticleFilterSlam.open_stream) and the
node graph give the same trajectory: both run the predictor's scheduling
(core/scheduler.py PredictorScheduler), here on the car (wheel encoders + batched FOG, a
tilted lidar, kaist.yaml) and on the sample (nav_msgs/Odometry).

Same means: every scan's stamp equal, x and y equal bit for bit (float64 both ways, PoseStamped
carries them exactly), yaw within 1e-12 rad (the graph's pose goes out as a quaternion and
comes back through atan2: the round trip is not exact in the last bits).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from conftest import config_section  # noqa: E402

from pf_slam_nodes import graph  # noqa: E402
from pf_slam_nodes.core import config as cfg  # noqa: E402
from pf_slam_nodes.core.motion import wrap_angle  # noqa: E402
from pf_slam_nodes.core.slam import ParticleFilterSlam  # noqa: E402
from pf_slam_nodes.io.bag import bag_info, read_bag  # noqa: E402
from pf_slam_nodes.io.trajectory import quat_to_yaw, read_trajectory  # noqa: E402
from pf_slam_nodes.ros import cdr  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "ros2_ws/src/pf_slam_nodes/config"


def _graph_parameters(bag: Path, params_file: Path) -> tuple[dict, dict, dict, dict]:
    """What `pf-slam run` gives the predictor, the correlator and the mapper for this bag (the
    bag's implied parameters, then the file), and the inputs it selects."""
    info = bag_info(bag)
    file_layer = graph.load_params(params_file)
    inputs = graph.select_inputs(str(bag), info, graph.params_topics(file_layer))
    stamps = graph.inspect_stamps(str(bag), inputs)
    assert not stamps["restamp"]  # the replay passes the stamps on unchanged
    mount = graph.lidar_mount(str(bag), info, inputs)
    layers = [graph.detect_inputs(str(bag), info, inputs, mount=mount, stamps=stamps), file_layer]
    return (*(graph.node_params(layers, n) for n in ("predictor", "correlator", "mapper")), inputs)


def _stream_loop(bag: Path, params_file: Path) -> tuple[ParticleFilterSlam, list]:
    """The bag through the ROS-free loop, message by message in record order."""
    pred, corr, mapper, inputs = _graph_parameters(bag, params_file)
    slam = ParticleFilterSlam(
        config_section(cfg.FilterConfig, corr, "filter"),
        config_section(cfg.OdometryMotionConfig, pred, "motion"),
        config_section(cfg.GridConfig, corr, "grid"),
        config_section(cfg.CorrelationConfig, corr, "correlation"),
        config_section(cfg.ResampleConfig, corr, "resample"),
        config_section(cfg.LaserConfig, corr, "laser"),
        config_section(cfg.LoopClosureConfig, mapper, "loops"),
    )
    assert config_section(cfg.FilterConfig, pred, "filter") == slam.predictor.filter_cfg
    source = pred.get("odometry_source", "odom")
    fog = pred.get("fog_format", "none")
    slam.open_stream(
        source,
        pred.get("odom_sync", "interpolate"),
        config_section(cfg.WheelsConfig, pred, "wheels") if source == "encoders" else None,
        gyro=fog != "none",
        time_gap_s=float(pred.get("time_gap_s", 60.0)),
    )
    roles = {t: r for r, t in inputs.items()}
    for topic, _, _, raw in read_bag(bag, [inputs[r] for r in ("scan", "odom", "encoders", "fog") if r in inputs]):
        role = roles[topic]
        if role == "scan":
            stamp, (a_min, a_max, a_inc), (r_min, r_max), ranges = cdr.laser_scan_fields(raw)
            slam.add_scan(stamp, ranges, a_min, a_max, a_inc, r_min, r_max)
        elif role == "encoders":
            stamp, position = cdr.joint_state_positions(raw)
            slam.add_encoders(stamp, position)
        elif role == "fog":
            assert fog == "batch"
            slam.add_gyro(*cdr.fog_batch_yaw(raw))
        else:
            from pf_slam_nodes.io.bag import deserialize, stamp_ns_of

            m = deserialize(raw, "nav_msgs/msg/Odometry")
            q = m.pose.pose.orientation
            slam.add_odometry(
                stamp_ns_of(m),
                np.array([m.pose.pose.position.x, m.pose.pose.position.y, quat_to_yaw(q.x, q.y, q.z, q.w)]),
            )
    return slam, slam.end_of_stream()


def _graph_run(bag: Path, params: Path, out: Path, domain_id: int, **kwargs):
    """`pf-slam run` of the bag with the parameter file, quiet, nothing recorded."""
    return graph.run(
        str(bag),
        out,
        params_file=str(params),
        progress=False,
        domain_id=domain_id,
        snapshot_every=0,
        record=False,
        **kwargs,
    )


def _assert_same(stream: list, res) -> None:
    stamps = np.array([s for s, _ in stream])
    poses = np.array([p for _, p in stream])
    graph_poses = np.array(res.poses)
    assert len(stream) == len(res.stamps_ns) == res.summary["scans_processed"]
    assert np.array_equal(stamps, np.array(res.stamps_ns))
    assert np.array_equal(poses[:, :2], graph_poses[:, :2])  # bit for bit
    dyaw = np.abs(wrap_angle(poses[:, 2] - graph_poses[:, 2]))
    print(f"{len(stream)} poses: x, y equal; yaw: {int((dyaw == 0).sum())} equal, max difference {dyaw.max():.3g} rad")
    assert dyaw.max() <= 1e-12


def test_car_encoders_fog_stream_loop_equals_graph(tmp_path, ros_domain):
    bag, params = ROOT / "bags" / "car_sample", CONFIG / "kaist.yaml"
    slam, stream = _stream_loop(bag, params)
    res = _graph_run(bag, params, tmp_path / "car", ros_domain, texture=False)
    assert len(stream) == 2000
    _assert_same(stream, res)
    # the same decisions: corrections, faults, the gyro's rest calibration
    assert slam.num_updates + 1 == res.summary["scans_corrected"] == 63
    faults = slam.scheduler.faults()
    assert {k: v for k, v in faults.items() if v} == {"odom_missing": 1}
    assert all(res.summary["faults"][k] == v for k, v in faults.items())
    assert slam.scheduler.gyro_status()["gyro"] == res.summary["gyro"]


def test_loop_closure_stream_loop_equals_graph(tmp_path, ros_domain):
    """loops.enabled with a re-rendering at every closed loop (rebuild_m 0; loop edges trusted
    to a millimetre, so every one disagrees enough with the chain to be solved at once): the
    mapper's frame change reaches the correlator (the marker, then the whole map) exactly where
    the loop's does; the poses as published are the same, and so is the final trajectory (the
    graph's matches in the mapper's worker process, the loop's in this one)."""
    params = tmp_path / "sample_loops.yaml"
    params.write_text(
        (CONFIG / "sim_indoor.yaml").read_text()
        + "mapper:\n  ros__parameters:\n    loops:\n      enabled: true\n      rebuild_m: 0.0\n"
        + "      loop_sigma_xy_m: 0.001\n      loop_sigma_rad: 0.0002\n"
    )
    bag = ROOT / "bags" / "sample_indoor"
    slam, stream = _stream_loop(bag, params)
    res = _graph_run(bag, params, tmp_path / "sample", ros_domain)
    _assert_same(stream, res)
    assert slam.mapper.rebuilds >= 2 and slam.corrector.frame_changes == slam.mapper.rebuilds
    stamps = np.array([s for s, _ in stream])
    final = slam.trajectory(stamps / 1e9, np.array([p for _, p in stream]))  # (+ the end's rendering, if due)
    assert res.summary["loops"]["map_renders"] == slam.mapper.rebuilds
    # every re-rendering during the run sent the poses so far in its new frame (the live texture's)
    assert res.summary["loops"]["loop_trajectories"] == slam.corrector.frame_changes
    assert res.summary["loops"]["matched_in"] == "process"  # the node's default: a worker process
    t, p = read_trajectory(tmp_path / "sample" / "trajectory.tum")[:2]
    assert np.allclose(t, stamps / 1e9, atol=1e-9)
    assert np.abs(p[:, :2] - final[:, :2]).max() < 2e-6  # the TUM file's 6 decimals
    online = read_trajectory(tmp_path / "sample" / "trajectory_online.tum")[1]
    assert np.abs(online[:, :2] - np.array(res.poses)[:, :2]).max() < 2e-6
    assert np.abs(final[:, :2] - online[:, :2]).max() > 0.001  # the loop closure moved them


def test_sample_odometry_stream_loop_equals_graph(tmp_path, ros_domain):
    bag, params = ROOT / "bags" / "sample_indoor", CONFIG / "sim_indoor.yaml"
    slam, stream = _stream_loop(bag, params)
    res = _graph_run(bag, params, tmp_path / "sample", ros_domain)
    assert len(stream) == 600
    _assert_same(stream, res)
    assert not any(slam.scheduler.faults().values())


def test_car_odometry_scale_estimate_stream_loop_equals_graph(tmp_path, ros_domain):
    """correlation.odom_scale (on in kaist.yaml): the correlator node gets each set's odometry
    pose from the ParticleArray, the loop from the scheduler; same estimate, same poses."""
    params = CONFIG / "kaist.yaml"
    assert "      odom_scale: true" in params.read_text()
    bag = ROOT / "bags" / "car_sample"
    slam, stream = _stream_loop(bag, params)
    est = slam.corrector.odom_scale
    assert est is not None and est.steps > 10 and est.scale != 1.0  # measured and applied
    res = _graph_run(bag, params, tmp_path / "car", ros_domain, texture=False)
    _assert_same(stream, res)
