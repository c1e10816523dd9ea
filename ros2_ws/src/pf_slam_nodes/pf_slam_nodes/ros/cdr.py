"""Direct CDR reading/writing of the high-rate messages (no Python message objects).

rclpy turns every received message into Python objects (a JointState is eight of them) and
every published one back; at the car's rates (100 Hz encoders, FOG batches and scans, a pose
per scan) that costs more than the filter. The nodes therefore subscribe to these topics raw
(``raw=True``) and publish the pose as bytes, through the readers and the writer below.

The format is plain CDR (XCDR1) as rmw_fastrtps / rmw_cyclonedds and rosbags write it: a 4-byte
encapsulation header (byte 1: 1 = little endian), then the fields in order, each primitive aligned
to its size counted from the end of that header; a string is a uint32 length (with the NUL) and
its bytes; a sequence a uint32 count and its elements. Every reader checks what it reads against
the buffer's length and raises ``ValueError`` naming the message type otherwise, and the unit
tests compare each against rclpy's own (de)serialization.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from ..core.geometry import quat_to_yaw, yaw_to_quat

_HDR = 4  # encapsulation header; alignment counts from its end
_LITTLE_ENDIAN = b"\x00\x01\x00\x00"  # the encapsulation header the writers below emit
_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time: sec, nanosec


class CdrReader:
    """Sequential reader over one serialized message."""

    def __init__(self, raw: bytes, what: str) -> None:
        if len(raw) < 12 or raw[0] != 0 or raw[1] not in (0, 1):
            raise ValueError(f"{what}: not a CDR-serialized message ({len(raw)} bytes)")
        self.raw = raw
        self.what = what
        self.little = raw[1] == 1
        self.end = "<" if self.little else ">"
        self.pos = _HDR

    def _align(self, n: int) -> None:
        self.pos += (-(self.pos - _HDR)) % n

    def _need(self, n: int) -> None:
        if self.pos + n > len(self.raw):
            raise ValueError(f"{self.what}: truncated CDR ({len(self.raw)} bytes, field at {self.pos}+{n})")

    def u32(self) -> int:
        self._align(4)
        self._need(4)
        v = struct.unpack_from(self.end + "I", self.raw, self.pos)[0]
        self.pos += 4
        return v

    def stamp_ns(self) -> int:
        self._align(4)
        self._need(8)
        sec, nsec = struct.unpack_from(self.end + "iI", self.raw, self.pos)
        self.pos += 8
        return sec * 1_000_000_000 + nsec

    def skip_string(self) -> None:
        n = self.u32()
        self._need(n)
        self.pos += n

    def string(self) -> str:
        n = self.u32()
        self._need(n)
        s = bytes(self.raw[self.pos : self.pos + n]).rstrip(b"\0").decode("utf-8", "replace")
        self.pos += n
        return s

    def header(self) -> int:
        """std_msgs/Header -> stamp (ns); the frame_id is skipped."""
        stamp = self.stamp_ns()
        self.skip_string()
        return stamp

    def array(self, dtype: str) -> np.ndarray:
        """A sequence of a numeric primitive (``'f8'``, ``'i8'``, ``'f4'``) as a read-only view."""
        n = self.u32()
        if n == 0:
            return np.empty(0, dtype=dtype)
        size = np.dtype(dtype).itemsize
        self._align(size)
        self._need(size * n)
        out = np.frombuffer(self.raw, dtype=np.dtype(dtype).newbyteorder(self.end), count=n, offset=self.pos)
        self.pos += size * n
        return out


def tf_transforms(raw: bytes) -> list[tuple[int, str, str, tuple, tuple]]:
    """tf2_msgs/TFMessage bytes -> [(stamp ns, parent, child, (x, y, z), (qx, qy, qz, qw))]
    (the predictor takes a moving lidar mount from /tf at 100 Hz: no message objects)."""
    r = CdrReader(raw, "tf2_msgs/TFMessage")
    out = []
    for _ in range(r.u32()):
        stamp = r.stamp_ns()
        parent = r.string()
        child = r.string()
        r._align(8)
        r._need(56)
        v = struct.unpack_from(r.end + "7d", raw, r.pos)
        r.pos += 56
        out.append((stamp, parent, child, v[:3], v[3:]))
    return out


def joint_state_positions(raw: bytes) -> tuple[int, np.ndarray]:
    """sensor_msgs/JointState bytes -> (header stamp ns, position (K,) float64)."""
    r = CdrReader(raw, "sensor_msgs/JointState")
    stamp = r.header()
    for _ in range(r.u32()):  # name[]
        r.skip_string()
    return stamp, r.array("f8")


def laser_scan_ranges(raw: bytes) -> tuple[int, tuple[float, float, float], np.ndarray]:
    """sensor_msgs/LaserScan bytes -> (stamp ns, (angle_min, angle_max, angle_increment),
    ranges (B,) float32 view); the rest of the message is not read."""
    stamp, angles, _, ranges = laser_scan_fields(raw)
    return stamp, angles, ranges


def laser_scan_fields(raw: bytes) -> tuple[int, tuple[float, float, float], tuple[float, float], np.ndarray]:
    """sensor_msgs/LaserScan bytes -> (stamp ns, (angle_min, angle_max, angle_increment),
    (range_min, range_max), ranges (B,) float32 view); the intensities are not read."""
    r = CdrReader(raw, "sensor_msgs/LaserScan")
    stamp = r.header()
    r._align(4)
    r._need(28)  # angle_min, angle_max, angle_increment, time_increment, scan_time, range_min, range_max
    f = struct.unpack_from(r.end + "7f", raw, r.pos)
    r.pos += 28
    return stamp, f[:3], f[5:], r.array("f4")


_U32 = struct.Struct("<I")


def _fog_batch_fast(raw: bytes):
    """The little-endian FogBatch fast path (the car's 100 Hz stream): the four sequences at
    offsets computed from the frame id's length, or None when the bytes do not fit that layout
    exactly (then the checked reader decides). Same result as the reader, a third of its time."""
    if len(raw) < 16 or raw[:2] != b"\x00\x01":
        return None
    pos = 16 + _U32.unpack_from(raw, 12)[0]  # header: stamp (8), frame_id length (4) + bytes
    pos += -(pos - _HDR) % 4
    if pos + 4 > len(raw):
        return None
    n = _U32.unpack_from(raw, pos)[0]
    pos += 4
    out = []
    for _ in range(4):  # stamps_ns, delta_roll, delta_pitch, delta_yaw: count, align 8, data
        if out:
            pos += -(pos - _HDR) % 4
            if pos + 4 > len(raw) or _U32.unpack_from(raw, pos)[0] != n:
                return None
            pos += 4
        if n:
            pos += -(pos - _HDR) % 8
        if pos + 8 * n > len(raw):
            return None
        out.append(pos)
        pos += 8 * n
    return (
        np.frombuffer(raw, dtype="<i8", count=n, offset=out[0]),
        np.frombuffer(raw, dtype="<f8", count=n, offset=out[3]),
    )


def fog_batch_yaw(raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    """pf_slam_interfaces/FogBatch bytes -> (stamps_ns (K,) int64, delta_yaw (K,) float64)."""
    fast = _fog_batch_fast(raw)
    if fast is not None:
        return fast
    r = CdrReader(raw, "pf_slam_interfaces/FogBatch")
    r.header()
    stamps = r.array("i8")
    r.array("f8")  # delta_roll
    r.array("f8")  # delta_pitch
    yaw = r.array("f8")
    if yaw.size != stamps.size:
        raise ValueError(f"pf_slam_interfaces/FogBatch: {stamps.size} stamps but {yaw.size} delta_yaw")
    return stamps, yaw


def pose_stamped_xy_yaw(raw: bytes) -> tuple[int, np.ndarray]:
    """geometry_msgs/PoseStamped bytes -> (stamp ns, ``[x, y, yaw]``)."""
    r = CdrReader(raw, "geometry_msgs/PoseStamped")
    stamp = r.header()
    return stamp, _pose_xy_yaw(r, raw)


def odometry_xy_yaw(raw: bytes) -> tuple[int, np.ndarray]:
    """nav_msgs/Odometry bytes -> (header stamp ns, ``[x, y, yaw]`` of ``pose.pose``); the
    child frame, the covariance and the twist are not read (the odometry arrives with every scan:
    rclpy would build some twenty message objects per Odometry)."""
    r = CdrReader(raw, "nav_msgs/Odometry")
    stamp = r.header()
    r.skip_string()  # child_frame_id
    return stamp, _pose_xy_yaw(r, raw)


def _pose_xy_yaw(r: CdrReader, raw: bytes) -> np.ndarray:
    """``[x, y, yaw]`` of the geometry_msgs/Pose at the reader's position."""
    r._align(8)
    r._need(56)
    x, y, _z, qx, qy, qz, qw = struct.unpack_from(r.end + "7d", raw, r.pos)
    return np.array([x, y, float(quat_to_yaw(qx, qy, qz, qw))])


def _string_bytes(s: str) -> bytes:
    """A CDR string: its length with the NUL (uint32, little endian), its bytes, the NUL."""
    b = s.encode() + b"\0"
    return struct.pack("<I", len(b)) + b


def _pose_records(stamps_ns: np.ndarray, poses: np.ndarray, frame: bytes, offset: int) -> bytes:
    """PoseStamped records (the stamp, ``frame`` = the frame_id's length and bytes, the pose's
    seven doubles) laid out from payload offset ``offset`` (a multiple of 4), built as one array:
    the caller passes records that all start at the same offset modulo 8."""
    n = stamps_ns.size
    pad = (-(offset + 8 + len(frame))) % 8
    size = 8 + len(frame) + pad + 56
    rec = np.zeros((n, size), np.uint8)
    rec[:, 0:4] = np.floor_divide(stamps_ns, 1_000_000_000).astype("<i4").view(np.uint8).reshape(n, 4)
    rec[:, 4:8] = np.remainder(stamps_ns, 1_000_000_000).astype("<u4").view(np.uint8).reshape(n, 4)
    rec[:, 8 : 8 + len(frame)] = np.frombuffer(frame, np.uint8)
    half = [0.5 * float(y) for y in poses[:, 2]]  # yaw_to_quat's math.sin / math.cos, bit for bit
    vals = np.zeros((n, 7))
    vals[:, 0], vals[:, 1] = poses[:, 0], poses[:, 1]
    vals[:, 5] = [math.sin(h) for h in half]
    vals[:, 6] = [math.cos(h) for h in half]
    rec[:, size - 56 :] = vals.astype("<f8").view(np.uint8).reshape(n, 56)
    return rec.tobytes()


def path_bytes(stamps_ns: np.ndarray, poses: np.ndarray, stamp_ns: int, frame_id: str) -> bytes:
    """nav_msgs/Path (little-endian CDR) of planar poses ``(K, 3)`` at ``stamps_ns`` (``(K,)``),
    every pose and the path in ``frame_id``, the path stamped ``stamp_ns``: the same bytes as
    rclpy's serialization of the message, built without K PoseStamped objects (the final
    trajectory of a car drive has 30 000)."""
    t = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    if t.size != p.shape[0]:
        raise ValueError(f"nav_msgs/Path: {t.size} stamps but {p.shape[0]} poses")
    frame = _string_bytes(frame_id)
    head = _STAMP.pack(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000) + frame
    head += b"\0" * ((-len(head)) % 4) + struct.pack("<I", t.size)
    if t.size == 0:
        return _LITTLE_ENDIAN + head
    # every record ends 8-aligned: the first has its own padding, the others all the same
    return _LITTLE_ENDIAN + head + _pose_records(t[:1], p[:1], frame, len(head)) + _pose_records(t[1:], p[1:], frame, 0)


def path_xy_yaw(raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    """nav_msgs/Path bytes -> the poses' stamps (ns, ``(K,)``) and ``[x, y, yaw]`` ``(K, 3)``.

    After the first pose, the records are read as one array when they all have the first
    one's frame_id length (as :func:`path_bytes` writes them); otherwise pose by pose."""
    r = CdrReader(raw, "nav_msgs/Path")
    r.header()
    k = r.u32()
    stamps = np.empty(k, np.int64)
    poses = np.empty((k, 3))

    def record(i: int) -> int:
        """Pose ``i`` at the reader's position (4-aligned); returns its frame_id's length."""
        at = r.pos
        stamps[i] = r.header()
        frame_len = r.pos - at - 12  # the stamp and the string's length field
        poses[i] = _pose_xy_yaw(r, raw)
        r.pos += 56
        return frame_len

    i = 0
    if k:
        frame_len = record(0)
        i = 1
        n, size = k - 1, 12 + frame_len + (-(12 + frame_len)) % 8 + 56
        # after the first record the payload offset is 8-aligned: every further record is `size` long
        if n and r.little and (r.pos - _HDR) % 8 == 0 and len(raw) - r.pos >= n * size:
            rec = np.frombuffer(raw, np.uint8, count=n * size, offset=r.pos).reshape(n, size)

            def column(lo: int, width: int, dtype: str) -> np.ndarray:
                return np.ascontiguousarray(rec[:, lo : lo + width]).view(dtype)

            if np.all(column(8, 4, "<u4") == frame_len):
                stamps[1:] = column(0, 4, "<i4")[:, 0].astype(np.int64) * 1_000_000_000 + column(4, 4, "<u4")[:, 0]
                q = column(size - 56, 56, "<f8")
                poses[1:] = np.column_stack([q[:, 0], q[:, 1], quat_to_yaw(q[:, 3], q[:, 4], q[:, 5], q[:, 6])])
                i = k
    while i < k:
        record(i)
        i += 1
    return stamps, poses


def clock_bytes(stamp_ns: int) -> bytes:
    """rosgraph_msgs/Clock (little-endian CDR) at ``stamp_ns``."""
    return _LITTLE_ENDIAN + _STAMP.pack(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)


class PoseStampedWriter:
    """Serializes planar poses as geometry_msgs/PoseStamped (little-endian CDR) for one frame."""

    def __init__(self, frame_id: str) -> None:
        head = _string_bytes(frame_id)  # after the 8-byte stamp
        pad = (-(8 + len(head))) % 8  # the pose's doubles are 8-aligned
        self._frame = head + b"\0" * pad
        self._pose = struct.Struct("<3d4d")

    def pack(self, pose, stamp_ns: int) -> bytes:
        return b"".join(
            (
                _LITTLE_ENDIAN,
                _STAMP.pack(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000),
                self._frame,
                self._pose.pack(float(pose[0]), float(pose[1]), 0.0, *yaw_to_quat(float(pose[2]))),
            )
        )


class TransformWriter:
    """Serializes a planar transform as tf2_msgs/TFMessage with one TransformStamped
    (little-endian CDR) for a fixed parent -> child: odom -> base_link at every scan."""

    def __init__(self, parent: str, child: str) -> None:
        head = _string_bytes(parent)  # after the count (4) and the stamp (8)
        head += b"\0" * ((-(12 + len(head))) % 4) + _string_bytes(child)
        self._frames = head + b"\0" * ((-(12 + len(head))) % 8)  # the doubles are 8-aligned
        self._count = struct.pack("<I", 1)
        self._tf = struct.Struct("<3d4d")

    def pack(self, pose, stamp_ns: int) -> bytes:
        return b"".join(
            (
                _LITTLE_ENDIAN,
                self._count,
                _STAMP.pack(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000),
                self._frames,
                self._tf.pack(float(pose[0]), float(pose[1]), 0.0, *yaw_to_quat(float(pose[2]))),
            )
        )


class PoseArrayWriter:
    """Serializes planar poses ``(N, 3)`` as geometry_msgs/PoseArray (little-endian CDR) for one
    frame, in one numpy pass: the particle cloud (thousands of particles after a global
    localization) without a Python object per pose."""

    def __init__(self, frame_id: str) -> None:
        head = _string_bytes(frame_id)  # after the 8-byte stamp
        head += b"\0" * ((-(8 + len(head))) % 4)  # the sequence count is 4-aligned
        self._frame = head
        self._pad = b"\0" * ((-(8 + len(head) + 4)) % 8)  # the poses' doubles are 8-aligned

    def pack(self, poses: np.ndarray, stamp_ns: int) -> bytes:
        p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        body = np.zeros((p.shape[0], 7))
        body[:, 0], body[:, 1] = p[:, 0], p[:, 1]
        body[:, 5], body[:, 6] = np.sin(0.5 * p[:, 2]), np.cos(0.5 * p[:, 2])
        return b"".join(
            (
                _LITTLE_ENDIAN,
                _STAMP.pack(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000),
                self._frame,
                struct.pack("<I", p.shape[0]),
                self._pad if p.shape[0] else b"",
                body.astype("<f8").tobytes(),
            )
        )


def tf_message_stamp(raw: bytes) -> int | None:
    """tf2_msgs/TFMessage bytes -> the first transform's header stamp (ns); None if empty."""
    r = CdrReader(raw, "tf2_msgs/TFMessage")
    return r.stamp_ns() if r.u32() else None


def header_stamp(raw: bytes) -> int:
    """The header stamp (ns) of a message whose first field is a std_msgs/Header."""
    return CdrReader(raw, "message with a header").stamp_ns()


def with_header_stamp(raw: bytes, stamp_ns: int) -> bytes:
    """The same message with its header stamp replaced (the stamp sits right after the 4-byte
    CDR header: int32 sec, uint32 nanosec, in the message's byte order)."""
    if len(raw) < 12 or raw[0] != 0 or raw[1] not in (0, 1):
        raise ValueError(f"not a CDR-serialized message ({len(raw)} bytes)")
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return b"".join((bytes(raw[:4]), struct.pack("<iI" if raw[1] == 1 else ">iI", sec, nsec), bytes(raw[12:])))
