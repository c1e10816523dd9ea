"""Builds and runs the node graph on a bag: `pf-slam run`.

One process with one executor (`single`), or one process per node over DDS (`multi`); the
nodes are the same classes either way. A recorder node in this process collects the pose of
every scan (pose), the corrections (particles/updated) and the final /map, and writes the
outputs.

run() is a sequence of steps; the parts live in runner/ by concern: parameters
(runner/params.py), bag inspection (runner/inputs.py, runner/mount.py), the recorder nodes
(runner/recorder.py), process supervision and the spin (runner/supervise.py), outputs and
summary.json (runner/outputs.py). Their names stay importable from here. The bag inspection
is called through this module's names (tests replace `graph.inspect_stamps`).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .io.bag import bag_info
from .ros.domain import RosDomain, run_domain

# the parts, under their old names (graph.X)
from .runner.common import (  # noqa: F401
    DEFAULT_INPUTS,
    INPUT_TYPES,
    NODE_NAMES,
    TEXTURE_INPUT,
    RunError,
    RunPlan,
    snapshot_cadence,
)
from .runner.inputs import (  # noqa: F401
    ROLE_WORDS,
    STAMP_JUMP_NS,
    STAMP_OFFSET_NS,
    _canonical_view,
    _check_stamps_and_pairing,
    _no_input,
    detect_inputs,
    input_report,
    inspect_stamps,
    restamp_param,
    select_inputs,
    tf_inputs,
    topic_remaps,
)
from .runner.memory import keep_freed_memory
from .runner.mount import (  # noqa: F401
    MOUNT_PARAMS,
    LidarMount,
    _compose_up,
    _mount_report,
    _odom_child,
    _tf_static_tree,
    _up_chain,
    lidar_mount,
)
from .runner.outputs import (  # noqa: F401
    RunResult,
    _OutDir,
    _stage_split,
    _write_outputs,
    _write_texture,
    build_summary,
    gyro_line,
    odom_scale_line,
)
from .runner.params import (  # noqa: F401
    CLI_FLAGS,
    _default_particles,
    check_names,
    check_node_values,
    filter_overrides,
    flatten,
    load_params,
    node_params,
    params_topics,
    unflatten,
)
from .runner.recorder import ResultRecorder, _drain_result, _message_class, _Recorder  # noqa: F401
from .runner.sample import BagSample, sample_bag  # noqa: F401
from .runner.supervise import (  # noqa: F401
    STOP_SIGNALS,
    GraphOutcome,
    _catch_stop_signals,
    _exit_text,
    _last_line,
    _make_node,
    _remap_args,
    _spawn,
    _stop_children,
    make_executor,
    remove_stale_shm,
    spin_graph,
)

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"


def run(
    bag: str,
    out_dir: str | os.PathLike,
    params_file: str | None = None,
    rate: str = "max",
    processes: str = "single",
    overrides: dict[str, dict[str, Any]] | None = None,
    snapshot_every: int | str = "30s",
    progress: bool = True,
    idle_timeout_s: float = 60.0,
    drain_timeout_s: float = 5.0,
    domain_id: int | None = None,
    executor: str = "events",
    texture: bool = True,
    texture_timeout_s: float = 120.0,
    record: bool = True,
    record_map_every_s: float | None = None,
    input_topics: dict[str, str] | None = None,
    profile: str | None = None,
) -> RunResult:
    """Replay `bag` through the graph and write the outputs into `out_dir`; returns the summary.

    `snapshot_every`: a snapshot PNG every N scans (int) or every N seconds of bag time ("30s");
    0: none. `record`: also write result.mcap (ResultRecorder), with a map every `record_map_every_s`
    of bag time (default: bag duration / 20). `input_topics`: the bag's topic per input
    ({'scan': '/front/scan', 'odom': ...}; also `topics.*` in the parameter file), see
    select_inputs(). `domain_id`: run on that ROS domain with the normal discovery (as does a set
    ROS_DOMAIN_ID), so viewers can watch; default: isolated (ros/domain.py: a free domain held
    by the run, discovery OFF in one process, LOCALHOST for one process per node).
    `profile`: the parameter profile (profiles.py): None / "auto" chooses it from the bag (its
    converter metadata, else its sensors) when no `params_file` is given ("none" with one: the
    file is the whole tuning, as before), "none" uses the built-in defaults, a name forces that
    one (also under a `params_file`). Layers: defaults < profile < implied by the bag <
    params_file < overrides."""
    if processes not in ("single", "multi"):
        raise RunError(f"--processes must be 'single' or 'multi', got {processes!r}")
    try:
        snapshot_cadence(snapshot_every)
    except ValueError as e:
        raise RunError(str(e)) from None
    keep_freed_memory()  # the graph's nodes run in this process (single) or each in its own (run_node)
    plan = _plan(
        bag,
        params_file,
        rate,
        processes,
        overrides,
        texture,
        record,
        input_topics,
        profile,
        dict(
            executor=executor,
            record_map_every_s=record_map_every_s,
            snapshot_every=snapshot_every,
            progress=progress,
            idle_timeout_s=idle_timeout_s,
            drain_timeout_s=drain_timeout_s,
            texture_timeout_s=texture_timeout_s,
        ),
    )
    domain_scope, dom, out, out_dir_ = _open_domain_and_out(plan, out_dir, domain_id)
    _report(plan, dom)
    done = spin_graph(plan, dom, out, out_dir_, domain_scope)
    return _write_results(plan, dom, out, done)


def _plan(
    bag: str,
    params_file: str | None,
    rate: str,
    processes: str,
    overrides: dict | None,
    texture: bool,
    record: bool,
    input_topics: dict[str, str] | None,
    profile: str | None,
    how: dict[str, Any],
) -> RunPlan:
    """Everything decided before anything starts: the inputs, the bag's inspection, the profile,
    each node's parameters (checked); `how`: RunPlan's fields on how the graph runs."""
    info = bag_info(bag)
    file_layer = load_params(params_file) if params_file else {}
    inputs = select_inputs(bag, info, {**params_topics(file_layer), **(input_topics or {})})
    texture = texture and any(
        a in inputs and b in inputs and info["topics"][inputs[a]][1] > 0  # images, not just the topic
        for a, b in (("stereo_left", "stereo_right"), ("rgbd_rgb", "rgbd_depth"))
    )
    node_names = NODE_NAMES + (("texture",) if texture else ())
    user = [file_layer] + ([overrides] if overrides else [])
    mount, stamps = _inspect_bag(bag, info, inputs, user)
    prof = _choose_profile(info, inputs, mount, stamps, params_file, profile)
    detected = detect_inputs(bag, info, inputs, mount=mount, stamps=stamps)
    mount_text, mount_notes = _mount_report(mount, detected, user, node_names)
    per_node = _layer_params(bag, params_file, rate, overrides, texture, record, node_names, prof, detected, file_layer)
    checks = _check_stamps_and_pairing(str(bag), stamps, per_node, params_file)
    if texture and per_node["mapper"].get("loops.enabled", False):
        # the final texture is placed on the loop closure's corrected trajectory
        per_node["texture"].setdefault("await_trajectory", True)
    if str(per_node["bag_replay"].get("rate", "max")) == "max":
        # arrival times say nothing about the clocks at --rate max (the bag's stamps were checked
        # before the run: inspect_stamps)
        per_node["predictor"].setdefault("stamp_offset_s", 0.0)
        if texture:  # pace the image pairs on the texture node as the scans on the poses: none skipped
            per_node["bag_replay"].setdefault("image_topic", inputs.get("stereo_left") or inputs["rgbd_rgb"])
            # pairs queued at the texture node while the replay goes on: the texture worker
            # overlaps the SLAM chain (two cores) and absorbs the pairs that take longer under
            # load instead of stopping the chain (300 s car drives with stereo at 1 Hz: 10.1-11.2x
            # with 2, 12.4-13.5x with 8, 11.6-12.9x with 16; ~1.4 MB a pair)
            per_node["bag_replay"].setdefault("max_pairs_in_flight", 8)
            for key in ("queue_depth", "max_pending_pairs"):  # the replay bounds what is in flight
                per_node["texture"][key] = max(int(per_node["texture"].get(key, 0)), 1000)
    return RunPlan(
        bag=bag,
        params_file=params_file,
        rate=rate,
        processes=processes,
        record=record,
        info=info,
        inputs=inputs,
        texture=texture,
        node_names=node_names,
        per_node=per_node,
        prof=prof,
        mount_text=mount_text,
        mount_notes=mount_notes,
        checks=checks,
        **how,
    )


def _inspect_bag(bag: str, info: dict, inputs: dict[str, str], user: list[dict]) -> tuple[LidarMount, dict]:
    """The lidar's mount (/tf_static, the base frame by /tf or the user's base_frame) and the
    header stamps of the scans and the odometry (inspect_stamps), from one pass over the bag."""
    user_mapper = node_params(user, "mapper")
    sample = sample_bag(bag, info, inputs)
    mount = lidar_mount(
        sample,
        info,
        inputs,
        base_frame=user_mapper.get("base_frame"),
        odom_frame=str(user_mapper.get("odom_frame", "odom")),
    )
    stamps = inspect_stamps(sample, inputs)
    return mount, stamps


def _choose_profile(
    info: dict, inputs: dict[str, str], mount: LidarMount, stamps: dict, params_file: str | None, profile: str | None
):
    """The parameter profile (profiles.py) for this bag, or "none" under a parameter file."""
    from .profiles import Profile, ProfileError, choose_profile

    try:
        if params_file and profile in (None, "", "auto"):
            # a parameter file is the whole tuning, as before profiles (its results do not
            # change); --profile NAME layers one under it
            prof = Profile(
                "none", f"--params {params_file} is the whole tuning; --profile NAME layers one under it", None
            )
        else:
            prof = choose_profile(
                info.get("custom_data", {}),
                inputs,
                mount.planar,
                tuple(math.degrees(v) for v in mount.rpy),
                stamps.get("scan_range_max"),
                profile,
            )
    except ProfileError as e:
        raise RunError(str(e)) from None
    return prof


def _layer_params(
    bag: str,
    params_file: str | None,
    rate: str,
    overrides: dict | None,
    texture: bool,
    record: bool,
    node_names: tuple[str, ...],
    prof,
    detected: dict,
    file_layer: dict,
) -> dict[str, dict[str, Any]]:
    """Each node's parameters: defaults < profile < implied by the bag (`detected`) < params_file <
    what pf-slam run sets < overrides, checked (RunError naming where a bad value was set)."""
    prof_layer = load_params(prof.file) if prof.file else {}
    params_topics(prof_layer)  # a profile names no topics (the bag's are chosen above)
    # the profile tunes; what the bag says about itself (odometry source, pairing, gyro format,
    # wheels, mount) wins over it; the user's file and flags win over both
    layers = ([prof_layer] if prof_layer else []) + [detected]
    if file_layer:
        layers.append(file_layer)
    layers.append(
        {
            "bag_replay": {"bag": str(bag), "rate": str(rate)},
            "correlator": {"expected_observers": 1},  # the recorder below
            "predictor": {"expected_observers": 1},
            "texture": {"expected_observers": 1},
        }
    )
    layers[-1]["bag_replay"]["wait_for"] = (
        ["predictor", "correlator", "mapper"]
        + (["texture"] if texture else [])
        + ([ResultRecorder.NAME] if record else [])
    )
    if overrides:
        layers.append(overrides)
    per_node = {n: node_params(layers, n) for n in node_names}
    labels = [lambda sec: f"profile {prof.name} ({prof.file}), section {sec!r}"] if prof_layer else []
    labels.append(lambda sec: f"{bag} (implied by the bag)")
    if file_layer:
        labels.append(lambda sec: f"{params_file}, section {sec!r}")
    labels.append(lambda sec: "the command line")  # --rate (and what pf-slam run sets itself)
    if overrides:
        labels.append(lambda sec: "the command line")
    check_node_values(per_node, list(zip(labels, layers)))
    # the replay says when it stopped for the poses (pf_slam/replay_stall): that, not the number
    # of scans waiting (odom_wait_scans, for live inputs), decides that odometry will not come
    per_node["predictor"].setdefault("odom_wait_scans", 0)
    return per_node


def _open_domain_and_out(
    plan: RunPlan, out_dir: str | os.PathLike, domain_id: int | None
) -> tuple[contextlib.ExitStack, RosDomain, Path, _OutDir]:
    """The run's ROS domain (held until the run's end: the returned ExitStack) and --out."""
    # isolated on a free domain of its own unless `domain_id` / ROS_DOMAIN_ID names one
    # (ros/domain.py); chosen before --out is created: a bad ROS_DOMAIN_ID writes nothing
    domain_scope = contextlib.ExitStack()
    dom = domain_scope.enter_context(run_domain(domain_id, single_participant=plan.processes == "single"))
    out = Path(out_dir)
    try:
        out_dir_ = _OutDir(out)
    except BaseException:
        domain_scope.close()
        raise
    return domain_scope, dom, out, out_dir_


def _report(plan: RunPlan, dom: RosDomain) -> None:
    """The profile, the inputs and the mount (with progress output); warnings always."""
    if plan.progress:
        print(
            plan.prof.line() + (f"; --params {plan.params_file} on top" if plan.params_file and plan.prof.file else ""),
            file=sys.stderr,
        )
        print(
            input_report(str(plan.bag), plan.info, plan.inputs, plan.per_node["predictor"]) + f"\n  {plan.mount_text}",
            file=sys.stderr,
        )
    for note in plan.mount_notes:
        print(f"[pf-slam] warning: {note}", file=sys.stderr)
    for line in plan.checks["warnings"]:  # once, with the numbers, also without progress output
        print(f"[pf-slam] warning: {line}", file=sys.stderr)
    if plan.progress:
        print(dom.describe(), file=sys.stderr)


def _write_results(plan: RunPlan, dom: RosDomain, out: Path, done: GraphOutcome) -> RunResult:
    """The outputs (also those of a stopped run) and summary.json."""
    extra = _write_outputs(out, done.rec, plan.texture, done.texture_out)
    summary = build_summary(plan, dom, done, extra)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return RunResult(summary, done.rec.stamps, done.rec.poses)


def run_cli(args: Any, log: Callable[[str], None] = print) -> int:
    res = run(
        args.bag,
        args.out,
        params_file=args.params,
        rate=args.rate,
        processes=args.processes,
        overrides=_cli_overrides(args),
        snapshot_every=args.snapshot_every,
        executor=args.executor,
        texture=not getattr(args, "no_texture", False),
        record=not getattr(args, "no_record", False),
        record_map_every_s=getattr(args, "record_map_every", None),
        domain_id=getattr(args, "domain", None),
        input_topics={role: getattr(args, f"{role}_topic", None) for role in INPUT_TYPES},
        profile=getattr(args, "profile", None),
    )
    s = res.summary
    dropped = "?" if s["scans_dropped"] is None else s["scans_dropped"]
    log(
        f"{s['scans_processed']} scans ({s['scans_corrected']} corrected), {dropped} dropped, "
        f"wall {s['wall_time_s']:.1f} s, RTF {s['real_time_factor']}x; outputs in {args.out}"
    )
    if lc := s.get("loops"):
        frames = (
            "; trajectory.tum in the final frame, trajectory_online.tum as published"
            if (Path(args.out) / "trajectory_online.tum").is_file()
            else ""
        )
        log(
            f"loop closure: {lc['closed']} loops closed over {lc['keyframes']} keyframes ({lc['rejected']} matches "
            f"refused, {lc['dropped']} dropped by the graph)"
            + (f", {lc['pair_edges']} scan-pair edges in the final solve" if lc.get("pair_edges") else "")
            + f", map re-rendered {lc['map_renders']}x{frames}"
        )
    if g := s.get("gyro"):
        log(gyro_line(g))
    if sc := s.get("odom_scale"):
        log(odom_scale_line(sc))
    if s["scans_dropped"]:
        log(
            f"warning: {s['scans_dropped']} of {s['scans_published']} scans published were dropped: the graph "
            f"fell behind --rate {s['rate']} (--rate max never drops)"
        )
    if any(s["faults"].values()):
        log(
            "input faults (skipped or clamped, the run went on): "
            + ", ".join(f"{k} {n}" for k, n in s["faults"].items() if n)
            + "; see the node logs"
        )
    if "texture" in s:
        t = s["texture"]
        log(
            f"texture: {t.get('frames_processed')} of {t.get('frames_received')} {t.get('mode', 'stereo')} pairs used "
            f"({t.get('frames_skipped')} skipped under load, {t.get('frames_dropped')} without a pose), "
            f"{t['cells_coloured']} cells coloured; {', '.join(t['files']) or 'no image'}"
        )
        if t.get("worker_error"):
            log(f"{t['worker_error']} (the pairs after it are among the {t.get('frames_dropped')} dropped)")
    if not s["complete"]:
        log(f"run incomplete: stopped by {s['stopped_by']}; the outputs hold the scans processed until then")
        return STOP_SIGNALS.get(s["stopped_by"], 1)
    return 0


def _cli_overrides(args: Any) -> dict[str, dict[str, Any]]:
    out = filter_overrides(args)
    if getattr(args, "delay", None):
        if not args.delay >= 0:
            raise RunError(f"--delay must be a number of seconds >= 0, got {args.delay}")
        out["bag_replay"] = {"start_delay_s": float(args.delay)}
    out.update(_localize_overrides(getattr(args, "localize", None), getattr(args, "initial_pose", None)))
    return out


def _localize_overrides(map_yaml: str | None, initial_pose: str | None) -> dict[str, dict[str, Any]]:
    """--localize MAP_YAML [--initial-pose X,Y,YAW] -> the correlator's and the mapper's
    parameters (mode localization, map_file, localization.initial_pose_*); the map is read here
    first, so a bad one stops the run before anything starts."""
    if map_yaml is None:
        if initial_pose is not None:
            raise RunError("--initial-pose needs --localize MAP_YAML")
        return {}
    from .io.mapfile import read_map

    path = str(Path(map_yaml).resolve())
    try:
        read_map(path)
    except (OSError, ValueError) as e:
        raise RunError(f"--localize: {e}") from None
    corr: dict[str, Any] = {"mode": "localization"}
    if initial_pose is not None:
        try:
            x, y, yaw = (float(v) for v in initial_pose.split(","))
        except ValueError:
            raise RunError(f"--initial-pose: expected X,Y,YAW (m, m, rad), got {initial_pose!r}") from None
        corr.update(
            {
                "localization.use_initial_pose": True,
                "localization.initial_pose_x_m": x,
                "localization.initial_pose_y_m": y,
                "localization.initial_pose_yaw_rad": yaw,
            }
        )
    return {"correlator": corr, "mapper": {"mode": "localization", "map_file": path}}
