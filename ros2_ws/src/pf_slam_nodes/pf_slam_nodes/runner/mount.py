"""The lidar's mount from the bag's /tf_static (bag inspection, part 2)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.geometry import quat_to_matrix
from ..io.bag import deserialize
from .params import node_params
from .sample import BagSample, sample_bag

#: the parameters that describe the lidar's mount (planar: filter.sensor_offset_*; 3D: laser.extrinsic)
MOUNT_PARAMS = (
    "filter.sensor_offset_x_m",
    "filter.sensor_offset_y_m",
    "filter.sensor_offset_yaw_rad",
    "laser.extrinsic",
    "laser.dynamic_frame",
)


@dataclass
class LidarMount:
    """The scan frame's pose in the robot's base frame: ``p_base = rot @ p_scan + t``.

    ``source``: "/tf_static" (composed along ``chain``, base frame first) or "parameters"
    (the bag has none: the graph's parameters, default identity). ``warnings``: what the user
    must know (a scan frame missing from /tf_static, a chain that does not reach the base)."""

    source: str
    base_frame: str
    scan_frame: str
    rot: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    chain: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    base_from_tf: bool = False  # base_frame is the child of odom in the bag's /tf
    dynamic_frame: str = ""  # a moving mount: base -> dynamic_frame on /tf, rot/t the static rest

    @property
    def planar(self) -> bool:
        """Scan plane horizontal and upright: an exact 2D mount (x, y, yaw)."""
        return abs(float(self.rot[2, 2]) - 1.0) < 1e-6

    @property
    def rpy(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) in rad, R = Rz(yaw) Ry(pitch) Rx(roll)."""
        r = self.rot
        return (math.atan2(r[2, 1], r[2, 2]), math.asin(max(-1.0, min(1.0, -r[2, 0]))), math.atan2(r[1, 0], r[0, 0]))

    def params(self) -> dict[str, Any]:
        """The graph parameters that apply it: the planar path when the plane is horizontal and
        upright (filter.sensor_offset_*: exact 2D; z does not matter), the 3D projection
        otherwise (laser.extrinsic; an upside-down lidar is a mirrored planar scan there)."""
        if self.source == "parameters":
            return {}
        if self.dynamic_frame:
            return {
                "laser.dynamic_frame": self.dynamic_frame,
                "laser.extrinsic": [float(v) for v in self.rot.reshape(-1)] + [float(v) for v in self.t],
            }
        if self.planar:
            return {
                "filter.sensor_offset_x_m": float(self.t[0]),
                "filter.sensor_offset_y_m": float(self.t[1]),
                "filter.sensor_offset_yaw_rad": float(math.atan2(self.rot[1, 0], self.rot[0, 0])),
            }
        return {"laser.extrinsic": [float(v) for v in self.rot.reshape(-1)] + [float(v) for v in self.t]}

    def describe(self) -> str:
        """'lidar mount from /tf_static: base_link -> laser: x 0.30 y 0.00 z 0.20, yaw 90.0°'."""
        roll, pitch, yaw = (math.degrees(v) for v in self.rpy)
        frames = " -> ".join(self.chain) if self.chain else f"{self.base_frame} -> {self.scan_frame}"
        if self.dynamic_frame:
            return (
                f"lidar on a moving mount: {frames}: {self.base_frame} -> {self.dynamic_frame} from /tf at each "
                f"scan's stamp, {self.dynamic_frame} -> {self.scan_frame} from /tf_static: x {self.t[0]:.2f} "
                f"y {self.t[1]:.2f} z {self.t[2]:.2f}, roll {roll:.1f}° pitch {pitch:.1f}° yaw {yaw:.1f}° "
                "(laser.dynamic_frame, laser.extrinsic)"
            )
        angles = f"yaw {yaw:.1f}°" if self.planar else f"roll {roll:.1f}° pitch {pitch:.1f}° yaw {yaw:.1f}°"
        how = (
            "planar: filter.sensor_offset_*"
            if self.planar
            else "3D: laser.extrinsic, "
            + ("upside down, a mirrored scan" if self.rot[2, 2] < -1 + 1e-6 else "tilted, projected")
        )
        return (
            f"lidar mount from {self.source}: {frames}: x {self.t[0]:.2f} y {self.t[1]:.2f} z {self.t[2]:.2f}, "
            f"{angles} ({how})"
        )


def _tf_static_tree(sample: BagSample, topics: dict) -> tuple[dict[str, tuple[str, np.ndarray, np.ndarray]], list[str]]:
    """Every /tf_static transform of the bag: child -> (parent, R, t) (a later message's
    transform of the same child replaces the earlier one, as tf2 does), and warnings."""
    tree: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
    warnings: list[str] = []
    if "/tf_static" not in topics:
        return tree, warnings
    for msgtype, _, raw in sample.of("/tf_static"):  # damaged mid-bag: the transforms before it count
        for tr in deserialize(raw, msgtype).transforms:
            add_transform(tree, tr, warnings)
    return tree, warnings


def add_transform(tree: dict, tr, warnings: list[str], topic: str = "/tf_static") -> None:
    """A geometry_msgs/TransformStamped into `tree` (child -> (parent, R, t)); a bad one is warned."""
    tt = tr.transform.translation
    t = np.array([tt.x, tt.y, tt.z], dtype=np.float64)
    try:
        q = tr.transform.rotation
        rot = quat_to_matrix(q.x, q.y, q.z, q.w)
        if not np.isfinite(t).all():
            raise ValueError(f"translation {t.tolist()} is not finite")
    except ValueError as e:
        warnings.append(f"{topic}: {tr.header.frame_id} -> {tr.child_frame_id} ignored: {e}")
        return
    tree[tr.child_frame_id.lstrip("/")] = (tr.header.frame_id.lstrip("/"), rot, t)  # tf2 drops a leading /


def _odom_child(sample: BagSample, topics: dict, odom_frame: str) -> str | None:
    """The robot's base frame by its /tf: the child of `odom_frame` (the sample's first /tf messages)."""
    if "/tf" not in topics:
        return None
    for msgtype, _, raw in sample.of("/tf"):  # damaged mid-bag: what precedes it
        for tr in deserialize(raw, msgtype).transforms:
            if tr.header.frame_id.lstrip("/") == odom_frame and tr.child_frame_id:
                return tr.child_frame_id.lstrip("/")
    return None


def _dynamic_parent(sample: BagSample, topics: dict, frame: str) -> str | None:
    """The parent of `frame` in the bag's /tf (the sample's first /tf messages): a moving mount."""
    if "/tf" not in topics:
        return None
    for msgtype, _, raw in sample.of("/tf"):
        for tr in deserialize(raw, msgtype).transforms:
            if tr.child_frame_id.lstrip("/") == frame:
                return tr.header.frame_id.lstrip("/")
    return None


def _up_chain(tree: dict, frame: str) -> list[str]:
    """`frame` and its /tf_static ancestors, nearest first (stops at a cycle)."""
    out = [frame]
    while out[-1] in tree and tree[out[-1]][0] not in out:
        out.append(tree[out[-1]][0])
    return out


def _compose_up(tree: dict, chain: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Pose of chain[0] in chain[-1] (chain: a frame and its ancestors, nearest first)."""
    rot, t = np.eye(3), np.zeros(3)
    for child in chain[:-1]:
        _, r, tt = tree[child]
        rot, t = r @ rot, r @ t + tt
    return rot, t


def lidar_mount(
    bag: str | BagSample,
    info: dict,
    inputs: dict[str, str],
    scan_frame: str | None = None,
    base_frame: str | None = None,
    odom_frame: str = "odom",
) -> LidarMount:
    """The lidar's mount from the bag's /tf_static: the scan's frame composed up the chain of
    static transforms to the robot's base frame (`base_frame` if given, else the child of
    `odom_frame` in the bag's /tf, else base_link), e.g. base_link -> shell_link -> rplidar_link.
    A bag without /tf_static, or whose /tf_static lacks the scan's frame (warned, naming what it
    has), gives source "parameters": the graph's filter.sensor_offset_* / laser.extrinsic.
    `bag`: a path, or the run's one-pass BagSample (runner/sample.py)."""
    topics = info["topics"]
    sample = bag if isinstance(bag, BagSample) else sample_bag(bag, info, inputs, max_scans=1)
    if scan_frame is None:
        first = sample.of(inputs["scan"])[:1]
        if not first and sample.error is not None:
            raise sample.error
        for msgtype, _, raw in first:
            scan_frame = deserialize(raw, msgtype).header.frame_id
    scan_frame = (scan_frame or "").lstrip("/")
    from_tf = None
    if base_frame is None:
        from_tf = _odom_child(sample, topics, odom_frame)
    base = base_frame or from_tf or "base_link"
    m = LidarMount("parameters", base, scan_frame, base_from_tf=from_tf is not None)
    tree, m.warnings = _tf_static_tree(sample, topics)
    if "/tf_static" not in topics:
        return m
    return mount_in_tree(
        m, tree, inputs["scan"], odom_frame, dynamic_parent=lambda frame: _dynamic_parent(sample, topics, frame)
    )


def mount_in_tree(
    m: LidarMount,
    tree: dict,
    scan_topic: str,
    odom_frame: str = "odom",
    source: str = "/tf_static",
    dynamic_parent=None,
) -> LidarMount:
    """`m` (its base_frame, scan_frame) completed from `tree` (child -> (parent, R, t): a bag's
    /tf_static, or what `pf-slam live` heard on /tf_static and /tf); `source` names where the
    transforms came from; `dynamic_parent(frame)`: the frame's parent on the moving /tf, if any
    (a lidar on a moving head)."""
    base, scan_frame, from_tf = m.base_frame, m.scan_frame, m.base_from_tf
    if not scan_frame:
        m.warnings.append(
            f"{scan_topic}: scans have no header.frame_id: the lidar mount is not looked up "
            f"in {source}; the parameters' mount is used"
        )
        return m
    if scan_frame == base:
        m.source = source
        m.chain = [base]
        return m
    if scan_frame not in tree:
        have = ", ".join(f"{p} -> {c}" for c, (p, _, _) in sorted(tree.items())) or "no transforms"
        m.warnings.append(
            f"{source} has no transform to the scan's frame {scan_frame!r} (it has: {have}): "
            "the parameters' mount is used (filter.sensor_offset_*, laser.extrinsic; default: "
            f"the lidar at the origin of {base})"
        )
        return m
    up = _up_chain(tree, scan_frame)
    if base in up:
        up = up[: up.index(base) + 1]
        rot, t = _compose_up(tree, up)
    elif base in tree and (common := [f for f in _up_chain(tree, base) if f in up]):
        # the base hangs off the same tree (base_footprint -> base_link -> laser, base_link
        # the base): scan in base = inverse(base in the common ancestor) * scan in it
        anc = common[0]
        up_s, up_b = up[: up.index(anc) + 1], _up_chain(tree, base)
        up_b = up_b[: up_b.index(anc) + 1]
        r_s, t_s = _compose_up(tree, up_s)
        r_b, t_b = _compose_up(tree, up_b)
        rot, t = r_b.T @ r_s, r_b.T @ (t_s - t_b)
        up = list(reversed(up_b + list(reversed(up_s))[1:]))  # shown as base -> .. -> ancestor -> .. -> scan
    elif dynamic_parent is not None and dynamic_parent(up[-1]) == base:
        # a moving mount (a lidar on a head): base -> up[-1] on /tf, the static rest from here
        rot, t = _compose_up(tree, up)
        m.dynamic_frame = up[-1]
        up = up + [base]
    else:
        rot, t = _compose_up(tree, up)
        m.warnings.append(
            f"{source}: the scan's frame {scan_frame!r} hangs off {up[-1]!r}, not the robot's base "
            f"frame {base!r} ({'child of ' + odom_frame + ' in /tf' if from_tf else 'base_frame'}): "
            f"the mount is taken relative to {up[-1]!r}"
        )
    m.source, m.rot, m.t, m.chain = source, rot, t, list(reversed(up))
    return m


def _mount_report(mount: LidarMount, detected: dict, user: list[dict], node_names) -> tuple[str, list[str]]:
    """(the mount line of the input report, warnings). Mount parameters the user gives
    (--params, overrides) replace the bag's mount as a whole: the bag's are dropped from
    `detected` (so a planar offset and a 3D extrinsic never mix) and the override is warned."""
    given = {k: v for layer in user for sec in layer.values() for k, v in sec.items() if k in MOUNT_PARAMS}
    notes = list(mount.warnings)
    if not given:
        if mount.source == "/tf_static":
            return mount.describe(), notes
        text = (
            "lidar mount from the parameters (the bag has "
            + ("no /tf_static" if not notes else "no mount for it in /tf_static")
            + "): the lidar at the origin of "
            + mount.base_frame
        )
        return text, notes
    for k in MOUNT_PARAMS:
        detected.get("/**", {}).pop(k, None)
    merged = node_params(user, "correlator")
    text = "lidar mount from the parameters: " + ", ".join(
        f"{k} {merged.get(k, given[k])}" for k in MOUNT_PARAMS if k in given
    )
    if mount.source == "/tf_static":
        notes.append(f"the parameters' lidar mount replaces the bag's ({mount.describe()})")
    return text, notes
