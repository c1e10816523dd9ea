"""Geometry helpers (pure numpy / math): SE(2) pose algebra, quaternions, rotation matrices.

The one place of these formulas in the package: core/, io/, ros/, nodes/, sim/ and graph.py
import them from here.

* SE(2): poses are float64 ``[x, y, theta]`` (m, m, rad), single ``(3,)`` or batched
  ``(N, 3)``; angles returned are wrapped to ``[-pi, pi)`` (:func:`wrap_angle`,
  :func:`compose`, :func:`relative_pose`).
* Quaternions are ``(x, y, z, w)`` (the ROS order): :func:`quat_to_yaw`,
  :func:`yaw_to_quat`, :func:`quat_to_matrix`, :func:`matrix_to_quat`, :func:`rpy_to_quat`.
* Rotation matrices (3, 3): :func:`rpy_to_matrix` (degrees, ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``),
  :func:`nearest_rotation`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = [
    "compose",
    "matrix_to_quat",
    "nearest_rotation",
    "quat_to_matrix",
    "quat_to_yaw",
    "relative_pose",
    "rpy_to_matrix",
    "rpy_to_quat",
    "wrap_angle",
    "yaw_to_quat",
]


# --------------------------------------------------------------------------------------------
# SE(2)


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Wrap angle(s) to ``[-pi, pi)``.

    Parameters
    ----------
    a : array_like
        Angles (rad), any shape.

    Returns
    -------
    numpy.ndarray
        Wrapped angles, same shape, float64.
    """
    a = np.asarray(a, dtype=np.float64)
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _wrap(a: float) -> float:
    """:func:`wrap_angle` of one Python float (same formula, no array)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def relative_pose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose ``b`` expressed in the frame of pose ``a`` (``a^-1 (+) b``, the odometry increment).

    Parameters
    ----------
    a, b : numpy.ndarray
        ``(3,)`` or ``(N, 3)`` poses, broadcast against each other.

    Returns
    -------
    numpy.ndarray
        ``(3,)`` or ``(N, 3)`` float64 relative pose(s).
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape == b.shape == (3,):  # one pose: scalar math (the per-scan path of the nodes)
        ax, ay, at = a.tolist()
        dx, dy = b[0] - ax, b[1] - ay
        c, s = math.cos(at), math.sin(at)
        return np.array([c * dx + s * dy, -s * dx + c * dy, _wrap(float(b[2]) - at)])
    dx = b[..., 0] - a[..., 0]
    dy = b[..., 1] - a[..., 1]
    c = np.cos(a[..., 2])
    s = np.sin(a[..., 2])
    return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[..., 2] - a[..., 2])], axis=-1)


def compose(poses: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Pose composition ``poses (+) delta`` (``delta`` expressed in the frame of ``poses``).

    Parameters
    ----------
    poses : numpy.ndarray
        ``(3,)`` or ``(N, 3)``.
    delta : numpy.ndarray
        ``(3,)`` or ``(N, 3)``; broadcast against ``poses``.

    Returns
    -------
    numpy.ndarray
        ``(3,)`` or ``(N, 3)`` float64.
    """
    poses = np.asarray(poses, dtype=np.float64)
    delta = np.asarray(delta, dtype=np.float64)
    if poses.shape == delta.shape == (3,):  # one pose: scalar math (the per-scan path of the nodes)
        px, py, pt = poses.tolist()
        dx, dy, dt = delta.tolist()
        c, s = math.cos(pt), math.sin(pt)
        return np.array([px + c * dx - s * dy, py + s * dx + c * dy, _wrap(pt + dt)])
    c = np.cos(poses[..., 2])
    s = np.sin(poses[..., 2])
    x = poses[..., 0] + c * delta[..., 0] - s * delta[..., 1]
    y = poses[..., 1] + s * delta[..., 0] + c * delta[..., 1]
    th = wrap_angle(poses[..., 2] + delta[..., 2])
    return np.stack(np.broadcast_arrays(x, y, th), axis=-1)


# --------------------------------------------------------------------------------------------
# quaternions (x, y, z, w)


def quat_to_yaw(qx: np.ndarray, qy: np.ndarray, qz: np.ndarray, qw: np.ndarray) -> np.ndarray:
    """Yaw (rad) of quaternions (rotation about z of the ZYX Euler decomposition)."""
    return np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def yaw_to_quat(yaw: float) -> tuple[float, float, float, float]:
    """Rotation about z -> quaternion ``(x, y, z, w)``."""
    return 0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)


def quat_to_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """Quaternion ``(x, y, z, w)`` -> rotation matrix (3, 3), normalised first.

    Raises ``ValueError`` when the quaternion has no direction (zero, or not finite).
    """
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0 or not math.isfinite(n):
        raise ValueError(f"rotation quaternion ({x}, {y}, {z}, {w}) has no direction")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


# --------------------------------------------------------------------------------------------
# rotation matrices


def rpy_to_matrix(rpy_deg: np.ndarray | list[float]) -> np.ndarray:
    """Roll, pitch, yaw (deg, "XYZ extrinsic") -> ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``, (3, 3)."""
    r, p, y = np.radians(np.asarray(rpy_deg, dtype=np.float64))
    cr, sr = math.cos(r), math.sin(r)
    cp, sp = math.cos(p), math.sin(p)
    cy, sy = math.cos(y), math.sin(y)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def nearest_rotation(rot: np.ndarray) -> np.ndarray:
    """The rotation matrix closest (Frobenius) to ``rot`` (3, 3): ``U @ V^T`` of its SVD.

    Calibration files round R to ~6 digits, so its columns are unit vectors only to ~1e-5.
    """
    u, _, vt = np.linalg.svd(np.asarray(rot, dtype=np.float64))
    if np.linalg.det(u @ vt) < 0.0:
        u[:, -1] = -u[:, -1]
    return u @ vt


def matrix_to_quat(rot: np.ndarray) -> tuple[float, float, float, float]:
    """Rotation matrix (3, 3) -> unit quaternion ``(x, y, z, w)`` with ``w >= 0``.

    Shepperd's method: the largest of ``w, x, y, z`` is taken from the diagonal (no division by
    a small number, exact for 180-degree rotations). A slightly non-orthonormal input (a
    rounded calibration file) gives the quaternion of a nearby rotation, normalised.
    """
    m = np.asarray(rot, dtype=np.float64)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise ValueError(f"rotation must be a finite (3, 3) matrix, got {m!r}")
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    cand = (tr, m[0, 0], m[1, 1], m[2, 2])
    k = int(np.argmax(cand))
    if k == 0:
        s = 2.0 * math.sqrt(max(1.0 + tr, 0.0))
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s)
    elif k == 1:
        s = 2.0 * math.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 0.0))
        q = (0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif k == 2:
        s = 2.0 * math.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 0.0))
        q = ((m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 0.0))
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s)
    qa = np.array(q, dtype=np.float64)
    norm = float(np.linalg.norm(qa))
    if not norm > 0.0:
        raise ValueError(f"not a rotation matrix: {m!r}")
    qa /= norm
    if qa[3] < 0.0:
        qa = -qa
    return float(qa[0]), float(qa[1]), float(qa[2]), float(qa[3])


def rpy_to_quat(rpy: Sequence[float]) -> tuple[float, float, float, float]:
    """(roll, pitch, yaw) rad -> quaternion (x, y, z, w) of Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = (0.5 * float(v) for v in rpy)
    if r == 0.0 and p == 0.0 and y == 0.0:
        return (0.0, 0.0, 0.0, 1.0)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )
