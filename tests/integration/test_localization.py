"""Localization on a saved map, through the whole graph (`pf-slam run BAG --localize MAP.yaml`).

The sample bag is mapped first (`pf-slam run`); a second pass of the same office -- the
simulator's seed 1 (other corners, speed, odometry drift), from 20 s on, so it starts away from
where the map began -- is then localized on that map from a wrong initial guess (1 m, 30 deg)
and from no guess (global initialisation). Errors are against the second pass's ground truth,
taken into the map's frame by the mapping run's own alignment to its ground truth (one fixed
transform: the localization is not aligned again).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("pf_slam_tools")

from pf_slam_nodes.core import metrics  # noqa: E402
from pf_slam_nodes.core.geometry import wrap_angle  # noqa: E402
from pf_slam_nodes.graph import _localize_overrides, run  # noqa: E402
from pf_slam_nodes.io.bag import bag_info, open_writer, read_bag  # noqa: E402
from pf_slam_nodes.io.mapfile import read_map  # noqa: E402
from pf_slam_nodes.io.trajectory import read_trajectory  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "bags" / "sample_indoor"
SEGMENT_START_S = 20.0  # the second pass starts here (seed 1's drive, 20 s in)
CONVERGED_M, CONVERGED_DEG = 0.10, 2.0  # "converged": every later scan's pose within these
MAX_SCANS_TO_CONVERGE = 20  # 2 s of the 10 Hz laser


def _crop(src: Path, dst: Path, start_ns: int) -> None:
    """The bag from `start_ns` on (its /tf_static kept), with the same metadata."""
    info = bag_info(str(src))
    with open_writer(dst) as w:
        for key, value in info.get("custom_data", {}).items():
            w.set_custom_data(key, value)
        for topic, msgtype, stamp, raw in read_bag(src):
            if topic not in w.counts:
                w.add_connection(topic, msgtype)
            if stamp >= start_ns or topic == "/tf_static":
                w.write_raw(topic, stamp, raw)


@pytest.fixture(scope="module")
def mapped(tmp_path_factory, module_ros_domain):
    """The sample bag mapped; (map.yaml, the map frame -> ground truth frame transform)."""
    out = tmp_path_factory.mktemp("map")
    run(str(SAMPLE), out, progress=False, domain_id=module_ros_domain, record=False)
    t_est, p_est = read_trajectory(out / "trajectory.tum")
    t_gt, p_gt = read_trajectory(SAMPLE.parent / "ground_truth.tum")
    assert np.array_equal(np.rint(t_est * 1e9), np.rint(t_gt * 1e9))
    return out / "map.yaml", metrics.align_se2(p_est[:, :2], p_gt[:, :2])


@pytest.fixture(scope="module")
def second_pass(tmp_path_factory):
    """Seed 1 of the office simulator from 20 s on: (bag, ground-truth stamps, poses)."""
    from pf_slam_tools.sim.indoor import simulate_indoor

    sim = tmp_path_factory.mktemp("sim1")
    simulate_indoor(sim, seed=1, duration_s=60.0)
    t_gt, p_gt = read_trajectory(sim / "ground_truth.tum")
    start_ns = int(round((t_gt[0] + SEGMENT_START_S) * 1e9))
    _crop(sim / "sample_indoor", sim / "segment", start_ns)
    keep = np.rint(t_gt * 1e9) >= start_ns
    return sim / "segment", t_gt[keep], p_gt[keep]


def _to_map(align, poses: np.ndarray) -> np.ndarray:
    """Ground-truth poses into the map frame (the inverse of the mapping run's alignment)."""
    theta, t = align
    c, s = math.cos(-theta), math.sin(-theta)
    xy = poses[:, :2] - t
    out = poses.copy()
    out[:, 0], out[:, 1] = c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]
    out[:, 2] = wrap_angle(poses[:, 2] - theta)
    return out


def _localize(out: Path, bag: Path, map_yaml: Path, domain: int, initial_pose: str | None = None):
    overrides = _localize_overrides(str(map_yaml), initial_pose)
    return run(str(bag), out, progress=False, domain_id=domain, overrides=overrides)


def _errors(out: Path, align, t_gt: np.ndarray, p_gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per scan: position error (m) and heading error (deg) against the ground truth."""
    t_est, p_est = read_trajectory(out / "trajectory.tum")
    assert np.array_equal(np.rint(t_est * 1e9), np.rint(t_gt * 1e9))
    truth = _to_map(align, p_gt)
    return (np.hypot(*(p_est[:, :2] - truth[:, :2]).T), np.degrees(np.abs(wrap_angle(p_est[:, 2] - truth[:, 2]))))


def _convergence(err_m: np.ndarray, err_deg: np.ndarray) -> int:
    """The first scan from which every pose is within CONVERGED_M / CONVERGED_DEG."""
    bad = np.flatnonzero((err_m > CONVERGED_M) | (err_deg > CONVERGED_DEG))
    return 0 if bad.size == 0 else int(bad[-1]) + 1


def _check(out: Path, res, align, t_gt, p_gt, what: str, init: str) -> None:
    s = res.summary
    assert s["complete"] and s["scans_processed"] == len(t_gt) and s["scans_dropped"] == 0
    loc = s["localization"]
    assert loc["last_init"] == init and loc["initialisations"] == 1 and loc["particles"] == s["particles"]
    err_m, err_deg = _errors(out, align, t_gt, p_gt)
    k = _convergence(err_m, err_deg)
    rmse = float(np.sqrt(np.mean(err_m[k:] ** 2)))
    print(
        f"\n{what}: converged after {k} scans ({k / 10:.1f} s; first scan error {err_m[0]:.3f} m "
        f"{err_deg[0]:.1f} deg), ATE after convergence rmse {rmse:.4f} m max {err_m[k:].max():.4f} m, "
        f"heading rmse {np.sqrt(np.mean(err_deg[k:] ** 2)):.2f} deg, first correction {loc['init_seconds']:.2f} s, "
        f"wall {s['wall_time_s']:.1f} s"
    )
    assert k <= MAX_SCANS_TO_CONVERGE, (k, err_m[: k + 5], err_deg[: k + 5])
    assert rmse < 0.03 and err_m[k:].max() < CONVERGED_M


def test_localize_from_a_wrong_initial_guess(mapped, second_pass, tmp_path, module_ros_domain):
    map_yaml, align = mapped
    bag, t_gt, p_gt = second_pass
    truth = _to_map(align, p_gt[:1])[0]
    guess = truth + np.array([0.8, -0.6, math.radians(30.0)])  # 1 m and 30 deg off
    assert math.hypot(*(guess - truth)[:2]) == pytest.approx(1.0)
    res = _localize(tmp_path, bag, map_yaml, module_ros_domain, ",".join(f"{v:.6f}" for v in guess))
    _check(tmp_path, res, align, t_gt, p_gt, "initial guess 1 m / 30 deg off", "initial pose")


def test_localize_without_a_guess_and_the_map_is_unchanged(mapped, second_pass, tmp_path, module_ros_domain):
    map_yaml, align = mapped
    bag, t_gt, p_gt = second_pass
    res = _localize(tmp_path, bag, map_yaml, module_ros_domain)
    _check(tmp_path, res, align, t_gt, p_gt, "global initialisation", "global")
    # the map a user gets back is the map given, byte for byte: map.pgm and every /map recorded
    assert (tmp_path / "map.pgm").read_bytes() == map_yaml.with_name("map.pgm").read_bytes()
    occ, res_m, origin = read_map(map_yaml)
    maps = [raw for topic, _, _, raw in read_bag(tmp_path / "result.mcap", ["/map"])]
    assert maps
    from nav_msgs.msg import OccupancyGrid
    from rclpy.serialization import deserialize_message

    for raw in maps:
        m = deserialize_message(raw, OccupancyGrid)
        assert (m.info.width, m.info.height) == (occ.shape[1], occ.shape[0])
        assert m.info.resolution == pytest.approx(res_m)
        assert (m.info.origin.position.x, m.info.origin.position.y) == pytest.approx(tuple(origin[:2]))
        assert np.frombuffer(bytes(m.data), np.int8).tobytes() == occ.tobytes()


def _initialpose(pose: np.ndarray):
    """What rviz2's "2D Pose Estimate" sends: map frame, its default spread (0.5 m, 15 deg)."""
    from geometry_msgs.msg import PoseWithCovarianceStamped

    from pf_slam_nodes.core.geometry import yaw_to_quat

    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = "map"
    msg.pose.pose.position.x, msg.pose.pose.position.y = float(pose[0]), float(pose[1])
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = yaw_to_quat(float(pose[2]))
    cov = np.zeros((6, 6))
    cov[0, 0] = cov[1, 1] = 0.25
    cov[5, 5] = 0.06853891945200942
    msg.pose.covariance = cov.reshape(-1).tolist()
    return msg


def _graph_on_served_map(ros_domain: int, correlator: dict, first_guess=None, later: tuple | None = None):
    """The sample bag through the in-process graph in mode localization, the ground-truth map
    served on a latched /map by an observer (as nav2's map_server; the mapper has no map_file),
    /initialpose sent before the replay starts (`first_guess`) and/or, `later` = (k, pose), once
    k scans are posed. Returns (poses by stamp, particle clouds, correlator node, mapper node)."""
    import rclpy
    from conftest import spin_until
    from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped
    from nav_msgs.msg import OccupancyGrid
    from rclpy.executors import SingleThreadedExecutor

    from pf_slam_nodes.graph import NODE_NAMES, _make_node, detect_inputs, load_params, node_params
    from pf_slam_nodes.nodes.common import announce_when_matched
    from pf_slam_nodes.ros import convert, qos

    layers = [
        detect_inputs(str(SAMPLE), bag_info(str(SAMPLE))),
        load_params(ROOT / "ros2_ws/src/pf_slam_nodes/config/sim_indoor.yaml"),
        {"correlator": {"mode": "localization", **correlator}, "mapper": {"mode": "localization"}},
        {
            "bag_replay": {"bag": str(SAMPLE), "wait_for": ["predictor", "correlator", "mapper", "observer"]},
            # as pf-slam run: the replay's stall, not a count of waiting scans, says odometry will not come
            "predictor": {"odom_wait_scans": 0, "stamp_offset_s": 0.0},
        },
    ]
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    try:
        ex = SingleThreadedExecutor(context=ctx)
        obs = rclpy.create_node("observer", context=ctx)
        clouds: list[PoseArray] = []
        poses: dict[int, PoseStamped] = {}
        pub_init = obs.create_publisher(PoseWithCovarianceStamped, "initialpose", 5)  # as rviz2: reliable, volatile

        def on_pose(m: PoseStamped) -> None:
            poses[convert.stamp_to_ns(m.header.stamp)] = m
            if later is not None and len(poses) == later[0]:
                pub_init.publish(_initialpose(later[1]))

        sub_cloud = obs.create_subscription(PoseArray, "particlecloud", clouds.append, qos.outputs(1000))
        sub_pose = obs.create_subscription(PoseStamped, "pose", on_pose, qos.pipeline())
        occ, res, origin = read_map(SAMPLE.parent / "ground_truth_map.yaml")
        pub_map = obs.create_publisher(OccupancyGrid, "map", qos.latched())
        pub_map.publish(convert.grid_to_msg(occ, res, origin[:2], 0, "map"))
        ex.add_node(obs)
        nodes = {n: _make_node(n, ctx, node_params(layers, n)) for n in NODE_NAMES}
        for n in nodes.values():
            ex.add_node(n)
        corr, mapper = nodes["correlator"], nodes["mapper"]
        assert spin_until(ex, lambda: pub_init.get_subscription_count() >= 1, 30.0)
        if first_guess is not None:
            pub_init.publish(_initialpose(first_guess))
            assert spin_until(
                ex, lambda: corr.stage.pending_init is not None and corr.stage.pending_init[0] is not None, 10.0
            )
        announce_when_matched(obs, [(sub_cloud, 1), (sub_pose, 1)])  # now the replay may start
        assert spin_until(ex, lambda: mapper.last_index == 599 and mapper.total is None, 120.0)
        spin_until(ex, lambda: len(poses) == 600 and len(clouds) == corr.corrections_sent, 10.0)
    finally:
        rclpy.shutdown(context=ctx)
    assert len(poses) == 600 and len(clouds) == corr.corrections_sent > 100
    assert mapper.stage.grid is None  # nothing integrated
    return poses, clouds, corr, mapper


def _pose_errors(poses: dict) -> np.ndarray:
    """(600, 2): position (m) and heading (rad) error of every /pose against the ground truth
    (the simulator's map is in the ground truth's frame)."""
    from pf_slam_nodes.core.geometry import quat_to_yaw

    t_gt, p_gt = read_trajectory(SAMPLE.parent / "ground_truth.tum")
    out = []
    for k, stamp in enumerate(sorted(poses)):
        p = poses[stamp].pose
        yaw = quat_to_yaw(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)
        out.append(
            (math.hypot(p.position.x - p_gt[k, 0], p.position.y - p_gt[k, 1]), abs(wrap_angle(yaw - p_gt[k, 2])))
        )
    return np.array(out)


def test_initialpose_and_particlecloud_on_a_served_map(ros_domain):
    """rviz2's "2D Pose Estimate" (1 m, 30 deg off) before the drive, the map from another
    node's /map: the first /particlecloud lies around that guess (a global start could be anywhere
    on the floor), later ones hold the converged filter.num_particles, /pose ends on the truth."""
    t_gt, p_gt = read_trajectory(SAMPLE.parent / "ground_truth.tum")
    guess = p_gt[0] + np.array([-0.6, 0.8, math.radians(-30.0)])
    poses, clouds, corr, _ = _graph_on_served_map(ros_domain, {}, first_guess=guess)
    assert corr.stage.localization_status(30)["last_init"] == "initial pose"  # not the global start
    first = np.array([[p.position.x, p.position.y] for p in clouds[0].poses])
    assert clouds[0].header.frame_id == "map" and len(first) in (30, 2000)
    assert np.hypot(*(first - guess[:2]).T).max() < 3.0  # around the guess, not over the floor (20 x 15 m)
    assert {len(c.poses) for c in clouds[-100:]} == {30}  # converged: filter.num_particles
    err = _pose_errors(poses)
    assert err[-1, 0] < 0.05 and err[-1, 1] < math.radians(1.0)


def test_initialpose_during_the_run_relocalizes(ros_domain):
    """A confident wrong start (where the robot is 15 s later, in another room; 0.1 m spread)
    tracks the wrong place; an /initialpose at the true pose, sent once 300 scans are posed, puts
    the filter back on the truth."""
    t_gt, p_gt = read_trajectory(SAMPLE.parent / "ground_truth.tum")
    wrong = {
        "localization.use_initial_pose": True,
        "localization.initial_pose_x_m": float(p_gt[150, 0]),
        "localization.initial_pose_y_m": float(p_gt[150, 1]),
        "localization.initial_pose_yaw_rad": float(p_gt[150, 2]),
        "localization.initial_sigma_xy_m": 0.1,
        "localization.initial_sigma_yaw_rad": 0.05,
    }
    poses, _, corr, _ = _graph_on_served_map(ros_domain, wrong, later=(300, p_gt[299]))
    err = _pose_errors(poses)
    print(
        f"\nbefore the /initialpose: median error {np.median(err[:300, 0]):.2f} m; "
        f"from 20 scans after it: max {err[320:, 0].max():.3f} m"
    )
    assert np.median(err[:300, 0]) > 1.0  # lost
    assert err[320:, 0].max() < 0.05 and err[320:, 1].max() < math.radians(1.0)
    st = corr.stage.localization_status(30)
    assert st["initialisations"] == 2 and st["last_init"] == "initial pose"
