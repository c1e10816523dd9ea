"""`pf-slam play BAG`: publish a rosbag2's topics on their own names, paced by the bag's record
times (1x or N times faster), with /clock (`--clock`), as `ros2 bag play --clock` does, for a
live graph started on its own (`pf-slam live`, the launch file, or any other ROS node).

It is not part of the pipeline: it waits on nobody (no pf_slam/ready, no pacing on /pose) and
publishes nothing of pf_slam's own topics (no end-of-bag status), so a live graph sees exactly
what a robot or `ros2 bag play` would give it. Messages go out as recorded (CDR bytes); the bag
reading, message classes, QoS of latched topics and the /clock bytes are bag_replay's.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from .io.bag import bag_info, read_bag
from .nodes.bag_replay import LATCHED_TOPICS, message_class, parse_rate
from .ros import cdr, qos, topics


def play(
    bag: str,
    rate: str = "1",
    clock: bool = False,
    delay_s: float = 0.0,
    clock_period_s: float = 0.025,
    topic_filter: list[str] | None = None,
    context=None,
    log: Callable[[str], None] = print,
    wait_for: list[str] | None = None,
    wait_timeout_s: float = 30.0,
) -> dict[str, int]:
    """Publish the bag (see the module); returns the messages published per topic.

    `rate`: '1' real time, 'N' N times faster, 'max' as fast as possible. `delay_s`: wait this long
    (wall time) after the publishers are created before the first message (discovery: DDS readers
    that match late miss what was published before). `clock_period_s`: with `clock`, /clock goes
    out at least this often in bag time (and with every message whose stamp moved past it).
    `context`: an rclpy Context already initialised (default: a new one on the environment's domain).
    `wait_for`: before the first message (and the delay), wait until each of these topics has a
    subscriber matched (discovery only: at most `wait_timeout_s`, then it plays anyway, saying so).
    """
    import rclpy
    from rosgraph_msgs.msg import Clock

    try:
        factor = parse_rate(rate)
    except ValueError:
        raise ValueError(f"--rate must be 'max' or a positive number, got {rate!r}") from None
    info = bag_info(bag)
    wanted = set(topic_filter) if topic_filter else set(info["topics"])
    unknown = (wanted | set(wait_for or ())) - set(info["topics"])
    if unknown:
        raise ValueError(f"{bag}: no topic {', '.join(sorted(unknown))} (it has {', '.join(sorted(info['topics']))})")
    own = context is None
    if own:
        context = rclpy.Context()
        rclpy.init(context=context)
    node = rclpy.create_node("pf_slam_player", context=context)
    published = {t: 0 for t in sorted(wanted)}
    try:
        pubs = {
            t: node.create_publisher(
                message_class(info["topics"][t][0]), t, qos.latched(10) if t in LATCHED_TOPICS else qos.pipeline(1000)
            )
            for t in published
        }
        pub_clock = node.create_publisher(Clock, topics.CLOCK, qos.outputs(10)) if clock else None
        deadline = time.monotonic() + wait_timeout_s
        for t in wait_for or ():
            while pubs[t].get_subscription_count() < 1 and time.monotonic() < deadline:
                time.sleep(0.02)
            if pubs[t].get_subscription_count() < 1:
                log(f"[pf-slam] warning: no subscriber on {t} after {wait_timeout_s:g} s: playing anyway")
        time.sleep(max(delay_s, 0.0))
        log(
            f"[pf-slam] playing {bag}: {sum(info['topics'][t][1] for t in published)} messages on "
            f"{len(published)} topics at rate {rate}{', with /clock' if clock else ''}"
        )
        period_ns = int(clock_period_s * 1e9)
        t0_wall, t0_bag, last_clock = time.monotonic(), info["start_ns"], None
        for topic, _msgtype, stamp_ns, raw in read_bag(bag, topics=published):
            if factor is not None:
                due = t0_wall + (stamp_ns - t0_bag) / 1e9 / factor
                while True:
                    now = time.monotonic()
                    if now >= due:
                        break
                    if pub_clock is not None and last_clock is not None:
                        # the clock keeps ticking between sparse messages, as a player's does
                        tick = t0_bag + int((now - t0_wall) * factor * 1e9)
                        if tick - last_clock >= period_ns:
                            pub_clock.publish(cdr.clock_bytes(tick))
                            last_clock = tick
                    time.sleep(min(due - now, clock_period_s / factor))
            if pub_clock is not None and (last_clock is None or stamp_ns > last_clock):
                pub_clock.publish(cdr.clock_bytes(stamp_ns))  # never behind the message it precedes
                last_clock = stamp_ns
            pubs[topic].publish(raw)
            published[topic] += 1
        time.sleep(0.5)  # let reliable writers hand over their last samples before the node goes
    finally:
        node.destroy_node()
        if own and context.ok():
            rclpy.shutdown(context=context)
    log(f"[pf-slam] played {sum(published.values())} messages: " + ", ".join(f"{t} {n}" for t, n in published.items()))
    return published


def play_cli(args) -> int:
    play(
        args.bag,
        rate=args.rate,
        clock=args.clock,
        delay_s=args.delay,
        topic_filter=args.topics or None,
        wait_for=args.wait_for,
    )
    return 0
