"""mount_from_tf: the predictor decides the lidar mount at the first scan from /tf_static + /tf
and the correlator and the mapper take that decision before they use a scan (real nodes, real
DDS, one Context on the test's own domain)."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("rclpy")

from conftest import spin_until  # noqa: E402


def _graph(ctx, wait_s: float = 5.0):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from pf_slam_nodes.nodes.correlator import Correlator
    from pf_slam_nodes.nodes.mapper import Mapper
    from pf_slam_nodes.nodes.predictor import Predictor

    ex = SingleThreadedExecutor(context=ctx)
    p = [Parameter("mount_from_tf", value=True)]
    nodes = {
        "predictor": Predictor(context=ctx, parameter_overrides=p + [Parameter("mount_wait_s", value=wait_s)]),
        "correlator": Correlator(context=ctx, parameter_overrides=p),
        "mapper": Mapper(context=ctx, parameter_overrides=p),
    }
    for n in nodes.values():
        ex.add_node(n)
    return ex, nodes


def _publish(ctx, ex, tf_static: list, scans: int = 3):
    import rclpy
    from geometry_msgs.msg import TransformStamped
    from sensor_msgs.msg import LaserScan
    from tf2_msgs.msg import TFMessage

    from pf_slam_nodes.core.geometry import rpy_to_quat
    from pf_slam_nodes.ros import qos

    src = rclpy.create_node("robot", context=ctx)
    ex.add_node(src)
    pub_static = src.create_publisher(TFMessage, "/tf_static", qos.latched(10))
    pub_scan = src.create_publisher(LaserScan, "/scan", qos.pipeline())
    msg = TFMessage()
    for parent, child, xyz, rpy in tf_static:
        t = TransformStamped()
        t.header.frame_id, t.child_frame_id = parent, child
        t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = xyz
        q = rpy_to_quat(rpy)
        t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w = q
        msg.transforms.append(t)
    pub_static.publish(msg)
    assert spin_until(ex, lambda: pub_scan.get_subscription_count() >= 1, 10)
    for k in range(scans):
        s = LaserScan()
        s.header.frame_id = "laser"
        s.header.stamp.sec = 100 + k
        s.angle_min, s.angle_max, s.angle_increment = -1.0, 1.0, 0.5
        s.range_min, s.range_max = 0.1, 10.0
        s.ranges = [5.0] * 5
        pub_scan.publish(s)
    return src


def test_planar_and_tilted_mounts_reach_every_stage(ros_context):
    ex, nodes = _graph(ros_context)
    _publish(
        ros_context,
        ex,
        [
            ("base_link", "plate", (0.2, 0.0, 0.1), (0.0, 0.0, 0.0)),
            ("plate", "laser", (0.1, 0.05, 0.0), (0.0, 0.0, math.pi / 2)),
        ],
    )
    assert spin_until(ex, lambda: nodes["correlator"].mount_ready and nodes["mapper"].mount_ready, 15)
    d = nodes["predictor"].mount.decided
    assert d["source"] == "/tf_static + /tf" and "base_link -> plate -> laser" in d["text"]
    for name in ("correlator", "mapper"):
        np.testing.assert_allclose(nodes[name].stage.filter_cfg.sensor_offset, [0.3, 0.05, math.pi / 2], atol=1e-9)
    assert nodes["mapper"].pub_tf_static is None  # the robot's TF has the mount
    assert len(nodes["predictor"]._held) == 0  # the held scans went on once it was decided


def test_tilted_mount_and_fallback_to_parameters(ros_context):
    ex, nodes = _graph(ros_context, wait_s=0.5)
    _publish(ros_context, ex, [("base_link", "laser", (0.5, 0.0, 1.0), (0.0, 0.3, 0.0))])
    assert spin_until(ex, lambda: nodes["correlator"].mount_ready and nodes["mapper"].mount_ready, 15)
    ext = nodes["correlator"].stage.laser_cfg.extrinsic
    assert len(ext) == 12 and ext[9:] == pytest.approx((0.5, 0.0, 1.0))
    assert nodes["mapper"].stage.laser_cfg.extrinsic == ext


def test_no_transform_uses_the_parameters_after_the_wait(ros_context):
    ex, nodes = _graph(ros_context, wait_s=0.5)
    _publish(ros_context, ex, [("base_link", "camera", (0.5, 0.0, 1.0), (0.0, 0.0, 0.0))])
    assert spin_until(ex, lambda: nodes["correlator"].mount_ready and nodes["mapper"].mount_ready, 15)
    d = nodes["predictor"].mount.decided
    assert d["source"] == "parameters" and "no transform to the scan's frame 'laser'" in d["text"]
    np.testing.assert_allclose(nodes["mapper"].stage.filter_cfg.sensor_offset, [0, 0, 0])
    assert nodes["mapper"].pub_tf_static is not None  # no mount on TF: the mapper publishes its own
