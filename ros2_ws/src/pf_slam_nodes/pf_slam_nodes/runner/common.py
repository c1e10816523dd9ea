"""What the parts of `pf-slam run` share: the graph's nodes and inputs, the run's error, the run's plan."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

NODE_NAMES = ("bag_replay", "predictor", "correlator", "mapper")
TEXTURE_INPUT = "/stereo/left/image_raw"  # a bag with it gets the texture node


class RunError(Exception):
    """A run cannot start or did not complete; the message says why."""


def snapshot_cadence(value: int | str) -> tuple[int, float]:
    """``--snapshot-every``: ``N`` (every N scans) or ``"Ns"`` (every N seconds of bag time); 0
    (or ``"0s"``): none. Returns ``(scans, seconds)``, one of them 0."""
    text = str(value).strip()
    try:
        if text.endswith("s"):
            sec = float(text[:-1])
            if sec >= 0 and sec == sec and sec != float("inf"):
                return 0, sec
        else:
            n = int(text)
            if n >= 0:
                return n, 0.0
    except ValueError:
        pass
    raise ValueError(f"--snapshot-every: {value!r} is neither a scan count N >= 0 nor seconds of bag time like '30s'")


class SnapshotCadence:
    """When `pf-slam run` writes a snapshot: called with the k-th pose (1-based) and its stamp
    (ns), True every N scans, or at the first pose at least N seconds of bag time after
    the previous snapshot's due time (the first one N seconds after the first pose)."""

    def __init__(self, every: int | str) -> None:
        self.scans, seconds = snapshot_cadence(every)
        self.period_ns = int(round(seconds * 1e9))
        self._next_ns: int | None = None

    def __call__(self, k: int, stamp_ns: int) -> bool:
        if self.scans:
            return k % self.scans == 0
        if not self.period_ns:
            return False
        if self._next_ns is None:
            self._next_ns = stamp_ns + self.period_ns
        if stamp_ns < self._next_ns:
            return False
        self._next_ns += self.period_ns * ((stamp_ns - self._next_ns) // self.period_ns + 1)
        return True


#: The graph's inputs: the nodes' (relative) topic name -> the message types it takes
INPUT_TYPES: dict[str, tuple[str, ...]] = {
    "scan": ("sensor_msgs/msg/LaserScan",),
    "odom": ("nav_msgs/msg/Odometry",),
    "encoders": ("sensor_msgs/msg/JointState",),
    "fog": ("pf_slam_interfaces/msg/FogBatch", "geometry_msgs/msg/Vector3Stamped"),
    "imu": ("sensor_msgs/msg/Imu",),
    "stereo_left": ("sensor_msgs/msg/Image",),
    "stereo_right": ("sensor_msgs/msg/Image",),
    "rgbd_rgb": ("sensor_msgs/msg/Image",),
    "rgbd_depth": ("sensor_msgs/msg/Image",),
}


DEFAULT_INPUTS = {
    "scan": "/scan",
    "odom": "/odom",
    "encoders": "/encoders",
    "fog": "/fog",
    "imu": "/imu",
    "stereo_left": TEXTURE_INPUT,
    "stereo_right": "/stereo/right/image_raw",
    "rgbd_rgb": "/kinect/rgb/image_raw",
    "rgbd_depth": "/kinect/depth/image_raw",
}


@dataclass
class RunPlan:
    """What a run will do, decided before anything starts: the bag and what it holds, each node's
    parameters (all layers merged), and how the graph runs (see graph.run for the arguments)."""

    bag: str
    params_file: str | None
    rate: str
    processes: str
    executor: str
    record: bool
    record_map_every_s: float | None
    snapshot_every: int | str
    progress: bool
    idle_timeout_s: float
    drain_timeout_s: float
    texture_timeout_s: float
    info: dict
    inputs: dict[str, str]
    texture: bool  # the texture node runs (the bag has stereo or RGB-D images and it was not turned off)
    node_names: tuple[str, ...]
    per_node: dict[str, dict[str, Any]]
    prof: Any  # profiles.Profile
    mount_text: str
    mount_notes: list[str]
    checks: dict[str, Any]  # inputs._check_stamps_and_pairing's answer

    @property
    def scans_total(self) -> int:
        return self.info["topics"][self.inputs["scan"]][1]

    @property
    def bag_duration_s(self) -> float:
        return self.info["duration_ns"] / 1e9
