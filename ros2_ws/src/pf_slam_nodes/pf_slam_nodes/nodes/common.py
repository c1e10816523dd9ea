"""Helpers shared by the nodes: parameters mirrored from the core's config dataclasses."""

from __future__ import annotations

import dataclasses
import math
import os
import re
import signal
import sys
from collections import deque
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from ..core.deferred import inline
from ..runner.memory import keep_freed_memory
from .declared import CONFIG_SECTIONS

T = TypeVar("T")


#: Descriptions of the plain (non-config) node parameters: they go into each parameter's
#: ParameterDescriptor (`ros2 param describe`) and into docs/parameters.md (`pf-slam params`).
#: Config sections take theirs from the dataclasses' "Attributes" docstrings.
PARAM_DOCS: dict[str, str] = {
    "bag": "rosbag2 to replay (folder or file; mcap or sqlite3); required",
    "rate": "'max': as fast as the pipeline takes it, lossless (paced on pose); N: N x real time (s/s)",
    "restamp": "topics whose header stamps are rewritten as replayed: 'TOPIC=record' (the bag's record time) or "
    "'TOPIC=NS' (shifted by NS ns), comma-separated; pf-slam run sets it when the bag's stamps cannot be right",
    "max_in_flight": "rate max: at most this many scans published and not yet posed",
    "image_topic": "rate max: the texture node's left stereo topic; its next image waits while max_pairs_in_flight "
    "pairs are with the texture node and not waiting for a pose (no pair skipped); '' = no pacing "
    "on images (pf-slam run sets it when the texture node runs)",
    "max_pairs_in_flight": "rate max, with image_topic: stereo pairs the texture node may hold (being worked on "
    "or queued) before the replay waits",
    "scan_topic": "the bag's LaserScan topic (pacing, end-of-bag counts)",
    "scan_subscribers": "subscriptions the scan topic must have matched before the replay starts",
    "clock_period_s": "/clock goes out at least this often in bag time, and with every scan (s)",
    "sensor_qos": "QoS reliability of the sensor subscriptions (scan, odometry, encoders, gyro): 'reliable' "
    "(lossless replay) or 'best_effort' (drivers that publish with the sensor-data QoS)",
    "scan_queue_depth": "scans the predictor's scan subscription holds while it is busy; when the filter falls "
    "further behind the oldest is dropped (counted in the summary). Deep for a lossless replay; a live robot that "
    "wants only recent scans may set it low",
    "start_delay_s": "wait this long after the graph is ready before the first message (s; like ros2 bag "
    "play --delay: time for a viewer on an open --domain to discover the run)",
    "wait_for": "nodes whose pf_slam/ready announcement the replay waits for before it starts",
    "map_frame": "REP-105 map frame: /map, /path, /pose and particle sets are in it",
    "odom_frame": "REP-105 odom frame: parent of base_frame (dead reckoning), child of map_frame",
    "base_frame": "REP-105 robot frame (base_link): child of odom_frame, parent of the sensor frames",
    "odometry_source": "'odom' (nav_msgs/Odometry on odom), 'encoders' (JointState wheel angles on encoders) or 'tf' "
    "(the odom_frame -> base_frame transform on /tf, as a robot's base controller publishes it)",
    "odom_sync": "'exact': odometry stamped like each scan (same log line); 'interpolate': asynchronous odometry",
    "fog_format": "yaw from a gyro instead of the wheels: 'none', 'batch' (FogBatch on fog), 'vector3' "
    "(Vector3Stamped on fog) or 'imu' (sensor_msgs/Imu on imu, mounted level: angular_velocity.z)",
    "odom_wait_scans": "live inputs: a scan whose odometry has not arrived while this many scans wait behind it is "
    "posed with the nearest earlier odometry (counted: odom_not_arrived); 0: off (pf-slam run: "
    "the replay's pf_slam/replay_stall decides instead, deterministically)",
    "stamp_offset_s": "odometry stamps this far (s) ahead of or behind the scan stamps are reported (odom_stamp_offset)",
    "time_gap_s": "scan stamps stepping forward by more than this are counted as a time gap (s)",
    "publish_odom_tf": "publish odom -> base_frame on /tf at every scan (off when the bag carries its own /tf); never "
    "with odometry_source tf, and stopped once another node is seen publishing that transform",
    "publish_sensor_tf": "publish base_frame -> the scan's frame on /tf_static from filter.sensor_offset_* / "
    "laser.extrinsic (off when the bag's /tf_static has it)",
    "mount_from_tf": "live: the lidar mount is the first scan's frame in /tf_static + /tf (the predictor decides, "
    "the correlator and mapper wait for it on pf_slam/lidar_mount); mount parameters are the fallback",
    "mount_wait_s": "mount_from_tf: after the first scan, wait this long for its transform before using the "
    "parameters' mount (s)",
    "expected_observers": "extra subscribers (e.g. pf-slam run's recorder) that must be matched before the replay starts",
    "mode": "'slam' (build the map) or 'localization' (track the pose on a fixed map: mapper map_file, or any "
    "map_server's /map; the map is never changed)",
    "map_file": "mode localization: the map to localize on (map_server .yaml: pf-slam's map.yaml or nav2 map_saver's; "
    "trinary, scale or raw, negate), published latched on /map; empty: another node publishes /map",
    "map_publish_period_s": "/map, /map_metadata and /path are published this often (wall time), and after the last scan (s)",
    "occupied_thresh": "/map: a cell with occupancy probability >= this is 100 (map_server trinary) (probability)",
    "free_thresh": "/map: a cell with occupancy probability <= this is 0; between the two, -1 (probability)",
    "publish_period_s": "texture: the texture image is published this often (s)",
    "calibration_dir": "texture: KAIST-style calibration folder; empty: camera_info + /tf_static from the bag",
    "camera_extrinsic": "texture: left camera in base_frame, R row-major (9) then T (3, m); all zeros: from /tf_static",
    "queue_depth": "texture: stereo pairs waiting for the worker; a newer pair replaces the oldest (skipped)",
    "max_pending_pairs": "texture: pairs kept while waiting for their pose",
    "final_idle_s": "texture: after the end of the bag, finish once idle this long (s)",
    "await_trajectory": "texture: the final texture waits for pf_slam/trajectory and is placed on it "
    "(pf-slam run sets it when the mapper closes loops)",
    "trajectory_timeout_s": "texture: with await_trajectory, finish without it this long after the end of the bag (s)",
    "worker_nice": "texture: nice increment of the worker thread / process (the SLAM nodes keep priority)",
    "worker": "texture, correlator, mapper: where the node's side work runs (texture: the pairs; correlator: "
    "correlation.odom_scale's scan pairs; mapper: the loop matches): 'process' (a worker process, no GIL "
    "shared with the SLAM nodes) or 'thread' (in the node's process); same results",
    "pose_buffer_size": "texture: poses kept for interpolation at image stamps",
    "left_topic": "texture: left image topic",
    "right_topic": "texture: right image topic",
    "left_info_topic": "texture: left camera_info topic",
    "right_info_topic": "texture: right camera_info topic",
    "use_map_metadata": "texture: take the geometry from map_metadata (true) or from map (false)",
    "camera": "texture: 'stereo' (a stereo pair) or 'depth' (an RGB-D camera: colour + 16UC1 depth)",
    "rgb_topic": "texture, depth mode: colour image topic (rgb8 / bgr8)",
    "depth_topic": "texture, depth mode: depth image topic (16UC1, mm)",
    "rgb_info_topic": "texture, depth mode: colour camera_info topic (k)",
    "depth_info_topic": "texture, depth mode: depth camera_info topic (k)",
    "depth_pair_tol_s": "texture, depth mode: a depth image is paired with the colour image nearest in time within this (s)",
    "floor_height_m": "texture, depth mode: the kinematic floor's height in base_frame (m); the fitted floor is checked against it",
}


def attribute_docs(cls: type) -> dict[str, str]:
    """Field name -> description from a numpydoc "Attributes" section (``a, b : type`` lines
    followed by indented text), so a config's docstring is its parameters' documentation."""
    doc = (cls.__doc__ or "").split("Attributes\n    ----------\n", 1)
    out: dict[str, str] = {}
    if len(doc) < 2:
        return out
    names: list[str] = []
    for line in doc[1].splitlines():
        m = re.match(r"^    (\w[\w, ]*) : ", line)
        if m:
            names = [n.strip() for n in m.group(1).split(",")]
            for n in names:
                out[n] = ""
        elif line.startswith("        ") and names:
            for n in names:
                out[n] = (out[n] + " " + line.strip()).strip()
        elif line.strip() and not line.startswith("    "):
            break
    return out


def _as_default_type(default: Any, value: Any) -> Any:
    """An int given where the default is a float becomes a float (YAML `100` for `100.0`)."""
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def declare_config(node: Node, prefix: str, cls: type | None = None) -> Any:
    """Declare `prefix.<field>` for every field of the section's config (`cls`, default
    CONFIG_SECTIONS[prefix]); return the config.

    Values keep their dataclass defaults unless set by parameters; ints are accepted where a
    float is expected. Invalid values raise ValueError naming `prefix.field`. Each parameter's
    description is the field's entry in the class docstring.
    """
    cls = cls or CONFIG_SECTIONS[prefix]
    docs = attribute_docs(cls)
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        name = f"{prefix}.{f.name}"
        p = node.declare_parameter(
            name,
            list(default) if isinstance(default, tuple) else default,
            ParameterDescriptor(dynamic_typing=True, description=docs.get(f.name, "")),
        )
        v = p.value
        values[f.name] = tuple(float(x) for x in v) if isinstance(default, tuple) else _as_default_type(default, v)
    try:
        return cls.from_dict(values)
    except ValueError as e:
        raise ValueError(f"node {node.get_name()}: parameter section '{prefix}': {e}") from None


def param(node: Node, name: str, default: T) -> T:
    """Declare a plain parameter (described by PARAM_DOCS) and return its value (ints accepted
    for floats)."""
    desc = ParameterDescriptor(dynamic_typing=True, description=PARAM_DOCS.get(name, ""))
    v = _as_default_type(default, node.declare_parameter(name, default, desc).value)
    if default is not None and type(v) is not type(default):
        raise ValueError(f"node {node.get_name()}: parameter '{name}' must be {type(default).__name__}, got {v!r}")
    return v


def worker_param(node: Node) -> str:
    """The node's ``worker`` parameter, checked: 'process' or 'thread'."""
    kind = param(node, "worker", "process")
    if kind not in ("process", "thread"):
        raise ValueError(f"node {node.get_name()}: parameter 'worker' must be 'process' or 'thread', got {kind!r}")
    return kind


def close_on_failure(setup: Callable[[], None], close: Callable[[], None]) -> None:
    """A node's set-up after its stage started a worker process: if ``setup()`` raises (a bad
    parameter), ``close()`` stops the worker before the error goes on (no process outlives a
    node that was never made)."""
    try:
        setup()
    except BaseException:
        close()
        raise


class SideWork:
    """A SLAM node's side work (core/deferred.py), as its ``worker`` parameter says: ``process``,
    each object it hands work to lives in a worker process named after the node
    (nodes/worker.py ``ProcessOrInline``); ``thread``, in the node. A worker that dies is one
    error of the node (:attr:`error`, ``lost`` says what it owed; then ``on_error()``), and the
    work goes on in the node."""

    def __init__(self, node: Node, lost: str, on_error: Callable[[], None] | None = None) -> None:
        self.node, self.lost, self.on_error = node, lost, on_error
        self.kind = worker_param(node)
        self.error = ""

    def offload(self, cls: type, args: tuple):
        """The stage's :data:`~..core.deferred.Offload`."""
        if self.kind != "process":
            return inline(cls, args)
        from .worker import ProcessOrInline

        return ProcessOrInline(cls, args, self._died, name=f"{self.node.get_name()} worker")

    def _died(self, text: str) -> None:
        self.error = f"{text}; its work goes on in the node ({self.lost})"
        self.node.get_logger().error(self.error)
        if self.on_error is not None:
            self.on_error()


def announce_when_matched(
    node: Node, needs: list[tuple[Any, int]], period_s: float = 0.05, name: str | None = None
) -> None:
    """Publish `name` (default: the node's name) on pf_slam/ready (latched) once each publisher in
    `needs` has at least its number of matched subscriptions (each subscription: of matched
    publishers, for an observer such as the result recorder).

    Reliable, volatile topics lose what is published before a subscriber matches, so the replay
    starts only when every stage has announced (DDS matching is per writer/reader pair: only the
    two ends can see it).
    """
    from rclpy.publisher import Publisher
    from std_msgs.msg import String

    from ..ros import qos, topics

    pub = node.create_publisher(String, topics.READY, qos.latched(depth=1))
    timer = None

    def matched(e: Any) -> int:
        return e.get_subscription_count() if isinstance(e, Publisher) else e.get_publisher_count()

    def peers(e: Any) -> list[str]:
        infos = (
            node.get_subscriptions_info_by_topic if isinstance(e, Publisher) else node.get_publishers_info_by_topic
        )(e.topic_name)
        return [i.node_name for i in infos]

    def check() -> None:
        if all(matched(p) >= n for p, n in needs):
            node.get_logger().info(
                f"ready ({name or node.get_name()}): "
                + ", ".join(f"{p.topic_name} matched {matched(p)} {peers(p)}" for p, _ in needs)
            )
            pub.publish(String(data=name or node.get_name()))
            timer.cancel()

    timer = node.create_timer(period_s, check)


class ScanQueue:
    """Serialized scans in arrival order; a scan is deserialized only when it is taken. The
    correlator and the mapper receive only the scans that are corrected (pf_slam/scan_corrected,
    forwarded by the predictor).

    Scans are asked for by their number in the stream (the n-th corrected scan) and stamp.
    Without losses the n-th scan here is the n-th asked for; a replay faster than the graph can
    overflow the queues, and then messages may be lost on the way: the stamp finds the right scan
    (the nearest to where it is expected), or tells that it was lost here (a later-stamped scan
    has arrived and none matches), so a correction never uses another scan than its own.
    """

    def __init__(self) -> None:
        self._raw: deque[bytes] = deque()
        self._first = 0  # arrival number of _raw[0]
        self._shift = 0  # predictor's number - arrival number (0 unless scans were lost)
        self.received = 0
        self.lost = 0

    def append(self, raw: bytes) -> None:
        self._raw.append(raw)
        self.received += 1

    def _stamp(self, pos: int) -> int:
        from ..ros.convert import stamp_ns_from_cdr

        return stamp_ns_from_cdr(self._raw[pos])

    def _find(self, index: int, stamp_ns: int) -> int | None:
        """Queue position of the scan (index, stamp), -1 if it was lost here, None: not yet."""
        expected = index - self._shift - self._first
        if expected >= len(self._raw):
            return None  # not here yet (if scans were lost here: resolved as later ones arrive)
        if expected >= 0 and self._stamp(expected) == stamp_ns:
            return expected  # without losses: always here, one stamp read
        stamps = [self._stamp(p) for p in range(len(self._raw))]
        hits = [p for p, s in enumerate(stamps) if s == stamp_ns]
        if hits:
            return min(hits, key=lambda p: abs(p - expected))
        return -1 if any(s > stamp_ns for s in stamps) else None

    def has(self, index: int, stamp_ns: int) -> bool:
        """True when :meth:`take` can answer: the scan is here, or it is known lost."""
        return self._find(index, stamp_ns) is not None

    def take(self, index: int, stamp_ns: int):
        """Deserialize scan (index, stamp) (a LaserScan), or None if it was lost here; the scans
        before it are forgotten."""
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import LaserScan

        pos = self._find(index, stamp_ns)
        if pos is None:
            raise IndexError(f"scan {index} is not queued (have {self._first}..{self.received - 1})")
        if pos < 0:
            self.lost += 1
            return None
        for _ in range(pos):
            self._raw.popleft()
        self._first += pos + 1
        self._shift = index - (self._first - 1)
        return deserialize_message(self._raw.popleft(), LaserScan)


def scan_fields(scan) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(ranges, angles, range_min, range_max) of a taken LaserScan; no beams for a lost one
    (None): the stages then correct and map nothing, and every set still gets its answer."""
    if scan is None:
        return np.empty(0), np.empty(0), 0.0, math.inf
    from ..ros.convert import scan_arrays

    return (*scan_arrays(scan), float(scan.range_min), float(scan.range_max))


def mount_of(pa):
    """The per-scan lidar mount a ParticleArray carries ((12,) array), or None: the static one."""
    return np.asarray(pa.mount, dtype=np.float64) if len(pa.mount) == 12 else None


def status_publisher(node: Node, status: Callable[[], dict]) -> Callable[[], None]:
    """The node's pf_slam/status (latched JSON, for the run's summary): ``status()`` is published
    now, then at most once a second when it changed; returns the function that publishes it at
    once (only if changed), e.g. at the end of the run."""
    import json

    from std_msgs.msg import String

    from ..ros import qos, topics

    pub = node.create_publisher(String, topics.STATUS, qos.latched())
    sent: list[dict] = []

    def publish() -> None:
        s = {"node": node.get_name(), **status()}
        if not sent or s != sent[0]:
            pub.publish(String(data=json.dumps(s)))
            sent[:] = [s]

    node.create_timer(1.0, publish)
    publish()
    return publish


def die_with_parent() -> None:
    """Started by `pf-slam run --processes multi` (PF_SLAM_PARENT_PID set): get SIGTERM when that
    process ends, however it ends (Linux prctl PR_SET_PDEATHSIG), so no node outlives its run."""
    parent = os.environ.get("PF_SLAM_PARENT_PID")
    if not parent or not sys.platform.startswith("linux"):
        return
    import ctypes

    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # 1 = PR_SET_PDEATHSIG
    if os.getppid() != int(parent):  # the parent ended before prctl took effect
        sys.exit(1)


def warn_undeclared(node: Node) -> list[str]:
    """Warn about overrides (a --params-file, e.g. from ros2 launch) that no node of the graph
    declares: ROS ignores them, so a typo would silently keep the default. Names another node
    declares are not warned about ('/**' values reach every node). Returns the names."""
    from .declared import RUN_KEYS_PREFIXES, declared_by, nearest

    by = declared_by()
    names = sorted(
        k
        for k in getattr(node, "_parameter_overrides", {})
        if k not in by and not node.has_parameter(k) and not k.startswith(("qos_overrides.",) + RUN_KEYS_PREFIXES)
    )
    for k in names:
        near = nearest(k, by)
        node.get_logger().warning(
            f"parameter '{k}' is set but no node declares it: ignored" + (f" (nearest known: '{near}')" if near else "")
        )
    return names


def follow_clock(node, log: Callable[[str], None] | None = None) -> None:
    """Switch `node` to the simulated clock (use_sim_time) at the first /clock message, unless
    use_sim_time was set for it: `use_sim_time` follows /clock, as a user of a bag player expects."""
    from rclpy.parameter import Parameter
    from rosgraph_msgs.msg import Clock

    from ..ros import qos, topics

    if "use_sim_time" in getattr(node, "_parameter_overrides", {}):
        return
    holder: list = []

    def on_clock(_msg) -> None:
        if not holder:
            return
        node.destroy_subscription(holder.pop())
        node.set_parameters([Parameter("use_sim_time", Parameter.Type.BOOL, True)])
        (log or node.get_logger().info)(f"{node.get_name()}: /clock is published: use_sim_time true")

    holder.append(node.create_subscription(Clock, topics.CLOCK, on_clock, qos.outputs(10)))


def run_node(factory: Callable[..., Node], args: list[str] | None = None, clock_follower: bool = True) -> int:
    """`main()` of a node console script: init, spin until Ctrl-C / SIGTERM / shutdown, clean up.
    `clock_follower`: use_sim_time follows /clock when not set (not for the clock's own source)."""
    die_with_parent()
    keep_freed_memory()
    rclpy.init(args=args)
    node = None
    try:
        node = factory()
        warn_undeclared(node)
        if clock_follower:
            follow_clock(node)  # use_sim_time unset (a launch file's use_sim_time:=auto): it follows /clock
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        ex.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ValueError as e:  # bad parameters: one clear line, no traceback
        print(f"error: {e}", file=sys.stderr)
        return 2
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0
