"""The toolchain is real: our messages travel through real rclpy publishers/subscribers over DDS."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from conftest import spin_until  # noqa: E402
from nav_msgs.msg import OccupancyGrid  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from pf_slam_interfaces.msg import ParticleArray  # noqa: E402
from pf_slam_nodes.ros import convert, qos  # noqa: E402


def _particles(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    poses = rng.normal(size=(n, 3))
    lw = np.log(np.full(n, 1.0 / n))
    return poses, lw


def _grid(seed: int = 1):
    rng = np.random.default_rng(seed)
    occ = rng.choice(np.array([-1, 0, 100], dtype=np.int8), size=(240, 320))
    return occ


def test_particles_and_grid_between_two_nodes_in_one_executor(ros_context):
    ctx = ros_context
    pub_node = rclpy.create_node("talker", context=ctx)
    sub_node = rclpy.create_node("listener", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(pub_node)
    ex.add_node(sub_node)
    got_p, got_g = [], []
    sub_node.create_subscription(ParticleArray, "particles", got_p.append, qos.pipeline())
    sub_node.create_subscription(OccupancyGrid, "grid", got_g.append, qos.latched())
    pp = pub_node.create_publisher(ParticleArray, "particles", qos.pipeline())
    pg = pub_node.create_publisher(OccupancyGrid, "grid", qos.latched())
    assert spin_until(ex, lambda: pp.get_subscription_count() > 0 and pg.get_subscription_count() > 0, 10)

    poses, lw = _particles(1000)
    occ = _grid()
    for k in range(5):
        pp.publish(
            convert.particles_to_msg(
                poses + k, lw, stamp_ns=1_000 + k, frame_id="map", scan_index=k, update=True, odom_pose=np.zeros(3)
            )
        )
    pg.publish(convert.grid_to_msg(occ, 0.05, (-8.0, -6.0), 42, "map"))
    assert spin_until(ex, lambda: len(got_p) == 5 and len(got_g) == 1, 10)

    assert [m.scan_index for m in got_p] == [0, 1, 2, 3, 4]
    back, back_lw = convert.msg_to_particles(got_p[3])
    np.testing.assert_array_equal(back, poses + 3)
    np.testing.assert_array_equal(back_lw, lw)
    grid, res, origin = convert.msg_to_grid(got_g[0])
    np.testing.assert_array_equal(grid, occ)
    assert (res, origin) == (pytest.approx(0.05), (-8.0, -6.0))
    ex.shutdown()
    pub_node.destroy_node()
    sub_node.destroy_node()


PUBLISHER = textwrap.dedent("""
    import sys, time
    import numpy as np
    import rclpy
    from nav_msgs.msg import OccupancyGrid
    from pf_slam_interfaces.msg import ParticleArray
    from pf_slam_nodes.ros import convert, qos
    rclpy.init()
    node = rclpy.create_node("remote_talker")
    pp = node.create_publisher(ParticleArray, "particles", qos.pipeline())
    pg = node.create_publisher(OccupancyGrid, "grid", qos.latched())
    deadline = time.monotonic() + 20
    while (pp.get_subscription_count() == 0 or pg.get_subscription_count() == 0):
        if time.monotonic() > deadline:
            sys.exit("no subscriber discovered")
        rclpy.spin_once(node, timeout_sec=0.05)
    rng = np.random.default_rng(7)
    poses = rng.normal(size=(10000, 3))
    for k in range(3):
        pp.publish(convert.particles_to_msg(poses * (k + 1), np.zeros(10000), stamp_ns=k,
                   frame_id="map", scan_index=k, update=False, odom_pose=np.array([1.0, 2.0, 3.0])))
    occ = np.full((100, 200), -1, dtype=np.int8); occ[10:20, 30:40] = 100
    pg.publish(convert.grid_to_msg(occ, 0.1, (0.0, 0.0), 9, "map"))
    end = time.monotonic() + 5   # stay alive so reliable delivery completes
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    rclpy.shutdown()
""")


def test_particles_and_grid_between_two_processes(ros_context, ros_domain):
    ctx = ros_context
    node = rclpy.create_node("local_listener", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    got_p, got_g = [], []
    node.create_subscription(ParticleArray, "particles", got_p.append, qos.pipeline())
    node.create_subscription(OccupancyGrid, "grid", got_g.append, qos.latched())
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain))
    proc = subprocess.Popen(
        [sys.executable, "-c", PUBLISHER], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        ok = spin_until(ex, lambda: len(got_p) == 3 and len(got_g) == 1, 30)
    finally:
        out, _ = proc.communicate(timeout=30)
    assert ok, f"received {len(got_p)} particle sets, {len(got_g)} grids; publisher said:\n{out}"
    assert proc.returncode == 0, out
    rng = np.random.default_rng(7)
    poses = rng.normal(size=(10000, 3))
    back, _ = convert.msg_to_particles(got_p[2])
    np.testing.assert_array_equal(back, poses * 3)
    assert list(got_p[0].odom_pose) == [1.0, 2.0, 3.0]
    grid, res, _ = convert.msg_to_grid(got_g[0])
    assert grid.shape == (100, 200) and (grid == 100).sum() == 100
    ex.shutdown()
    node.destroy_node()


def test_tf_message_type_is_upstream():
    """Our TFMessage (fallback or upstream) has the official Jazzy type hash."""
    import json
    from pathlib import Path

    import tf2_msgs
    from rosbags.typesys import Stores, get_typestore

    # <prefix>/lib/python3.11/site-packages/tf2_msgs/__init__.py -> <prefix>/share/tf2_msgs
    prefix = Path(tf2_msgs.__file__).resolve().parents[4]
    desc = json.loads((prefix / "share/tf2_msgs/msg/TFMessage.json").read_text())
    ours = next(h["hash_string"] for h in desc["type_hashes"] if h["type_name"] == "tf2_msgs/msg/TFMessage")
    upstream = get_typestore(Stores.ROS2_JAZZY).hash_rihs01("tf2_msgs/msg/TFMessage")
    assert ours == upstream
