"""A lidar driver that publishes with the sensor-data QoS (best effort) reaches the predictor only
with sensor_qos: best_effort; with the default (reliable) nothing matches and the node says so."""

from __future__ import annotations

import pytest

pytest.importorskip("rclpy")

from conftest import spin_until  # noqa: E402


def _scan_subscription(node):
    subs = [s for s in node.subscriptions if s.topic_name == "/scan"]
    assert len(subs) == 1
    return subs[0]


@pytest.mark.parametrize("sensor_qos, matched", [("reliable", 0), ("best_effort", 1)])
def test_best_effort_scan_publisher(ros_context, sensor_qos, matched):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import LaserScan

    from pf_slam_nodes.nodes.predictor import Predictor

    pred = Predictor(context=ros_context, parameter_overrides=[Parameter("sensor_qos", value=sensor_qos)])
    drv = Node("lidar_driver", context=ros_context)
    drv.create_publisher(LaserScan, "/scan", qos_profile_sensor_data)
    ex = SingleThreadedExecutor(context=ros_context)
    for n in (pred, drv):
        ex.add_node(n)
    try:
        sub = _scan_subscription(pred)
        # discovery: the publisher is in the graph either way; matched only when the QoS allows it
        assert spin_until(ex, lambda: pred.count_publishers("/scan") == 1, 10.0)
        spin_until(ex, lambda: sub.get_publisher_count() == matched and matched == 1, 3.0)
        assert sub.get_publisher_count() == matched
    finally:
        ex.shutdown()
        drv.destroy_node()
        pred.destroy_node()


def test_bad_sensor_qos_value_is_refused(ros_context):
    from rclpy.parameter import Parameter

    from pf_slam_nodes.nodes.predictor import Predictor

    with pytest.raises(ValueError, match="sensor_qos"):
        Predictor(context=ros_context, parameter_overrides=[Parameter("sensor_qos", value="fast")])


def test_scan_queue_depth_sets_the_scan_subscription_and_refuses_zero(ros_context):
    from rclpy.parameter import Parameter

    from pf_slam_nodes.nodes.predictor import Predictor

    pred = Predictor(context=ros_context, parameter_overrides=[Parameter("scan_queue_depth", value=5)])
    try:
        assert _scan_subscription(pred).qos_profile.depth == 5
    finally:
        pred.destroy_node()
    pred = Predictor(context=ros_context)
    try:
        assert _scan_subscription(pred).qos_profile.depth == 1000  # the lossless replay's default
    finally:
        pred.destroy_node()
    with pytest.raises(ValueError, match="scan_queue_depth"):
        Predictor(context=ros_context, parameter_overrides=[Parameter("scan_queue_depth", value=0)])
