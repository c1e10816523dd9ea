"""rosbag2 writing and reading with ``rosbags`` (no ROS install needed), and message builders.

Messages are the ``rosbags`` typestore classes of ROS 2 Jazzy (``TYPESTORE``), serialised as
CDR, so a bag written here plays back with ``ros2 bag play`` and reads back with ``rosbags``.
Bags are written as rosbag2 format version 9 (Jazzy), MCAP storage by default, ``sqlite3`` on
request; both are read.

Writing::

    with open_writer('out_bag') as bag:
        bag.add_connection('/scan', 'sensor_msgs/msg/LaserScan')
        bag.write('/scan', stamp_ns, laser_scan(stamp_ns, 'laser', -1.57, 0.01, ranges, 0.0, 80.0))

Reading::

    for topic, msgtype, stamp_ns, raw in read_bag('out_bag'):
        msg = deserialize(raw, msgtype)          # rosbags object; rclpy users: deserialize_message

Any failure to open or read a bag (missing path, not a bag, corrupt file) raises ``BagError``
naming the path and the cause. ``check_run_inputs`` says, in one line, what a bag lacks for
``pf-slam run`` (topics, their types, message types this ROS install cannot publish).
"""

from __future__ import annotations

import importlib
import math
import os
import sqlite3
import struct
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.errors import ReaderError, WriterError
from rosbags.typesys import Stores, get_typestore

from ..core.geometry import yaw_to_quat

__all__ = [
    "BagError",
    "BagReadError",
    "BagWriter",
    "STORAGES",
    "TYPESTORE",
    "bag_info",
    "check_run_inputs",
    "camera_info",
    "clock",
    "deserialize",
    "image",
    "joint_state_wheels",
    "laser_scan",
    "make_header",
    "make_time",
    "odometry",
    "open_writer",
    "read_bag",
    "stamp_ns_of",
    "tf_static",
]

#: The ROS 2 Jazzy message definitions used for every message written or read here.
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)

#: Storage names accepted by ``open_writer``.
STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}

BAG_VERSION = 9

_ZERO = QosTime(sec=0, nsec=0)
_INF = QosTime(sec=0x7FFFFFFF, nsec=0xFFFFFFFF)
#: Offered QoS recorded for latched topics (``/tf_static``): reliable, transient local, depth 1.
LATCHED_QOS = Qos(
    history=QosHistory.KEEP_LAST,
    depth=1,
    reliability=QosReliability.RELIABLE,
    durability=QosDurability.TRANSIENT_LOCAL,
    deadline=_INF,
    lifespan=_INF,
    liveliness=QosLiveliness.AUTOMATIC,
    liveliness_lease_duration=_INF,
    avoid_ros_namespace_conventions=False,
)

# What rosbags and its storage backends raise on a missing, foreign or damaged bag.
_READ_ERRORS = (
    ReaderError,
    OSError,
    ValueError,
    KeyError,
    IndexError,
    TypeError,
    OverflowError,
    AttributeError,
    struct.error,
    sqlite3.Error,
    EOFError,
    UnicodeDecodeError,
)


class BagError(Exception):
    """A bag cannot be written, opened or read; the message names the path and the cause."""


class BagReadError(BagError):
    """Damage found while reading a bag's messages, after `messages` good ones (the last at
    record time `last_stamp_ns`, None if none): the messages before the damage were yielded.
    `damage`: ``damaged at message 1235 of PATH (1234 read, the last at record time 61.2 s):
    ReaderError: Chunk checksum mismatch.``"""

    def __init__(self, path: Path, messages: int, last_stamp_ns: int | None, cause: BaseException) -> None:
        self.path = path
        self.messages = messages
        self.last_stamp_ns = last_stamp_ns
        after = "" if last_stamp_ns is None else f", the last at record time {last_stamp_ns / 1e9:.9f} s"
        where = f"message {messages + 1}"
        what = f"({messages} read{after}): {type(cause).__name__}: {cause}"
        self.damage = f"damaged at {where} of {path} {what}"
        super().__init__(f"{path}: cannot read messages: damaged at {where} {what}")


# --------------------------------------------------------------------------------------------
# writing


class BagWriter:
    """Thin wrapper around ``rosbags.rosbag2.Writer`` keyed by topic name.

    Use through ``open_writer``. ``counts`` holds the number of messages written per topic.
    """

    def __init__(self, writer: Writer) -> None:
        self._writer = writer
        self._connections: dict[str, Any] = {}
        self._msgtypes: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        self.path = Path(writer.path)

    def add_connection(self, topic: str, msgtype: str, latched: bool | None = None) -> None:
        """Register ``topic`` with a message type such as ``'sensor_msgs/msg/LaserScan'``.

        ``latched`` records a transient-local offered QoS (so ``ros2 bag play`` re-publishes it
        latched); ``None`` means: latched for topics ending in ``tf_static``.
        """
        if topic in self._connections:
            raise BagError(f"{self.path}: topic {topic!r} already added")
        if msgtype not in TYPESTORE.types:
            raise BagError(
                f"{self.path}: unknown message type {msgtype!r} for {topic!r} (not in the ROS 2 Jazzy typestore)"
            )
        if latched is None:
            latched = topic.rstrip("/").endswith("tf_static")
        qos = [LATCHED_QOS] if latched else []
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=TYPESTORE, offered_qos_profiles=qos
        )
        self._msgtypes[topic] = msgtype
        self.counts[topic] = 0

    def write(self, topic: str, stamp_ns: int, msg: object) -> None:
        """Serialise ``msg`` (a ``TYPESTORE`` message) as CDR and record it at ``stamp_ns``."""
        msgtype = self._msgtype(topic)
        got = getattr(msg, "__msgtype__", None)
        if got != msgtype:
            raise BagError(f"{self.path}: topic {topic!r} carries {msgtype}, got {got}")
        self.write_raw(topic, stamp_ns, TYPESTORE.serialize_cdr(msg, msgtype))

    def write_raw(self, topic: str, stamp_ns: int, data: bytes | memoryview) -> None:
        """Record already serialised CDR bytes at ``stamp_ns``."""
        self._msgtype(topic)
        stamp_ns = int(stamp_ns)
        if stamp_ns < 0:
            raise BagError(f"{self.path}: negative record time {stamp_ns} on {topic!r}")
        self._writer.write(self._connections[topic], stamp_ns, data)
        self.counts[topic] += 1

    def set_custom_data(self, key: str, value: str) -> None:
        """Store a string in ``metadata.yaml`` ``custom_data`` (``bag_info`` returns it)."""
        self._writer.set_custom_data(str(key), str(value))

    def _msgtype(self, topic: str) -> str:
        try:
            return self._msgtypes[topic]
        except KeyError:
            raise BagError(f"{self.path}: topic {topic!r} was not added (call add_connection first)") from None


@contextmanager
def open_writer(out_path: str | os.PathLike, storage: str = "mcap") -> Iterator[BagWriter]:
    """Create a new rosbag2 directory at ``out_path`` and yield a ``BagWriter``.

    ``storage`` is ``'mcap'`` (default) or ``'sqlite3'``. Refuses to touch an existing path
    (``BagError``); missing parent directories are created. The bag is closed (``metadata.yaml`` written) when the block ends, also
    when it ends with an exception, so a partial bag stays readable.
    """
    if storage not in STORAGES:
        raise ValueError(f"storage must be one of {sorted(STORAGES)}, got {storage!r}")
    path = Path(out_path)
    if path.exists():
        raise BagError(f"{path}: already exists; refusing to overwrite (remove it or choose another output path)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)  # `convert … bags_local/x` with no bags_local yet
    except OSError as exc:
        raise BagError(f"{path}: cannot create its parent directory: {exc}") from exc
    try:
        writer = Writer(path, version=BAG_VERSION, storage_plugin=STORAGES[storage])
        writer.open()
    except (WriterError, OSError) as exc:
        raise BagError(f"{path}: cannot create bag: {exc}") from exc
    try:
        yield BagWriter(writer)
    finally:
        writer.close()


# --------------------------------------------------------------------------------------------
# reading


def _open_reader(path: str | os.PathLike) -> Reader:
    p = Path(path)
    if not p.exists():
        raise BagError(f"{p}: no such file or directory")
    if p.is_dir() and not (p / "metadata.yaml").is_file():
        raise BagError(f"{p}: not a rosbag2 directory (no metadata.yaml)")
    try:
        reader = Reader(p)
        reader.open()
    except _READ_ERRORS as exc:
        raise BagError(f"{p}: cannot open bag: {type(exc).__name__}: {exc}") from exc
    return reader


def read_bag(path: str | os.PathLike, topics: Iterable[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
    """Yield ``(topic, msgtype, stamp_ns, rawdata)`` of every message, in record-time order.

    ``path`` is a rosbag2 directory (mcap or sqlite3) or a single ``.mcap`` / ``.db3`` file.
    ``topics`` restricts the output to those topics. ``rawdata`` is CDR bytes (feed it to
    ``deserialize`` or to ``rclpy.serialization.deserialize_message``). Messages with equal
    record times come in the order they were written.

    Raises ``BagError`` at the call if the bag is missing, not a bag or damaged.
    """
    p = Path(path)
    _open_reader(p).close()  # fail here, at the call, on a missing / foreign / damaged bag
    return _iter_bag(p, None if topics is None else set(topics))


def _iter_bag(p: Path, wanted: set[str] | None) -> Iterator[tuple[str, str, int, bytes]]:
    reader = _open_reader(p)
    try:
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if wanted is not None and not conns:
            return
        n, last = 0, None
        try:
            for conn, stamp_ns, raw in reader.messages(connections=conns):
                last = int(stamp_ns)
                yield conn.topic, conn.msgtype, last, bytes(raw)
                n += 1
        except _READ_ERRORS as exc:
            raise BagReadError(p, n, last, exc) from exc
    finally:
        reader.close()


def bag_info(path: str | os.PathLike) -> dict:
    """Summary of a bag.

    Returns
    -------
    dict
        ``topics``: ``{topic: (msgtype, count)}``; ``start_ns``, ``end_ns`` (record time of the
        first and last message), ``duration_ns``, ``message_count``, ``storage``
        (``'mcap'`` / ``'sqlite3'``), ``custom_data`` (``{str: str}`` from ``metadata.yaml``;
        empty for a bare ``.mcap`` / ``.db3`` file) and ``path``.
    """
    p = Path(path)
    reader = _open_reader(p)
    try:
        topics = {name: (info.msgtype, int(info.msgcount)) for name, info in reader.topics.items()}
        count = int(reader.message_count)
        start = int(reader.start_time) if count else 0
        duration = int(reader.duration) if count else 0
        # rosbags reports end_time as (last + 1); duration likewise; report the plain span.
        if count:
            duration = max(duration - 1, 0)
        meta = getattr(reader.storage, "metadata", None)
        custom = dict(getattr(meta, "custom", None) or {})
    except _READ_ERRORS as exc:
        raise BagError(f"{p}: cannot read bag metadata: {type(exc).__name__}: {exc}") from exc
    finally:
        reader.close()
    storage = _storage_of(p)
    return {
        "path": str(p),
        "topics": topics,
        "start_ns": start,
        "end_ns": start + duration,
        "duration_ns": duration,
        "message_count": count,
        "storage": storage,
        "custom_data": custom,
    }


#: Topics ``pf-slam run`` reads, with the message types it accepts on each.
RUN_TOPICS = {
    "/scan": ("sensor_msgs/msg/LaserScan",),
    "/odom": ("nav_msgs/msg/Odometry",),
    "/encoders": ("sensor_msgs/msg/JointState",),
    "/fog": ("pf_slam_interfaces/msg/FogBatch", "geometry_msgs/msg/Vector3Stamped"),
    "/tf_static": ("tf2_msgs/msg/TFMessage",),
    "/stereo/left/image_raw": ("sensor_msgs/msg/Image",),
    "/stereo/right/image_raw": ("sensor_msgs/msg/Image",),
    "/stereo/left/camera_info": ("sensor_msgs/msg/CameraInfo",),
    "/stereo/right/camera_info": ("sensor_msgs/msg/CameraInfo",),
}
RUN_NEEDS = (
    "/scan [sensor_msgs/msg/LaserScan] with messages, and /odom [nav_msgs/msg/Odometry] "
    "or /encoders [sensor_msgs/msg/JointState]"
)


def ros_type_available(msgtype: str) -> bool:
    """Whether this Python environment has the ROS message class ``pkg/msg/Name``."""
    pkg, _, name = msgtype.rpartition("/msg/")
    try:
        return bool(pkg) and hasattr(importlib.import_module(f"{pkg}.msg"), name)
    except ImportError:
        return False


def check_run_inputs(info: dict) -> None:
    """Raise ``BagError`` (one line) unless the bag of ``info`` (``bag_info``) can be run.

    It needs ``RUN_NEEDS``; a topic of ``RUN_TOPICS`` must carry one of its types; every
    topic's type must be importable (the replay publishes every topic). The message lists all
    problems, then what the bag has and what is needed.
    """
    topics = info["topics"]
    problems = [
        f"{t} is {m}, expected {' or '.join(RUN_TOPICS[t])}"
        for t, (m, _) in sorted(topics.items())
        if m not in RUN_TOPICS.get(t, (m,))
    ]
    if "/scan" not in topics:
        problems.append("no /scan topic")
    elif topics["/scan"][1] == 0:
        problems.append("/scan has no messages")
    if "/odom" not in topics and "/encoders" not in topics:
        problems.append("no /odom or /encoders topic")
    unknown = sorted({m for m, _ in topics.values() if not ros_type_available(m)})
    if unknown:
        problems.append(f"message types unknown to this ROS install: {', '.join(unknown)}")
    if problems:
        found = ", ".join(f"{t} [{m}] ({n})" for t, (m, n) in sorted(topics.items())) or "no topic"
        raise BagError(f"{info['path']}: cannot run: {'; '.join(problems)}. Found: {found}. Needs: {RUN_NEEDS}")


def _storage_of(p: Path) -> str:
    files = [p] if p.is_file() else sorted(p.iterdir())
    for f in files:
        if f.suffix == ".mcap":
            return "mcap"
        if f.suffix == ".db3":
            return "sqlite3"
    return "unknown"


def deserialize(rawdata: bytes | memoryview, msgtype: str) -> Any:
    """CDR bytes -> ``TYPESTORE`` message object. Raises ``BagError`` on bad data."""
    try:
        return TYPESTORE.deserialize_cdr(rawdata, msgtype)
    except (KeyError, ValueError, IndexError, struct.error) as exc:
        raise BagError(f"cannot deserialize {msgtype}: {type(exc).__name__}: {exc}") from exc


# --------------------------------------------------------------------------------------------
# message builders (TYPESTORE classes)

_T = TYPESTORE.types
Time = _T["builtin_interfaces/msg/Time"]
Header = _T["std_msgs/msg/Header"]


def make_time(stamp_ns: int) -> Any:
    """``builtin_interfaces/Time`` from integer nanoseconds."""
    stamp_ns = int(stamp_ns)
    if stamp_ns < 0:
        raise ValueError(f"stamp_ns must be >= 0, got {stamp_ns}")
    return Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)


def stamp_ns_of(msg: Any) -> int:
    """Integer nanoseconds of a ``Time`` or of a message with a ``header``."""
    t = msg.header.stamp if hasattr(msg, "header") else msg
    return int(t.sec) * 1_000_000_000 + int(t.nanosec)


def make_header(stamp_ns: int, frame_id: str) -> Any:
    """``std_msgs/Header``."""
    return Header(stamp=make_time(stamp_ns), frame_id=str(frame_id))


def laser_scan(
    stamp_ns: int,
    frame_id: str,
    angle_min: float,
    angle_increment: float,
    ranges: Sequence[float] | np.ndarray,
    range_min: float,
    range_max: float,
    scan_time: float = 0.0,
    time_increment: float = 0.0,
) -> Any:
    """``sensor_msgs/LaserScan``; ``ranges`` (m, float32, ``+inf`` = no return), no intensities.

    ``angle_max = angle_min + (B - 1) * angle_increment``.
    """
    r = np.ascontiguousarray(ranges, dtype=np.float32).ravel()
    return _T["sensor_msgs/msg/LaserScan"](
        header=make_header(stamp_ns, frame_id),
        angle_min=float(angle_min),
        angle_max=float(angle_min + (len(r) - 1) * angle_increment),
        angle_increment=float(angle_increment),
        time_increment=float(time_increment),
        scan_time=float(scan_time),
        range_min=float(range_min),
        range_max=float(range_max),
        ranges=r,
        intensities=np.zeros(0, dtype=np.float32),
    )


def odometry(
    stamp_ns: int,
    frame_id: str = "odom",
    child: str = "base_link",
    pose: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
    twist: Sequence[float] | None = None,
) -> Any:
    """``nav_msgs/Odometry`` from a planar pose ``(x, y, theta)`` and optional twist ``(v, w)``.

    Covariances are left zero (unknown); ``twist`` is in the child frame.
    """
    x, y, th = (float(v) for v in pose)
    v, w = (0.0, 0.0) if twist is None else (float(twist[0]), float(twist[1]))
    qx, qy, qz, qw = yaw_to_quat(th)
    pose_msg = _T["geometry_msgs/msg/Pose"](
        position=_T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
        orientation=_T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
    )
    twist_msg = _T["geometry_msgs/msg/Twist"](
        linear=_T["geometry_msgs/msg/Vector3"](x=v, y=0.0, z=0.0),
        angular=_T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=w),
    )
    return _T["nav_msgs/msg/Odometry"](
        header=make_header(stamp_ns, frame_id),
        child_frame_id=str(child),
        pose=_T["geometry_msgs/msg/PoseWithCovariance"](pose=pose_msg, covariance=np.zeros(36, dtype=np.float64)),
        twist=_T["geometry_msgs/msg/TwistWithCovariance"](twist=twist_msg, covariance=np.zeros(36, dtype=np.float64)),
    )


def joint_state_wheels(stamp_ns: int, left_rad: float, right_rad: float, frame_id: str = "") -> Any:
    """``sensor_msgs/JointState`` named ``['left_wheel', 'right_wheel']``.

    ``position`` = cumulative wheel angles (rad); velocity and effort are empty.
    """
    return _T["sensor_msgs/msg/JointState"](
        header=make_header(stamp_ns, frame_id),
        name=["left_wheel", "right_wheel"],
        position=np.array([left_rad, right_rad], dtype=np.float64),
        velocity=np.zeros(0, dtype=np.float64),
        effort=np.zeros(0, dtype=np.float64),
    )


def tf_static(stamp_ns: int, transforms: Iterable[tuple[str, str, Sequence[float], Sequence[float]]]) -> Any:
    """``tf2_msgs/TFMessage`` from ``(parent, child, (x, y, z), (qx, qy, qz, qw))`` tuples."""
    out = []
    for parent, child, xyz, quat in transforms:
        qx, qy, qz, qw = (float(v) for v in quat)
        norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        if not norm > 0.0:
            raise ValueError(f"zero quaternion for {parent} -> {child}")
        tr = _T["geometry_msgs/msg/Transform"](
            translation=_T["geometry_msgs/msg/Vector3"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])),
            rotation=_T["geometry_msgs/msg/Quaternion"](x=qx / norm, y=qy / norm, z=qz / norm, w=qw / norm),
        )
        out.append(
            _T["geometry_msgs/msg/TransformStamped"](
                header=make_header(stamp_ns, parent), child_frame_id=str(child), transform=tr
            )
        )
    return _T["tf2_msgs/msg/TFMessage"](transforms=out)


def clock(stamp_ns: int) -> Any:
    """``rosgraph_msgs/Clock``."""
    return _T["rosgraph_msgs/msg/Clock"](clock=make_time(stamp_ns))


def image(stamp_ns: int, frame_id: str, pixels: np.ndarray, encoding: str) -> Any:
    """``sensor_msgs/Image`` of a ``uint8`` array ``(H, W)`` or ``(H, W, C)``, copied as is.

    ``step = W * C``; ``encoding`` is the ROS name (``'mono8'``, ``'bgr8'``,
    ``'bayer_rggb8'`` ...), not checked against the array.
    """
    a = np.ascontiguousarray(pixels)
    if a.dtype != np.uint8 or a.ndim not in (2, 3):
        raise ValueError(f"image pixels must be uint8 (H, W) or (H, W, C), got {a.dtype} {a.shape}")
    h, w = a.shape[:2]
    return _T["sensor_msgs/msg/Image"](
        header=make_header(stamp_ns, frame_id),
        height=int(h),
        width=int(w),
        encoding=str(encoding),
        is_bigendian=0,
        step=int(a.strides[0]),
        data=a.reshape(-1),
    )


def camera_info(
    stamp_ns: int,
    frame_id: str,
    width: int,
    height: int,
    distortion_model: str,
    d: Sequence[float] | np.ndarray,
    k: Sequence[float] | np.ndarray,
    r: Sequence[float] | np.ndarray,
    p: Sequence[float] | np.ndarray,
) -> Any:
    """``sensor_msgs/CameraInfo``; ``k`` (3x3), ``r`` (3x3), ``p`` (3x4) row-major, any shape.

    Binning 0 and an empty region of interest (the full image).
    """

    def arr(v: Any, n: int | None, name: str) -> np.ndarray:
        a = np.asarray(v, dtype=np.float64).ravel()
        if n is not None and a.size != n:
            raise ValueError(f"camera_info {name} needs {n} values, got {a.size}")
        return a

    roi = _T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return _T["sensor_msgs/msg/CameraInfo"](
        header=make_header(stamp_ns, frame_id),
        height=int(height),
        width=int(width),
        distortion_model=str(distortion_model),
        d=arr(d, None, "d"),
        k=arr(k, 9, "k"),
        r=arr(r, 9, "r"),
        p=arr(p, 12, "p"),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )
