"""texture: colours the map's floor from the stereo camera (core: ``core/texture/``).

Subscribes
----------
* ``/stereo/left/image_raw``, ``/stereo/right/image_raw`` (``sensor_msgs/Image``; Bayer
  ``bayer_rggb8`` as ``pf-slam convert kaist`` writes, or ``rgb8`` / ``bgr8`` / ``mono8``):
  paired by exact header stamp.
* ``/stereo/left/camera_info``, ``/stereo/right/camera_info`` (``sensor_msgs/CameraInfo``): the
  first of each is the camera model (``k, d, r, p``), unless ``calibration_dir`` is set.
* ``/tf_static`` (``tf2_msgs/TFMessage``): ``base_frame -> <left image frame_id>`` is the
  camera mounting, unless ``camera_extrinsic`` or ``calibration_dir`` is set.
* ``pose`` (``geometry_msgs/PoseStamped``, map frame, one per scan): the vehicle pose, linearly
  interpolated at each image stamp; a pair waits until a pose at or after its stamp has
  arrived. A pair older than the oldest buffered pose is dropped (``frames_dropped``).
* ``map_metadata`` (``nav_msgs/MapMetaData``, latched, as the mapper publishes it with every
  ``map``), or with ``use_map_metadata:=false`` ``map`` (``nav_msgs/OccupancyGrid``): only the
  map's geometry (origin, resolution, size) is used, as the geometry of the texture.
* ``pf_slam/trajectory`` (``nav_msgs/Path``, latched; the mapper's, with loop closure: every
  scan's pose in the final, corrected frame): once the pairs it covers are textured, the texture
  is rebuilt with every kept pair at its corrected pose (core ``PairPatches``; the online poses
  of ``pose`` are the filter's, which a closed loop corrects only afterwards).
* ``pf_slam/loop_trajectory`` (``nav_msgs/Path``, latched; the mapper's at every closed loop that
  re-renders the map: every pose so far in the new frame): the same, during the run, so the live
  texture stays on the re-rendered map (counted: ``loop_replacements``); pairs after its last
  pose keep their online poses until the next one. Never taken for the final placement.
* ``pf_slam/replay_status`` (latched): at the end of a bag, once nothing is left to do (or
  ``final_idle_s`` passed without progress), the final texture is published once more and
  pairs still waiting for a pose are dropped. With ``await_trajectory`` (``pf-slam run`` sets it
  when the mapper closes loops) the final texture first waits for ``pf_slam/trajectory`` (at most
  ``trajectory_timeout_s``) and is placed on it.

Publishes
---------
* ``texture`` (``sensor_msgs/Image``, ``rgb8``, latched; on a timer every ``publish_period_s``
  and by :meth:`TextureNode.publish_texture`): the texture in the geometry of the last ``map``
  received, in the ``OccupancyGrid`` layout: ``width`` = ``map.info.width``, ``height`` =
  ``map.info.height``, **row 0 = the map's first row = lowest y** (the image looks upside
  down in an image viewer; flip the rows for north up). Pixel ``(row, col)`` is the cell whose
  centre is ``x = origin.x + (col + 0.5) * resolution``, ``y = origin.y + (row + 0.5) *
  resolution`` (map frame; the map origin has no rotation). ``(0, 0, 0)`` = no colour
  (observed cells are at least ``(1, 1, 1)``). ``header.frame_id`` = ``map_frame``,
  ``header.stamp`` = the stamp of the last pair processed. Before a map arrives the texture's
  own extent at ``texture.cell_m`` is published.
* ``texture_metadata`` (``nav_msgs/MapMetaData``, latched): that geometry (resolution, width,
  height, origin) of every ``texture`` image, published with it.
* ``pf_slam/texture_status`` (``std_msgs/String``, latched): JSON counters
  ``frames_received`` (complete pairs), ``frames_processed``, ``frames_skipped`` (replaced
  by a newer pair while queued: load), ``frames_dropped`` (no pose / calibration for them),
  ``ms_per_frame``, ``replaced`` (the last re-placement: pairs moved, median / max shift),
  ``loop_replacements``, ``final``.
* ``pf_slam/texture_progress`` (``std_msgs/UInt32MultiArray``, latched): ``[pairs finished
  (processed + skipped + dropped), pairs waiting for their pose]`` after every change: in
  ``--rate max`` the replay holds the next pair back while ``max_pairs_in_flight`` pairs are
  neither finished nor waiting for a pose, so every pair is textured (none skipped) and the
  same pairs are textured on every run.

Threading: the subscription callbacks only store messages; one worker thread feeds the pairs
(debayering, stereo matching, accumulation) and the timer's rendering to the texture engine
(nodes/texture_worker.py), so the node never blocks an executor it shares with the SLAM nodes.
With ``worker: process`` (default) the engine runs in a worker process that the node starts when
it is built and stops when it is destroyed (the per-pair numpy / OpenCV work does not wait for
the GIL beside the SLAM nodes); ``worker: thread`` runs it in the worker thread. Both give the
same texture bit for bit. A worker process that dies is logged as an error of this node once;
later pairs are dropped (``frames_dropped``, ``worker_error`` in the status) and the rest of the
graph goes on. Ready pairs wait in a queue of ``queue_depth``
(default 1): a new pair arriving while the queue is full replaces the oldest queued one
(``frames_skipped``). Pairs waiting for their pose are kept up to ``max_pending_pairs``
(older ones are skipped too).

Depth mode (``mode: depth``, an RGB-D camera: THOR's Kinect v2; `pf-slam run` chooses it for a
bag with ``/kinect/rgb/image_raw`` + ``/kinect/depth/image_raw``): ``rgb_topic`` (``rgb8`` /
``bgr8``) and ``depth_topic`` (``16UC1`` mm) paired by time (nearest within
``depth_pair_tol_s``), their ``camera_info`` (``k``), the camera's mount at the image stamp from
``/tf_static`` + ``/tf`` (the chain from the RGB optical frame up to ``base_frame``, dynamic
links such as base_link -> head interpolated at the stamp; the depth frame's ``/tf_static``
transform in the RGB frame is ``P_rgb = R P_depth + T``), and the kinematic floor height
``floor_height_m`` in the base frame (core/texture/depth.py).

Parameters: ``texture.<field>`` for every :class:`pf_slam_nodes.core.texture.TextureConfig`
field, plus the ones declared in ``__init__``.
"""

from __future__ import annotations

import array
import dataclasses
import json
import os
import threading
import time
from collections import deque

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import MapMetaData, OccupancyGrid, Path
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import String, UInt32MultiArray
from tf2_msgs.msg import TFMessage

from pf_slam_interfaces.msg import ReplayStatus

from ..core.geometry import quat_to_matrix
from ..core.mount import MountBuffer
from ..core.texture import (
    DepthCamera,
    StereoRig,
    TextureConfig,
    interpolate_poses,
)
from ..io.calib import read_stereo_rig
from ..ros import cdr, convert, qos, topics
from .common import announce_when_matched, declare_config, param, run_node, worker_param
from .texture_worker import WorkerDied, make_backend

TEXTURE = "texture"
TEXTURE_METADATA = "texture_metadata"
TEXTURE_STATUS = "pf_slam/texture_status"


def image_array(msg: Image) -> np.ndarray:
    """``sensor_msgs/Image`` (8-bit, 1 or 3 channels) -> ``(H, W)`` / ``(H, W, C)`` uint8."""
    enc = msg.encoding.lower()
    ch = 3 if enc in ("rgb8", "bgr8") else 1
    if enc not in ("rgb8", "bgr8", "mono8", "8uc1") and not enc.startswith("bayer_"):
        raise ValueError(f"unsupported image encoding {msg.encoding!r}")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    buf = np.frombuffer(msg.data, dtype=np.uint8)
    if step < w * ch or buf.size < h * step:
        raise ValueError(f"image {w} x {h} ({msg.encoding}) with step {step} has {buf.size} bytes")
    a = buf[: h * step].reshape(h, step)[:, : w * ch]
    return a.reshape(h, w, ch) if ch == 3 else a


def depth_array(msg: Image) -> np.ndarray:
    """``sensor_msgs/Image`` ``16UC1`` / ``mono16`` (mm) -> ``(H, W)`` uint16."""
    if msg.encoding.lower() not in ("16uc1", "mono16"):
        raise ValueError(f"depth image encoding {msg.encoding!r}: needs 16UC1 (mm)")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    buf = np.frombuffer(msg.data, dtype=np.uint8)
    if step < 2 * w or buf.size < h * step:
        raise ValueError(f"depth image {w} x {h} with step {step} has {buf.size} bytes")
    a = buf[: h * step].reshape(h, step)[:, : 2 * w].copy().view(">u2" if msg.is_bigendian else "<u2")
    return a.astype(np.uint16)


@dataclasses.dataclass
class _Pair:
    stamp_ns: int
    left: Image
    right: Image
    pose: np.ndarray | None = None
    mount: tuple[np.ndarray, np.ndarray] | None = None  # depth mode: the RGB camera in the base frame
    rgb_from_depth: tuple[np.ndarray, np.ndarray] | None = None  # depth mode: at their two stamps


class TextureNode(Node):
    """The texture node (see the module docstring).

    Attributes
    ----------
    frames_received, frames_processed, frames_skipped, frames_dropped : int
        Pair counters (``received = processed + skipped + dropped + in flight``).
    worker : str
        ``'process'`` or ``'thread'``: where the texture engine (texturer + TextureMap) runs.
    """

    def __init__(self, **kwargs) -> None:
        super().__init__("texture", **kwargs)
        self.cfg = declare_config(self, "texture", TextureConfig)
        self.map_frame = param(self, "map_frame", "map")
        self.base_frame = param(self, "base_frame", "base_link")
        period = param(self, "publish_period_s", 1.0)
        self.calibration_dir = param(self, "calibration_dir", "")
        ext = param(self, "camera_extrinsic", [0.0] * 12)
        self.queue_depth = param(self, "queue_depth", 1)
        self.max_pending_pairs = param(self, "max_pending_pairs", 10)
        self.final_idle_s = param(self, "final_idle_s", 2.0)
        self.await_trajectory = param(self, "await_trajectory", False)
        self.trajectory_timeout_s = param(self, "trajectory_timeout_s", 60.0)
        self.worker_nice = param(self, "worker_nice", 10)
        pose_buffer = param(self, "pose_buffer_size", 3000)
        left_topic = param(self, "left_topic", "/stereo/left/image_raw")
        right_topic = param(self, "right_topic", "/stereo/right/image_raw")
        left_info = param(self, "left_info_topic", "/stereo/left/camera_info")
        right_info = param(self, "right_info_topic", "/stereo/right/camera_info")
        self.mode = param(self, "camera", "stereo")
        if self.mode not in ("stereo", "depth"):
            raise ValueError(
                f"node {self.get_name()}: parameter 'camera' must be 'stereo' or 'depth', got {self.mode!r}"
            )
        rgb_topic = param(self, "rgb_topic", "/kinect/rgb/image_raw")
        depth_topic = param(self, "depth_topic", "/kinect/depth/image_raw")
        rgb_info = param(self, "rgb_info_topic", "/kinect/rgb/camera_info")
        depth_info = param(self, "depth_info_topic", "/kinect/depth/camera_info")
        self.pair_tol_ns = int(param(self, "depth_pair_tol_s", 0.05) * 1e9)
        self.floor_height_m = param(self, "floor_height_m", 0.0)
        self.worker = worker_param(self)
        if not period > 0 or self.queue_depth < 1 or self.max_pending_pairs < 1 or pose_buffer < 2:
            raise ValueError(
                f"node {self.get_name()}: publish_period_s must be > 0, queue_depth "
                ">= 1, max_pending_pairs >= 1, pose_buffer_size >= 2"
            )
        ext = [float(v) for v in ext]
        if len(ext) != 12:
            raise ValueError(
                f"node {self.get_name()}: camera_extrinsic needs 12 numbers (R row-major, T), got {len(ext)}"
            )
        self._extrinsic: tuple[np.ndarray, np.ndarray] | None = None
        if any(ext):
            self._extrinsic = (np.array(ext[:9]).reshape(3, 3), np.array(ext[9:]))
        self._infos: dict[str, CameraInfo] = {}
        self._tf: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._static: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}  # child -> (parent, R, t)
        self._dynamic: dict[str, tuple[str, MountBuffer]] = {}  # child -> (parent, samples) from /tf
        self.camera: DepthCamera | None = None
        self.rig: StereoRig | None = None
        if self.calibration_dir:
            self.rig = read_stereo_rig(self.calibration_dir)
        expected_observers = param(self, "expected_observers", 0)
        use_map_metadata = param(self, "use_map_metadata", True)
        # the engine once every parameter is read and checked (nothing after this can fail on a
        # parameter and leave its worker process behind): it imports while the graph starts
        self._backend = make_backend(self.worker, self.cfg, self.worker_nice)

        self.lock = threading.Lock()
        self._cond = threading.Condition(self.lock)
        self._engine_ready = False  # the texturer is set up (rig / camera sent)
        self._anchor: tuple[float, float] | None = None  # the map origin, to align the cells with
        self._texture_cells = 0
        self._texture_bytes = 0
        self._kept_bytes = 0
        self.worker_error = ""
        self._map_info: MapMetaData | None = None
        self._images: dict[str, dict[int, Image]] = {"left": {}, "right": {}}
        self._awaiting: deque[_Pair] = deque()
        self._ready: deque[_Pair] = deque()
        self._pose_t: deque[int] = deque(maxlen=pose_buffer)
        self._pose_v: deque[tuple[float, float, float]] = deque(maxlen=pose_buffer)
        self._want_render = False
        self._stop = False
        self._busy = False
        self.frames_received = 0
        self.frames_processed = 0
        self.frames_skipped = 0
        self.frames_dropped = 0
        self.plane_fits = 0  # depth mode: pairs whose floor fit passed the kinematic check
        self.ms_total = 0.0
        self.ms_stages: dict[str, float] = {}  # summed per stage (StereoTexturer timings + "accumulate")
        self.last_stamp_ns = 0
        self.last_error = ""
        self._replay_done = False
        self._replay_done_at: float | None = None
        # pf_slam/trajectory (final) or pf_slam/loop_trajectory (a closed loop, mid-run), not yet applied
        self._trajectory: tuple[np.ndarray, np.ndarray, bool] | None = None
        self.replaced: dict = {}  # what the last re-placement did (counters' "replaced")
        self.replaced_final = False  # placed on the final trajectory
        self.loop_replacements = 0  # placements on a closed loop's trajectory during the run
        self._final_sent = False
        self._last_activity = time.monotonic()
        self._last_input = time.monotonic()
        self._dirty = True

        self.pub_texture = self.create_publisher(Image, TEXTURE, qos.latched())
        self.pub_meta = self.create_publisher(MapMetaData, TEXTURE_METADATA, qos.latched())
        self.pub_status = self.create_publisher(String, TEXTURE_STATUS, qos.latched())
        self.pub_progress = self.create_publisher(UInt32MultiArray, topics.TEXTURE_PROGRESS, qos.latched())
        self._progress_sent: tuple[int, int] = (-1, -1)
        announce_when_matched(self, [(self.pub_texture, expected_observers)])
        img_qos = qos.pipeline(max(4 * self.max_pending_pairs, 20))
        if self.mode == "depth":
            self.create_subscription(Image, rgb_topic, lambda m: self._on_rgbd("left", m), img_qos)
            self.create_subscription(Image, depth_topic, lambda m: self._on_rgbd("right", m), img_qos)
            self.create_subscription(CameraInfo, rgb_info, lambda m: self._on_info("left", m), qos.pipeline(10))
            self.create_subscription(CameraInfo, depth_info, lambda m: self._on_info("right", m), qos.pipeline(10))
            self.create_subscription(TFMessage, topics.TF, self._on_tf, qos.pipeline(10000), raw=True)
        else:
            self.create_subscription(Image, left_topic, lambda m: self._on_image("left", m), img_qos)
            self.create_subscription(Image, right_topic, lambda m: self._on_image("right", m), img_qos)
            self.create_subscription(CameraInfo, left_info, lambda m: self._on_info("left", m), qos.pipeline(10))
            self.create_subscription(CameraInfo, right_info, lambda m: self._on_info("right", m), qos.pipeline(10))
        self.create_subscription(TFMessage, topics.TF_STATIC, self._on_tf_static, qos.latched(10))
        self.create_subscription(PoseStamped, topics.POSE, self._on_pose, qos.pipeline(), raw=True)
        if use_map_metadata:  # same geometry, without the cells
            self.create_subscription(MapMetaData, topics.MAP_METADATA, self._on_map_info, qos.latched())
        else:
            self.create_subscription(OccupancyGrid, topics.MAP, lambda m: self._on_map_info(m.info), qos.latched())
        self.create_subscription(ReplayStatus, topics.REPLAY_STATUS, self._on_replay_status, qos.latched())
        self.create_subscription(Path, topics.TRAJECTORY, self._on_trajectory, qos.latched(), raw=True)
        self.create_subscription(
            Path, topics.LOOP_TRAJECTORY, lambda raw: self._on_trajectory(raw, final=False), qos.latched(), raw=True
        )
        self.create_timer(period, self._on_timer)
        self._worker = threading.Thread(target=self._work, name="texture_worker", daemon=True)
        self._worker.start()

    # ------------------------------------------------------------------ inputs
    def _on_info(self, side: str, msg: CameraInfo) -> None:
        if side not in self._infos:
            self._infos[side] = msg
            self._ensure_rig()
            self._release()

    def _on_tf_static(self, msg: TFMessage) -> None:
        for tr in msg.transforms:
            t, q = tr.transform.translation, tr.transform.rotation
            try:
                self._static[tr.child_frame_id.lstrip("/")] = (
                    tr.header.frame_id.lstrip("/"),
                    quat_to_matrix(q.x, q.y, q.z, q.w),
                    np.array([t.x, t.y, t.z]),
                )
            except ValueError:
                pass  # warned below when it is the camera's
            if tr.header.frame_id == self.base_frame:
                t, q = tr.transform.translation, tr.transform.rotation
                try:
                    rot = quat_to_matrix(q.x, q.y, q.z, q.w)
                except ValueError as e:  # this mount stays unknown (or as it was)
                    self.get_logger().warning(f"/tf_static: {tr.header.frame_id} -> {tr.child_frame_id} ignored: {e}")
                    continue
                self._tf[tr.child_frame_id] = (rot, np.array([t.x, t.y, t.z]))
        self._ensure_rig()
        self._release()

    def _on_tf(self, raw: bytes) -> None:
        """/tf (depth mode): the moving links of the camera's chain (e.g. base_link -> head); read
        from the bytes (100 Hz: no message objects)."""
        own = (self.base_frame, "odom")
        try:
            transforms = cdr.tf_transforms(raw)
        except ValueError as exc:
            self.get_logger().error(f"/tf: message dropped: {exc}", throttle_duration_sec=5.0)
            return
        for stamp, parent, child, t, q in transforms:
            child = child.lstrip("/")
            if child in own:
                continue
            buf = self._dynamic.get(child)
            if buf is None:
                buf = self._dynamic[child] = (parent.lstrip("/"), MountBuffer())
            buf[1].add(stamp, q, t)
        if self._awaiting:
            self._release()

    def _chain_at(self, frame: str, stamp: int) -> tuple[np.ndarray, np.ndarray] | None:
        """`frame` in the base frame at `stamp` (static links and interpolated moving ones), or
        None while a link is missing."""
        rot, t, f = np.eye(3), np.zeros(3), frame
        for _ in range(32):
            if f == self.base_frame:
                return rot, t
            if f in self._static:
                parent, r, tt = self._static[f]
            elif f in self._dynamic:
                parent, buf = self._dynamic[f]
                at = buf.at(stamp)
                if at is None:
                    return None
                r, tt = at
            else:
                return None
            rot, t, f = r @ rot, r @ t + tt, parent
        return None

    def _on_rgbd(self, side: str, msg: Image) -> None:
        """A colour ("left") or depth ("right") image: paired with the other stream's image
        nearest in time (within depth_pair_tol_s) once the other stream has passed its stamp."""
        self._last_input = time.monotonic()
        self._images[side][convert.stamp_to_ns(msg.header.stamp)] = msg
        rgb, depth = self._images["left"], self._images["right"]
        for d in sorted(depth):
            if not rgb:
                break
            stamps = np.fromiter(rgb, dtype=np.int64, count=len(rgb))
            k = int(np.argmin(np.abs(stamps - d)))
            if abs(int(stamps[k]) - d) > self.pair_tol_ns:
                if stamps.max() > d + self.pair_tol_ns:  # none will come: this depth frame has no colour
                    depth.pop(d)
                continue
            if stamps.max() < d and abs(int(stamps[k]) - d) > 0:
                break  # a nearer colour image may still come
            pair = _Pair(d, rgb.pop(int(stamps[k])), depth.pop(d))
            with self.lock:
                self.frames_received += 1
                self._awaiting.append(pair)
                while len(self._awaiting) > self.max_pending_pairs:
                    self._awaiting.popleft()
                    self.frames_skipped += 1
        for store in (rgb, depth):
            while len(store) > 2 * self.max_pending_pairs:
                store.pop(min(store))
        self._release()

    def _ensure_camera(self) -> bool:
        if self.camera is not None:
            return True
        if len(self._infos) < 2:
            return False
        rgb, depth = self._infos["left"], self._infos["right"]
        link = self._static.get(depth.header.frame_id.lstrip("/"))
        if link is None or link[0] != rgb.header.frame_id.lstrip("/"):
            return False  # P_rgb = R P_depth + T: /tf_static rgb frame -> depth frame
        try:
            self.camera = DepthCamera(
                np.asarray(depth.k).reshape(3, 3),
                np.asarray(rgb.k).reshape(3, 3),
                link[1],
                link[2],
                (int(rgb.width), int(rgb.height)),
            )
        except ValueError as e:
            self.last_error = str(e)
            self.get_logger().error(f"bad RGB-D calibration: {e}")
            return False
        return True

    def _on_map_info(self, info: MapMetaData) -> None:
        with self.lock:
            first = self._map_info is None
            self._map_info = info
            self._dirty = True
            if first:  # align the texture cells with the map's (while nothing is coloured)
                self._anchor = (info.origin.position.x, info.origin.position.y)

    def _on_image(self, side: str, msg: Image) -> None:
        self._last_input = time.monotonic()
        stamp = convert.stamp_to_ns(msg.header.stamp)
        other = "right" if side == "left" else "left"
        mate = self._images[other].pop(stamp, None)
        if mate is None:
            store = self._images[side]
            store[stamp] = msg
            while len(store) > 2 * self.max_pending_pairs:  # its mate never came
                store.pop(min(store))
            return
        left, right = (msg, mate) if side == "left" else (mate, msg)
        with self.lock:
            self.frames_received += 1
            self._awaiting.append(_Pair(stamp, left, right))
            while len(self._awaiting) > self.max_pending_pairs:
                self._awaiting.popleft()
                self.frames_skipped += 1
        self._release()

    def _on_pose(self, raw: bytes) -> None:
        self._last_input = time.monotonic()
        stamp, pose = cdr.pose_stamped_xy_yaw(raw)
        self._pose_t.append(stamp)
        self._pose_v.append((float(pose[0]), float(pose[1]), float(pose[2])))
        if self._awaiting:
            self._release()

    def _on_replay_status(self, msg: ReplayStatus) -> None:
        self._replay_done = bool(msg.done)
        if self._replay_done and self._replay_done_at is None:
            self._replay_done_at = time.monotonic()

    def _on_trajectory(self, raw: bytes, final: bool = True) -> None:
        """The final trajectory, or (``final`` False) a closed loop's during the run; either
        places every kept pair again once the pairs it covers are textured. A loop's is ignored
        once a final one has arrived (waiting or placed): the two topics are not ordered against
        each other, and a late loop's would move the final texture back."""
        try:
            stamps, poses = cdr.path_xy_yaw(raw)
        except ValueError as exc:
            topic = topics.TRAJECTORY if final else topics.LOOP_TRAJECTORY
            self.get_logger().error(f"{topic}: message dropped: {exc}")
            return
        with self._cond:
            final_seen = self.replaced_final or (self._trajectory is not None and self._trajectory[2])
            if final or not final_seen:
                self._trajectory = (stamps.astype(np.float64) / 1e9, poses, final)
            self._cond.notify()

    # ------------------------------------------------------------------ scheduling
    def _ensure_rig(self) -> bool:
        if self.rig is not None:
            return True
        if len(self._infos) < 2:
            return False
        left, right = self._infos["left"], self._infos["right"]
        mount = self._extrinsic or self._tf.get(left.header.frame_id or "stereo_left")
        if mount is None:
            return False

        def info(m: CameraInfo) -> dict:
            return {
                "width": m.width,
                "height": m.height,
                "k": np.asarray(m.k),
                "d": np.asarray(m.d),
                "r": np.asarray(m.r),
                "p": np.asarray(m.p),
            }

        try:
            self.rig = StereoRig.from_camera_infos(info(left), info(right), *mount)
        except ValueError as e:
            self.last_error = str(e)
            self.get_logger().error(f"bad stereo calibration: {e}")
            return False
        return True

    def _release(self) -> None:
        """Move the pairs whose pose is known (interpolated) to the worker's queue; then the
        progress (pf_slam/texture_progress) if it changed."""
        self._release_ready()
        self._publish_progress()

    def _release_ready(self) -> None:
        ready = self._ensure_camera() if self.mode == "depth" else self._ensure_rig()
        if not self._awaiting or not self._pose_t or not ready:
            return
        if self._awaiting[0].stamp_ns > self._pose_t[-1]:
            return  # the oldest pair is not posed yet (the loop below would stop there)
        t = np.fromiter(self._pose_t, dtype=np.int64, count=len(self._pose_t))
        with self.lock:
            while self._awaiting:
                pair = self._awaiting[0]
                if pair.stamp_ns < t[0]:
                    self._awaiting.popleft()
                    self.frames_dropped += 1
                    continue
                if pair.stamp_ns > t[-1]:
                    break
                j = int(np.searchsorted(t, pair.stamp_ns))
                i = max(j - 1, 0)
                j = min(j, len(t) - 1)
                if self.mode == "depth":
                    frame = pair.left.header.frame_id.lstrip("/")
                    rgb_stamp = convert.stamp_to_ns(pair.left.header.stamp)
                    latest = max(rgb_stamp, pair.stamp_ns)
                    if any(not b.covers(latest) for _, b in self._dynamic.values()) and not self._replay_done:
                        break  # the moving links have not reached the images' stamps yet
                    pair.mount = self._chain_at(frame, rgb_stamp)
                    depth_mount = self._chain_at(pair.right.header.frame_id.lstrip("/"), pair.stamp_ns)
                    if pair.mount is None or depth_mount is None:
                        break  # the camera's chain to the base is not known yet
                    # the depth camera at its stamp in the RGB camera at its own (the head moves between)
                    r_c, t_c = pair.mount
                    pair.rgb_from_depth = (r_c.T @ depth_mount[0], r_c.T @ (depth_mount[1] - t_c))
                pair.pose = interpolate_poses(
                    t[[i, j]], np.array([self._pose_v[i], self._pose_v[j]]), np.array([pair.stamp_ns])
                )[0]
                self._awaiting.popleft()
                self._ready.append(pair)
                while len(self._ready) > self.queue_depth:
                    self._ready.popleft()
                    self.frames_skipped += 1
                self._cond.notify()

    def _publish_progress(self) -> None:
        """``[finished, waiting for a pose]`` on pf_slam/texture_progress, when it changed."""
        with self.lock:
            now = (self.frames_processed + self.frames_skipped + self.frames_dropped, len(self._awaiting))
            if now == self._progress_sent:
                return
            self._progress_sent = now
        self.pub_progress.publish(UInt32MultiArray(data=list(now)))

    # ------------------------------------------------------------------ worker
    def _work(self) -> None:
        if self.worker_nice > 0:  # Linux: per-thread niceness; the SLAM threads come first
            try:
                os.setpriority(
                    os.PRIO_PROCESS,
                    threading.get_native_id(),
                    min(os.getpriority(os.PRIO_PROCESS, 0) + self.worker_nice, 19),
                )
            except (AttributeError, OSError):
                pass
        while True:
            with self._cond:
                while not self._stop and not self._ready and not self._want_render and not self._replace_due():
                    self._cond.wait(0.5)
                if self._stop:
                    return
                pair = self._ready.popleft() if self._ready else None
                traj = None
                if pair is None and self._replace_due():
                    traj, self._trajectory = self._trajectory, None
                render = self._want_render and pair is None and traj is None
                if render:
                    self._want_render = False
                self._busy = True
            try:
                if pair is not None:
                    self._process(pair)
                elif traj is not None:
                    self._replace(*traj)
                elif render:
                    self.publish_texture()
            except WorkerDied as e:  # logged once; every later pair is dropped
                if not self.worker_error:
                    self.worker_error = self.last_error = f"texture node: {e}; no more pairs are textured"
                    self.get_logger().error(self.worker_error)
                if pair is not None:
                    with self.lock:
                        self.frames_dropped += 1
            except Exception as e:  # noqa: BLE001  (a bad frame must not kill the worker)
                self.last_error = f"{type(e).__name__}: {e}"
                self.get_logger().error(f"texture worker: {self.last_error}")
                if pair is not None:
                    with self.lock:
                        self.frames_dropped += 1
            finally:
                with self.lock:
                    self._busy = False
                    self._last_activity = time.monotonic()
                self._publish_progress()

    def _replace_due(self) -> bool:
        """A corrected trajectory is here and every pair it covers is textured (under the lock)."""
        if self._trajectory is None or self._ready:
            return False
        last = self._trajectory[0][-1] if len(self._trajectory[0]) else -np.inf
        return not any(p.stamp_ns / 1e9 <= last for p in self._awaiting)

    def _replace(self, stamps_s: np.ndarray, poses: np.ndarray, final: bool) -> None:
        t0 = time.perf_counter()
        out = self._backend.call("replace", stamps_s, poses)
        ms = 1e3 * (time.perf_counter() - t0)
        with self.lock:
            self._engine_stats(out)
            self.replaced = {
                k: out[k] for k in ("pairs_moved", "pairs_frozen", "shift_median_m", "shift_max_m") if k in out
            }
            self.replaced["ms"] = round(ms, 1)
            self.replaced_final = self.replaced_final or final
            self.loop_replacements += 0 if final else 1
            self._dirty = True
        what = "the corrected trajectory" if final else "a closed loop's trajectory"
        self.get_logger().info(f"texture placed again on {what} ({len(stamps_s)} poses): {json.dumps(self.replaced)}")

    def _sync_anchor(self) -> None:
        """Hand the map origin received since the last call to the engine (it aligns its cells
        with it while nothing is coloured)."""
        with self.lock:
            anchor, self._anchor = self._anchor, None
        if anchor is not None:
            self._backend.call("set_anchor", anchor)

    def _engine_stats(self, out: dict) -> None:
        self._texture_cells, self._texture_bytes = out["cells"], out["memory_bytes"]
        self._kept_bytes = out.get("kept_bytes", 0)

    def _process(self, pair: _Pair) -> None:
        if self.mode == "depth":
            return self._process_depth(pair)
        t0 = time.perf_counter()
        if not self._engine_ready:
            assert self.rig is not None
            self._backend.call("setup_stereo", self.rig)
            self._engine_ready = True
        left, right = image_array(pair.left), image_array(pair.right)
        self._sync_anchor()
        out = self._backend.call("stereo", left, right, pair.pose, pair.left.encoding, pair.stamp_ns / 1e9)
        with self.lock:
            self._engine_stats(out)
            for k, v in out["ms_stages"].items():
                self.ms_stages[k] = self.ms_stages.get(k, 0.0) + float(v)
            self._dirty = True
            self.frames_processed += 1
            self.ms_total += 1e3 * (time.perf_counter() - t0)
            self.last_stamp_ns = max(self.last_stamp_ns, pair.stamp_ns)

    def _process_depth(self, pair: _Pair) -> None:
        t0 = time.perf_counter()
        if not self._engine_ready:
            assert self.camera is not None
            self._backend.call("setup_depth", self.camera, self.floor_height_m)
            self._engine_ready = True
        rgb = image_array(pair.left)
        if pair.left.encoding.lower() == "bgr8":
            rgb = rgb[..., ::-1]
        self._sync_anchor()
        out = self._backend.call(
            "depth", depth_array(pair.right), rgb, pair.mount, pair.pose, pair.rgb_from_depth, pair.stamp_ns / 1e9
        )
        with self.lock:
            self._engine_stats(out)
            self._dirty = True
            self.frames_processed += 1
            self.plane_fits += int(out["plane_fitted"])
            self.ms_total += 1e3 * (time.perf_counter() - t0)
            self.last_stamp_ns = max(self.last_stamp_ns, pair.stamp_ns)

    # ------------------------------------------------------------------ outputs
    def counters(self) -> dict:
        """The pair counters and mean processing time (ms per processed pair)."""
        with self.lock:
            return {
                "frames_received": self.frames_received,
                "frames_processed": self.frames_processed,
                "frames_skipped": self.frames_skipped,
                "frames_dropped": self.frames_dropped,
                "frames_pending": len(self._awaiting) + len(self._ready) + int(self._busy),
                "ms_per_frame": round(self.ms_total / self.frames_processed, 1) if self.frames_processed else None,
                "ms_stages": {k: round(v / self.frames_processed, 1) for k, v in self.ms_stages.items()}
                if self.frames_processed
                else {},
                "texture_cells": self._texture_cells,
                "texture_memory_mb": round(self._texture_bytes / 2**20, 1),
                "kept_memory_mb": round(self._kept_bytes / 2**20, 1),
                **({"replaced": dict(self.replaced)} if self.replaced else {}),
                "loop_replacements": self.loop_replacements,
                "final": self._final_sent,
                "mode": self.mode,
                "worker": self.worker,
                **({"worker_error": self.worker_error} if self.worker_error else {}),
                **({"plane_fits": self.plane_fits} if self.mode == "depth" else {}),
            }

    def render(self) -> tuple[np.ndarray, np.ndarray, MapMetaData] | None:
        """``(rgb, covered, geometry)`` of the texture in the current /map geometry (or its own
        extent before a map arrived); None while nothing is coloured and no map is known, or
        once the worker process is gone."""
        with self.lock:
            self._dirty = False
            info = self._map_info
            stamp = self.last_stamp_ns
        try:
            self._sync_anchor()
            if info is not None:
                rgb, cov = self._backend.call(
                    "render", (info.origin.position.x, info.origin.position.y), info.resolution, info.width, info.height
                )
                meta = info
            else:
                nat = self._backend.call("render_native")
                if nat is None:
                    return None
                rgb, cov, origin = nat
                meta = MapMetaData()
                meta.resolution = float(self.cfg.cell_m)
                meta.height, meta.width = int(rgb.shape[0]), int(rgb.shape[1])
                meta.origin.position.x, meta.origin.position.y = float(origin[0]), float(origin[1])
                meta.origin.orientation.w = 1.0
        except WorkerDied as e:
            if not self.worker_error:
                self.worker_error = self.last_error = f"texture node: {e}; no more pairs are textured"
                self.get_logger().error(self.worker_error)
            return None
        meta.map_load_time = convert.ns_to_stamp(stamp)
        return rgb, cov, meta

    def publish_texture(self) -> Image | None:
        """Render and publish ``texture`` + ``texture_metadata`` + the status now (any thread).
        Returns the published image, or None when there is nothing to publish."""
        out = self.render()
        if out is not None:
            rgb, _, meta = out
            msg = Image()
            msg.header.stamp = meta.map_load_time
            msg.header.frame_id = self.map_frame
            msg.height, msg.width = int(rgb.shape[0]), int(rgb.shape[1])
            msg.encoding = "rgb8"
            msg.is_bigendian = 0
            msg.step = 3 * msg.width
            msg.data = array.array("B", np.ascontiguousarray(rgb).tobytes())
            self.pub_texture.publish(msg)
            self.pub_meta.publish(meta)
        self.pub_status.publish(String(data=json.dumps(self.counters())))
        return None if out is None else msg

    def _on_timer(self) -> None:
        now = time.monotonic()
        with self.lock:
            quiet = now - max(self._last_activity, self._last_input) > self.final_idle_s
            # with await_trajectory the final texture is the one placed on the corrected trajectory
            placed = (
                not self.await_trajectory
                or (self.replaced_final and self._trajectory is None)
                or now - (self._replay_done_at or now) > self.trajectory_timeout_s
            )
            finish = (
                self._replay_done
                and not self._final_sent
                and not self._ready
                and not self._busy
                and (not self._awaiting or quiet)
                and placed
            )
            if finish:  # end of the bag: pairs still without a pose never get one
                self.frames_dropped += len(self._awaiting)
                self._awaiting.clear()
                self._final_sent = True
            if self._dirty or finish:
                self._want_render = True
                self._cond.notify()
        if finish:
            self._publish_progress()
            self.get_logger().info(f"final texture: {json.dumps(self.counters())}")

    def wait_idle(self, timeout_s: float = 10.0) -> bool:
        """Block until the worker has processed every ready pair (True) or ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if not self._ready and not self._busy:
                    return True
            time.sleep(0.01)
        return False

    def destroy_node(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._worker.is_alive():
            self._worker.join(timeout=10.0)
        self._backend.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(TextureNode, args)


if __name__ == "__main__":
    import sys

    sys.exit(main())
