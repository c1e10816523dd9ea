"""Live use: `pf-slam live` started on its own, a bag played into it from a separate process
(`pf-slam play --clock`, as `ros2 bag play --clock`), the mapper's services called by an rclpy
client. Asserts what a live user gets: every scan posed, the error against ground truth as
`pf-slam run` on the same bag, files from save_map, pause / reset doing what they say."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from pf_slam_nodes.io.evaluation import evaluate  # noqa: E402
from pf_slam_nodes.io.mapfile import read_map  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "bags" / "sample_indoor"
GT = ROOT / "bags" / "ground_truth.tum"
SIM = ROOT / "ros2_ws/src/pf_slam_nodes/config/sim_indoor.yaml"
PF_SLAM = [sys.executable, "-m", "pf_slam_nodes.cli"]


class Proc:
    """A child process whose merged output is collected line by line."""

    def __init__(self, args: list[str], env: dict | None = None) -> None:
        self.p = subprocess.Popen(
            args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env or dict(os.environ)
        )
        self.lines: list[str] = []
        self._t = threading.Thread(target=self._read, daemon=True)
        self._t.start()

    def _read(self) -> None:
        for line in self.p.stdout:
            self.lines.append(line.rstrip())

    def text(self) -> str:
        return "\n".join(self.lines)

    def wait_for(self, needle: str, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if needle in self.text():
                return True
            if self.p.poll() is not None:
                time.sleep(0.2)
                return needle in self.text()
            time.sleep(0.05)
        return False

    def stop(self, sig=signal.SIGINT, timeout_s: float = 30.0) -> int:
        if self.p.poll() is None:
            self.p.send_signal(sig)
        try:
            rc = self.p.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.p.kill()
            rc = self.p.wait()
        self._t.join(timeout=5)
        return rc


def _start_live(out: Path, *extra: str, params: Path = SIM) -> Proc:
    live = Proc(PF_SLAM + ["live", "--params", str(params), "--out", str(out), *extra])
    assert live.wait_for("running; save the map", 60), live.text()
    return live


def _play(bag: Path, rate: str, wait_for: str = "/odom") -> str:
    # as `ros2 bag play --delay`: the player's writers must have found the graph's readers (discovery
    # between two processes) or the first messages are not delivered; here it waits for the readers
    r = subprocess.run(
        PF_SLAM + ["play", str(bag), "--rate", rate, "--clock", "--delay", "0.5", "--wait-for", "/scan", wait_for],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr + r.stdout
    return r.stdout


class Client:
    """rclpy clients of the mapper's services."""

    def __init__(self, ctx) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from std_srvs.srv import SetBool, Trigger

        from pf_slam_interfaces.srv import SaveMap

        self.node = rclpy.create_node("live_test_client", context=ctx)
        self.ex = SingleThreadedExecutor(context=ctx)
        self.ex.add_node(self.node)
        self.save = self.node.create_client(SaveMap, "pf_slam/save_map")
        self.pause = self.node.create_client(SetBool, "pf_slam/pause_mapping")
        self.reset = self.node.create_client(Trigger, "pf_slam/reset")
        self.types = SaveMap, SetBool, Trigger
        for c in (self.save, self.pause, self.reset):
            assert c.wait_for_service(timeout_sec=30), c.srv_name

    def call(self, client, req):
        fut = client.call_async(req)
        self.ex.spin_until_future_complete(fut, timeout_sec=30)
        assert fut.done(), client.srv_name
        return fut.result()

    def save_to(self, path: Path):
        return self.call(self.save, self.types[0].Request(directory=str(path)))

    def close(self) -> None:
        self.ex.shutdown()
        self.node.destroy_node()


def _poses(path: Path) -> np.ndarray:
    return np.loadtxt(path, ndmin=2)


def _saved_until(client: Client, path: Path, n: int, timeout_s: float = 60) -> np.ndarray:
    """Save repeatedly until the trajectory has `n` poses and stops growing (the graph caught up)."""
    deadline, last = time.monotonic() + timeout_s, -1
    while True:
        res = client.save_to(path)
        assert res.success, res.message
        k = len(_poses(path / "trajectory.tum"))
        if (k >= n and k == last) or time.monotonic() > deadline:
            return _poses(path / "trajectory.tum")
        last = k
        time.sleep(1.0)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """`pf-slam run` on the sample bag, same parameters (isolated on its own domain)."""
    from pf_slam_nodes.graph import run

    out = tmp_path_factory.mktemp("ref")
    run(str(SAMPLE), out, params_file=str(SIM), progress=False, record=False, snapshot_every=0)
    return evaluate(out / "trajectory.tum", GT)["ate"]["rmse"], _poses(out / "trajectory.tum")


@pytest.mark.parametrize("rate", ["1", "3"])
def test_live_graph_fed_by_separate_player(rate, reference, tmp_path, ros_context):
    """A bag played at 1x and 3x by another process, with /clock: every scan is posed, use_sim_time
    follows /clock, the ATE is within 20 % of `pf-slam run`'s, save_map and Ctrl-C write the files."""
    ref_ate, ref_poses = reference
    live = _start_live(tmp_path / "out")
    try:
        client = Client(ros_context)
        early = client.save_to(tmp_path / "early")
        assert not early.success and "no map yet" in early.message
        played = _play(SAMPLE, rate)
        assert "/scan 600" in played
        traj = _saved_until(client, tmp_path / "saved", 600)
        client.close()
    finally:
        rc = live.stop()
    assert rc == 0, live.text()
    assert "/clock is published: use_sim_time true" in live.text()
    assert "lidar mount from /tf_static + /tf: base_link -> laser" in live.text()
    assert len(traj) == 600
    ate = evaluate(tmp_path / "saved" / "trajectory.tum", GT)["ate"]["rmse"]
    assert ate <= 1.2 * ref_ate, (ate, ref_ate)
    # the map server files and the Ctrl-C save
    for d in (tmp_path / "saved", tmp_path / "out"):
        occ, res, origin = read_map(d / "map.yaml")
        assert res == pytest.approx(0.05) and (occ >= 65).sum() > 500
        assert (d / "map.pgm").read_bytes()[:2] == b"P5"
    assert len(_poses(tmp_path / "out" / "trajectory.tum")) == 600
    # nothing lost on the way, nothing waited on: the same trajectory as the paced replay
    assert np.abs(traj[:, 1:3] - ref_poses[:, 1:3]).max() < 0.05


def test_live_one_process_per_node(reference, tmp_path, ros_context):
    """--processes multi, the mount in the parameters (so the node processes start before the first
    scan): the same 600 poses as `pf-slam run`, saved on Ctrl-C through the mapper's service."""
    params = tmp_path / "params.yaml"
    params.write_text(SIM.read_text().replace("      seed: 0\n", "      seed: 0\n      sensor_offset_x_m: 0.0\n"))
    assert "sensor_offset_x_m" in params.read_text()
    live = _start_live(tmp_path / "out", "--processes", "multi", params=params)
    try:
        client = Client(ros_context)  # the mapper's services: its process is up
        _play(SAMPLE, "4")
        traj = _saved_until(client, tmp_path / "saved", 600)
        client.close()
    finally:
        rc = live.stop()
    assert rc == 0, live.text()
    assert len(traj) == 600 and len(_poses(tmp_path / "out" / "trajectory.tum")) == 600
    assert np.abs(traj[:, 1:3] - reference[1][:, 1:3]).max() < 0.05
    assert (tmp_path / "out" / "logs" / "mapper.log").is_file()


def test_pause_resume_reset_services(reference, tmp_path, ros_context):
    """pause freezes the map while the poses go on; resume maps again; reset starts a new, small map
    and trajectory from the next scan, in the same map frame (still close to ground truth)."""
    live = _start_live(tmp_path / "out")
    player = Proc(
        PF_SLAM + ["play", str(SAMPLE), "--rate", "2", "--clock", "--delay", "0.5", "--wait-for", "/scan", "/odom"]
    )
    try:
        c = Client(ros_context)
        _, SetBool, Trigger = c.types
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # some map first
            res = c.save_to(tmp_path / "a")
            if res.success and len(_poses(tmp_path / "a" / "trajectory.tum")) > 150:
                break
            time.sleep(0.5)
        (tmp_path / "a_file").write_text("")
        bad = c.save_to(tmp_path / "a_file" / "map")  # a folder under a file: cannot be written
        assert not bad.success and "cannot write into" in bad.message
        r = c.call(c.pause, SetBool.Request(data=True))
        assert r.success and "paused" in r.message
        time.sleep(1.0)  # what was in flight is integrated
        assert c.save_to(tmp_path / "p1").success
        time.sleep(3.0)
        assert c.save_to(tmp_path / "p2").success
        n1, n2 = len(_poses(tmp_path / "p1/trajectory.tum")), len(_poses(tmp_path / "p2/trajectory.tum"))
        assert n2 > n1 + 20, (n1, n2)  # the filter goes on
        assert (tmp_path / "p1/map.pgm").read_bytes() == (tmp_path / "p2/map.pgm").read_bytes()  # the map does not
        assert c.call(c.pause, SetBool.Request(data=False)).success
        time.sleep(3.0)
        assert c.save_to(tmp_path / "r1").success
        assert (tmp_path / "r1/map.pgm").read_bytes() != (tmp_path / "p2/map.pgm").read_bytes()
        known_before = int((read_map(tmp_path / "r1/map.yaml")[0] >= 0).sum())
        t_reset = _poses(tmp_path / "r1/trajectory.tum")[-1, 0]
        assert c.call(c.reset, Trigger.Request()).success
        time.sleep(1.5)
        assert c.save_to(tmp_path / "z").success
        after = _poses(tmp_path / "z/trajectory.tum")
        known_after = int((read_map(tmp_path / "z/map.yaml")[0] >= 0).sum())
        assert after[0, 0] > t_reset and 0 < len(after) < 200
        assert 0 < known_after < known_before, (known_after, known_before)
        assert player.p.wait(timeout=120) == 0
        c.close()
    finally:
        player.stop()
        rc = live.stop()
    assert rc == 0, live.text()
    # after the reset the map frame is the same: the new trajectory is where `pf-slam run` has it
    final, ref = _poses(tmp_path / "out" / "trajectory.tum"), reference[1]
    idx = np.searchsorted(ref[:, 0], final[:, 0] - 1e-4)
    assert np.all(np.abs(ref[idx, 0] - final[:, 0]) < 1e-3)
    assert np.median(np.hypot(*(final[:, 1:3] - ref[idx, 1:3]).T)) < 0.1


def _tf_bag(out: Path, with_odom: bool) -> Path:
    """The sample bag with the odometry as odom -> base_link on /tf (and /odom if `with_odom`)."""
    from pf_slam_nodes.core.geometry import quat_to_yaw
    from pf_slam_nodes.io.bag import deserialize, open_writer, read_bag
    from pf_slam_nodes.ros import cdr

    tfw = cdr.TransformWriter("odom", "base_link")
    with open_writer(out) as w:
        w.add_connection("/scan", "sensor_msgs/msg/LaserScan")
        w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage")
        w.add_connection("/tf", "tf2_msgs/msg/TFMessage")
        if with_odom:
            w.add_connection("/odom", "nav_msgs/msg/Odometry")
        for topic, msgtype, t, raw in read_bag(SAMPLE):
            if topic == "/odom":
                m = deserialize(raw, msgtype)
                p, q = m.pose.pose.position, m.pose.pose.orientation
                stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                w.write_raw("/tf", t, tfw.pack(np.array([p.x, p.y, quat_to_yaw(q.x, q.y, q.z, q.w)]), stamp))
                if not with_odom:
                    continue
            w.write_raw(topic, t, raw)
    return out


def test_odometry_from_tf_and_no_odom_tf_fight(reference, tmp_path, ros_context):
    """--odometry tf: odometry from the robot's odom -> base_link; the predictor publishes none of
    its own; and with /odom as input it stops publishing odom -> base_link once another node does."""
    ref_ate, _ = reference
    bag = _tf_bag(tmp_path / "tf_bag", with_odom=False)
    live = _start_live(tmp_path / "out", "--odometry", "tf")
    try:
        client = Client(ros_context)
        _play(bag, "4", wait_for="/tf")
        traj = _saved_until(client, tmp_path / "saved", 600)
        client.close()
    finally:
        assert live.stop() == 0, live.text()
    assert len(traj) == 600
    assert evaluate(tmp_path / "saved" / "trajectory.tum", GT)["ate"]["rmse"] <= 1.2 * ref_ate

    bag2 = _tf_bag(tmp_path / "tf_odom_bag", with_odom=True)
    live = _start_live(tmp_path / "out2")
    try:
        _play(bag2, "4")
        assert live.wait_for("another node publishes odom -> base_link on /tf", 20), live.text()
    finally:
        assert live.stop() == 0, live.text()


def test_stopped_before_any_scan_says_so(tmp_path, ros_domain):
    """Ctrl-C before any scan: nothing to save, one line saying why, exit code 1, no traceback."""
    live = _start_live(tmp_path / "out")
    rc = live.stop()
    assert rc == 1, live.text()
    assert "no map yet" in live.text() and "Traceback" not in live.text()
    assert not (tmp_path / "out" / "map.yaml").exists()
