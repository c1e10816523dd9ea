"""The replay-only ceiling: how fast this machine and this middleware can move a bag through
the graph's topics when the nodes do nothing but count.

bag_replay (the real node, `rate:=max`) publishes every topic of the bag into three sinks
standing in for predictor, correlator and mapper: each subscribes (serialized, no
deserialization) to what the real node subscribes to; the predictor's sink answers every scan
with one pose (a pre-serialized PoseStamped), which is what the replay paces on. The real
graph cannot be faster than this; `pf-slam bench` prints each run's ratio to it. A bag with
stereo images gets a fourth sink standing in for the texture node: it takes both images raw and
reports each left image finished at once on pf_slam/texture_progress, which the replay paces the
images on as in the real run.
"""

from __future__ import annotations

import contextlib
import time

from pf_slam_nodes.io.bag import bag_info


def _sink_class():
    from geometry_msgs.msg import PoseStamped
    from rclpy.node import Node
    from rclpy.serialization import serialize_message
    from std_msgs.msg import UInt32MultiArray

    from pf_slam_nodes.nodes.bag_replay import message_class
    from pf_slam_nodes.nodes.common import announce_when_matched
    from pf_slam_nodes.ros import qos, topics

    class CountingSink(Node):
        """Subscribes to `subscribe` (topic -> type name) raw and counts; optionally answers
        every scan with a pose."""

        def __init__(
            self, name: str, subscribe: dict[str, str], echo_pose: bool, context, progress_on: str = ""
        ) -> None:
            super().__init__(name, context=context)
            self.counts = {t: 0 for t in subscribe}
            self.pose_raw = serialize_message(PoseStamped())
            needs = []
            self.progress_on = progress_on
            if progress_on:  # the texture node's stand-in: every pair finished at once
                self.pub_progress = self.create_publisher(UInt32MultiArray, topics.TEXTURE_PROGRESS, qos.latched())
                needs.append((self.pub_progress, 1))
            if echo_pose:
                self.pub_pose = self.create_publisher(PoseStamped, topics.POSE, qos.pipeline())
                needs.append((self.pub_pose, 1))
            for topic, msgtype in subscribe.items():
                cb = self._scan if echo_pose and topic == "/scan" else self._counter(topic)
                self.create_subscription(message_class(msgtype), topic, cb, qos.pipeline(10000), raw=True)
            announce_when_matched(self, needs)

        def _counter(self, topic: str):
            def cb(_raw: bytes) -> None:
                self.counts[topic] += 1
                if topic == self.progress_on:
                    self.pub_progress.publish(UInt32MultiArray(data=[self.counts[topic], 0]))

            return cb

        def _scan(self, _raw: bytes) -> None:
            self.counts["/scan"] += 1
            self.pub_pose.publish(self.pose_raw)

    return CountingSink


def replay_ceiling(bag: str, executor: str = "events", domain_id: int | None = None, timeout_s: float = 600.0) -> dict:
    """Replay `bag` at max into counting sinks in one process; returns wall time, RTF, counts.
    On an isolated domain (ros.domain.ros_context) unless `domain_id` / ROS_DOMAIN_ID names one."""
    from rclpy.parameter import Parameter

    from pf_slam_nodes.graph import make_executor
    from pf_slam_nodes.nodes.bag_replay import BagReplay
    from pf_slam_nodes.ros.domain import ros_context

    info = bag_info(bag)
    tp = {t: m for t, (m, _) in info["topics"].items()}
    odom = {t: tp[t] for t in ("/odom", "/encoders", "/fog") if t in tp}
    scan = {"/scan": tp["/scan"]} if "/scan" in tp else {}
    left, right = "/stereo/left/image_raw", "/stereo/right/image_raw"
    images = {t: tp[t] for t in (left, right) if t in tp}
    domain_scope = contextlib.ExitStack()
    ctx, _dom = domain_scope.enter_context(ros_context(domain_id))
    nodes = []
    ex = None
    try:
        ex = make_executor(executor, ctx)
        Sink = _sink_class()
        sinks = [
            Sink("predictor", {**scan, **odom}, True, ctx),
            Sink("correlator", scan, False, ctx),
            Sink("mapper", scan, False, ctx),
        ]
        extra = []
        if left in images:
            sinks.append(Sink("texture", images, False, ctx, progress_on=left))
            extra = [
                Parameter("image_topic", value=left),
                Parameter("wait_for", value=["predictor", "correlator", "mapper", "texture"]),
            ]
        replay = BagReplay(
            context=ctx, parameter_overrides=[Parameter("bag", value=str(bag)), Parameter("rate", value="max"), *extra]
        )
        nodes = [*sinks, replay]
        for n in nodes:
            ex.add_node(n)
        expected = {t: c for t, (_, c) in info["topics"].items()}
        while not replay.started:
            ex.spin_once(timeout_sec=0.05)
        t0 = time.monotonic()
        while not (
            replay.done
            and sinks[0].counts.get("/scan", 0) >= expected.get("/scan", 0)
            and all(sinks[0].counts[t] >= expected[t] for t in sinks[0].counts)
        ):
            ex.spin_once(timeout_sec=0.05)
            if time.monotonic() - t0 > timeout_s:
                raise TimeoutError(f"replay-only run of {bag} did not finish in {timeout_s:.0f} s")
        wall = time.monotonic() - t0
        received = sinks[0].counts
    finally:
        if ex is not None:
            ex.shutdown()
        for n in nodes:
            n.destroy_node()
        domain_scope.close()
    dur = info["duration_ns"] / 1e9
    return {
        "bag": str(bag),
        "bag_duration_s": round(dur, 3),
        "wall_time_s": round(wall, 3),
        "real_time_factor": round(dur / wall, 2) if wall > 0 else None,
        "messages": sum(expected.values()),
        "received_by_predictor_sink": dict(received),
        "images": sum(expected.get(t, 0) for t in images),
        "executor": executor,
    }
