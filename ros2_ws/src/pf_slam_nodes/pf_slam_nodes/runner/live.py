"""`pf-slam live`: the SLAM graph on live topics (a robot, or `ros2 bag play --clock` / `pf-slam play`
elsewhere): predictor, correlator, mapper (+ texture) and no bag_replay.

No bag, so no end of the run: it spins until Ctrl-C / SIGTERM. The map and the trajectory are
obtained from the mapper's pf_slam/save_map service at any time, and with `--out DIR` they are
saved there when the graph is stopped. Parameters as `pf-slam run`: a profile (default indoor: there
is no bag to choose one from) < `--params FILE` < flags. The domain is the environment's (or
--domain): a live graph must meet the robot's nodes, so it is never isolated.

The lidar's mount is the first scan's frame looked up in /tf_static and /tf, as `pf-slam run`
does in a bag's /tf_static (mount parameters given by the user skip that): the nodes'
``mount_from_tf`` (nodes/mount_tf.py; the predictor decides, waiting `--mount-wait` seconds at
most for the transform, and the correlator and the mapper wait for its decision). `use_sim_time` follows /clock: each node switches
to the simulated clock at the first /clock message (`--sim-time auto`, the default).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..nodes.common import follow_clock
from ..ros.domain import RosDomain
from .common import DEFAULT_INPUTS, RunError
from .inputs import topic_remaps
from .mount import MOUNT_PARAMS
from .params import check_node_values, filter_overrides, load_params, node_params, params_topics

LIVE_NODES = ("predictor", "correlator", "mapper")
ODOMETRY_CHOICES = ("odom", "encoders", "tf")


class LiveDomain(RosDomain):
    """The environment's domain as it is (discovery range included): node processes of a live
    graph must reach the robot's nodes, also on other hosts."""

    def child_env(self, base: dict[str, str] | None = None) -> dict[str, str]:
        return dict(os.environ if base is None else base, ROS_DOMAIN_ID=str(self.id))


def live_domain(domain_id: int | None) -> LiveDomain:
    if domain_id is not None:
        return LiveDomain(domain_id, False, os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "SUBNET"), "--domain")
    env = os.environ.get("ROS_DOMAIN_ID", "")
    try:
        dom = int(env) if env.strip() else 0
    except ValueError:
        raise RunError(f"ROS_DOMAIN_ID={env!r} is not a number") from None
    return LiveDomain(
        dom,
        False,
        os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "SUBNET"),
        "ROS_DOMAIN_ID" if env.strip() else "the default (0)",
    )


@dataclass
class LivePlan:
    per_node: dict[str, dict[str, Any]]
    node_names: tuple[str, ...]
    remaps: dict[str, str]
    inputs: dict[str, str]
    profile_line: str
    user_mount: bool  # the user gave mount parameters: no lookup on /tf_static, /tf


def plan_live(
    params_file: str | None = None,
    profile: str | None = None,
    odometry: str | None = None,
    input_topics: dict[str, str | None] | None = None,
    texture: bool = False,
    overrides: dict[str, dict[str, Any]] | None = None,
) -> LivePlan:
    """Each node's parameters (checked), the topic remaps and the profile line; nothing started."""
    from ..profiles import PROFILES, profile_file

    file_layer = load_params(params_file) if params_file else {}
    topics_ = {**params_topics(file_layer), **{k: v for k, v in (input_topics or {}).items() if v}}
    inputs = {role: topics_.get(role, DEFAULT_INPUTS[role]) for role in DEFAULT_INPUTS}
    profile = profile or "auto"
    if profile == "auto":
        profile = "none" if params_file else "indoor"
    if profile not in ("none", *PROFILES):
        raise RunError(f"--profile {profile!r}: one of auto, none, {', '.join(PROFILES)}")
    prof_file = profile_file(profile) if profile != "none" else None
    prof_layer = load_params(prof_file) if prof_file else {}
    params_topics(prof_layer)
    line = (
        f"[pf-slam] profile: {profile}"
        + (f" ({prof_file})" if prof_file else "")
        + (
            f"; --params {params_file} on top"
            if params_file and prof_file
            else (f" (--params {params_file} is the whole tuning)" if params_file else "")
        )
    )
    cli: dict[str, dict[str, Any]] = {"predictor": {}}
    if odometry is not None:
        if odometry not in ODOMETRY_CHOICES:
            raise RunError(f"--odometry must be one of {', '.join(ODOMETRY_CHOICES)}, got {odometry!r}")
        cli["predictor"]["odometry_source"] = odometry
    layers = (
        ([prof_layer] if prof_layer else [])
        + ([file_layer] if file_layer else [])
        + [cli]
        + ([overrides] if overrides else [])
    )
    node_names = LIVE_NODES + (("texture",) if texture else ())
    per_node = {n: node_params(layers, n) for n in node_names}
    labels = (
        ([lambda sec: f"profile {profile} ({prof_file}), section {sec!r}"] if prof_layer else [])
        + ([lambda sec: f"{params_file}, section {sec!r}"] if file_layer else [])
        + [lambda sec: "the command line"]
        + ([lambda sec: "the command line"] if overrides else [])
    )
    check_node_values(per_node, list(zip(labels, layers)))
    user = [file_layer] + ([overrides] if overrides else [])
    user_mount = any(
        k in layer.get(sec, {}) for layer in user for sec in ("/**", "correlator", "mapper") for k in MOUNT_PARAMS
    )
    return LivePlan(per_node, node_names, topic_remaps(inputs), inputs, line, user_mount)


def _report_mount(node, log: Callable[[str], None]) -> None:
    """Print the predictor's lidar mount decision (pf_slam/lidar_mount) when it comes."""
    from ..nodes.mount_tf import receive_mount

    def show(decision: dict) -> None:
        log(f"[pf-slam] {decision['text']}")
        for w in decision.get("warnings", []):
            log(f"[pf-slam] warning: {w}")

    receive_mount(node, show)


def live(
    params_file: str | None = None,
    profile: str | None = None,
    out: str | None = None,
    processes: str = "single",
    texture: bool = False,
    domain_id: int | None = None,
    input_topics: dict[str, str | None] | None = None,
    odometry: str | None = None,
    sim_time: str = "auto",
    mount_wait_s: float = 5.0,
    overrides: dict[str, dict[str, Any]] | None = None,
    log: Callable[[str], None] = lambda s: print(s, file=sys.stderr, flush=True),
    stop: list[str] | None = None,
) -> int:
    """Run the live graph until a stop signal (or `stop` gets an entry); with `out`, save the map and
    the trajectory there at the end. Returns the exit code."""
    import rclpy

    from .supervise import _catch_stop_signals, _make_node, _spawn, _stop_children, make_executor

    if processes not in ("single", "multi"):
        raise RunError(f"--processes must be 'single' or 'multi', got {processes!r}")
    if sim_time not in ("auto", "true", "false"):
        raise RunError(f"--sim-time must be auto, true or false, got {sim_time!r}")
    plan = plan_live(params_file, profile, odometry, input_topics, texture, overrides)
    if sim_time != "auto":
        for p in plan.per_node.values():
            p["use_sim_time"] = sim_time == "true"
    dom = live_domain(domain_id)
    log(plan.profile_line)
    log(
        f"[pf-slam] live on ROS domain {dom.id} ({dom.chosen_by}); inputs: {plan.inputs['scan']}, "
        + {"odom": plan.inputs["odom"], "encoders": plan.inputs["encoders"], "tf": "/tf (odom -> base)"}[
            str(plan.per_node["predictor"].get("odometry_source", "odom"))
        ]
    )
    stop = [] if stop is None else stop
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=dom.id)
    ex = make_executor("events", ctx)
    nodes: list = []
    children: dict = {}
    saved = 0
    try:
        with _catch_stop_signals(stop):
            if not plan.user_mount:  # the predictor decides it at the first scan (nodes/mount_tf.py)
                for name in ("predictor", "correlator", "mapper"):
                    plan.per_node[name]["mount_from_tf"] = True
                plan.per_node["predictor"]["mount_wait_s"] = float(mount_wait_s)
            control = rclpy.create_node("pf_slam_live", context=ctx)
            nodes.append(control)
            ex.add_node(control)
            _report_mount(control, log)
            if processes == "single":
                for name in plan.node_names:
                    node = _make_node(name, ctx, plan.per_node[name], plan.remaps)
                    if sim_time == "auto":
                        follow_clock(node, log=lambda s: log(f"[pf-slam] {s}"))
                    nodes.append(node)
                    ex.add_node(node)
            else:
                logs = Path(out) if out else Path(os.environ.get("TMPDIR", "/tmp")) / f"pf_slam_live_{os.getpid()}"
                children = _spawn(plan.per_node, dom, logs, plan.remaps, follow_clock=sim_time == "auto")
                log(f"[pf-slam] node logs in {logs / 'logs'}")
            log(
                f"[pf-slam] live: {', '.join(plan.node_names)} running; save the map with the service "
                f"pf_slam/save_map (pf_slam_interfaces/srv/SaveMap){'; on Ctrl-C it goes to ' + out if out else ''}"
            )
            from rclpy.task import Future

            done = Future()

            def check() -> None:  # on a timer: no Python per message in the spin loop
                if stop and not done.done():
                    done.set_result(None)
                for name, c in children.items():
                    if c.poll() is not None and not done.done():
                        done.set_result(f"node {name} exited with code {c.returncode}; log: {logs / 'logs' / name}.log")

            control.create_timer(0.1, check)
            while not done.done():
                ex.spin_until_future_complete(done, timeout_sec=1.0)
            if done.result() is not None:
                raise RunError(done.result())
            if out:  # still under the signal handlers: a second Ctrl-C does not cut the save short
                saved = save_map_via_service(ctx, ex, str(Path(out).resolve()), log)
    finally:
        _stop_children(children)
        ex.shutdown()
        for node in nodes:
            node.destroy_node()
        if ctx.ok():
            rclpy.shutdown(context=ctx)
    return 0 if saved == 0 else 1


def save_map_via_service(ctx, executor, out: str, log: Callable[[str], None], timeout_s: float = 10.0) -> int:
    """Ask the mapper (this process or another) to save into `out`; 0 on success."""
    import rclpy

    from pf_slam_interfaces.srv import SaveMap

    from ..ros import topics

    node = rclpy.create_node("pf_slam_live_saver", context=ctx)
    executor.add_node(node)
    try:
        client = node.create_client(SaveMap, topics.SAVE_MAP)
        if not client.wait_for_service(timeout_sec=timeout_s):
            log(f"[pf-slam] error: no {topics.SAVE_MAP} service: nothing saved in {out}")
            return 1
        fut = client.call_async(SaveMap.Request(directory=str(out)))
        executor.spin_until_future_complete(fut, timeout_sec=timeout_s)
        res = fut.result()
        if res is None:
            log(f"[pf-slam] error: {topics.SAVE_MAP} did not answer within {timeout_s:g} s")
            return 1
        log(f"[pf-slam] {res.message}" if res.success else f"[pf-slam] error: {res.message}")
        return 0 if res.success else 1
    finally:
        executor.remove_node(node)
        node.destroy_node()


def live_cli(args) -> int:
    overrides = filter_overrides(args)
    if getattr(args, "sensor_qos", None):
        overrides["predictor"] = {"sensor_qos": args.sensor_qos}
    return live(
        args.params,
        args.profile,
        args.out,
        args.processes,
        args.texture,
        args.domain,
        {role: getattr(args, f"{role}_topic", None) for role in DEFAULT_INPUTS},
        args.odometry,
        args.sim_time,
        args.mount_wait,
        overrides or None,
    )
