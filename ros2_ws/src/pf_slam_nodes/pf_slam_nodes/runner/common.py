"""What the parts of `pf-slam run` share: the graph's nodes and inputs, the run's error, the run's plan."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

NODE_NAMES = ("bag_replay", "predictor", "correlator", "mapper")
TEXTURE_INPUT = "/stereo/left/image_raw"  # a bag with it gets the texture node


class RunError(Exception):
    """A run cannot start or did not complete; the message says why."""


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
    snapshot_every: int
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
