"""The lidar's mount from the live TF tree (parameter ``mount_from_tf``: `pf-slam live`, the launch
file without a bag).

The predictor decides it once, when the first scan arrives: the scan's frame looked up in what
it heard on /tf_static and /tf (the chain logic of `pf-slam run`'s bag /tf_static,
runner/mount.mount_in_tree), waiting up to ``mount_wait_s`` for the transform, else the
parameters' mount. It holds its scans until then and publishes the decision on
pf_slam/lidar_mount (latched JSON: source, the mount parameters, a description, warnings). The
correlator and the mapper hold their first scan until that message is there and put its
parameters into their stages, so all three use one mount, decided once.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from typing import Any

from ..ros import qos, topics


class MountDecider:
    """The predictor's side: hears /tf_static + /tf, decides at the first scan, publishes."""

    def __init__(self, node, base_frame: str, odom_frame: str, wait_s: float, on_decided: Callable[[], None]) -> None:
        from std_msgs.msg import String
        from tf2_msgs.msg import TFMessage

        self.node, self.base, self.odom_frame, self.wait_s = node, base_frame, odom_frame, wait_s
        self.on_decided = on_decided
        self.tree: dict = {}
        self.warnings: list[str] = []
        self.frame: str | None = None
        self.t_first: float | None = None
        self.decided: dict[str, Any] | None = None
        self.pub = node.create_publisher(String, topics.LIDAR_MOUNT, qos.latched())
        self._subs = [
            node.create_subscription(TFMessage, topics.TF_STATIC, self._on_tf("/tf_static"), qos.latched(100)),
            node.create_subscription(TFMessage, topics.TF, self._on_tf("/tf"), qos.outputs(1000)),
        ]
        self._timer = node.create_timer(0.1, self.try_decide)

    def _on_tf(self, topic: str):
        from ..runner.mount import add_transform

        def cb(msg) -> None:
            for tr in msg.transforms:
                add_transform(self.tree, tr, self.warnings, topic)

        return cb

    def first_scan(self, frame_id: str) -> None:
        if self.frame is None:
            self.frame, self.t_first = frame_id.lstrip("/"), time.monotonic()
            self.try_decide()

    def try_decide(self) -> None:
        if self.decided is not None or self.frame is None:
            return
        from std_msgs.msg import String

        from ..runner.mount import LidarMount, mount_in_tree

        m = mount_in_tree(
            LidarMount("parameters", self.base, self.frame), dict(self.tree), "scan", self.odom_frame, source="/tf"
        )
        if m.source == "parameters" and time.monotonic() - self.t_first < self.wait_s:
            return  # the transform may still come
        if m.source != "parameters":
            m.source = "/tf_static + /tf"
            text = m.describe()
        else:
            text = (
                f"no transform to the scan's frame {self.frame!r} on /tf_static or /tf within {self.wait_s:g} s: "
                "the parameters' mount is used"
            )
        self.decided = {"source": m.source, "params": m.params(), "text": text, "warnings": self.warnings + m.warnings}
        self.pub.publish(String(data=json.dumps(self.decided)))
        self.node.get_logger().info(f"lidar mount: {text}")
        for sub in self._subs:
            self.node.destroy_subscription(sub)
        self.node.destroy_timer(self._timer)
        self.on_decided()


def receive_mount(node, on_mount: Callable[[dict], None]) -> None:
    """The correlator's and the mapper's side: `on_mount(decision)` when pf_slam/lidar_mount comes."""
    from std_msgs.msg import String

    node.create_subscription(String, topics.LIDAR_MOUNT, lambda msg: on_mount(json.loads(msg.data)), qos.latched())


def apply_to_stage(stage, params: dict[str, Any]) -> None:
    """The mount parameters (filter.sensor_offset_*, laser.extrinsic) into a stage's configs."""
    fields = {k.split(".", 1)[1]: float(v) for k, v in params.items() if k.startswith("filter.")}
    if fields:
        stage.filter_cfg = dataclasses.replace(stage.filter_cfg, **fields)
    if "laser.extrinsic" in params:
        stage.laser_cfg = dataclasses.replace(
            stage.laser_cfg, extrinsic=tuple(float(v) for v in params["laser.extrinsic"])
        )
