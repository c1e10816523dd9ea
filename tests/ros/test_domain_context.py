"""An isolated Context (ros.domain.init_context) at the DDS level: its nodes talk to each other,
a participant of another Context on the same domain never matches it (discovery OFF: Jazzy's
rmw_fastrtps admits one participant, the local one), and the process environment is as before."""

from __future__ import annotations

import os
import time

import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from pf_slam_nodes.ros import domain  # noqa: E402


def test_isolated_context_talks_inside_and_not_to_its_domain(monkeypatch):
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv("ROS_STATIC_PEERS", "127.0.0.1")
    env_before = dict(os.environ)
    with domain.run_domain(single_participant=True) as dom:
        ctx, first = domain.init_context(dom, "iso_first")
        assert dict(os.environ) == env_before and ctx.get_domain_id() == dom.id
        # an open Context on the same domain, as a foreign node that found the domain would be
        other_ctx = rclpy.Context()
        rclpy.init(context=other_ctx, domain_id=dom.id)
        got = {"inside": 0, "foreign": 0, "from_foreign": 0}
        try:
            second = rclpy.create_node("iso_second", context=ctx)
            foreign = rclpy.create_node("foreign", context=other_ctx)
            pub = first.create_publisher(String, "/chatter", 10)
            second.create_subscription(String, "/chatter", lambda _m: got.__setitem__("inside", got["inside"] + 1), 10)
            foreign.create_subscription(
                String, "/chatter", lambda _m: got.__setitem__("foreign", got["foreign"] + 1), 10
            )
            fpub = foreign.create_publisher(String, "/junk", 10)
            first.create_subscription(
                String, "/junk", lambda _m: got.__setitem__("from_foreign", got["from_foreign"] + 1), 10
            )
            ex, fex = SingleThreadedExecutor(context=ctx), SingleThreadedExecutor(context=other_ctx)
            ex.add_node(first)
            ex.add_node(second)
            fex.add_node(foreign)
            t0 = time.monotonic()
            while time.monotonic() - t0 < 3.0:
                pub.publish(String(data="run"))
                fpub.publish(String(data="junk"))
                ex.spin_once(timeout_sec=0.005)
                fex.spin_once(timeout_sec=0.005)
            assert got["inside"] > 50, got  # the run's nodes hear each other
            assert got["foreign"] == 0 and got["from_foreign"] == 0, got  # and nothing crosses either way
            assert pub.get_subscription_count() == 1 and fpub.get_subscription_count() == 0
            ex.shutdown()
            fex.shutdown()
        finally:
            rclpy.shutdown(context=other_ctx)
            rclpy.shutdown(context=ctx)
