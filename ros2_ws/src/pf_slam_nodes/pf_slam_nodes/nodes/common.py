"""Helpers shared by the nodes: parameters mirrored from the core's config dataclasses."""
from __future__ import annotations

import dataclasses
import re
import sys
from collections import deque
from typing import Any, Callable, TypeVar

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from ..core import config as cfg

T = TypeVar("T")

#: Dotted parameter prefix -> core config class (kiss-icp style: `grid.resolution_m`).
CONFIG_SECTIONS: dict[str, type] = {
    "filter": cfg.FilterConfig,
    "motion": cfg.OdometryMotionConfig,
    "diff_drive": cfg.DiffDriveConfig,
    "grid": cfg.GridConfig,
    "correlation": cfg.CorrelationConfig,
    "resample": cfg.ResampleConfig,
    "laser": cfg.LaserConfig,
}


#: Descriptions of the plain (non-config) node parameters: they go into each parameter's
#: ParameterDescriptor (`ros2 param describe`) and into docs/parameters.md (`pf-slam params`).
#: Config sections take theirs from the dataclasses' "Attributes" docstrings.
PARAM_DOCS: dict[str, str] = {
    "bag": "rosbag2 to replay (folder or file; mcap or sqlite3); required",
    "rate": "'max': as fast as the pipeline takes it, lossless (paced on pose); N: N x real time (s/s)",
    "max_in_flight": "rate max: at most this many scans published and not yet posed",
    "scan_topic": "the bag's LaserScan topic (pacing, end-of-bag counts)",
    "scan_subscribers": "subscriptions the scan topic must have matched before the replay starts",
    "clock_period_s": "/clock goes out at least this often in bag time, and with every scan (s)",
    "wait_for": "nodes whose pf_slam/ready announcement the replay waits for before it starts",
    "map_frame": "REP-105 map frame: /map, /path, /pose and particle sets are in it",
    "odom_frame": "REP-105 odom frame: parent of base_frame (dead reckoning), child of map_frame",
    "base_frame": "REP-105 robot frame (base_link): child of odom_frame, parent of the sensor frames",
    "odometry_source": "'odom' (nav_msgs/Odometry on odom) or 'encoders' (JointState wheel angles on encoders)",
    "odom_sync": "'exact': odometry stamped like each scan (same log line); 'interpolate': asynchronous odometry",
    "fog_format": "yaw from a gyro on fog instead of the wheels: 'none', 'batch' (FogBatch) or 'vector3' (Vector3Stamped)",
    "wheels.left_diameter_m": "left wheel diameter, odometry_source encoders (m)",
    "wheels.right_diameter_m": "right wheel diameter, odometry_source encoders (m)",
    "wheels.base_m": "distance between the wheels, odometry_source encoders (m)",
    "publish_odom_tf": "publish odom -> base_frame on /tf at every scan (off when the bag carries its own /tf)",
    "publish_sensor_tf": "publish base_frame -> the scan's frame on /tf_static from filter.sensor_offset_* / "
                         "laser.extrinsic (off when the bag's /tf_static has it)",
    "expected_observers": "extra subscribers (e.g. pf-slam run's recorder) that must be matched before the replay starts",
    "map_publish_period_s": "/map, /map_metadata and /path are published this often (wall time), and after the last scan (s)",
    "occupied_thresh": "/map: a cell with occupancy probability >= this is 100 (map_server trinary) (probability)",
    "free_thresh": "/map: a cell with occupancy probability <= this is 0; between the two, -1 (probability)",
    "publish_period_s": "texture: the texture image is published this often (s)",
    "calibration_dir": "texture: KAIST-style calibration folder; empty: camera_info + /tf_static from the bag",
    "camera_extrinsic": "texture: left camera in base_frame, R row-major (9) then T (3, m); all zeros: from /tf_static",
    "queue_depth": "texture: stereo pairs waiting for the worker; a newer pair replaces the oldest (skipped)",
    "max_pending_pairs": "texture: pairs kept while waiting for their pose",
    "final_idle_s": "texture: after the end of the bag, finish once idle this long (s)",
    "worker_nice": "texture: nice increment of the worker thread (the SLAM nodes keep priority)",
    "pose_buffer_size": "texture: poses kept for interpolation at image stamps",
    "left_topic": "texture: left image topic",
    "right_topic": "texture: right image topic",
    "left_info_topic": "texture: left camera_info topic",
    "right_info_topic": "texture: right camera_info topic",
    "use_map_metadata": "texture: take the geometry from map_metadata (true) or from map (false)",
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
        p = node.declare_parameter(name, list(default) if isinstance(default, tuple) else default,
                                   ParameterDescriptor(dynamic_typing=True, description=docs.get(f.name, "")))
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
        raise ValueError(f"node {node.get_name()}: parameter '{name}' must be "
                         f"{type(default).__name__}, got {v!r}")
    return v


def announce_when_matched(node: Node, needs: list[tuple[Any, int]], period_s: float = 0.05,
                          name: str | None = None) -> None:
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
        infos = (node.get_subscriptions_info_by_topic if isinstance(e, Publisher)
                 else node.get_publishers_info_by_topic)(e.topic_name)
        return [i.node_name for i in infos]

    def check() -> None:
        if all(matched(p) >= n for p, n in needs):
            node.get_logger().info(f"ready ({name or node.get_name()}): " + ", ".join(
                f"{p.topic_name} matched {matched(p)} {peers(p)}" for p, _ in needs))
            pub.publish(String(data=name or node.get_name()))
            timer.cancel()
    timer = node.create_timer(period_s, check)


class ScanQueue:
    """Serialized scans in arrival order, numbered from 0; a scan is deserialized only when it
    is taken. The correlator and the mapper need only the scans that are corrected (the car's
    lidar runs at 100 Hz, corrections every ~2 m), so most scans are dropped unread."""

    def __init__(self) -> None:
        self._raw: deque[bytes] = deque()
        self._first = 0  # index of _raw[0]
        self.received = 0

    def append(self, raw: bytes) -> None:
        self._raw.append(raw)
        self.received += 1

    def has(self, index: int) -> bool:
        return index < self.received

    def take(self, index: int):
        """Deserialize scan `index` (a LaserScan); scans before it are forgotten."""
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import LaserScan
        if not self._first <= index < self.received:
            raise IndexError(f"scan {index} is not queued (have {self._first}..{self.received - 1})")
        for _ in range(index - self._first):
            self._raw.popleft()
        self._first = index + 1
        return deserialize_message(self._raw.popleft(), LaserScan)


def run_node(factory: Callable[..., Node], args: list[str] | None = None) -> int:
    """`main()` of a node console script: init, spin until Ctrl-C / shutdown, clean up."""
    rclpy.init(args=args)
    node = None
    try:
        node = factory()
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
