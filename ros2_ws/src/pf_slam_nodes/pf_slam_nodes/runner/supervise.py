"""Process supervision of `pf-slam run`: the executor, the nodes in this process or one process
per node, stop signals, the children's exits, stale shared memory."""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from ..io.bag import stamp_ns_of
from ..profiles import CONFIG_DIR
from ..ros.domain import RosDomain, init_context
from .common import RunError, RunPlan
from .inputs import topic_remaps
from .outputs import _OutDir, _stage_split
from .params import unflatten
from .recorder import ResultRecorder, _drain_result, _Recorder

#: the signals that stop a run early (partial outputs written) -> the exit code of `pf-slam run`
STOP_SIGNALS = {"SIGINT": 130, "SIGTERM": 143}


def make_executor(kind: str, context):
    """'events': rclpy's C++ EventsExecutor (rclpy.experimental, much less Python per callback);
    'single': the classic SingleThreadedExecutor. The graph's result does not depend on it."""
    from rclpy.executors import SingleThreadedExecutor

    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor(context=context)
    if kind == "single":
        return SingleThreadedExecutor(context=context)
    raise RunError(f"executor must be 'events' or 'single', got {kind!r}")


def _make_node(name: str, context, overrides: dict[str, Any], remaps: dict[str, str] | None = None):
    from rclpy.parameter import Parameter

    from ..nodes.bag_replay import BagReplay
    from ..nodes.correlator import Correlator
    from ..nodes.mapper import Mapper
    from ..nodes.predictor import Predictor

    if name == "texture":
        from ..nodes.texture import TextureNode as cls
    else:
        cls = {"bag_replay": BagReplay, "predictor": Predictor, "correlator": Correlator, "mapper": Mapper}[name]
    params = [Parameter(k, value=v) for k, v in overrides.items()]
    try:
        return cls(context=context, parameter_overrides=params, cli_args=_remap_args(remaps))
    except ValueError as e:  # a parameter it refused: say which node
        raise RunError(str(e) if str(e).startswith("node ") else f"node {name}: {e}") from None


def _remap_args(remaps: dict[str, str] | None) -> list[str] | None:
    """{'scan': '/front/scan'} -> ['--ros-args', '-r', 'scan:=/front/scan'] (None: no remaps)."""
    if not remaps:
        return None
    return ["--ros-args"] + [a for k, v in sorted(remaps.items()) for a in ("-r", f"{k}:={v}")]


@contextlib.contextmanager
def _catch_stop_signals(stop: list[str]):
    """While the graph spins: SIGINT / SIGTERM append their name to `stop` (the run's check
    timer then ends it and the outputs so far are written) instead of killing the process.
    Only the main thread can set handlers; elsewhere the defaults stay."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {
        sig: signal.signal(getattr(signal, sig), lambda num, _frame: stop.append(signal.Signals(num).name))
        for sig in STOP_SIGNALS
    }
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(getattr(signal, sig), handler)


def _last_line(path: Path) -> str:
    """The last non-empty line of a node's log (its error), or a note that there is none."""
    try:
        lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        lines = []
    return lines[-1] if lines else "(its log is empty)"


def _exit_text(code: int) -> str:
    return f"died ({signal.Signals(-code).name})" if code < 0 else f"exited with code {code}"


def _stop_children(children: dict[str, subprocess.Popen]) -> None:
    """SIGINT to the node processes still running, SIGKILL to any that ignore it for 10 s; then
    remove the shared-memory segments that a killed one left (it could not clean up)."""
    for c in children.values():
        if c.poll() is None:
            c.send_signal(signal.SIGINT)
    for c in children.values():
        try:
            c.wait(timeout=10)
        except subprocess.TimeoutExpired:
            c.kill()
            c.wait()
    if any(c.returncode < 0 and c.returncode != -signal.SIGINT for c in children.values()):
        remove_stale_shm()


def remove_stale_shm(shm: Path = Path("/dev/shm"), min_age_s: float = 2.0) -> list[str]:
    """Remove the shared-memory segments of Fast DDS participants that are gone (a killed node
    cannot remove its own), as `fastdds shm clean` does: a live participant holds an exclusive
    flock on its segment's ``fastrtps_<id>_el`` file, so a lockable one (older than `min_age_s`:
    not one being created right now) is stale. The ``fastrtps_port*`` segments are shared by all
    participants and persist by design: left alone. Returns the names removed."""
    removed = []
    for lock in shm.glob("fastrtps_*_el"):
        if not re.fullmatch(r"fastrtps_[0-9a-f]{16}_el", lock.name):
            continue
        try:
            if time.time() - lock.stat().st_mtime < min_age_s:
                continue
            fd = os.open(lock, os.O_RDONLY)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            continue  # held: its participant is alive
        finally:
            os.close(fd)
        seg = lock.name[:-3]
        for f in (shm / seg, lock):
            with contextlib.suppress(FileNotFoundError):
                f.unlink()
                removed.append(f.name)
    return removed


FASTDDS_PROFILE = CONFIG_DIR / "fastdds_large_data.xml"


def fastdds_env(env: dict[str, str]) -> dict[str, str]:
    """`env` with Fast DDS's profile file set to config/fastdds_large_data.xml (a 4 MiB shared-memory
    segment: camera images between node processes; the default 512 KiB segment sent them as UDP
    fragments, 1.2x instead of 5.8x real time for the car with stereo), unless one is set already."""
    if not any(env.get(k) for k in ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")):
        if FASTDDS_PROFILE.is_file():
            env = dict(env, FASTRTPS_DEFAULT_PROFILES_FILE=str(FASTDDS_PROFILE))
    return env


def _spawn(
    per_node: dict[str, dict[str, Any]],
    dom: RosDomain,
    out: Path,
    remaps: dict[str, str] | None = None,
    follow_clock: bool = False,
) -> dict[str, subprocess.Popen]:
    """Start one process per node, each with its own parameter file, in their own session: a
    Ctrl-C in the terminal reaches only this process, which stops them in order. They also
    die with it (PF_SLAM_PARENT_PID, see nodes.common.run_node), so none is left orphaned.
    They run on the run's domain `dom` (RosDomain.child_env) and inherit its lock, so an
    isolated domain stays held until the last of them is gone. Their use_sim_time is false unless
    `follow_clock` (`pf-slam live`: each switches to /clock when one is published)."""
    logs = out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    env = fastdds_env(dom.child_env())
    env["PF_SLAM_PARENT_PID"] = str(os.getpid())
    keep = () if dom.lock_fd is None else (dom.lock_fd,)
    procs = {}
    for name in per_node:  # parameter files next to the logs: what each process ran with
        pfile = logs / f"{name}.params.yaml"
        ros_params = ({} if follow_clock else {"use_sim_time": False}) | unflatten(per_node[name])
        pfile.write_text(yaml.safe_dump({name: {"ros__parameters": ros_params}}))
        with open(logs / f"{name}.log", "w") as log:
            procs[name] = subprocess.Popen(
                [sys.executable, "-m", f"pf_slam_nodes.nodes.{name}", "--ros-args", "--params-file", str(pfile)]
                + (_remap_args(remaps) or [])[1:],
                env=env,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                pass_fds=keep,
            )
    return procs


@dataclass
class GraphOutcome:
    """What spinning the graph leaves for the outputs."""

    rec: _Recorder
    result: ResultRecorder | None
    texture_out: Any  # the texture rendered in the final /map geometry (one process), or None
    stage_split: dict[str, float] | None
    wall: float
    stopped_by: str | None


def spin_graph(
    plan: RunPlan, dom: RosDomain, out: Path, out_dir_: _OutDir, domain_scope: contextlib.ExitStack
) -> GraphOutcome:
    """Build the graph (its nodes in this process, or one process per node) with the recorders,
    spin it until it is done, stopped (a signal, a node gone, no progress) or fails, and take it
    down. A graph that failed before it started removes what the run created in --out
    (RunError); the domain's lock is released here."""
    import rclpy

    executor, processes, node_names, per_node = plan.executor, plan.processes, plan.node_names, plan.per_node
    scans_total, bag_duration_s, inputs, texture = plan.scans_total, plan.bag_duration_s, plan.inputs, plan.texture
    snapshot_every, progress, record, record_map_every_s = (
        plan.snapshot_every,
        plan.progress,
        plan.record,
        plan.record_map_every_s,
    )
    idle_timeout_s, drain_timeout_s, texture_timeout_s = (
        plan.idle_timeout_s,
        plan.drain_timeout_s,
        plan.texture_timeout_s,
    )
    remaps = topic_remaps(inputs)
    ctx = None
    children: dict[str, subprocess.Popen] = {}
    stop_signal: list[str] = []  # set by SIGINT / SIGTERM while the graph runs
    result: ResultRecorder | None = None
    nodes = []  # every node of this process, destroyed at the end: a node left alive keeps its
    ex = None  # DDS readers matched by later runs on the same domain (ghost subscribers)
    t_start = time.monotonic()
    started = [False]  # the graph is up (its nodes built): from then on a failure keeps outputs
    early: list[str] = []  # why the graph failed to start (--out is then removed)
    try:
        ctx, rec_node = init_context(dom, "pf_slam_recorder")
        nodes.append(rec_node)
        ex = make_executor(executor, ctx)
        ex.add_node(rec_node)
        loops = bool(per_node.get("mapper", {}).get("loops.enabled", False))
        rec = _Recorder(rec_node, out, scans_total, bag_duration_s, snapshot_every, progress, texture, loops)
        if record:
            result = ResultRecorder(
                rec_node,
                out / "result.mcap",
                inputs["scan"],
                record_map_every_s if record_map_every_s is not None else bag_duration_s / 20,
                texture,
                pose_feed=rec,
            )
        texture_node = None
        if processes == "single":
            for name in node_names:
                node = _make_node(name, ctx, per_node[name], remaps)
                nodes.append(node)
                ex.add_node(node)
                if name == "texture":
                    texture_node = node
            started[0] = True
        else:
            children = _spawn(per_node, dom, out, remaps)
        state = {"last_progress": time.monotonic(), "last_count": -1}
        slam_done: dict[str, float] = {}  # "t": when the SLAM finished (before the texture's tail)

        def finished() -> bool:
            m = rec.map_msg
            expected = scans_total
            if rec.bag_error() is not None and rec.replay_counts is not None:
                # damaged mid-bag: the replay ended there; finish the scans it published
                expected = rec.replay_counts.get(inputs["scan"], 0)
                if expected == 0:
                    return True
            if len(rec.poses) >= expected:  # and the predictor's final fault counts are here
                return (
                    m is not None
                    and stamp_ns_of(m) == rec.stamps[-1]
                    and rec.node_status.get("predictor", {}).get("final", False)
                    and (not loops or rec.final_trajectory() is not None)
                )
            # paced replays (--rate N) may lose scans under load: once the bag is out and the
            # pipeline has been idle for drain_timeout_s, finish and report them as dropped
            return (
                rec.replay_counts is not None
                and m is not None
                and time.monotonic() - state["last_progress"] > drain_timeout_s
            )

        def check() -> None:
            """Every 50 ms: done? stopped by a signal? a child process gone? stuck? -> resolve
            `outcome` with None (complete) or why the run stopped early (the executor then
            returns; checking on a timer keeps Python out of the per-message path)."""
            if outcome.done():
                return
            if stop_signal:
                outcome.set_result(stop_signal[0])
                return
            if len(rec.poses) != state["last_count"]:
                state["last_count"], state["last_progress"] = len(rec.poses), time.monotonic()
            if rec.poses:
                started[0] = True
            for name, c in children.items():
                if c.poll() is not None:
                    if not started[0]:  # e.g. a parameter it refused: nothing was processed
                        early.append(
                            f"node {name} {_exit_text(c.returncode)} before the first scan: "
                            f"{_last_line(out / 'logs' / f'{name}.log')}"
                        )
                    outcome.set_result(f"node {name} {_exit_text(c.returncode)}; log: {out / 'logs' / name}.log")
                    return
            if time.monotonic() - state["last_progress"] > idle_timeout_s:
                outcome.set_result(
                    f"no progress for {idle_timeout_s:.0f} s: {len(rec.poses)}/{scans_total} scans processed"
                )
            elif finished():
                slam_done.setdefault("t", time.monotonic())
                # the texture node finishes on its own after the last pair (it may skip pairs
                # under load, never holds the SLAM nodes back); wait for its final texture
                if (
                    not texture
                    or (rec.texture_status or {}).get("final")
                    or time.monotonic() - slam_done["t"] > texture_timeout_s
                ):
                    outcome.set_result(None)

        from rclpy.task import Future

        outcome = Future()
        rec_node.create_timer(0.05, check)
        with _catch_stop_signals(stop_signal):
            while not outcome.done():
                ex.spin_until_future_complete(outcome, timeout_sec=1.0)
        stopped_by = outcome.result()
        if stopped_by is None and rec.bag_error() is not None:
            stopped_by = f"BAG: {rec.bag_error()}"
        wall = (slam_done["t"] if slam_done else time.monotonic()) - t_start
        rec.print_progress(final=True)
        if result is not None:
            _drain_result(ex, result, len(rec.poses))
            result.finish(rec.map_msg)
        texture_out = None
        if stopped_by is None and texture_node is not None and texture_node.wait_idle(30.0):
            texture_out = texture_node.render()  # in the final /map geometry
        stage_split = _stage_split(nodes, wall, len(rec.poses)) if processes == "single" else None
    except BaseException:
        if not started[0]:
            early.append("")
        raise
    finally:
        _stop_children(children)
        if ex is not None:
            ex.shutdown()
        if result is not None:
            result.close()  # a failed run's partial recording stays readable
        for node in nodes:
            node.destroy_node()
        if ctx is not None and ctx.ok():
            rclpy.shutdown(context=ctx)
        domain_scope.close()  # the domain's lock (node processes hold it until they are gone)
        if early:  # failed before the graph started: leave no half-written --out
            out_dir_.remove_new()
    if early:
        raise RunError(early[0])
    return GraphOutcome(rec, result, texture_out, stage_split, wall, stopped_by)
