"""bag_replay: publishes a rosbag2 (mcap or sqlite3) into the graph, with /clock from the bag.

Messages are published as recorded (serialized CDR, never deserialized here), in record-time
order. Rates: `rate:=max` paces on the pipeline: at most `max_in_flight` scans are published
and not yet posed (counted on pose, one per scan), so nothing is dropped and the run is
reproducible; each time it stops there it says so on pf_slam/replay_stall (ReplayStatus with
done=false and the counts so far: a predictor that has all of them and still lacks a scan's
odometry knows that it will not come before it poses that scan); with `image_topic` set (the
texture node's left stereo topic, `pf-slam run` sets it when the texture node runs), `rate:=max`
also paces on the texture node: the next image of that topic waits while `max_pairs_in_flight`
pairs are published and neither finished nor waiting for their pose (pf_slam/texture_progress),
so no stereo pair is skipped and every run textures the same pairs; `rate:=1` is real time, `rate:=N` N times real time. At the end of the bag the
number of messages published per topic goes out on pf_slam/replay_status (latched).

A bag damaged mid-file ends the replay where the damage is: what was read before it has been
published, the damage (message index, record time, cause) goes out on pf_slam/status (latched
JSON ``{"node": "bag_replay", "error": ...}``) and then replay_status, with the counts published,
as at the end of a bag, so the graph finishes the scans it has.
"""

from __future__ import annotations

import importlib
import time
from typing import Any

from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.publisher import Publisher
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String, UInt32MultiArray

from pf_slam_interfaces.msg import ReplayStatus

from ..io.bag import BagReadError, bag_info, read_bag
from ..ros import cdr, qos, topics
from .common import param, run_node

LATCHED_TOPICS = ("/tf_static",)


def message_class(msgtype: str) -> Any:
    """'sensor_msgs/msg/LaserScan' -> the rclpy message class; ValueError if not installed."""
    pkg, _, name = msgtype.rpartition("/msg/")
    try:
        return getattr(importlib.import_module(f"{pkg}.msg"), name)
    except (ImportError, AttributeError):
        raise ValueError(f"message type {msgtype!r} is not available in this ROS install") from None


def parse_rate(rate: str) -> float | None:
    """'max' -> None; '1', '2.5' -> that factor (> 0)."""
    if rate == "max":
        return None
    try:
        r = float(rate)
    except ValueError:
        r = -1.0
    if not r > 0:
        raise ValueError(f"parameter 'rate' must be 'max' or a positive number, got {rate!r}")
    return r


def parse_restamp(text: str) -> dict[str, object]:
    """'/scan=record,/odom=3000000000' -> {'/scan': 'record', '/odom': 3000000000}: the topics
    whose header stamps are replaced by the record time, or shifted by that many ns (pf-slam run
    sets it from the bag's stamps: graph.inspect_stamps)."""
    out: dict[str, object] = {}
    for item in filter(None, (p.strip() for p in text.split(","))):
        topic, _, v = item.partition("=")
        try:
            out[topic] = "record" if v == "record" else int(v)
        except ValueError:
            raise ValueError(f"parameter 'restamp': {item!r} is not TOPIC=record or TOPIC=NANOSECONDS") from None
    return out


class BagReplay(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("bag_replay", **kwargs)
        self.bag = param(self, "bag", "")
        if not self.bag:
            raise ValueError("parameter 'bag' (path of a rosbag2) is required")
        self.rate = parse_rate(str(param(self, "rate", "max")))
        self.max_in_flight = param(self, "max_in_flight", 100)
        self.scan_topic = param(self, "scan_topic", "/scan")
        self.image_topic = param(self, "image_topic", "")
        self.max_pairs_in_flight = param(self, "max_pairs_in_flight", 1)
        if self.max_pairs_in_flight < 1:
            raise ValueError(f"parameter 'max_pairs_in_flight' must be >= 1, got {self.max_pairs_in_flight}")
        self.images_published = 0
        self.texture_progress = (0, 0)  # [pairs finished, pairs waiting for a pose] (texture node)
        self.texture_waits = 0  # times the replay stopped for the texture node
        # wall seconds the replay stood still in rate max: for the SLAM nodes, for the texture node
        self.waited_s = {"pipeline": 0.0, "texture": 0.0}
        self._stalled: tuple[str, float] | None = None
        self.clock_period_ns = int(param(self, "clock_period_s", 0.01) * 1e9)
        self.start_delay_s = float(param(self, "start_delay_s", 0.0))
        self.ready_at: float | None = None  # when graph_ready() first held (monotonic)
        self.restamp = parse_restamp(param(self, "restamp", ""))
        self.restamp_failed = 0
        self.ready_nodes: set[str] = set()
        # the nodes whose pf_slam/ready announcement the replay waits for
        self.wait_for = set(param(self, "wait_for", ["predictor", "correlator", "mapper"]))
        info = bag_info(self.bag)
        self.info = info
        self.scans_in_bag = info["topics"].get(self.scan_topic, ("", 0))[1]
        self.publishers_: dict[str, Publisher] = {}
        for topic, (msgtype, _) in info["topics"].items():
            profile = qos.latched() if topic in LATCHED_TOPICS else qos.pipeline(10000)
            self.publishers_[topic] = self.create_publisher(message_class(msgtype), topic, profile)
        self.pub_clock = self.create_publisher(Clock, topics.CLOCK, qos.outputs(10))
        self.pub_status = self.create_publisher(ReplayStatus, topics.REPLAY_STATUS, qos.latched())
        self.pub_stall = self.create_publisher(ReplayStatus, topics.REPLAY_STALL, qos.pipeline())
        self.stall_sent_at = -1  # scans_published when the last stall went out
        self.pub_node_status = self.create_publisher(String, topics.STATUS, qos.latched())
        self.error: str | None = None  # the damage that ended the replay early
        self.create_subscription(PoseStamped, topics.POSE, self._on_progress, qos.pipeline(), raw=True)
        self.create_subscription(String, topics.READY, self._on_ready, qos.latched(depth=10))
        if self.image_topic:
            self.create_subscription(
                UInt32MultiArray, topics.TEXTURE_PROGRESS, self._on_texture_progress, qos.latched()
            )
        self.messages = read_bag(self.bag)
        self.pending: tuple[str, str, int, bytes] | None = None
        self.published: dict[str, int] = {t: 0 for t in info["topics"]}
        self.scans_published = 0
        self.scans_processed = 0
        self.done = False
        self.last_clock_ns = -1
        self.t0_wall: float | None = None
        self.t0_bag = info["start_ns"]
        self.started = False
        self.timer = self.create_timer(0.001, self.pump)

    def _on_progress(self, _raw: bytes) -> None:
        self.scans_processed += 1
        if self.timer.is_canceled() and not self.done:
            self.timer.reset()

    def _on_texture_progress(self, msg: UInt32MultiArray) -> None:
        if len(msg.data) >= 2:
            self.texture_progress = (int(msg.data[0]), int(msg.data[1]))
        if self.timer.is_canceled() and not self.done:
            self.timer.reset()

    def _texture_busy(self) -> bool:
        """True while `max_pairs_in_flight` published pairs are neither finished by the texture
        node nor waiting there for their pose (those need later scans: never held back)."""
        done, waiting = self.texture_progress
        return self.images_published - done - waiting >= self.max_pairs_in_flight

    def _on_ready(self, msg: String) -> None:
        self.ready_nodes.add(msg.data)

    def graph_ready(self) -> bool:
        """True once nothing published can be lost: every stage announced that its outputs are
        matched (pf_slam/ready), and the scan topic has its subscriber, the predictor, matched here
        (the correlator and the mapper get the scans they correct from the predictor)."""
        scan_pub = self.publishers_.get(self.scan_topic)
        return self.ready_nodes >= self.wait_for and (scan_pub is None or scan_pub.get_subscription_count() >= 1)

    def pump(self, budget: int = 200) -> None:
        """Publish what may be published now (at most `budget` messages)."""
        if self.done:
            self.timer.cancel()
            return
        if not self.started:
            if not self.graph_ready():
                return
            if self.ready_at is None:
                self.ready_at = time.monotonic()
            if time.monotonic() - self.ready_at < self.start_delay_s:
                return
            self.started = True
            self.t0_wall = time.monotonic()
        if self._stalled is not None:
            kind, since = self._stalled
            self.waited_s[kind] += time.monotonic() - since
            self._stalled = None
        for _ in range(budget):
            if self.pending is None:
                try:
                    self.pending = next(self.messages, None)
                except BagReadError as e:  # damaged mid-file: publish the end of what was read
                    self._damaged(e)
                    self.pending = None
                if self.pending is None:
                    self._finish()
                    return
            topic, _msgtype, stamp_ns, raw = self.pending
            if (
                topic == self.scan_topic
                and self.rate is None
                and self.scans_published - self.scans_processed >= self.max_in_flight
            ):
                self.timer.cancel()  # resumed by _on_progress
                self._stalled = ("pipeline", time.monotonic())
                if self.stall_sent_at != self.scans_published:
                    self.stall_sent_at = self.scans_published
                    stall = self._counts(done=False)  # + the poses it had: stopped until the next one
                    stall.topics.append(topics.POSE)
                    stall.counts.append(self.scans_processed)
                    self.pub_stall.publish(stall)
                return
            if topic == self.image_topic and self.rate is None and self._texture_busy():
                self.timer.cancel()  # resumed by _on_texture_progress
                self._stalled = ("texture", time.monotonic())
                self.texture_waits += 1
                return
            if self.rate is not None:
                due = self.t0_wall + (stamp_ns - self.t0_bag) / 1e9 / self.rate
                if time.monotonic() < due:
                    return
            fix = self.restamp.get(topic)
            if fix is not None:
                raw = self._restamped(raw, stamp_ns, fix)
            self.publishers_[topic].publish(raw)
            self.published[topic] += 1
            if topic == self.scan_topic:
                self.scans_published += 1
            elif topic == self.image_topic:
                self.images_published += 1
            if stamp_ns - self.last_clock_ns >= self.clock_period_ns or topic == self.scan_topic:
                self.pub_clock.publish(cdr.clock_bytes(stamp_ns))  # bytes: no message object per publish
                self.last_clock_ns = stamp_ns
            self.pending = None

    def _damaged(self, e: BagReadError) -> None:
        import json

        self.error = e.damage
        self.messages = iter(())
        self.get_logger().error(f"{e.damage}; the replay ends here ({self.scans_published} scans published)")
        self.pub_node_status.publish(
            String(
                data=json.dumps(
                    {
                        "node": "bag_replay",
                        "error": e.damage,
                        "messages_read": e.messages,
                        "last_stamp_ns": e.last_stamp_ns,
                    }
                )
            )
        )

    def _finish(self) -> None:
        self.done = True
        self.timer.cancel()
        self.pub_status.publish(self._counts(done=True))
        self.get_logger().info(
            f"end of bag: {sum(self.published.values())} messages, {self.scans_published} scans published; "
            f"stood {self.waited_s['pipeline']:.1f} s for the SLAM nodes, {self.waited_s['texture']:.1f} s for the "
            "texture node"
        )

    def _restamped(self, raw: bytes, record_ns: int, fix) -> bytes:
        """The header stamp replaced by the record time ("record") or shifted by `fix` ns."""
        try:
            return cdr.with_header_stamp(raw, record_ns if fix == "record" else cdr.header_stamp(raw) + fix)
        except ValueError:  # unreadable: published as recorded (the predictor counts it)
            self.restamp_failed += 1
            return raw

    def _counts(self, done: bool) -> ReplayStatus:
        topics_ = sorted(self.published)
        return ReplayStatus(done=done, topics=topics_, counts=[self.published[t] for t in topics_])


def main(args: list[str] | None = None) -> int:
    return run_node(BagReplay, args, clock_follower=False)  # it publishes /clock


if __name__ == "__main__":
    import sys

    sys.exit(main())
