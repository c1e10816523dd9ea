"""Run isolation: `pf-slam run` as a user starts it (ROS_DOMAIN_ID unset) keeps to itself.

Two runs at once, or a run next to another ROS 2 system on the default domain, used to exchange
/scan, /odom, particles and maps (each "processed" ~2250 of 600 scans). Here real CLI runs in
child processes with the user's default environment: two at once must give the trajectory of a
run alone, byte for byte; a foreign node on domain 0 publishing junk /scan and /odom must not
reach a run, and must not receive anything from it. An explicit domain (--domain N) stays open,
so rviz2 or Foxglove can watch.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "bags" / "sample_indoor"
PARAMS = ROOT / "ros2_ws/src/pf_slam_nodes/config/sim_indoor.yaml"
#: what a user's shell may have that would join a run to other graphs; unset for these runs
ROS_ENV = (
    "ROS_DOMAIN_ID",
    "ROS_AUTOMATIC_DISCOVERY_RANGE",
    "ROS_STATIC_PEERS",
    "ROS_LOCALHOST_ONLY",
    "ROS_DISCOVERY_SERVER",
)


def _user_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in ROS_ENV}


def _start(out: Path, processes: str = "single", *extra: str, env: dict | None = None) -> subprocess.Popen:
    cmd = [
        sys.executable,
        "-c",
        "import sys; from pf_slam_nodes.cli import main; sys.exit(main())",
        "run",
        str(SAMPLE),
        "--out",
        str(out),
        "--params",
        str(PARAMS),
        "--rate",
        "max",
        "--processes",
        processes,
        "--snapshot-every",
        "0",
        "--no-record",
        *extra,
    ]
    return subprocess.Popen(cmd, env=env or _user_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _finish(p: subprocess.Popen, out: Path, timeout_s: float = 400.0) -> dict:
    try:
        text, _ = p.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        p.kill()
        text, _ = p.communicate()
    assert p.returncode == 0, text[-3000:]
    s = json.loads((out / "summary.json").read_text())
    s["_stderr"] = text
    return s


@pytest.fixture(scope="module")
def solo(tmp_path_factory):
    """The sample bag alone, as a user runs it."""
    out = tmp_path_factory.mktemp("solo")
    s = _finish(_start(out), out)
    assert s["scans_processed"] == s["scans_published"] == 600 and s["complete"]
    return out, s


def _assert_same_as_solo(solo, out: Path, s: dict) -> None:
    assert s["scans_published"] == s["scans_processed"] == 600, s
    assert s["scans_dropped"] == 0 and s["complete"] and not any(s["faults"].values()), s
    assert (out / "trajectory.tum").read_bytes() == (solo[0] / "trajectory.tum").read_bytes()


def test_a_run_alone_is_isolated_and_says_so(solo):
    out, s = solo
    dom = s["ros_domain"]
    assert dom["isolated"] is True and 1 <= dom["id"] <= 100 and dom["discovery"] == "OFF", dom
    assert f"ROS domain {dom['id']} (isolated" in s["_stderr"]


@pytest.mark.parametrize("processes", ["single", "multi"])
def test_two_concurrent_runs_equal_a_solo_run(solo, tmp_path, processes):
    """Two runs started together (one process each, or one per node each), the user's default
    environment: each gets the solo trajectory byte for byte, on a domain of its own."""
    outs = [tmp_path / "a", tmp_path / "b"]
    procs = [_start(o, processes) for o in outs]
    sums = [_finish(p, o) for p, o in zip(procs, outs)]
    for o, s in zip(outs, sums):
        _assert_same_as_solo(solo, o, s)
        assert s["ros_domain"]["isolated"] is True
        assert s["ros_domain"]["discovery"] == ("OFF" if processes == "single" else "LOCALHOST")
    assert sums[0]["ros_domain"]["id"] != sums[1]["ros_domain"]["id"]


class _Foreign:
    """A node on the default domain 0, as another ROS 2 system on this host would have: publishes
    junk /scan and /odom (stamped inside the bag's time span) at ~500 Hz each and counts what it
    receives on the topics only a run publishes."""

    WATCHED = ("/pose", "/map", "/particles/updated", "/particles/predicted", "/pf_slam/status")

    def __init__(self, start_ns: int, duration_ns: int) -> None:
        import rclpy
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import OccupancyGrid, Odometry
        from sensor_msgs.msg import LaserScan
        from std_msgs.msg import String

        from pf_slam_interfaces.msg import ParticleArray
        from pf_slam_nodes.ros import qos

        self.start_ns, self.duration_ns = start_ns, duration_ns
        old = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE")
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # this host only: reaches any domain-0 node here
        try:
            self.ctx = rclpy.Context()
            rclpy.init(context=self.ctx, domain_id=0)
            self.node = rclpy.create_node("foreign_user_node", context=self.ctx)
        finally:
            if old is None:
                os.environ.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)
            else:
                os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = old
        self.received = {t: 0 for t in self.WATCHED}
        types = {
            "/pose": PoseStamped,
            "/map": OccupancyGrid,
            "/particles/updated": ParticleArray,
            "/particles/predicted": ParticleArray,
            "/pf_slam/status": String,
        }
        for t, cls in types.items():
            self.node.create_subscription(
                cls, t, lambda _m, t=t: self._count(t), qos.latched() if t in ("/map", "/pf_slam/status") else 10
            )
        self.scan_pub = self.node.create_publisher(LaserScan, "/scan", qos.pipeline())
        self.odom_pub = self.node.create_publisher(Odometry, "/odom", qos.pipeline())
        self.LaserScan, self.Odometry = LaserScan, Odometry
        self.published = 0
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, daemon=True)

    def _count(self, topic: str) -> None:
        self.received[topic] += 1

    def _loop(self) -> None:
        import math

        from rclpy.executors import SingleThreadedExecutor

        ex = SingleThreadedExecutor(context=self.ctx)
        ex.add_node(self.node)
        k = 0
        while not self._stop.is_set():
            ns = self.start_ns + (k * 7_919_000_000) % self.duration_ns
            scan = self.LaserScan()
            scan.header.stamp.sec, scan.header.stamp.nanosec = divmod(ns, 10**9)
            scan.header.frame_id = "laser"
            scan.angle_min, scan.angle_max = -math.pi / 2, math.pi / 2
            scan.angle_increment = math.pi / 180
            scan.range_min, scan.range_max = 0.1, 30.0
            scan.ranges = [0.5 + 0.01 * (k % 50)] * 181
            odom = self.Odometry()
            odom.header = scan.header
            odom.header.frame_id = "odom"
            odom.pose.pose.position.x = float(k % 97)
            odom.pose.pose.orientation.w = 1.0
            self.scan_pub.publish(scan)
            self.odom_pub.publish(odom)
            self.published += 1
            k += 1
            ex.spin_once(timeout_sec=0.002)
        ex.shutdown()

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        import rclpy

        self._stop.set()
        self.thread.join(10)
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


@pytest.mark.parametrize("processes", ["single", "multi"])
def test_a_foreign_graph_on_the_default_domain_does_not_reach_a_run(solo, tmp_path, processes):
    """Junk /scan and /odom from a node on domain 0 during the whole run: the run processes its
    600 scans, the solo trajectory byte for byte; the foreign node receives nothing of the run."""
    from pf_slam_nodes.io.bag import bag_info

    info = bag_info(SAMPLE)
    with _Foreign(info["start_ns"], info["duration_ns"]) as foreign:
        time.sleep(1.0)  # the foreign graph is up before the run starts, as a user's would be
        out = tmp_path / "run"
        s = _finish(_start(out, processes), out, timeout_s=240)  # reached by the junk, a run never ends
        time.sleep(0.5)
    assert foreign.published > 500, foreign.published  # it really published, all through the run
    _assert_same_as_solo(solo, out, s)
    assert foreign.received == {t: 0 for t in _Foreign.WATCHED}, foreign.received
    assert s["ros_domain"]["id"] != 0 and s["ros_domain"]["isolated"] is True


def test_an_explicit_domain_is_open_so_a_viewer_can_watch(solo, tmp_path, ros_domain):
    """--domain N: the run is on N with the normal discovery; a viewer node on N (as rviz2 would
    be) receives its /map and poses; summary.json and the first lines say it is not isolated."""
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import OccupancyGrid
    from rclpy.executors import SingleThreadedExecutor

    from pf_slam_nodes.ros import qos

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=ros_domain)  # ros_domain: held for this test, LOCALHOST
    got = {"/pose": 0, "/map": 0, "last_pose_ns": None}

    def on_pose(m):
        got["/pose"] += 1
        got["last_pose_ns"] = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec

    try:
        viewer = rclpy.create_node("viewer", context=ctx)
        viewer.create_subscription(PoseStamped, "/pose", on_pose, qos.pipeline())
        viewer.create_subscription(
            OccupancyGrid, "/map", lambda _m: got.__setitem__("/map", got["/map"] + 1), qos.latched()
        )
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(viewer)
        out = tmp_path / "open"
        # --delay: the replay waits 3 s once the graph is up, so the viewer has discovered the run
        # before its first scan even on a loaded machine (discovery is not instant)
        p = _start(
            out,
            "single",
            "--domain",
            str(ros_domain),
            "--delay",
            "3",
            env=dict(_user_env(), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"),
        )
        while p.poll() is None:
            ex.spin_once(timeout_sec=0.01)
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        s = _finish(p, out)
        ex.shutdown()
        viewer.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    _assert_same_as_solo(solo, out, s)
    assert s["ros_domain"] == {"id": ros_domain, "isolated": False, "discovery": "LOCALHOST", "chosen_by": "--domain"}
    assert f"ROS domain {ros_domain} (open" in s["_stderr"]
    # it watched from when discovery matched it (timing) to the end: the run's last pose and a map
    last_ns = int(round(float((out / "trajectory.tum").read_text().split("\n")[-2].split()[0]) * 1e9))
    assert got["/map"] >= 1 and got["/pose"] > 0 and abs(got["last_pose_ns"] - last_ns) < 1000, got
