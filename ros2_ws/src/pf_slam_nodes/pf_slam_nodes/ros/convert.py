"""Message <-> ndarray conversions at the edge of the nodes (no spinning needed to test them)."""

from __future__ import annotations

import array

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, TransformStamped
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import LaserScan

from pf_slam_interfaces.msg import ParticleArray

from ..core.geometry import quat_to_yaw, yaw_to_quat
from ..io.bag import stamp_ns_of as stamp_to_ns  # noqa: F401  (Time or message -> int ns)
from .cdr import CdrReader


def stamp_ns_from_cdr(raw: bytes) -> int:
    """header.stamp (ns) of a serialized message that starts with a std_msgs/Header
    (LaserScan, Image, ...), read from its CDR bytes without deserializing the rest."""
    return CdrReader(raw, "message with a header").stamp_ns()


def ns_to_stamp(ns: int) -> Time:
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def particles_to_msg(
    poses: np.ndarray,
    log_weights: np.ndarray,
    *,
    stamp_ns: int,
    frame_id: str,
    scan_index: int,
    update: bool,
    odom_pose: np.ndarray,
    pending_delta: np.ndarray | None = None,
    pose: np.ndarray | None = None,
    mount=None,
    odom_scale: float = 1.0,
) -> ParticleArray:
    """(N,3) poses and (N,) log-weights -> ParticleArray (struct of arrays)."""
    msg = ParticleArray()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame_id
    msg.scan_index = int(scan_index)
    msg.update = bool(update)
    msg.odom_pose = np.asarray(odom_pose, dtype=np.float64).reshape(3)
    msg.pending_delta = np.zeros(3) if pending_delta is None else np.asarray(pending_delta, dtype=np.float64).reshape(3)
    msg.pose = np.zeros(3) if pose is None else np.asarray(pose, dtype=np.float64).reshape(3)
    msg.odom_scale = float(odom_scale)
    if mount is not None and len(mount):
        msg.mount = array.array("d", np.ascontiguousarray(mount, dtype=np.float64).reshape(12).tobytes())
    p = np.ascontiguousarray(poses, dtype=np.float64)
    msg.x = array.array("d", p[:, 0].tobytes())
    msg.y = array.array("d", p[:, 1].tobytes())
    msg.theta = array.array("d", p[:, 2].tobytes())
    msg.log_weight = array.array("d", np.ascontiguousarray(log_weights, dtype=np.float64).tobytes())
    return msg


def msg_to_particles(msg: ParticleArray) -> tuple[np.ndarray, np.ndarray]:
    """ParticleArray -> ((N,3) poses, (N,) log-weights); raises ValueError on ragged arrays."""
    n = len(msg.x)
    if not (len(msg.y) == len(msg.theta) == len(msg.log_weight) == n):
        raise ValueError(
            f"ParticleArray has arrays of different lengths: x={n} y={len(msg.y)} "
            f"theta={len(msg.theta)} log_weight={len(msg.log_weight)}"
        )
    poses = np.empty((n, 3))
    poses[:, 0] = np.frombuffer(msg.x, dtype=np.float64) if n else []
    poses[:, 1] = np.frombuffer(msg.y, dtype=np.float64) if n else []
    poses[:, 2] = np.frombuffer(msg.theta, dtype=np.float64) if n else []
    lw = np.frombuffer(msg.log_weight, dtype=np.float64).copy() if n else np.empty(0)
    return poses, lw


def scan_arrays(msg: LaserScan) -> tuple[np.ndarray, np.ndarray]:
    """LaserScan -> (ranges (B,) float64, angles (B,) float64)."""
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    angles = msg.angle_min + msg.angle_increment * np.arange(ranges.size, dtype=np.float64)
    return ranges, angles


def pose_stamped(pose: np.ndarray, stamp_ns: int, frame_id: str) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = frame_id
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.pose.position.x, msg.pose.position.y = float(pose[0]), float(pose[1])
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = yaw_to_quat(float(pose[2]))
    return msg


def transform(parent: str, child: str, pose: np.ndarray, stamp_ns: int) -> TransformStamped:
    t = TransformStamped()
    t.header.stamp = ns_to_stamp(stamp_ns)
    t.header.frame_id = parent
    t.child_frame_id = child
    t.transform.translation.x = float(pose[0])
    t.transform.translation.y = float(pose[1])
    qx, qy, qz, qw = yaw_to_quat(float(pose[2]))
    t.transform.rotation.x, t.transform.rotation.y = qx, qy
    t.transform.rotation.z, t.transform.rotation.w = qz, qw
    return t


def grid_to_msg(
    occupancy: np.ndarray, resolution: float, origin_xy: tuple[float, float], stamp_ns: int, frame_id: str
) -> OccupancyGrid:
    """int8 (H,W) occupancy (row = y) -> nav_msgs/OccupancyGrid."""
    msg = OccupancyGrid()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame_id
    msg.info.map_load_time = msg.header.stamp
    msg.info.resolution = float(resolution)
    msg.info.height, msg.info.width = int(occupancy.shape[0]), int(occupancy.shape[1])
    msg.info.origin.position.x = float(origin_xy[0])
    msg.info.origin.position.y = float(origin_xy[1])
    msg.info.origin.orientation.w = 1.0
    msg.data = array.array("b", np.ascontiguousarray(occupancy, dtype=np.int8).tobytes())
    return msg


def frame_change_msg(transform, stamp_ns: int, frame_id: str) -> OccupancyGrid:
    """The mapper's frame-change marker on pf_slam/grid (loop closure): no cells, resolution -1,
    the transform ``(x, y, yaw)`` the filter's set follows as the origin pose."""
    msg = grid_to_msg(np.zeros((0, 0), np.int8), -1.0, (float(transform[0]), float(transform[1])), stamp_ns, frame_id)
    _, _, qz, qw = yaw_to_quat(float(transform[2]))
    msg.info.origin.orientation.z, msg.info.origin.orientation.w = qz, qw
    return msg


def frame_change_transform(msg: OccupancyGrid) -> np.ndarray:
    """``(x, y, yaw)`` of a frame-change marker (:func:`frame_change_msg`)."""
    p, q = msg.info.origin.position, msg.info.origin.orientation
    return np.array([p.x, p.y, quat_to_yaw(q.x, q.y, q.z, q.w)])


def msg_to_grid(msg: OccupancyGrid) -> tuple[np.ndarray, float, tuple[float, float]]:
    """nav_msgs/OccupancyGrid -> (int8 (H,W), resolution, origin_xy); ValueError on a size mismatch."""
    h, w = int(msg.info.height), int(msg.info.width)
    data = np.frombuffer(msg.data, dtype=np.int8)
    if data.size != h * w:
        raise ValueError(f"OccupancyGrid data has {data.size} cells, info says {w}x{h}")
    return (
        data.reshape(h, w),
        float(msg.info.resolution),
        (float(msg.info.origin.position.x), float(msg.info.origin.position.y)),
    )
