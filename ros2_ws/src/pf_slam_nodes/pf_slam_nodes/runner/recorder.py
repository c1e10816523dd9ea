"""The recorder nodes of `pf-slam run`: the run's own (poses, map, snapshots, progress, the
nodes' status) and the result recorder (result.mcap)."""

from __future__ import annotations

import json
import shutil
import sys
import threading
import time
from pathlib import Path

import numpy as np

from ..io.bag import stamp_ns_of
from ..io.mapfile import render_snapshot
from ..ros import cdr
from .common import SnapshotCadence


class _Recorder:
    """Collects per-scan poses and the latest /map; renders snapshots; prints progress."""

    def __init__(
        self,
        node,
        out_dir: Path,
        scans_total: int,
        bag_duration_s: float,
        snapshot_every: int | str,
        progress: bool,
        texture: bool = False,
        loops: bool = False,
    ) -> None:
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import OccupancyGrid, Path

        from pf_slam_interfaces.msg import ParticleArray, ReplayStatus

        from ..ros import qos, topics

        self.node = node
        self.out_dir = out_dir
        self.scans_total = scans_total
        self.bag_duration_s = bag_duration_s
        self.snapshot_due = SnapshotCadence(snapshot_every)  # every N scans or N s of bag time
        self._snapshot_waits = False  # one came due before the first map: written when it comes
        self._tty = sys.stderr.isatty()
        self.progress = progress
        self.stamps: list[int] = []
        self.poses: list[np.ndarray] = []
        self.updates = 0
        self.map_msg = None
        self.loops = loops  # the mapper closes loops: the final trajectory comes on pf_slam/trajectory
        self._final: tuple[np.ndarray, np.ndarray] | None = None  # pf_slam/trajectory: (stamps ns, poses)
        self.replay_counts: dict[str, int] | None = None
        self.texture_msg = None
        self.texture_meta = None
        self.texture_status: dict | None = None
        self.node_status: dict[str, dict] = {}  # pf_slam/status per node: fault counters
        self.t0 = time.monotonic()
        self._last_print = 0.0
        self._writer: threading.Thread | None = None  # the snapshot being written, if any
        self._writer_error: Exception | None = None
        self.snapshots_written = 0
        self.snapshots_skipped = 0
        #: more consumers of the raw /pose bytes (the result recorder): one subscription, one
        #: delivery per pose at the car's 100 Hz instead of one per consumer
        self.pose_listeners: list = []
        self.pose_subscription = node.create_subscription(
            PoseStamped, topics.POSE, self._on_pose, qos.pipeline(), raw=True
        )
        node.create_subscription(ParticleArray, topics.PARTICLES_UPDATED, self._on_updated, qos.pipeline())
        node.create_subscription(OccupancyGrid, topics.MAP, self._on_map, qos.latched())
        if loops:
            node.create_subscription(Path, topics.TRAJECTORY, self._on_trajectory, qos.latched(), raw=True)
        node.create_subscription(ReplayStatus, topics.REPLAY_STATUS, self._on_replay_status, qos.latched())
        from std_msgs.msg import String

        node.create_subscription(String, topics.STATUS, self._on_node_status, qos.latched(depth=10))
        if texture:
            from nav_msgs.msg import MapMetaData
            from sensor_msgs.msg import Image
            from std_msgs.msg import String

            from ..nodes.texture import TEXTURE, TEXTURE_METADATA, TEXTURE_STATUS

            node.create_subscription(Image, TEXTURE, self._on_texture, qos.latched())
            node.create_subscription(MapMetaData, TEXTURE_METADATA, self._on_texture_meta, qos.latched())
            node.create_subscription(String, TEXTURE_STATUS, self._on_texture_status, qos.latched())

    def _on_texture(self, msg) -> None:
        self.texture_msg = msg

    def _on_texture_meta(self, msg) -> None:
        self.texture_meta = msg

    def _on_texture_status(self, msg) -> None:
        self.texture_status = json.loads(msg.data)

    def _on_node_status(self, msg) -> None:
        status = json.loads(msg.data)
        self.node_status[status["node"]] = status

    def bag_error(self) -> str | None:
        """The damage that ended the replay early (bag_replay's pf_slam/status), or None."""
        return self.node_status.get("bag_replay", {}).get("error")

    def faults(self) -> dict[str, int]:
        """The input faults the nodes counted (summary.json "faults")."""
        out: dict[str, int] = {}
        for status in self.node_status.values():
            for kind, n in status.get("faults", {}).items():
                out[kind] = out.get(kind, 0) + int(n)
        return out

    def _on_replay_status(self, msg) -> None:
        self.replay_counts = dict(zip(msg.topics, (int(c) for c in msg.counts)))

    def _on_updated(self, msg) -> None:
        self.updates += int(msg.update)

    def _on_pose(self, raw: bytes) -> None:
        for listener in self.pose_listeners:
            listener(raw)
        stamp, pose = cdr.pose_stamped_xy_yaw(raw)
        self.stamps.append(stamp)
        self.poses.append(pose)
        k = len(self.poses)
        # the map comes on the mapper's wall-clock period: a snapshot due before the first one
        # (a short bag in --rate max) is written with the first pose after it, not lost
        self._snapshot_waits |= self.snapshot_due(k, stamp)
        if self._snapshot_waits and self.map_msg is not None:
            self._snapshot_waits = False
            self.snapshot(f"scan_{k:06d}.png")
        self.print_progress()

    def _on_map(self, msg) -> None:
        self.map_msg = msg

    def _on_trajectory(self, raw: bytes) -> None:
        self._final = cdr.path_xy_yaw(raw)  # 30 000 poses on a car drive: no message objects

    def final_trajectory(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The mapper's trajectory in the loop closure's final frame, ``(stamps ns, (K, 3))``, if it
        came and covers every scan posed here; else None."""
        t = self._final
        return t if t is not None and t[0].size == len(self.poses) else None

    def snapshot(self, name: str, wait: bool = False) -> None:
        """Render the latest map and path to ``snapshots/<name>`` on the writer thread.

        The executor thread only hands over references; a snapshot due while the previous one
        is still being written is skipped and counted (``snapshots_skipped`` in summary.json).
        ``wait``: write this one even if the writer is busy, and wait for it.
        """
        if self._writer is not None and self._writer.is_alive():
            if not wait:
                self.snapshots_skipped += 1
                return
            self._writer.join()
        job = (self.map_msg, list(self.poses), self.out_dir / "snapshots" / name, f"scan {len(self.poses)}")
        self._writer = threading.Thread(target=self._write_snapshot, args=job, daemon=True)
        self._writer.start()
        if wait:
            self._writer.join()
        if self._writer_error is not None:
            raise self._writer_error

    def _write_snapshot(self, map_msg, poses: list, path: Path, title: str) -> None:
        from ..ros import convert

        try:
            occ, res, origin = convert.msg_to_grid(map_msg)
            traj = np.array(poses)[:, :2] if poses else np.zeros((0, 2))
            render_snapshot(occ, res, origin, traj, path, pose=poses[-1] if poses else None, title=title)
            self.snapshots_written += 1
        except Exception as exc:  # surfaced by the next snapshot() on the executor thread
            self._writer_error = exc

    def print_progress(self, final: bool = False) -> None:
        now = time.monotonic()
        tty = self._tty
        if not self.progress or (not final and now - self._last_print < (0.5 if tty else 10.0)):
            return
        self._last_print = now
        k, n = len(self.poses), max(self.scans_total, 1)
        wall = now - self.t0
        rtf = (self.bag_duration_s * k / n) / wall if wall > 0 else 0.0
        eta = wall * (n - k) / k if k else float("nan")
        line = f"[pf-slam] scans {k}/{n}  RTF {rtf:5.1f}x  ETA {eta:5.0f} s"
        sys.stderr.write(f"\r{line} " if tty else line + "\n")
        if final and tty:
            sys.stderr.write("\n")
        sys.stderr.flush()


class ResultRecorder:
    """Records the run's outputs into ``OUT/result.mcap`` (rosbags' MCAP writer), so a user opens
    the run in Foxglove Studio (or ``ros2 bag play``) and scrubs through it.

    Subscribes raw (the CDR bytes go to the file as received: no message objects per scan at the
    car's 100 Hz): the scan topic, pose, path, /tf, /tf_static, map and texture image (each at
    most one per ``map_every_s`` of bag time, always the last one: a car's are megabytes, and the
    texture node publishes once a second of wall time, so at real time a 5 min drive would carry
    300 images of 6 MB). Log times are the
    messages' header stamps (bag time). It announces itself on pf_slam/ready once its streams
    are matched, so the replay waits for it and nothing is missed.
    """

    NAME = "pf_slam_result_recorder"

    def __init__(
        self,
        node,
        path: Path,
        scan_topic: str,
        map_every_s: float,
        texture: bool = False,
        pose_feed: _Recorder | None = None,
    ) -> None:
        """``pose_feed``: take /pose from that recorder's subscription instead of a second one."""
        from rclpy.qos import QoSProfile

        from ..io.bag import open_writer
        from ..nodes.common import announce_when_matched
        from ..nodes.texture import TEXTURE
        from ..ros import qos, topics

        self.path = path
        self._bag_dir = path.with_suffix(".bag_tmp")
        if self._bag_dir.exists():
            shutil.rmtree(self._bag_dir)
        self._cm = open_writer(self._bag_dir)
        self.bag = self._cm.__enter__()
        self.map_every_ns = int(map_every_s * 1e9)
        self.last_map_ns: int | None = None
        self.last_texture_ns: int | None = None
        self.texture_topic = "/" + TEXTURE
        self._held_texture: tuple[int, bytes] | None = None  # (stamp, raw): the newest one not written yet
        self.last_stamp = 0
        # topic, type, QoS, matched publishers to wait for (volatile topics only)
        streams: list[tuple[str, str, QoSProfile, int]] = [
            (scan_topic, "sensor_msgs/msg/LaserScan", qos.pipeline(), 1),
            ("/" + topics.POSE, "geometry_msgs/msg/PoseStamped", qos.pipeline(), 1),
            ("/" + topics.PATH, "nav_msgs/msg/Path", qos.outputs(10), 1),
            (topics.TF, "tf2_msgs/msg/TFMessage", qos.outputs(10000), 2),  # mapper + predictor or the bag
            (topics.TF_STATIC, "tf2_msgs/msg/TFMessage", qos.latched(10), 0),
            ("/" + topics.MAP, "nav_msgs/msg/OccupancyGrid", qos.latched(), 0),
        ]
        if texture:
            streams.append((self.texture_topic, "sensor_msgs/msg/Image", qos.latched(), 0))
        needs = []
        thinned = {"/" + topics.MAP: self._on_map, self.texture_topic: self._on_texture}  # by bag time
        for topic, msgtype, profile, wait in streams:
            self.bag.add_connection(topic, msgtype, latched=profile.durability == qos.latched().durability)
            cb = thinned.get(topic) or self._writer_for(topic, msgtype)
            if topic == "/" + topics.POSE and pose_feed is not None:
                pose_feed.pose_listeners.append(cb)
                needs.append((pose_feed.pose_subscription, wait))
                continue
            needs.append((node.create_subscription(_message_class(msgtype), topic, cb, profile, raw=True), wait))
        announce_when_matched(node, needs, name=self.NAME)

    def _writer_for(self, topic: str, msgtype: str):
        from ..ros import convert

        stamp_of = cdr.tf_message_stamp if msgtype == "tf2_msgs/msg/TFMessage" else convert.stamp_ns_from_cdr

        def write(raw: bytes) -> None:
            stamp = stamp_of(raw)
            if stamp is not None:
                self.last_stamp = stamp
            self.bag.write_raw(topic, self.last_stamp if stamp is None else stamp, raw)

        return write

    def _due(self, last_ns: int | None, stamp: int) -> bool:
        """A thinned-out stream (map, texture image): the first message, then one per map_every_ns."""
        return last_ns is None or stamp - last_ns >= self.map_every_ns

    def _on_texture(self, raw: bytes) -> None:
        """The texture image at most every map_every_ns of bag time; the newest one not written is
        held and written when the recording closes (the final texture)."""
        from ..ros import convert

        stamp = convert.stamp_ns_from_cdr(raw)
        if self._due(self.last_texture_ns, stamp):
            self.bag.write_raw(self.texture_topic, stamp, raw)
            self.last_texture_ns, self._held_texture = stamp, None
        else:
            self._held_texture = (stamp, raw)

    def flush_texture(self) -> None:
        """Write the held texture image (the newest one, thinned out by bag time), if any."""
        if self._held_texture is not None:
            self.bag.write_raw(self.texture_topic, *self._held_texture)
            self._held_texture = None

    def _on_map(self, raw: bytes) -> None:
        """A map at most every map_every_ns of bag time (a car map is megabytes); the final one
        is written by finish()."""
        from ..ros import convert

        stamp = convert.stamp_ns_from_cdr(raw)
        if stamp == 0:  # a fixed map (localization) published before any scan: its later copies carry stamps
            return
        if self._due(self.last_map_ns, stamp):
            self.bag.write_raw("/map", stamp, raw)
            self.last_map_ns = stamp

    @property
    def counts(self) -> dict[str, int]:
        return self.bag.counts

    def finish(self, final_map=None) -> None:
        """Write the final map (if not yet in the file), close, and leave a single result.mcap."""
        if final_map is not None:
            from rclpy.serialization import serialize_message

            stamp = stamp_ns_of(final_map)
            if self.last_map_ns != stamp:
                self.bag.write_raw("/map", stamp, serialize_message(final_map))
                self.last_map_ns = stamp
        self.close()

    def close(self) -> None:
        if self._cm is None:
            return
        self.flush_texture()
        self._cm.__exit__(None, None, None)
        self._cm = None
        (mcap,) = self._bag_dir.glob("*.mcap")
        mcap.replace(self.path)
        shutil.rmtree(self._bag_dir)


def _message_class(msgtype: str):
    from ..nodes.bag_replay import message_class

    return message_class(msgtype)


def _drain_result(ex, result: ResultRecorder, poses: int, timeout_s: float = 5.0) -> None:
    """Spin until the result recorder has every pose the run's recorder has (both subscribe)."""
    deadline = time.monotonic() + timeout_s
    while result.counts.get("/pose", 0) < poses and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.05)
