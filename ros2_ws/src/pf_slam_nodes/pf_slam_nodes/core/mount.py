"""A lidar on a moving mount (a humanoid's head): the mount at a scan's stamp, floor returns.

The lidar hangs off a frame that moves relative to the robot's base (THOR: ``base_link -> head``
is ``Rz(neck) Ry(head)`` at the joints' own stamps, ``head -> lidar`` is static). Each scan is
projected with the mount *at its own stamp*: :class:`MountBuffer` keeps the dynamic transform's
samples and interpolates them (rotation by slerp, translation linearly) at the scan's stamp;
:func:`compose_extrinsic` chains it with the static part into the 12-number ``laser.extrinsic``
(``R`` row-major, ``T``) that :func:`~pf_slam_nodes.core.scan.planar_scan` projects with. Returns
whose height in the base frame is below ``laser.min_height_m`` (the floor margin: base_link is on
the ground) are dropped there; :func:`kept_fraction` says how much of a scan is left, and a scan
below ``laser.min_kept_fraction`` is *mostly floor* (the head looks down): it is posed from
odometry, neither corrected nor mapped with, and counted (``faults.scan_mostly_floor``).
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from .geometry import quat_to_matrix
from .scan import gate_ranges, planar_scan

MOSTLY_FLOOR = "scan_mostly_floor"


def slerp(q0: np.ndarray, q1: np.ndarray, u: float) -> np.ndarray:
    """Spherical interpolation of unit quaternions ``(x, y, z, w)`` at ``u`` in [0, 1] (the
    shorter arc)."""
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    d = float(q0 @ q1)
    if d < 0.0:
        q1, d = -q1, -d
    if d > 0.9995:  # nearly equal: linear, renormalised
        q = q0 + u * (q1 - q0)
        return q / np.linalg.norm(q)
    th = math.acos(min(d, 1.0))
    s = math.sin(th)
    return (math.sin((1 - u) * th) / s) * q0 + (math.sin(u * th) / s) * q1


class MountBuffer:
    """Samples of a dynamic transform (parent = the robot's base, child = the mount frame), in
    stamp order, and its value at any stamp.

    :meth:`at` interpolates between the samples around the stamp (slerp + linear translation),
    and holds the first / last sample outside them. :meth:`covers` says whether a sample at or
    after the stamp has arrived (until then an interpolation could still change).
    """

    def __init__(self, keep: int = 4096) -> None:
        self.stamps: list[int] = []
        self.quats: list[tuple[float, float, float, float]] = []
        self.trans: list[tuple[float, float, float]] = []
        self.keep = int(keep)
        self.out_of_order = 0

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def latest_ns(self) -> int | None:
        return self.stamps[-1] if self.stamps else None

    def add(self, stamp: int, quat_xyzw, translation) -> None:
        """A sample at ``stamp`` (ns); one older than the newest, or not finite, is dropped and
        counted. Plain floats: 100 samples a second arrive one by one."""
        x, y, z, w = (float(v) for v in quat_xyzw)
        t = tuple(float(v) for v in translation)
        n = math.sqrt(x * x + y * y + z * z + w * w)
        if not (math.isfinite(n) and n > 1e-9 and len(t) == 3 and all(math.isfinite(v) for v in t)) or (
            self.stamps and stamp < self.stamps[-1]
        ):
            self.out_of_order += 1
            return
        self.stamps.append(int(stamp))
        self.quats.append((x / n, y / n, z / n, w / n))
        self.trans.append(t)
        if len(self.stamps) > 2 * self.keep:
            del self.stamps[: self.keep], self.quats[: self.keep], self.trans[: self.keep]

    def covers(self, stamp: int) -> bool:
        return bool(self.stamps) and self.stamps[-1] >= stamp

    def at(self, stamp: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(R (3, 3), t (3,)) of the mount at ``stamp``; None before the first sample."""
        if not self.stamps:
            return None
        i = bisect.bisect_left(self.stamps, stamp)
        if i == 0:
            q, t = self.quats[0], np.array(self.trans[0])
        elif i >= len(self.stamps):
            q, t = self.quats[-1], np.array(self.trans[-1])
        else:
            t0, t1 = self.stamps[i - 1], self.stamps[i]
            u = 0.0 if t1 == t0 else (stamp - t0) / (t1 - t0)
            q = slerp(np.array(self.quats[i - 1]), np.array(self.quats[i]), u)
            a, b = np.array(self.trans[i - 1]), np.array(self.trans[i])
            t = a + u * (b - a)
        return quat_to_matrix(*(float(v) for v in q)), np.asarray(t, dtype=np.float64)


def compose_extrinsic(rot_dyn: np.ndarray, t_dyn: np.ndarray, static_extrinsic) -> np.ndarray:
    """The lidar in the base frame: ``base <- mount`` (dynamic) composed with ``mount <- lidar``
    (``static_extrinsic``: 12 numbers, R row-major then T; all zeros: identity) -> (12,)."""
    ext = np.asarray(static_extrinsic, dtype=np.float64).reshape(12)
    if any(ext):
        r_s, t_s = ext[:9].reshape(3, 3), ext[9:]
    else:
        r_s, t_s = np.eye(3), np.zeros(3)
    rot = np.asarray(rot_dyn, dtype=np.float64) @ r_s
    t = np.asarray(rot_dyn, dtype=np.float64) @ t_s + np.asarray(t_dyn, dtype=np.float64)
    return np.concatenate([rot.reshape(-1), t])


def base_points(ranges: np.ndarray, angles: np.ndarray, extrinsic) -> np.ndarray:
    """3-D beam endpoints in the base frame, ``(3, B)`` (NaN where the range is not finite)."""
    ext = np.asarray(extrinsic, dtype=np.float64).reshape(12)
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        r = np.where(np.isfinite(r), r, np.nan)
        local = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)])
        return ext[:9].reshape(3, 3) @ local + ext[9:, None]


def kept_fraction(
    ranges: np.ndarray, angles: np.ndarray, laser, extrinsic, range_min: float = 0.0, range_max: float = math.inf
) -> float:
    """The fraction of a scan's returns (finite, within its own limits and ``laser``'s range
    gate) that survive the height gate (``laser.min_height_m`` .. ``max_height_m`` in the base
    frame) with the mount ``extrinsic`` (12): 1.0 for a scan without returns (nothing to judge)."""
    r = gate_ranges(ranges, range_min, range_max)
    with np.errstate(invalid="ignore"):
        returns = np.isfinite(r) & (r >= laser.min_range_m) & (r <= laser.max_range_m)
    n = int(returns.sum())
    if n == 0:
        return 1.0
    p = base_points(np.where(returns, r, np.nan), angles, extrinsic)
    with np.errstate(invalid="ignore"):
        kept = returns & (p[2] >= laser.min_height_m) & (p[2] <= laser.max_height_m)
    return float(kept.sum()) / n


def mounted_scan(
    ranges: np.ndarray, angles: np.ndarray, laser, extrinsic, range_min: float = 0.0, range_max: float = math.inf
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`planar_scan` with the mount ``extrinsic`` (12) of this scan in place of the
    configured one: ``(ranges, angles, offset)`` in the base frame, floor returns dropped."""
    import dataclasses

    ext = tuple(float(v) for v in np.asarray(extrinsic, dtype=np.float64).reshape(12))
    return planar_scan(ranges, angles, dataclasses.replace(laser, extrinsic=ext), np.zeros(3), range_min, range_max)
