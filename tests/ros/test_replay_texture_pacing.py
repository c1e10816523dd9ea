"""bag_replay at rate max holds the next stereo pair back while the texture node works on one
(pf_slam/texture_progress), and lets it through for a pair that waits for its pose."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402
from std_msgs.msg import UInt32MultiArray  # noqa: E402

from pf_slam_nodes.graph import make_executor  # noqa: E402
from pf_slam_nodes.nodes.bag_replay import BagReplay  # noqa: E402
from pf_slam_nodes.ros import qos, topics  # noqa: E402

CAR = Path(__file__).resolve().parents[2] / "bags" / "car_sample"
LEFT = "/stereo/left/image_raw"


def test_replay_waits_for_texture_progress(ros_context):
    from pf_slam_tools.bench.ceiling import _sink_class

    ctx = ros_context
    ex = make_executor("events", ctx)
    sink = _sink_class()
    scan = {"/scan": "sensor_msgs/msg/LaserScan"}
    sinks = [sink("predictor", scan, True, ctx), sink("correlator", scan, False, ctx), sink("mapper", scan, False, ctx)]
    probe = rclpy.create_node("probe", context=ctx)
    images: list[int] = []
    probe.create_subscription(Image, LEFT, lambda m: images.append(m.header.stamp.sec), qos.pipeline(100))
    progress = probe.create_publisher(UInt32MultiArray, topics.TEXTURE_PROGRESS, qos.latched())
    replay = BagReplay(
        context=ctx,
        parameter_overrides=[
            Parameter("bag", value=str(CAR)),
            Parameter("rate", value="max"),
            Parameter("image_topic", value=LEFT),
        ],
    )
    nodes = [*sinks, probe, replay]
    for n in nodes:
        ex.add_node(n)

    def spin_for(seconds: float, until=lambda: False) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            ex.spin_once(timeout_sec=0.02)

    try:
        spin_for(
            60.0,
            lambda: (
                replay.images_published == 1
                and replay.timer.is_canceled()
                and replay.pending is not None
                and replay.pending[0] == LEFT
            ),
        )
        spin_for(1.0)  # held: the texture node has not finished the first pair
        assert replay.images_published == 1 and not replay.done and replay.texture_waits >= 1
        scans_held = replay.scans_published
        assert 0 < scans_held < replay.scans_in_bag
        progress.publish(UInt32MultiArray(data=[0, 1]))  # the pair waits for its pose: let the next through
        spin_for(30.0, lambda: replay.images_published == 2)
        assert replay.images_published == 2
        # the bag's last pair: only a next image would wait for it, so the rest of the bag goes out
        spin_for(60.0, lambda: replay.done)
        assert replay.done and replay.scans_published == replay.scans_in_bag
        assert replay.images_published == 2
        spin_for(1.0, lambda: len(images) == 2)
        assert len(images) == 2
    finally:
        ex.shutdown()
        for n in nodes:
            n.destroy_node()
