"""The texture node over real rclpy: the real KAIST stereo pair in, a texture in /map geometry out."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
cv2 = pytest.importorskip("cv2")
from conftest import spin_until  # noqa: E402
from geometry_msgs.msg import PoseStamped, TransformStamped  # noqa: E402
from nav_msgs.msg import MapMetaData, OccupancyGrid  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from pf_slam_nodes.core.geometry import matrix_to_quat, nearest_rotation  # noqa: E402
from pf_slam_nodes.io.calib import parse_extrinsic, read_camera_yaml  # noqa: E402
from pf_slam_nodes.nodes.texture import TextureNode, image_array  # noqa: E402
from pf_slam_nodes.ros import convert, qos  # noqa: E402

T0 = 1_700_000_000_000_000_000
MAP_RES, MAP_W, MAP_H, MAP_ORIGIN = 0.2, 200, 150, (-5.0, -15.0)


@pytest.fixture(scope="module")
def kaist(data_dir: Path) -> Path:
    d = data_dir / "kaist_sample"
    if not (d / "stereo" / "image_left.png").is_file():
        pytest.skip(f"{d}/stereo: real stereo pair not available")
    return d


def _info(cam: dict, stamp: int, frame: str) -> CameraInfo:
    m = CameraInfo()
    m.header.stamp = convert.ns_to_stamp(stamp)
    m.header.frame_id = frame
    m.width, m.height = cam["width"], cam["height"]
    m.distortion_model = cam["distortion_model"]
    m.d = [float(v) for v in cam["D"]]
    m.k = [float(v) for v in cam["K"].ravel()]
    m.r = [float(v) for v in cam["R"].ravel()]
    m.p = [float(v) for v in cam["P"].ravel()]
    return m


def _image(raw: np.ndarray, stamp: int, frame: str) -> Image:
    m = Image()
    m.header.stamp = convert.ns_to_stamp(stamp)
    m.header.frame_id = frame
    m.height, m.width = raw.shape
    m.encoding = "bayer_rggb8"
    m.step = raw.shape[1]
    m.data = raw.tobytes()
    return m


class Feeder:
    """Publishes what the texture node needs, as bag_replay + correlator + mapper would."""

    def __init__(self, ctx, kaist: Path) -> None:
        self.node = rclpy.create_node("texture_feeder", context=ctx)
        p = kaist / "param"
        self.left_cam = read_camera_yaml(p / "left_camera.yaml")
        self.right_cam = read_camera_yaml(p / "right_camera.yaml")
        rot, t, _ = parse_extrinsic(p / "Vehicle2Stereo.txt")
        self.mount = (nearest_rotation(rot), t)
        self.left = cv2.imread(str(kaist / "stereo" / "image_left.png"), cv2.IMREAD_UNCHANGED)
        self.right = cv2.imread(str(kaist / "stereo" / "image_right.png"), cv2.IMREAD_UNCHANGED)
        n = self.node
        self.pub = {
            "left": n.create_publisher(Image, "/stereo/left/image_raw", qos.pipeline(100)),
            "right": n.create_publisher(Image, "/stereo/right/image_raw", qos.pipeline(100)),
            "left_info": n.create_publisher(CameraInfo, "/stereo/left/camera_info", qos.pipeline(10)),
            "right_info": n.create_publisher(CameraInfo, "/stereo/right/camera_info", qos.pipeline(10)),
            "tf": n.create_publisher(TFMessage, "/tf_static", qos.latched()),
            "pose": n.create_publisher(PoseStamped, "pose", qos.pipeline()),
            "map": n.create_publisher(OccupancyGrid, "map", qos.latched()),
            "map_metadata": n.create_publisher(MapMetaData, "map_metadata", qos.latched()),
        }
        self.textures: list[Image] = []
        self.status: list[dict] = []
        n.create_subscription(Image, "texture", self.textures.append, qos.latched())
        import json

        n.create_subscription(
            String, "pf_slam/texture_status", lambda m: self.status.append(json.loads(m.data)), qos.latched()
        )

    def matched(self) -> bool:  # the node listens to map or map_metadata, not both
        return (
            all(p.get_subscription_count() > 0 for k, p in self.pub.items() if k not in ("map", "map_metadata"))
            and self.pub["map"].get_subscription_count() + self.pub["map_metadata"].get_subscription_count() > 0
        )

    def publish_static(self, quat=None) -> None:
        tr = TransformStamped()
        tr.header.stamp = convert.ns_to_stamp(T0)
        tr.header.frame_id, tr.child_frame_id = "base_link", "stereo_left"
        tr.transform.translation.x, tr.transform.translation.y, tr.transform.translation.z = (
            float(v) for v in self.mount[1]
        )
        q = matrix_to_quat(self.mount[0]) if quat is None else quat
        r = tr.transform.rotation
        r.x, r.y, r.z, r.w = q
        self.pub["tf"].publish(TFMessage(transforms=[tr]))
        self.pub["left_info"].publish(_info(self.left_cam, T0, "stereo_left"))
        self.pub["right_info"].publish(_info(self.right_cam, T0, "stereo_right"))
        occ = np.full((MAP_H, MAP_W), -1, dtype=np.int8)
        grid = convert.grid_to_msg(occ, MAP_RES, MAP_ORIGIN, T0, "map")
        self.pub["map"].publish(grid)
        self.pub["map_metadata"].publish(grid.info)

    def publish_poses(self, t_from: int, t_to: int, speed: float = 0.0) -> None:
        for t in range(t_from, t_to + 1, 10_000_000):
            x = speed * (t - T0) / 1e9
            self.pub["pose"].publish(convert.pose_stamped(np.array([x, 0.0, 0.0]), t, "map"))

    def publish_pair(self, stamp: int) -> None:
        self.pub["left"].publish(_image(self.left, stamp, "stereo_left"))
        self.pub["right"].publish(_image(self.right, stamp, "stereo_right"))

    def destroy(self) -> None:
        self.node.destroy_node()


def _make(ctx, **params) -> TextureNode:
    base = {"publish_period_s": 0.2, "texture.rectify": "yes"}  # skip the ORB check: faster
    base.update(params)
    return TextureNode(context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in base.items()])


@contextlib.contextmanager
def _graph(ctx, kaist: Path, **params):
    """The texture node (``params``) and a Feeder on one executor; all destroyed afterwards."""
    node = _make(ctx, **params)
    feed = Feeder(ctx, kaist)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(feed.node)
    try:
        yield node, feed, ex
    finally:
        ex.shutdown()
        node.destroy_node()
        feed.destroy()


def test_image_array_handles_row_padding():
    msg = Image()
    msg.height, msg.width, msg.step, msg.encoding = 2, 3, 4, "mono8"
    msg.data = bytes([1, 2, 3, 0, 4, 5, 6, 0])
    np.testing.assert_array_equal(image_array(msg), [[1, 2, 3], [4, 5, 6]])


def test_texture_in_map_geometry(ros_context, kaist):
    ctx = ros_context
    with _graph(ctx, kaist) as (node, feed, ex):
        assert spin_until(ex, feed.matched, 10)
        feed.publish_static()
        stamps = [T0 + 100_000_000, T0 + 200_000_000]
        feed.publish_poses(T0, T0 + 300_000_000)  # parked car at the origin
        for k, s in enumerate(stamps):  # one at a time: a loaded machine must not skip one
            feed.publish_pair(s)
            assert spin_until(ex, lambda: node.frames_processed == k + 1, 30), node.counters()
        assert spin_until(ex, lambda: any(m.header.stamp == convert.ns_to_stamp(stamps[-1]) for m in feed.textures), 10)
        msg = [m for m in feed.textures if m.header.stamp == convert.ns_to_stamp(stamps[-1])][-1]
        assert (msg.width, msg.height, msg.encoding, msg.header.frame_id) == (MAP_W, MAP_H, "rgb8", "map")
        rgb = image_array(msg)
        coloured = rgb.any(axis=2)
        rows, cols = np.nonzero(coloured)
        # the road ahead: 3..20 m in front of the camera (x = 1.64 m), |y| <= 12 m
        x = MAP_ORIGIN[0] + (cols + 0.5) * MAP_RES
        y = MAP_ORIGIN[1] + (rows + 0.5) * MAP_RES
        assert coloured.sum() > 2000
        assert x.min() > 1.64 + 3.0 - MAP_RES and x.max() < 1.64 + 20.0 + MAP_RES
        assert np.abs(y).max() <= 12.5
        # dark asphalt (median grey ~47) with white markings (~1 % of the cells above 130)
        lum = rgb[coloured].mean(axis=1)
        assert np.median(lum) < 80 and (lum > 120).sum() > 20
        c = node.counters()
        assert (c["frames_received"], c["frames_processed"], c["frames_skipped"]) == (2, 2, 0)


def _coloured_xy(img: Image) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = np.nonzero(image_array(img).any(axis=2))
    return MAP_ORIGIN[0] + (cols + 0.5) * MAP_RES, MAP_ORIGIN[1] + (rows + 0.5) * MAP_RES


def test_final_texture_is_placed_on_the_corrected_trajectory(ros_context, kaist):
    """A closed loop corrects the trajectory after the pairs were textured: with
    await_trajectory the final texture waits for pf_slam/trajectory and moves with it."""
    from nav_msgs.msg import Path as PathMsg

    from pf_slam_interfaces.msg import ReplayStatus
    from pf_slam_nodes.ros import cdr, topics

    ctx = ros_context
    with _graph(ctx, kaist, await_trajectory=True, trajectory_timeout_s=30.0, final_idle_s=0.5) as (node, feed, ex):
        pub_traj = feed.node.create_publisher(PathMsg, topics.TRAJECTORY, qos.latched())
        pub_done = feed.node.create_publisher(ReplayStatus, topics.REPLAY_STATUS, qos.latched())
        assert spin_until(ex, feed.matched, 10)
        feed.publish_static()
        feed.publish_poses(T0, T0 + 300_000_000)  # parked at the origin, as the filter saw it
        feed.publish_pair(T0 + 100_000_000)
        assert spin_until(ex, lambda: node.frames_processed == 1, 30), node.counters()
        before = node.publish_texture()
        pub_done.publish(ReplayStatus(done=True, topics=["/scan"], counts=[31]))
        for _ in range(10):  # the end of the bag alone does not make the texture final
            ex.spin_once(timeout_sec=0.1)
        assert not node.counters()["final"]
        # the corrected trajectory: 2 m further along x, 0.6 m to the left
        st = np.arange(T0, T0 + 300_000_001, 10_000_000, dtype=np.int64)
        poses = np.tile([2.0, 0.6, 0.0], (len(st), 1))
        pub_traj.publish(cdr.path_bytes(st, poses, int(st[-1]), "map"))
        assert spin_until(ex, lambda: bool(feed.status) and feed.status[-1]["final"], 30), node.counters()
        c = node.counters()
        assert c["replaced"]["pairs_moved"] == 1 and abs(c["replaced"]["shift_median_m"] - np.hypot(2.0, 0.6)) < 1e-3
        assert c["kept_memory_mb"] > 0
        after = node.publish_texture()
        (xb, yb), (xa, ya) = _coloured_xy(before), _coloured_xy(after)
        assert abs(len(xa) - len(xb)) < 0.05 * len(xb)  # the same road, moved (0.2 m cells)
        for a, b, d in ((xa, xb, 2.0), (ya, yb, 0.6)):
            assert abs(np.median(a) - np.median(b) - d) < 0.15
            assert abs(a.min() - b.min() - d) < 0.25 and abs(a.max() - b.max() - d) < 0.25


def test_live_texture_moves_with_a_closed_loop_and_the_final_one_waits(ros_context, kaist):
    """A closed loop during the run (pf_slam/loop_trajectory) places the textured pairs again at
    once, without making the texture final; the end's pf_slam/trajectory still decides where
    the final texture lies."""
    from nav_msgs.msg import Path as PathMsg

    from pf_slam_interfaces.msg import ReplayStatus
    from pf_slam_nodes.ros import cdr, topics

    ctx = ros_context
    with _graph(ctx, kaist, await_trajectory=True, trajectory_timeout_s=30.0, final_idle_s=0.5) as (node, feed, ex):
        pub_loop = feed.node.create_publisher(PathMsg, topics.LOOP_TRAJECTORY, qos.latched())
        pub_traj = feed.node.create_publisher(PathMsg, topics.TRAJECTORY, qos.latched())
        pub_done = feed.node.create_publisher(ReplayStatus, topics.REPLAY_STATUS, qos.latched())
        assert spin_until(ex, feed.matched, 10)
        feed.publish_static()
        feed.publish_poses(T0, T0 + 300_000_000)
        feed.publish_pair(T0 + 100_000_000)
        assert spin_until(ex, lambda: node.frames_processed == 1, 30), node.counters()
        before = node.publish_texture()
        st = np.arange(T0, T0 + 300_000_001, 10_000_000, dtype=np.int64)

        def moved(offset) -> None:
            (xb, yb), (xa, ya) = _coloured_xy(before), _coloured_xy(node.publish_texture())
            for a, b, d in ((xa, xb, offset[0]), (ya, yb, offset[1])):
                assert abs(np.median(a) - np.median(b) - d) < 0.15

        pub_loop.publish(cdr.path_bytes(st, np.tile([1.0, -0.4, 0.0], (len(st), 1)), int(st[-1]), "map"))
        assert spin_until(ex, lambda: node.counters()["loop_replacements"] == 1, 30), node.counters()
        assert not node.counters()["final"] and node.counters()["replaced"]["pairs_moved"] == 1
        moved((1.0, -0.4))
        pub_done.publish(ReplayStatus(done=True, topics=["/scan"], counts=[31]))
        for _ in range(10):  # a loop's placement is not the final one
            ex.spin_once(timeout_sec=0.1)
        assert not node.counters()["final"]
        pub_traj.publish(cdr.path_bytes(st, np.tile([2.0, 0.6, 0.0], (len(st), 1)), int(st[-1]), "map"))
        assert spin_until(ex, lambda: bool(feed.status) and feed.status[-1]["final"], 30), node.counters()
        c = node.counters()
        assert c["loop_replacements"] == 1 and abs(c["replaced"]["shift_median_m"] - np.hypot(1.0, 1.0)) < 1e-3
        moved((2.0, 0.6))
        # a loop's trajectory delivered after the final one (topics are not ordered) moves nothing
        pub_loop.publish(cdr.path_bytes(st, np.tile([5.0, 5.0, 0.0], (len(st), 1)), int(st[-1]), "map"))
        for _ in range(20):
            ex.spin_once(timeout_sec=0.05)
        assert node.counters()["loop_replacements"] == 1
        moved((2.0, 0.6))


def test_flooded_pairs_are_skipped_not_queued(ros_context, kaist):
    ctx = ros_context
    with _graph(ctx, kaist, queue_depth=1, max_pending_pairs=20, use_map_metadata=False) as (node, feed, ex):
        n = 10
        assert spin_until(ex, feed.matched, 10)
        feed.publish_static()
        feed.publish_poses(T0, T0 + 2_000_000_000, speed=5.0)
        assert spin_until(ex, lambda: node.rig is not None and len(node._pose_t) > 150, 10)
        for k in range(n):  # 10 pairs at once: 100 fps, far above what one core processes
            feed.publish_pair(T0 + 100_000_000 * (k + 1))
        done = lambda: (
            node.frames_received == n and node.frames_processed + node.frames_skipped + node.frames_dropped == n
        )  # noqa: E731
        assert spin_until(ex, done, 20), node.counters()
        c = node.counters()
        assert c["frames_skipped"] >= 1 and c["frames_processed"] >= 1 and c["frames_dropped"] == 0
        assert c["frames_processed"] < n
        # an image older than every buffered pose is dropped, not processed
        feed.publish_pair(T0 - 500_000_000)
        assert spin_until(ex, lambda: node.frames_dropped == 1, 10), node.counters()
        img = node.publish_texture()
        assert img is not None and (img.width, img.height) == (MAP_W, MAP_H)
        assert spin_until(ex, lambda: bool(feed.status) and feed.status[-1]["frames_dropped"] == 1, 10)


@pytest.mark.parametrize("bad", [(0.0, 0.0, 0.0, 0.0), (float("nan"), 0.0, 0.0, 1.0)])
def test_mount_rotation_without_direction_is_ignored(ros_context, kaist, bad):
    """A /tf_static rotation that is zero or not finite is no mount (it was taken as the identity
    or NaN): no rig from it, and the next good transform gives the rig."""
    ctx = ros_context
    with _graph(ctx, kaist) as (node, feed, ex):
        assert spin_until(ex, feed.matched, 10)
        feed.publish_static(quat=bad)
        assert spin_until(ex, lambda: len(node._infos) == 2, 10)
        spin_until(ex, lambda: "stereo_left" in node._tf, 1.0)  # the transform has arrived by then
        assert "stereo_left" not in node._tf and node.rig is None
        feed.publish_static()
        assert spin_until(ex, lambda: node.rig is not None, 10)
        np.testing.assert_allclose(node.rig.R_vehicle_cam, feed.mount[0], atol=1e-9)
        np.testing.assert_allclose(node.rig.t_vehicle_cam, feed.mount[1], atol=1e-12)


def test_killed_worker_process_is_a_clear_error_not_a_hang(ros_context, kaist):
    """worker: process: a worker killed under the node is logged as a texture node error; the
    pairs after it are dropped (progress goes on, so the replay is not held), the status says
    why, and the node still shuts down promptly."""
    import os
    import signal
    import time

    ctx = ros_context
    node = _make(ctx, worker="process")
    feed = Feeder(ctx, kaist)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(feed.node)
    try:
        assert node._backend.kind == "process" and node._backend.process.is_alive()
        assert spin_until(ex, feed.matched, 10)
        feed.publish_static()
        feed.publish_poses(T0, T0 + 500_000_000)
        feed.publish_pair(T0 + 100_000_000)
        assert spin_until(ex, lambda: node.frames_processed == 1, 60), node.counters()
        os.kill(node._backend.process.pid, signal.SIGKILL)
        for k in (1, 2):  # one at a time (queue_depth 1)
            feed.publish_pair(T0 + (k + 1) * 100_000_000)
            assert spin_until(ex, lambda: node.frames_dropped == k, 20), node.counters()
        c = node.counters()
        assert (c["frames_processed"], c["frames_pending"]) == (1, 0)
        assert c["worker_error"].startswith("texture node: texture worker process") and "signal 9" in c["worker_error"]
        assert node.render() is None  # the texture went with the process
        node.publish_texture()
        assert spin_until(ex, lambda: bool(feed.status) and "worker_error" in feed.status[-1], 10)
    finally:
        ex.shutdown()
        t0 = time.monotonic()
        node.destroy_node()
        assert time.monotonic() - t0 < 5.0
        feed.destroy()


def test_destroy_stops_the_worker_process(ros_context):
    node = _make(ros_context, worker="process")
    proc = node._backend.process
    assert proc.is_alive()
    node.destroy_node()
    assert not proc.is_alive() and proc.exitcode == 0


def test_unknown_worker_is_refused(ros_context):
    with pytest.raises(ValueError, match="'worker' must be 'process' or 'thread'"):
        _make(ros_context, worker="fork")
