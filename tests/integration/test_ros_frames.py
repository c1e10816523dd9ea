"""What a ROS user sees of a running graph: REP-105 transforms that agree with /pose, frame ids
from parameters, and a latched trinary /map that a node started after the run still receives."""

from __future__ import annotations

import pathlib
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from conftest import spin_until  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from pf_slam_nodes.core.geometry import quat_to_yaw  # noqa: E402
from pf_slam_nodes.core.motion import compose  # noqa: E402
from pf_slam_nodes.graph import NODE_NAMES, _make_node, detect_inputs, load_params, node_params  # noqa: E402
from pf_slam_nodes.io.bag import bag_info  # noqa: E402
from pf_slam_nodes.io.mapfile import trinary  # noqa: E402
from pf_slam_nodes.nodes.common import announce_when_matched  # noqa: E402
from pf_slam_nodes.ros import convert, qos  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "bags" / "sample_indoor"
PARAMS = ROOT / "ros2_ws/src/pf_slam_nodes/config/sim_indoor.yaml"
FRAMES = {"map_frame": "world", "odom_frame": "wheel_odom", "base_frame": "robot"}


def _xy_yaw(tr) -> np.ndarray:
    r = tr.transform.rotation
    return np.array([tr.transform.translation.x, tr.transform.translation.y, float(quat_to_yaw(r.x, r.y, r.z, r.w))])


def test_rep105_transforms_and_late_map_subscriber(ros_domain):
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import MapMetaData, OccupancyGrid, Path
    from tf2_msgs.msg import TFMessage

    info = bag_info(str(SAMPLE))
    layers = [
        detect_inputs(str(SAMPLE), info),
        load_params(PARAMS),
        {
            "/**": dict(FRAMES),
            "mapper": {"publish_sensor_tf": True},
            "bag_replay": {"bag": str(SAMPLE), "wait_for": ["predictor", "correlator", "mapper", "observer"]},
        },
    ]
    assert layers[0]["mapper"] == {"publish_sensor_tf": False}  # the bag's /tf_static has the laser
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    late_ctx = None
    try:
        ex = SingleThreadedExecutor(context=ctx)
        obs = rclpy.create_node("observer", context=ctx)
        poses, tf, tf_static, paths = {}, [], [], []
        needs = [
            (
                obs.create_subscription(
                    PoseStamped,
                    "pose",
                    lambda m: poses.__setitem__(convert.stamp_to_ns(m.header.stamp), m),
                    qos.pipeline(),
                ),
                1,
            ),
            (obs.create_subscription(TFMessage, "/tf", lambda m: tf.extend(m.transforms), qos.outputs(10000)), 2),
            (obs.create_subscription(Path, "path", paths.append, qos.outputs()), 1),
        ]
        announce_when_matched(obs, needs)  # the replay waits for "observer" too
        obs.create_subscription(TFMessage, "/tf_static", lambda m: tf_static.extend(m.transforms), qos.latched(5))
        ex.add_node(obs)
        nodes = {n: _make_node(n, ctx, node_params(layers, n)) for n in NODE_NAMES}
        for n in nodes.values():
            ex.add_node(n)
        mapper = nodes["mapper"]
        assert spin_until(ex, lambda: mapper.last_index == 599 and mapper.total is None, 120.0)

        def all_in() -> bool:  # every scan's odom -> base, and map -> odom up to the last scan
            return (
                len(poses) == 600
                and sum(t.child_frame_id == "robot" for t in tf) == 600
                and any(
                    t.child_frame_id == "wheel_odom" and convert.stamp_to_ns(t.header.stamp) == max(poses) for t in tf
                )
            )

        spin_until(ex, all_in, 5.0)
        assert len(poses) == 600 and {m.header.frame_id for m in poses.values()} == {"world"}
        assert paths and paths[-1].header.frame_id == "world"

        # map -> odom (mapper, at corrections) composed with odom -> base (predictor, every scan) is /pose
        odom_base = {
            convert.stamp_to_ns(t.header.stamp): _xy_yaw(t)
            for t in tf
            if (t.header.frame_id, t.child_frame_id) == ("wheel_odom", "robot")
        }
        map_odom = sorted(
            (convert.stamp_to_ns(t.header.stamp), _xy_yaw(t))
            for t in tf
            if (t.header.frame_id, t.child_frame_id) == ("world", "wheel_odom")
        )
        assert len(odom_base) == 600 and set(odom_base) == set(poses)
        assert 50 < len(map_odom) < 600  # one per correction (+ the end of the run)
        stamps = np.array([s for s, _ in map_odom])
        checked = 0
        for stamp, msg in poses.items():
            k = np.searchsorted(stamps, stamp, side="right") - 1
            if k < 0:
                continue
            p = msg.pose
            pose = np.array(
                [
                    p.position.x,
                    p.position.y,
                    float(quat_to_yaw(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)),
                ]
            )
            est = compose(map_odom[k][1], odom_base[stamp])
            assert np.allclose(est[:2], pose[:2], atol=1e-6), (stamp, est, pose)
            assert abs(np.angle(np.exp(1j * (est[2] - pose[2])))) < 1e-6
            checked += 1
        assert checked >= 595
        # sensor mounts: the bag's /tf_static (replayed) and the mapper's from the parameters
        pairs = {(t.header.frame_id, t.child_frame_id) for t in tf_static}
        assert {("base_link", "laser"), ("robot", "laser")} <= pairs

        # /map: RELIABLE + TRANSIENT_LOCAL, depth 1, trinary; a fresh node started now still gets it
        (pub,) = obs.get_publishers_info_by_topic("/map")  # as discovered (depth is not announced)
        assert (pub.qos_profile.reliability, pub.qos_profile.durability) == (
            qos.latched().reliability,
            qos.latched().durability,
        )
        assert mapper.pub_map.qos_profile.depth == mapper.pub_meta.qos_profile.depth == 1
        occ, res, origin = mapper.stage.map_occupancy()
        expected = trinary(occ)
        time.sleep(0.5)  # the map went out before the late node exists
        late_ctx = rclpy.Context()
        rclpy.init(context=late_ctx, domain_id=ros_domain)
        late = rclpy.create_node("late_map_saver", context=late_ctx)
        got: dict = {}
        late.create_subscription(OccupancyGrid, "map", lambda m: got.__setitem__("map", m), qos.latched())
        late.create_subscription(MapMetaData, "map_metadata", lambda m: got.__setitem__("meta", m), qos.latched())
        late_ex = SingleThreadedExecutor(context=late_ctx)
        late_ex.add_node(late)
        deadline = time.monotonic() + 10.0
        while len(got) < 2 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
            late_ex.spin_once(timeout_sec=0.01)
        assert set(got) == {"map", "meta"}
        data, r, o = convert.msg_to_grid(got["map"])
        assert got["map"].header.frame_id == "world" and abs(r - res) < 1e-6 and np.allclose(o, origin)
        assert set(np.unique(data).tolist()) == {-1, 0, 100}
        assert np.array_equal(data, expected)
        assert (got["meta"].width, got["meta"].height) == (data.shape[1], data.shape[0])
        late.destroy_node()
        for n in [*nodes.values(), obs]:
            n.destroy_node()
    finally:
        for c in (late_ctx, ctx):
            if c is not None and c.ok():
                rclpy.shutdown(context=c)


def test_run_records_result_mcap(tmp_path, ros_domain):
    """`pf-slam run` writes result.mcap: every scan's /pose, the /map the run ended with, the
    inputs and transforms; read back with rosbags."""
    from pf_slam_nodes.graph import run
    from pf_slam_nodes.io.bag import deserialize, read_bag
    from pf_slam_nodes.io.mapfile import read_map
    from pf_slam_nodes.io.trajectory import read_trajectory

    res = run(str(SAMPLE), tmp_path, params_file=str(PARAMS), progress=False, domain_id=ros_domain, snapshot_every=0)
    msgs: dict[str, list] = {}
    for topic, msgtype, t, raw in read_bag(tmp_path / "result.mcap"):
        msgs.setdefault(topic, []).append((t, deserialize(raw, msgtype)))
    assert res.summary["result_mcap"]["messages"] == {k: len(v) for k, v in msgs.items()}
    # one /pose per processed scan, the poses of trajectory.tum, stamped with the scans' stamps
    t_tum, p_tum = read_trajectory(tmp_path / "trajectory.tum")
    poses = msgs["/pose"]
    assert len(poses) == res.summary["scans_processed"] == 600 == len(msgs["/scan"])
    assert [t for t, _ in poses] == [convert.stamp_to_ns(m.header.stamp) for _, m in poses]
    assert [t for t, _ in poses] == [t for t, _ in msgs["/scan"]]
    xy = np.array([[m.pose.position.x, m.pose.position.y] for _, m in poses])
    assert np.allclose(xy, p_tum[:, :2], atol=1e-6) and np.allclose(np.array([t for t, _ in poses]) / 1e9, t_tum)
    # the maps: a few during the run (throttled), the last = map.pgm, at the last scan's stamp
    maps = msgs["/map"]
    assert 2 <= len(maps) <= 25
    last = maps[-1][1]
    occ, r, o = read_map(tmp_path / "map.yaml")
    data = np.asarray(last.data, dtype=np.int8).reshape(last.info.height, last.info.width)
    assert np.array_equal(data, occ) and abs(last.info.resolution - r) < 1e-6
    assert maps[-1][0] == poses[-1][0]
    # REP-105 transforms and the path
    pairs = {(tr.header.frame_id, tr.child_frame_id) for _, m in msgs["/tf"] for tr in m.transforms}
    assert pairs == {("map", "odom"), ("odom", "base_link")}
    assert ("base_link", "laser") in {
        (tr.header.frame_id, tr.child_frame_id) for _, m in msgs["/tf_static"] for tr in m.transforms
    }
    n_corr = res.summary["scans_corrected"]
    assert len(msgs["/path"][-1][1].poses) in (n_corr, n_corr + 1)  # (+ the end-of-run pose)
