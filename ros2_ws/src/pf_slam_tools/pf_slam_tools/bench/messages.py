"""ParticleArray layout benchmark: struct-of-arrays vs an array of nested Particle messages.

Measures the cost of publish + receive (build the message from ndarrays, publish, deliver,
convert back to ndarrays) between two nodes under one SingleThreadedExecutor, for several
particle counts. This is the measurement that fixed ParticleArray's layout (README).
"""

from __future__ import annotations

import array
import time

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor

from pf_slam_interfaces.msg import Particle, ParticleArray, ParticleArrayNested
from pf_slam_nodes.ros import convert, qos
from pf_slam_nodes.ros.domain import ros_context


def _soa_msg(poses: np.ndarray, lw: np.ndarray) -> ParticleArray:
    return convert.particles_to_msg(
        poses, lw, stamp_ns=0, frame_id="map", scan_index=0, update=True, odom_pose=np.zeros(3)
    )


def _nested_msg(poses: np.ndarray, lw: np.ndarray) -> ParticleArrayNested:
    msg = ParticleArrayNested()
    msg.header.frame_id = "map"
    msg.particles = [
        Particle(x=float(p[0]), y=float(p[1]), theta=float(p[2]), log_weight=float(w)) for p, w in zip(poses, lw)
    ]
    return msg


def _nested_back(msg: ParticleArrayNested) -> tuple[np.ndarray, np.ndarray]:
    a = np.array([(p.x, p.y, p.theta, p.log_weight) for p in msg.particles]).reshape(-1, 4)
    return a[:, :3], a[:, 3]


def measure(n_particles: int, layout: str, repeats: int, context) -> float:
    """Mean seconds per message (build + publish + receive + convert back)."""
    msg_type, build, back = (
        (ParticleArray, _soa_msg, convert.msg_to_particles)
        if layout == "soa"
        else (ParticleArrayNested, _nested_msg, _nested_back)
    )
    pub_node = rclpy.create_node("bench_pub", context=context)
    sub_node = rclpy.create_node("bench_sub", context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(pub_node)
    ex.add_node(sub_node)
    received: list[int] = []
    sub_node.create_subscription(msg_type, "bench", lambda m: received.append(len(back(m)[1])), qos.pipeline())
    pub = pub_node.create_publisher(msg_type, "bench", qos.pipeline())
    deadline = time.monotonic() + 10
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.01)
    rng = np.random.default_rng(0)
    poses = rng.normal(size=(n_particles, 3))
    lw = np.full(n_particles, -np.log(n_particles))
    t0 = time.perf_counter()
    for k in range(repeats):
        pub.publish(build(poses, lw))
        while len(received) <= k:
            ex.spin_once(timeout_sec=1.0)
    dt = (time.perf_counter() - t0) / repeats
    assert all(r == n_particles for r in received)
    ex.shutdown()
    pub_node.destroy_node()
    sub_node.destroy_node()
    return dt


def run(counts=(100, 10_000), domain_id: int | None = None) -> list[dict]:
    """`domain_id`: None = an isolated domain (ros.domain.ros_context), unless ROS_DOMAIN_ID is set."""
    rows = []
    with ros_context(domain_id) as (ctx, _dom):
        for n in counts:
            for layout in ("soa", "nested"):
                repeats = max(5, min(500, 200_000 // n))
                rows.append({"particles": n, "layout": layout, "ms_per_msg": 1e3 * measure(n, layout, repeats, ctx)})
    return rows


def format_table(rows: list[dict]) -> str:
    lines = ["| particles | struct-of-arrays (ms/msg) | nested Particle[] (ms/msg) | ratio |", "|---:|---:|---:|---:|"]
    for n in sorted({r["particles"] for r in rows}):
        soa = next(r["ms_per_msg"] for r in rows if r["particles"] == n and r["layout"] == "soa")
        nes = next(r["ms_per_msg"] for r in rows if r["particles"] == n and r["layout"] == "nested")
        lines.append(f"| {n} | {soa:.3f} | {nes:.3f} | {nes / soa:.0f}x |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(format_table(run()))


def measure_fog(seconds: float = 10.0, batch: int = 10, domain_id: int | None = None) -> dict:
    """Publish + receive one simulated second-by-second FOG stream (1 kHz) through rclpy, in one
    executor: per-sample geometry_msgs/Vector3Stamped vs FogBatch of `batch` samples.

    Returns wall seconds per second of data for each layout (lower is better; > 0.1 means the
    FOG alone would stop a 10x-real-time replay).
    """
    from geometry_msgs.msg import Vector3Stamped

    from pf_slam_interfaces.msg import FogBatch

    n = int(seconds * 1000)
    stamps = (np.arange(n, dtype=np.int64) + 1) * 1_000_000
    dyaw = np.random.default_rng(0).normal(0, 1e-4, n)
    out = {}
    with ros_context(domain_id) as (ctx, _dom):
        for layout in ("vector3", "batch"):
            pub_node = rclpy.create_node("fog_pub", context=ctx)
            sub_node = rclpy.create_node("fog_sub", context=ctx)
            ex = SingleThreadedExecutor(context=ctx)
            ex.add_node(pub_node)
            ex.add_node(sub_node)
            got = [0]
            if layout == "vector3":

                def cb(m, got=got):
                    got[0] += 1

                sub_node.create_subscription(Vector3Stamped, "fog", cb, qos.pipeline(100000))
                pub = pub_node.create_publisher(Vector3Stamped, "fog", qos.pipeline(100000))
                msgs = []
                for t, d in zip(stamps, dyaw):
                    m = Vector3Stamped()
                    m.header.stamp = convert.ns_to_stamp(int(t))
                    m.vector.z = float(d)
                    msgs.append(m)
            else:

                def cb(m, got=got):
                    got[0] += len(m.stamps_ns)

                sub_node.create_subscription(FogBatch, "fog", cb, qos.pipeline(10000))
                pub = pub_node.create_publisher(FogBatch, "fog", qos.pipeline(10000))
                msgs = []
                for k in range(0, n, batch):
                    m = FogBatch()
                    m.header.stamp = convert.ns_to_stamp(int(stamps[k + batch - 1]))
                    m.stamps_ns = array.array("q", stamps[k : k + batch].tobytes())
                    m.delta_roll = array.array("d", bytes(8 * batch))
                    m.delta_pitch = array.array("d", bytes(8 * batch))
                    m.delta_yaw = array.array("d", dyaw[k : k + batch].tobytes())
                    msgs.append(m)
            while pub.get_subscription_count() == 0:
                ex.spin_once(timeout_sec=0.01)
            t0 = time.perf_counter()
            for i, m in enumerate(msgs):
                pub.publish(m)
                if i % 100 == 99:
                    while (
                        ex.spin_once(timeout_sec=0) is None
                        and got[0] < (i + 1) * (1 if layout == "vector3" else batch) - 2000
                    ):
                        pass
            while got[0] < n:
                ex.spin_once(timeout_sec=0.1)
            out[layout] = (time.perf_counter() - t0) / seconds
            ex.shutdown()
            pub_node.destroy_node()
            sub_node.destroy_node()
    return out
