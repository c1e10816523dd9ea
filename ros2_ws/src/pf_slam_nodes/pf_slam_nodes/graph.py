"""Builds and runs the node graph on a bag: `pf-slam run`.

One process with one executor (`single`), or one process per node over DDS (`multi`); the
nodes are the same classes either way. A recorder node in this process collects the pose of
every scan (pose), the corrections (particles/updated) and the final /map, and writes the
outputs.
"""
from __future__ import annotations

import contextlib
import fcntl
import json
import math
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml

from .core.geometry import quat_to_matrix
from .io.bag import BagError, BagReadError, bag_info, check_run_inputs, deserialize, read_bag, stamp_ns_of
from .io.mapfile import render_snapshot, write_map
from .io.trajectory import write_tum
from .ros import cdr
from .ros.domain import RosDomain, init_context, run_domain

NODE_NAMES = ("bag_replay", "predictor", "correlator", "mapper")
TEXTURE_INPUT = "/stereo/left/image_raw"  # a bag with it gets the texture node
CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"


class RunError(Exception):
    """A run cannot start or did not complete; the message says why."""


#: the signals that stop a run early (partial outputs written) -> the exit code of `pf-slam run`
STOP_SIGNALS = {"SIGINT": 130, "SIGTERM": 143}


# ---------------------------------------------------------------------------- parameters
def flatten(d: dict, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, name + "."))
        else:
            out[name] = v
    return out


def unflatten(flat: dict[str, Any]) -> dict:
    out: dict = {}
    for name, v in flat.items():
        *parents, leaf = name.split(".")
        d = out
        for p in parents:
            d = d.setdefault(p, {})
        d[leaf] = v
    return out


def load_params(path: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """A ROS 2 parameter YAML -> {node name or '/**': flat {dotted name: value}}."""
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
    except OSError as e:
        raise RunError(f"{p}: cannot read parameter file: {e}") from None
    except yaml.YAMLError as e:  # one line: where and what (PyYAML's own text spans lines)
        mark = getattr(e, "problem_mark", None)
        at = f":{mark.line + 1}:{mark.column + 1}" if mark is not None else ""
        what = " ".join(x for x in (getattr(e, "context", None), getattr(e, "problem", None)) if x) or str(e)
        raise RunError(f"{p}{at}: cannot read parameter file: not valid YAML: {' '.join(what.split())}") from None
    if not isinstance(doc, dict):
        raise RunError(f"{p}: not a ROS 2 parameter file (expected a mapping of node names)")
    out: dict[str, dict[str, Any]] = {}
    for node, body in doc.items():
        if not isinstance(body, dict) or "ros__parameters" not in body:
            raise RunError(f"{p}: section {node!r} has no 'ros__parameters'")
        key = node if node == "/**" else str(node).lstrip("/")
        if key != "/**" and key not in NODE_NAMES + ("texture",):
            raise RunError(f"{p}: unknown node {node!r}; nodes: {', '.join(NODE_NAMES)}")
        params = body["ros__parameters"] or {}
        if not isinstance(params, dict):
            raise RunError(f"{p}: section {node!r}: 'ros__parameters' must be a mapping of names to values")
        flat = flatten(params)
        check_names(p, node, key, flat)
        out.setdefault(key, {}).update(flat)
    return out


def check_names(path: Path, section: str, key: str, flat: dict[str, Any]) -> None:
    """RunError for the first name of a parameter file's section that no node would read:
    in a node's section, one that node does not declare; in '/**', one no node declares
    (`topics.*` are `pf-slam run`'s own). Names the file, the section, the name and the
    nearest declared one. (ROS itself ignores undeclared overrides: a typo would silently
    leave the default.)"""
    from .nodes.declared import RUN_KEYS_PREFIXES, declared, declared_by, nearest
    by = declared_by()
    for name in flat:
        if key == "/**":
            run_keys = [f"{prefix}{r}" for prefix in RUN_KEYS_PREFIXES for r in INPUT_TYPES]
            if name in by or name in run_keys:
                continue
            known = run_keys if name.startswith(RUN_KEYS_PREFIXES) else list(by) + run_keys
            where = ("the inputs are " + ", ".join(INPUT_TYPES)) if name.startswith(RUN_KEYS_PREFIXES) \
                else "no node declares it"
        else:
            if name in declared(key):
                continue
            known = list(declared(key))
            where = (f"{key} does not declare it (declared by {', '.join(by[name])}: put it in that "
                     "section or under '/**')") if name in by else f"{key} does not declare it"
        near = nearest(name, known)
        hint = f"; nearest known: '{near}'" if near else ""
        raise RunError(f"{path}: section {section!r}: unknown parameter '{name}' ({where}){hint}")


#: `pf-slam run` flags -> the parameter they set (named in errors)
CLI_FLAGS = {"filter.num_particles": "--particles", "filter.seed": "--seed", "rate": "--rate"}


def check_node_values(per_node: dict[str, dict[str, Any]], labelled: list[tuple[Callable[[str], str], dict]]) -> None:
    """RunError (one line) for the first value a node would refuse at start-up (bad type, a
    config out of range: what the nodes check when built), naming where it was set, before
    anything is created. `labelled`: the layers (as node_params) with a function section ->
    where that layer's values come from."""
    from .nodes.bag_replay import parse_rate
    from .nodes.declared import check_values
    for node, params in per_node.items():
        bad = check_values(node, params)
        if bad is None and node == "bag_replay":
            try:
                parse_rate(str(params.get("rate", "max")))
            except ValueError as e:
                bad = ("rate", str(e))
        if bad is None:
            continue
        name, what = bad
        where = "defaults"
        for label, layer in reversed(labelled):
            sec = node if name in layer.get(node, {}) else ("/**" if name in layer.get("/**", {}) else None)
            if sec is not None:
                where = label(sec)
                break
        if where == "the command line" and name in CLI_FLAGS:
            where = f"the command line ({CLI_FLAGS[name]})"
        raise RunError(f"{where}: parameter '{name}' of {node}: {what}")


class _OutDir:
    """The run's output folder: created (with snapshots/) by the run, or a user's existing one.
    `remove_new()` undoes what a run that failed before its graph started left there: the
    topmost folder it created, or in an existing folder only the entries it added (never what
    was there before)."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.top = None
        for p in [out, *out.parents]:
            if p.exists():
                break
            self.top = p
        self.before = set(out.iterdir()) if out.is_dir() else set()
        (out / "snapshots").mkdir(parents=True, exist_ok=True)

    def remove_new(self) -> None:
        if self.top is not None:
            shutil.rmtree(self.top, ignore_errors=True)
            return
        for p in set(self.out.iterdir()) - self.before:
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                with contextlib.suppress(OSError):
                    p.unlink()


def node_params(layers: list[dict[str, dict[str, Any]]], node: str) -> dict[str, Any]:
    """Merge layers (later wins): per layer, '/**' then the node's own section."""
    merged: dict[str, Any] = {}
    for layer in layers:
        merged.update(layer.get("/**", {}))
        merged.update(layer.get(node, {}))
    return merged


# ---------------------------------------------------------------------------- bag inspection, bring your own bag
#: The graph's inputs: the nodes' (relative) topic name -> the message types it takes
INPUT_TYPES: dict[str, tuple[str, ...]] = {
    "scan": ("sensor_msgs/msg/LaserScan",),
    "odom": ("nav_msgs/msg/Odometry",),
    "encoders": ("sensor_msgs/msg/JointState",),
    "fog": ("pf_slam_interfaces/msg/FogBatch", "geometry_msgs/msg/Vector3Stamped"),
    "imu": ("sensor_msgs/msg/Imu",),
    "stereo_left": ("sensor_msgs/msg/Image",),
    "stereo_right": ("sensor_msgs/msg/Image",),
}
DEFAULT_INPUTS = {"scan": "/scan", "odom": "/odom", "encoders": "/encoders", "fog": "/fog", "imu": "/imu",
                  "stereo_left": TEXTURE_INPUT, "stereo_right": "/stereo/right/image_raw"}
ROLE_WORDS = {"scan": "lidar (LaserScan)", "odom": "odometry (Odometry)", "encoders": "wheel encoders (JointState)",
              "fog": "gyro yaw (fog)", "imu": "gyro yaw (Imu angular_velocity.z)", "stereo_left": "stereo left (texture)", "stereo_right": "stereo right (texture)"}


def select_inputs(bag: str, info: dict, requested: dict[str, str] | None = None) -> dict[str, str]:
    """Input -> the bag's topic for it: the requested name (``--scan-topic`` ..., or ``topics.*``
    in the parameter file; it must exist with that input's type), else the default name, else,
    for the lidar and the odometry, the bag's only topic of that type. Odometry wins over
    encoders unless encoders are requested; a gyro is used only with encoders."""
    topics = info["topics"]
    found = ", ".join(f"{t} [{m}]" for t, (m, _) in sorted(topics.items())) or "none"
    req = {k: v for k, v in (requested or {}).items() if v}
    sel: dict[str, str] = {}
    for role, name in req.items():
        if role not in INPUT_TYPES:
            raise RunError(f"unknown input {role!r}; inputs: {', '.join(INPUT_TYPES)}")
        if name not in topics:
            raise RunError(f"{bag}: {role} topic {name} is not in the bag; found: {found}")
        if topics[name][0] not in INPUT_TYPES[role]:
            raise RunError(f"{bag}: {name} is {topics[name][0]}; {role} needs {' or '.join(INPUT_TYPES[role])}")
        sel[role] = name
    for role, name in DEFAULT_INPUTS.items():
        if role not in sel and topics.get(name, ("",))[0] in INPUT_TYPES[role]:
            sel[role] = name
    for role in ("scan", "odom", "encoders", "imu"):
        of_type = sorted(t for t, (m, _) in topics.items() if m in INPUT_TYPES[role])
        if role not in sel and len(of_type) == 1:
            sel[role] = of_type[0]
        elif role == "scan" and role not in sel and of_type:
            raise RunError(f"{bag}: several LaserScan topics ({', '.join(of_type)}): choose one with --scan-topic")
    if "scan" not in sel:
        raise _no_input(bag, info, f"no sensor_msgs/msg/LaserScan topic (set --scan-topic); found: {found}")
    if "odom" in sel and "encoders" in sel:
        del sel["odom" if "encoders" in req and "odom" not in req else "encoders"]
    if "odom" not in sel and "encoders" not in sel:
        raise _no_input(bag, info, "needs nav_msgs/msg/Odometry (--odom-topic) or sensor_msgs/msg/JointState "
                                   f"wheel angles (--encoders-topic) for the motion model; found: {found}")
    if "encoders" not in sel or "fog" in sel:
        sel.pop("imu", None)  # one gyro, with the encoders only (Odometry has its own yaw)
    if "encoders" not in sel:
        sel.pop("fog", None)
    return sel


def _canonical_view(info: dict, inputs: dict[str, str]) -> dict:
    """`info` with the chosen input topics under the graph's default names, as check_run_inputs
    expects; a topic on a default name that was not chosen is renamed out of the way."""
    canon = {t: DEFAULT_INPUTS[r] for r, t in inputs.items()}
    taken = set(canon.values())
    topics = {canon.get(t, t + " (unused)" if t in taken else t): v for t, v in info["topics"].items()}
    return dict(info, topics=topics)


def _no_input(bag: str, info: dict, what: str) -> RunError:
    """The error for a bag without a usable lidar or odometry: the standard names' diagnosis
    (check_run_inputs: wrong types, missing topics, what was found) + how to name other topics."""
    try:
        check_run_inputs(info)
    except BagError as e:
        return RunError(f"{e}; or name the bag's topics: --scan-topic, --odom-topic, --encoders-topic")
    return RunError(f"{bag}: {what}")


def params_topics(layer: dict[str, dict[str, Any]]) -> dict[str, str]:
    """`topics.<input>` values of a parameter file's '/**' section (removed from it: no node
    declares them), e.g. ``topics: {scan: /front/scan, odom: /wheel/odom}``."""
    shared = layer.get("/**", {})
    return {k.split(".", 1)[1]: str(shared.pop(k)) for k in [k for k in shared if k.startswith("topics.")]}


def topic_remaps(inputs: dict[str, str]) -> dict[str, str]:
    """The nodes' relative input names remapped to the bag's topics (as `ros2 launch ... scan_topic:=`)."""
    return {role: t for role, t in inputs.items() if role in ("scan", "odom", "encoders", "fog", "imu") and t != f"/{role}"}


def input_report(bag: str, info: dict, inputs: dict[str, str], predictor: dict[str, Any]) -> str:
    """Which topics the bag has and what the graph uses each for (printed by `pf-slam run`)."""
    used = {t: role for role, t in inputs.items()}
    lines = [f"[pf-slam] inputs from {bag}:"]
    for t, (msgtype, n) in sorted(info["topics"].items()):
        role = used.get(t)
        if role is not None:
            what = "-> " + ROLE_WORDS[role]
            if role in ("odom", "encoders"):
                what += f", pairing with scans: {predictor.get('odom_sync')}"
        elif t in ("/tf", "/tf_static"):
            what = "-> replayed (transforms)"
        else:
            what = "   not used (replayed as recorded)"
        lines.append(f"  {t:<32} {msgtype:<36} {n:>7}  {what}")
    return "\n".join(lines)


#: header stamps of two streams offset by more than this (median of header - record time) are
#: on different clocks; a step of header - record time larger than STAMP_JUMP_NS is a jump
STAMP_OFFSET_NS = 500_000_000
STAMP_JUMP_NS = 1_000_000_000


def inspect_stamps(bag: str, inputs: dict[str, str], max_scans: int = 200) -> dict[str, Any]:
    """The header stamps of the scans and the odometry against the bag's record times (the
    first `max_scans` scans and the odometry among them), and what the replay must do about them.

    Per stream: header stamps that are stuck (at least half of them equal to the previous one
    while the record time advances) or that jump against the record time (5 % of the steps by
    more than 1 s) cannot be right: the stream is replayed with its record times ("record").
    Then the two streams' clocks: each scan against the odometry message nearest to it in record
    time; when their header stamps are, in the median, more than 0.5 s further apart than their
    record times (scan and odometry stamps that do not overlap while their record times do), the
    odometry is shifted onto the scans' clock (an int: ns to add). Not done when a gyro
    stream is used (its per-sample stamps are not rewritten): then only reported.

    Returns {"restamp": {topic: "record" | shift_ns}, "notes": {topic: why, with numbers},
    "pairing": (scans with an odometry message of the same stamp, scans checked), "scan_frame",
    "scan_range_max" (the first scan's)}, the pairing counted on the stamps as they will be replayed."""
    scan_topic = inputs["scan"]
    odom_topic = inputs["odom" if "odom" in inputs else "encoders"]
    rows: dict[str, list[tuple[int, int]]] = {scan_topic: [], odom_topic: []}
    scan_frame = None
    scan_range_max = None
    try:
        for t, msgtype, rec, raw in read_bag(bag, topics=[scan_topic, odom_topic]):
            try:
                msg = deserialize(raw, msgtype)
            except Exception:  # an unreadable message: the predictor counts it at run time
                continue
            rows[t].append((stamp_ns_of(msg), rec))
            if t == scan_topic:
                scan_frame = msg.header.frame_id
                if scan_range_max is None:
                    scan_range_max = float(msg.range_max)
                if len(rows[t]) >= max_scans:
                    break
    except BagReadError:
        if not rows[scan_topic]:
            raise  # damaged before the first scan: nothing to run
        # damaged later: decide from the scans before it; the replay stops at the damage and says so
    arr = {t: np.array(r, dtype=np.int64).reshape(-1, 2) for t, r in rows.items()}
    restamp: dict[str, Any] = {}
    notes: dict[str, str] = {}
    for topic, a in arr.items():
        if len(a) < 10:
            continue
        steps = len(a) - 1
        hdr, rec = a[:, 0], a[:, 1]
        stuck = int(np.count_nonzero((np.diff(hdr) == 0) & (np.diff(rec) > 0)))
        jumps = int(np.count_nonzero(np.abs(np.diff(hdr - rec)) > STAMP_JUMP_NS))
        if stuck >= 0.5 * steps:
            restamp[topic] = "record"
            notes[topic] = (f"header stamps stuck: {stuck} of {steps} equal to the previous one while the "
                            f"record time advances ({(rec[-1] - rec[0]) / 1e9:.1f} s); replayed with the record times")
        elif jumps >= 0.05 * steps:
            restamp[topic] = "record"
            notes[topic] = (f"header stamps do not follow the record time: {jumps} of {steps} steps jump by "
                            f"more than {STAMP_JUMP_NS / 1e9:.0f} s against it; replayed with the record times")

    def replayed(topic: str) -> np.ndarray:
        a, fix = arr[topic], restamp.get(topic)
        return a[:, 1] if fix == "record" else a[:, 0] + (fix or 0)

    if len(arr[scan_topic]) and len(arr[odom_topic]):
        # each scan against the odometry message nearest to it in record time: how much further
        # apart their header stamps are than their record times (robust to a gap or a jump
        # that both streams share)
        s_hdr, s_rec = replayed(scan_topic), arr[scan_topic][:, 1]
        o_hdr, o_rec = replayed(odom_topic), arr[odom_topic][:, 1]
        order = np.argsort(o_rec, kind="stable")
        o_hdr, o_rec = o_hdr[order], o_rec[order]
        j = np.clip(np.searchsorted(o_rec, s_rec), 1, len(o_rec) - 1) if len(o_rec) > 1 else np.zeros(len(s_rec), int)
        if len(o_rec) > 1:
            j = np.where(np.abs(o_rec[j - 1] - s_rec) <= np.abs(o_rec[j] - s_rec), j - 1, j)
        off = int(np.median((s_hdr - o_hdr[j]) - (s_rec - o_rec[j])))
        if abs(off) > STAMP_OFFSET_NS:
            fix = "fog" not in inputs and "imu" not in inputs
            notes[odom_topic] = (
                f"stamps {-off / 1e9:+.3f} s from the scans' (median over {len(s_rec)} scans of the header stamp "
                f"difference to the odometry nearest in record time, less their record time difference): "
                + ("shifted onto the scans' clock" if fix else "NOT corrected (a gyro stream is used); "
                   "the pairing is wrong by that much"))
            if fix:
                restamp[odom_topic] = int(off) if restamp.get(odom_topic) != "record" else "record"

    scans = replayed(scan_topic)
    odom = set(replayed(odom_topic).tolist())
    paired = int(sum(int(s) in odom for s in scans))
    return {"restamp": restamp, "notes": notes, "pairing": (paired, len(scans)), "scan_frame": scan_frame,
            "scan_range_max": scan_range_max}


def restamp_param(restamp: dict[str, Any]) -> str:
    """{'/scan': 'record', '/odom': 3000000000} -> '/scan=record,/odom=3000000000' (bag_replay's `restamp`)."""
    return ",".join(f"{t}={v}" for t, v in sorted(restamp.items()))


def detect_inputs(bag: str, info: dict, inputs: dict[str, str] | None = None,
                  mount: "LidarMount | None" = None, stamps: dict[str, Any] | None = None) -> dict[str, dict[str, Any]]:
    """Parameters implied by the bag: odometry source and pairing, gyro, wheel geometry (from a
    converted bag's custom data), and the lidar's mount (from /tf_static, see lidar_mount:
    filter.sensor_offset_* when planar, laser.extrinsic otherwise). `inputs`: select_inputs()'s
    choice (default: select_inputs(bag, info)); `mount`: lidar_mount()'s (default: looked up);
    `stamps`: inspect_stamps()'s answer (default: computed here). The pairing: what the converter
    wrote in the bag's custom data (pf_slam.odom_sync), else exact when 90 % of the first 200 scans
    have an odometry message with their stamp (as replayed), else interpolate."""
    topics = info["topics"]
    inputs = select_inputs(bag, info) if inputs is None else inputs
    check_run_inputs(_canonical_view(info, inputs))  # BagError: an input without messages, unknown types
    scan_topic = inputs["scan"]
    source = "odom" if "odom" in inputs else "encoders"
    stamps = inspect_stamps(bag, inputs) if stamps is None else stamps
    scan_frame = stamps["scan_frame"]
    paired, checked = stamps["pairing"]
    exact = checked > 0 and paired >= 0.9 * checked
    custom = info.get("custom_data", {})
    if custom.get("pf_slam.odom_sync") in ("exact", "interpolate") and not stamps["restamp"]:
        exact = custom["pf_slam.odom_sync"] == "exact"
    predictor: dict[str, Any] = {"odometry_source": source, "odom_sync": "exact" if exact else "interpolate"}
    if source == "encoders":
        if "pf_slam.wheel_radius_m" in custom:  # written by `convert mines`
            d = 2.0 * float(custom["pf_slam.wheel_radius_m"])
            predictor.update({"wheels.left_diameter_m": d, "wheels.right_diameter_m": d,
                              "wheels.base_m": 2.0 * float(custom["pf_slam.half_axle_m"])})
        elif "pf_slam.wheel_base_m" in custom:  # written by `convert kaist`
            predictor.update({"wheels.left_diameter_m": float(custom["pf_slam.left_wheel_diameter_m"]),
                              "wheels.right_diameter_m": float(custom["pf_slam.right_wheel_diameter_m"]),
                              "wheels.base_m": float(custom["pf_slam.wheel_base_m"])})
        if "fog" in inputs:
            predictor["fog_format"] = {"pf_slam_interfaces/msg/FogBatch": "batch",
                                       "geometry_msgs/msg/Vector3Stamped": "vector3"}[topics[inputs["fog"]][0]]
        elif "imu" in inputs:
            predictor["fog_format"] = "imu"
    out: dict[str, dict[str, Any]] = {"predictor": predictor, "bag_replay": {"scan_topic": scan_topic}}
    if "stereo_left" in inputs and "stereo_right" in inputs:
        left, right = inputs["stereo_left"], inputs["stereo_right"]
        out["texture"] = {"left_topic": left, "right_topic": right,
                          "left_info_topic": left.rsplit("/", 1)[0] + "/camera_info",
                          "right_info_topic": right.rsplit("/", 1)[0] + "/camera_info"}
    lm = mount if mount is not None else lidar_mount(bag, info, inputs, scan_frame=scan_frame)
    out["/**"] = dict(lm.params())
    if lm.base_from_tf:
        out["/**"]["base_frame"] = lm.base_frame
    for node, params in tf_inputs(topics, lm).items():
        out.setdefault(node, {}).update(params)
    return out


def _check_stamps_and_pairing(bag: str, stamps: dict[str, Any], per_node: dict[str, dict[str, Any]],
                              params_file: str | None) -> dict[str, Any]:
    """Apply inspect_stamps()'s fixes to the replay, and refuse a pairing that cannot work on
    this bag: odom_sync exact (from a parameter file or a flag) where fewer than 90 % of the
    scans checked have an odometry message with their stamp would pair nothing; interpolate is
    used instead. Returns {"warnings": [...], "odom_sync": {...}, "timestamps": {...}} for the
    run's output and summary.json."""
    warnings, timestamps = [], {}
    for topic, why in sorted(stamps["notes"].items()):
        fix = stamps["restamp"].get(topic)
        timestamps[topic] = {"fix": ("record time" if fix == "record" else
                                     None if fix is None else f"{fix / 1e9:+.3f} s"), "why": why}
        warnings.append(f"{bag}: {topic}: {why}")
    if stamps["restamp"]:
        per_node["bag_replay"]["restamp"] = restamp_param(stamps["restamp"])
    pred = per_node["predictor"]
    paired, checked = stamps["pairing"]
    sync = {"used": pred.get("odom_sync", "interpolate"), "scans_checked": checked, "with_odometry_stamp": paired}
    if sync["used"] == "exact" and checked and paired < 0.9 * checked:
        where = f" (from {params_file} or a flag)" if params_file else " (from a flag)"
        warnings.append(f"{bag}: odom_sync exact{where} cannot work on this bag: only {paired} of the first "
                        f"{checked} scans have an odometry message with their stamp (the odometry is logged "
                        f"at its own times); pairing by interpolation instead. Set odom_sync: interpolate "
                        f"(or leave it out: pf-slam run picks it from the bag)")
        pred["odom_sync"] = "interpolate"
        sync.update(requested="exact", used="interpolate")
    return {"warnings": warnings, "odom_sync": sync, "timestamps": timestamps}


def tf_inputs(topics: dict, mount: "LidarMount | None") -> dict[str, dict[str, Any]]:
    """REP-105 transforms the bag already has, so the graph does not publish them twice: its
    own /tf (odom -> base_link from the robot) turns the predictor's off, a /tf_static mount of
    the scan's frame (`mount` from /tf_static, see lidar_mount) the mapper's."""
    out: dict[str, dict[str, Any]] = {}
    if "/tf" in topics:
        out["predictor"] = {"publish_odom_tf": False}
    if mount is not None and mount.source == "/tf_static":
        out["mapper"] = {"publish_sensor_tf": False}
    return out


def _mount_report(mount: LidarMount, detected: dict, user: list[dict], node_names) -> tuple[str, list[str]]:
    """(the mount line of the input report, warnings). Mount parameters the user gives
    (--params, overrides) replace the bag's mount as a whole: the bag's are dropped from
    `detected` (so a planar offset and a 3D extrinsic never mix) and the override is warned."""
    given = {k: v for layer in user for sec in layer.values() for k, v in sec.items() if k in MOUNT_PARAMS}
    notes = list(mount.warnings)
    if not given:
        if mount.source == "/tf_static":
            return mount.describe(), notes
        text = "lidar mount from the parameters (the bag has " + (
            "no /tf_static" if not notes else "no mount for it in /tf_static") + "): the lidar at the origin of " + mount.base_frame
        return text, notes
    for k in MOUNT_PARAMS:
        detected.get("/**", {}).pop(k, None)
    merged = node_params(user, "correlator")
    text = "lidar mount from the parameters: " + ", ".join(f"{k} {merged.get(k, given[k])}" for k in MOUNT_PARAMS
                                                           if k in given)
    if mount.source == "/tf_static":
        notes.append(f"the parameters' lidar mount replaces the bag's ({mount.describe()})")
    return text, notes


#: the parameters that describe the lidar's mount (planar: filter.sensor_offset_*; 3D: laser.extrinsic)
MOUNT_PARAMS = ("filter.sensor_offset_x_m", "filter.sensor_offset_y_m", "filter.sensor_offset_yaw_rad",
                "laser.extrinsic")


@dataclass
class LidarMount:
    """The scan frame's pose in the robot's base frame: ``p_base = rot @ p_scan + t``.

    ``source``: "/tf_static" (composed along ``chain``, base frame first) or "parameters"
    (the bag has none: the graph's parameters, default identity). ``warnings``: what the user
    must know (a scan frame missing from /tf_static, a chain that does not reach the base)."""
    source: str
    base_frame: str
    scan_frame: str
    rot: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    chain: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    base_from_tf: bool = False  # base_frame is the child of odom in the bag's /tf

    @property
    def planar(self) -> bool:
        """Scan plane horizontal and upright: an exact 2D mount (x, y, yaw)."""
        return abs(float(self.rot[2, 2]) - 1.0) < 1e-6

    @property
    def rpy(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) in rad, R = Rz(yaw) Ry(pitch) Rx(roll)."""
        r = self.rot
        return (math.atan2(r[2, 1], r[2, 2]), math.asin(max(-1.0, min(1.0, -r[2, 0]))), math.atan2(r[1, 0], r[0, 0]))

    def params(self) -> dict[str, Any]:
        """The graph parameters that apply it: the planar path when the plane is horizontal and
        upright (filter.sensor_offset_*: exact 2D; z does not matter), the 3D projection
        otherwise (laser.extrinsic; an upside-down lidar is a mirrored planar scan there)."""
        if self.source != "/tf_static":
            return {}
        if self.planar:
            return {"filter.sensor_offset_x_m": float(self.t[0]), "filter.sensor_offset_y_m": float(self.t[1]),
                    "filter.sensor_offset_yaw_rad": float(math.atan2(self.rot[1, 0], self.rot[0, 0]))}
        return {"laser.extrinsic": [float(v) for v in self.rot.reshape(-1)] + [float(v) for v in self.t]}

    def describe(self) -> str:
        """'lidar mount from /tf_static: base_link -> laser: x 0.30 y 0.00 z 0.20, yaw 90.0°'."""
        roll, pitch, yaw = (math.degrees(v) for v in self.rpy)
        frames = " -> ".join(self.chain) if self.chain else f"{self.base_frame} -> {self.scan_frame}"
        angles = f"yaw {yaw:.1f}°" if self.planar else f"roll {roll:.1f}° pitch {pitch:.1f}° yaw {yaw:.1f}°"
        how = ("planar: filter.sensor_offset_*" if self.planar else
               "3D: laser.extrinsic, " + ("upside down, a mirrored scan" if self.rot[2, 2] < -1 + 1e-6
                                          else "tilted, projected"))
        return (f"lidar mount from {self.source}: {frames}: x {self.t[0]:.2f} y {self.t[1]:.2f} z {self.t[2]:.2f}, "
                f"{angles} ({how})")


def _tf_static_tree(bag: str, topics: dict) -> tuple[dict[str, tuple[str, np.ndarray, np.ndarray]], list[str]]:
    """Every /tf_static transform of the bag: child -> (parent, R, t) (a later message's
    transform of the same child replaces the earlier one, as tf2 does), and warnings."""
    tree: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
    warnings: list[str] = []
    if "/tf_static" not in topics:
        return tree, warnings
    with contextlib.suppress(BagReadError):  # damaged mid-bag: the transforms before it count
        for _, msgtype, _, raw in read_bag(bag, topics=["/tf_static"]):
            for tr in deserialize(raw, msgtype).transforms:
                tt = tr.transform.translation
                t = np.array([tt.x, tt.y, tt.z], dtype=np.float64)
                try:
                    q = tr.transform.rotation
                    rot = quat_to_matrix(q.x, q.y, q.z, q.w)
                    if not np.isfinite(t).all():
                        raise ValueError(f"translation {t.tolist()} is not finite")
                except ValueError as e:
                    warnings.append(f"/tf_static: {tr.header.frame_id} -> {tr.child_frame_id} ignored: {e}")
                    continue
                tree[tr.child_frame_id.lstrip("/")] = (tr.header.frame_id.lstrip("/"), rot, t)  # tf2 drops a leading /
    return tree, warnings


def _odom_child(bag: str, topics: dict, odom_frame: str) -> str | None:
    """The robot's base frame by its /tf: the child of `odom_frame` (first 200 messages)."""
    if "/tf" not in topics:
        return None
    with contextlib.suppress(BagReadError):  # damaged mid-bag: what precedes it
        for k, (_, msgtype, _, raw) in enumerate(read_bag(bag, topics=["/tf"])):
            for tr in deserialize(raw, msgtype).transforms:
                if tr.header.frame_id.lstrip("/") == odom_frame and tr.child_frame_id:
                    return tr.child_frame_id.lstrip("/")
            if k >= 200:
                break
    return None


def _up_chain(tree: dict, frame: str) -> list[str]:
    """`frame` and its /tf_static ancestors, nearest first (stops at a cycle)."""
    out = [frame]
    while out[-1] in tree and tree[out[-1]][0] not in out:
        out.append(tree[out[-1]][0])
    return out


def _compose_up(tree: dict, chain: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Pose of chain[0] in chain[-1] (chain: a frame and its ancestors, nearest first)."""
    rot, t = np.eye(3), np.zeros(3)
    for child in chain[:-1]:
        _, r, tt = tree[child]
        rot, t = r @ rot, r @ t + tt
    return rot, t


def lidar_mount(bag: str, info: dict, inputs: dict[str, str], scan_frame: str | None = None,
                base_frame: str | None = None, odom_frame: str = "odom") -> LidarMount:
    """The lidar's mount from the bag's /tf_static: the scan's frame composed up the chain of
    static transforms to the robot's base frame (`base_frame` if given, else the child of
    `odom_frame` in the bag's /tf, else base_link), e.g. base_link -> shell_link -> rplidar_link.
    A bag without /tf_static, or whose /tf_static lacks the scan's frame (warned, naming what it
    has), gives source "parameters": the graph's filter.sensor_offset_* / laser.extrinsic."""
    topics = info["topics"]
    if scan_frame is None:
        for _, msgtype, _, raw in read_bag(bag, topics=[inputs["scan"]]):
            scan_frame = deserialize(raw, msgtype).header.frame_id
            break
    scan_frame = (scan_frame or "").lstrip("/")
    from_tf = None
    if base_frame is None:
        from_tf = _odom_child(bag, topics, odom_frame)
    base = base_frame or from_tf or "base_link"
    m = LidarMount("parameters", base, scan_frame, base_from_tf=from_tf is not None)
    tree, m.warnings = _tf_static_tree(bag, topics)
    if "/tf_static" not in topics:
        return m
    if not scan_frame:
        m.warnings.append(f"{inputs['scan']}: scans have no header.frame_id: the lidar mount is not looked up "
                          "in /tf_static; the parameters' mount is used")
        return m
    if scan_frame == base:
        m.source = "/tf_static"
        m.chain = [base]
        return m
    if scan_frame not in tree:
        have = ", ".join(f"{p} -> {c}" for c, (p, _, _) in sorted(tree.items())) or "no transforms"
        m.warnings.append(f"/tf_static has no transform to the scan's frame {scan_frame!r} (it has: {have}): "
                          "the parameters' mount is used (filter.sensor_offset_*, laser.extrinsic; default: "
                          f"the lidar at the origin of {base})")
        return m
    up = _up_chain(tree, scan_frame)
    if base in up:
        up = up[:up.index(base) + 1]
        rot, t = _compose_up(tree, up)
    elif base in tree and (common := [f for f in _up_chain(tree, base) if f in up]):
        # the base hangs off the same tree (base_footprint -> base_link -> laser, base_link
        # the base): scan in base = inverse(base in the common ancestor) * scan in it
        anc = common[0]
        up_s, up_b = up[:up.index(anc) + 1], _up_chain(tree, base)
        up_b = up_b[:up_b.index(anc) + 1]
        r_s, t_s = _compose_up(tree, up_s)
        r_b, t_b = _compose_up(tree, up_b)
        rot, t = r_b.T @ r_s, r_b.T @ (t_s - t_b)
        up = list(reversed(up_b + list(reversed(up_s))[1:]))  # shown as base -> .. -> ancestor -> .. -> scan
    else:
        rot, t = _compose_up(tree, up)
        m.warnings.append(f"/tf_static: the scan's frame {scan_frame!r} hangs off {up[-1]!r}, not the robot's base "
                          f"frame {base!r} ({'child of ' + odom_frame + ' in /tf' if from_tf else 'base_frame'}): "
                          f"the mount is taken relative to {up[-1]!r}")
    m.source, m.rot, m.t, m.chain = "/tf_static", rot, t, list(reversed(up))
    return m


# ---------------------------------------------------------------------------- the run
@dataclass
class RunResult:
    summary: dict
    stamps_ns: list[int] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)


class _Recorder:
    """Collects per-scan poses and the latest /map; renders snapshots; prints progress."""

    def __init__(self, node, out_dir: Path, scans_total: int, bag_duration_s: float,
                 snapshot_every: int, progress: bool, texture: bool = False) -> None:
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import OccupancyGrid
        from pf_slam_interfaces.msg import ParticleArray, ReplayStatus

        from .ros import qos, topics
        self.node = node
        self.out_dir = out_dir
        self.scans_total = scans_total
        self.bag_duration_s = bag_duration_s
        self.snapshot_every = snapshot_every
        self.progress = progress
        self.stamps: list[int] = []
        self.poses: list[np.ndarray] = []
        self.updates = 0
        self.map_msg = None
        self.replay_counts: dict[str, int] | None = None
        self.texture_msg = None
        self.texture_meta = None
        self.texture_status: dict | None = None
        self.node_status: dict[str, dict] = {}  # pf_slam/status per node: fault counters
        self.t0 = time.monotonic()
        self._last_print = 0.0
        self._writer: threading.Thread | None = None  # the snapshot being written, if any
        self._writer_error: Exception | None = None
        self.snapshots_written = 0
        self.snapshots_skipped = 0
        #: more consumers of the raw /pose bytes (the result recorder): one subscription, one
        #: delivery per pose at the car's 100 Hz instead of one per consumer
        self.pose_listeners: list = []
        self.pose_subscription = node.create_subscription(PoseStamped, topics.POSE, self._on_pose, qos.pipeline(),
                                                          raw=True)
        node.create_subscription(ParticleArray, topics.PARTICLES_UPDATED, self._on_updated, qos.pipeline())
        node.create_subscription(OccupancyGrid, topics.MAP, self._on_map, qos.latched())
        node.create_subscription(ReplayStatus, topics.REPLAY_STATUS, self._on_replay_status, qos.latched())
        from std_msgs.msg import String
        node.create_subscription(String, topics.STATUS, self._on_node_status, qos.latched(depth=10))
        if texture:
            from nav_msgs.msg import MapMetaData
            from sensor_msgs.msg import Image
            from std_msgs.msg import String

            from .nodes.texture import TEXTURE, TEXTURE_METADATA, TEXTURE_STATUS
            node.create_subscription(Image, TEXTURE, self._on_texture, qos.latched())
            node.create_subscription(MapMetaData, TEXTURE_METADATA, self._on_texture_meta, qos.latched())
            node.create_subscription(String, TEXTURE_STATUS, self._on_texture_status, qos.latched())

    def _on_texture(self, msg) -> None:
        self.texture_msg = msg

    def _on_texture_meta(self, msg) -> None:
        self.texture_meta = msg

    def _on_texture_status(self, msg) -> None:
        self.texture_status = json.loads(msg.data)

    def _on_node_status(self, msg) -> None:
        status = json.loads(msg.data)
        self.node_status[status["node"]] = status

    def bag_error(self) -> str | None:
        """The damage that ended the replay early (bag_replay's pf_slam/status), or None."""
        return self.node_status.get("bag_replay", {}).get("error")

    def faults(self) -> dict[str, int]:
        """The input faults the nodes counted (summary.json "faults")."""
        out: dict[str, int] = {}
        for status in self.node_status.values():
            for kind, n in status.get("faults", {}).items():
                out[kind] = out.get(kind, 0) + int(n)
        return out

    def _on_replay_status(self, msg) -> None:
        self.replay_counts = dict(zip(msg.topics, (int(c) for c in msg.counts)))

    def _on_updated(self, msg) -> None:
        self.updates += int(msg.update)

    def _on_pose(self, raw: bytes) -> None:
        for listener in self.pose_listeners:
            listener(raw)
        stamp, pose = cdr.pose_stamped_xy_yaw(raw)
        self.stamps.append(stamp)
        self.poses.append(pose)
        k = len(self.poses)
        if self.snapshot_every and k % self.snapshot_every == 0 and self.map_msg is not None:
            self.snapshot(f"scan_{k:06d}.png")
        self.print_progress()

    def _on_map(self, msg) -> None:
        self.map_msg = msg

    def snapshot(self, name: str, wait: bool = False) -> None:
        """Render the latest map and path to ``snapshots/<name>`` on the writer thread.

        The executor thread only hands over references; a snapshot due while the previous one
        is still being written is skipped and counted (``snapshots_skipped`` in summary.json).
        ``wait``: write this one even if the writer is busy, and wait for it.
        """
        if self._writer is not None and self._writer.is_alive():
            if not wait:
                self.snapshots_skipped += 1
                return
            self._writer.join()
        job = (self.map_msg, list(self.poses), self.out_dir / "snapshots" / name, f"scan {len(self.poses)}")
        self._writer = threading.Thread(target=self._write_snapshot, args=job, daemon=True)
        self._writer.start()
        if wait:
            self._writer.join()
        if self._writer_error is not None:
            raise self._writer_error

    def _write_snapshot(self, map_msg, poses: list, path: Path, title: str) -> None:
        from .ros import convert
        try:
            occ, res, origin = convert.msg_to_grid(map_msg)
            traj = np.array(poses)[:, :2] if poses else np.zeros((0, 2))
            render_snapshot(occ, res, origin, traj, path, pose=poses[-1] if poses else None, title=title)
            self.snapshots_written += 1
        except Exception as exc:  # surfaced by the next snapshot() on the executor thread
            self._writer_error = exc

    def print_progress(self, final: bool = False) -> None:
        now = time.monotonic()
        tty = sys.stderr.isatty()
        if not self.progress or (not final and now - self._last_print < (0.5 if tty else 10.0)):
            return
        self._last_print = now
        k, n = len(self.poses), max(self.scans_total, 1)
        wall = now - self.t0
        rtf = (self.bag_duration_s * k / n) / wall if wall > 0 else 0.0
        eta = wall * (n - k) / k if k else float("nan")
        line = f"[pf-slam] scans {k}/{n}  RTF {rtf:5.1f}x  ETA {eta:5.0f} s"
        sys.stderr.write(f"\r{line} " if tty else line + "\n")
        if final and tty:
            sys.stderr.write("\n")
        sys.stderr.flush()


class ResultRecorder:
    """Records the run's outputs into ``OUT/result.mcap`` (rosbags' MCAP writer), so a user opens
    the run in Foxglove Studio (or ``ros2 bag play``) and scrubs through it.

    Subscribes raw (the CDR bytes go to the file as received: no message objects per scan at the
    car's 100 Hz): the scan topic, pose, path, /tf, /tf_static, map (at most one per
    ``map_every_s`` of bag time, always the final one) and the texture image. Log times are the
    messages' header stamps (bag time). It announces itself on pf_slam/ready once its streams
    are matched, so the replay waits for it and nothing is missed.
    """

    NAME = "pf_slam_result_recorder"

    def __init__(self, node, path: Path, scan_topic: str, map_every_s: float, texture: bool = False,
                 pose_feed: "_Recorder | None" = None) -> None:
        """``pose_feed``: take /pose from that recorder's subscription instead of a second one."""
        from rclpy.qos import QoSProfile

        from .io.bag import open_writer
        from .nodes.common import announce_when_matched
        from .ros import qos, topics
        self.path = path
        self._bag_dir = path.with_suffix(".bag_tmp")
        if self._bag_dir.exists():
            shutil.rmtree(self._bag_dir)
        self._cm = open_writer(self._bag_dir)
        self.bag = self._cm.__enter__()
        self.map_every_ns = int(map_every_s * 1e9)
        self.last_map_ns: int | None = None
        self.last_stamp = 0
        # topic, type, QoS, matched publishers to wait for (volatile topics only)
        streams: list[tuple[str, str, QoSProfile, int]] = [
            (scan_topic, "sensor_msgs/msg/LaserScan", qos.pipeline(), 1),
            ("/" + topics.POSE, "geometry_msgs/msg/PoseStamped", qos.pipeline(), 1),
            ("/" + topics.PATH, "nav_msgs/msg/Path", qos.outputs(10), 1),
            (topics.TF, "tf2_msgs/msg/TFMessage", qos.outputs(10000), 2),  # mapper + predictor or the bag
            (topics.TF_STATIC, "tf2_msgs/msg/TFMessage", qos.latched(10), 0),
            ("/" + topics.MAP, "nav_msgs/msg/OccupancyGrid", qos.latched(), 0)]
        if texture:
            from .nodes.texture import TEXTURE
            streams.append(("/" + TEXTURE, "sensor_msgs/msg/Image", qos.latched(), 0))
        needs = []
        for topic, msgtype, profile, wait in streams:
            self.bag.add_connection(topic, msgtype, latched=profile.durability == qos.latched().durability)
            cb = self._on_map if topic == "/" + topics.MAP else self._writer_for(topic, msgtype)
            if topic == "/" + topics.POSE and pose_feed is not None:
                pose_feed.pose_listeners.append(cb)
                needs.append((pose_feed.pose_subscription, wait))
                continue
            needs.append((node.create_subscription(_message_class(msgtype), topic, cb, profile, raw=True), wait))
        announce_when_matched(node, needs, name=self.NAME)

    def _writer_for(self, topic: str, msgtype: str):
        from .ros import convert
        stamp_of = cdr.tf_message_stamp if msgtype == "tf2_msgs/msg/TFMessage" else convert.stamp_ns_from_cdr

        def write(raw: bytes) -> None:
            stamp = stamp_of(raw)
            if stamp is not None:
                self.last_stamp = stamp
            self.bag.write_raw(topic, self.last_stamp if stamp is None else stamp, raw)
        return write

    def _on_map(self, raw: bytes) -> None:
        """A map at most every map_every_ns of bag time (a car map is megabytes); the final one
        is written by finish()."""
        from .ros import convert
        stamp = convert.stamp_ns_from_cdr(raw)
        if self.last_map_ns is None or stamp - self.last_map_ns >= self.map_every_ns:
            self.bag.write_raw("/map", stamp, raw)
            self.last_map_ns = stamp

    @property
    def counts(self) -> dict[str, int]:
        return self.bag.counts

    def finish(self, final_map=None) -> None:
        """Write the final map (if not yet in the file), close, and leave a single result.mcap."""
        if final_map is not None:
            from rclpy.serialization import serialize_message
            stamp = stamp_ns_of(final_map)
            if self.last_map_ns != stamp:
                self.bag.write_raw("/map", stamp, serialize_message(final_map))
                self.last_map_ns = stamp
        self.close()

    def close(self) -> None:
        if self._cm is None:
            return
        self._cm.__exit__(None, None, None)
        self._cm = None
        (mcap,) = self._bag_dir.glob("*.mcap")
        mcap.replace(self.path)
        shutil.rmtree(self._bag_dir)


def _message_class(msgtype: str):
    from .nodes.bag_replay import message_class
    return message_class(msgtype)


def _drain_result(ex, result: ResultRecorder, poses: int, timeout_s: float = 5.0) -> None:
    """Spin until the result recorder has every pose the run's recorder has (both subscribe)."""
    deadline = time.monotonic() + timeout_s
    while result.counts.get("/pose", 0) < poses and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.05)


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

    from .nodes.bag_replay import BagReplay
    from .nodes.correlator import Correlator
    from .nodes.mapper import Mapper
    from .nodes.predictor import Predictor
    if name == "texture":
        from .nodes.texture import TextureNode as cls
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


def run(bag: str, out_dir: str | os.PathLike, params_file: str | None = None, rate: str = "max",
        processes: str = "single", overrides: dict[str, dict[str, Any]] | None = None,
        snapshot_every: int = 200, progress: bool = True, idle_timeout_s: float = 60.0,
        drain_timeout_s: float = 5.0,
        domain_id: int | None = None, executor: str = "events", texture: bool = True,
        texture_timeout_s: float = 120.0, record: bool = True,
        record_map_every_s: float | None = None, input_topics: dict[str, str] | None = None,
        profile: str | None = None) -> RunResult:
    """Replay `bag` through the graph and write the outputs into `out_dir`; returns the summary.

    `record`: also write result.mcap (ResultRecorder), with a map every `record_map_every_s`
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
    import rclpy
    from .profiles import Profile, ProfileError, choose_profile

    if processes not in ("single", "multi"):
        raise RunError(f"--processes must be 'single' or 'multi', got {processes!r}")
    info = bag_info(bag)
    file_layer = load_params(params_file) if params_file else {}
    inputs = select_inputs(bag, info, {**params_topics(file_layer), **(input_topics or {})})
    texture = (texture and "stereo_right" in inputs
               and info["topics"].get(inputs.get("stereo_left", ""), (None, 0))[1] > 0)  # images, not just the topic
    node_names = NODE_NAMES + (("texture",) if texture else ())
    user = [file_layer] + ([overrides] if overrides else [])
    user_mapper = node_params(user, "mapper")
    mount = lidar_mount(bag, info, inputs, base_frame=user_mapper.get("base_frame"),
                        odom_frame=str(user_mapper.get("odom_frame", "odom")))
    stamps = inspect_stamps(bag, inputs)
    try:
        if params_file and profile in (None, "", "auto"):
            # a parameter file is the whole tuning, as before profiles (its results do not
            # change); --profile NAME layers one under it
            prof = Profile("none", f"--params {params_file} is the whole tuning; --profile NAME layers one under it",
                           None)
        else:
            prof = choose_profile(info.get("custom_data", {}), inputs, mount.planar,
                                  tuple(math.degrees(v) for v in mount.rpy), stamps.get("scan_range_max"), profile)
    except ProfileError as e:
        raise RunError(str(e)) from None
    prof_layer = load_params(prof.file) if prof.file else {}
    params_topics(prof_layer)  # a profile names no topics (the bag's are chosen above)
    detected = detect_inputs(bag, info, inputs, mount=mount, stamps=stamps)
    mount_text, mount_notes = _mount_report(mount, detected, user, node_names)
    # the profile tunes; what the bag says about itself (odometry source, pairing, gyro format,
    # wheels, mount) wins over it; the user's file and flags win over both
    layers = ([prof_layer] if prof_layer else []) + [detected]
    if file_layer:
        layers.append(file_layer)
    layers.append({"bag_replay": {"bag": str(bag), "rate": str(rate)},
                   "correlator": {"expected_observers": 1},  # the recorder below
                   "predictor": {"expected_observers": 1},
                   "texture": {"expected_observers": 1}})
    layers[-1]["bag_replay"]["wait_for"] = (["predictor", "correlator", "mapper"] + (["texture"] if texture else [])
                                            + ([ResultRecorder.NAME] if record else []))
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
    checks = _check_stamps_and_pairing(str(bag), stamps, per_node, params_file)
    if str(per_node["bag_replay"].get("rate", "max")) == "max":
        # arrival times say nothing about the clocks at --rate max (the bag's stamps were checked
        # before the run: inspect_stamps)
        per_node["predictor"].setdefault("stamp_offset_s", 0.0)
    # isolated on a free domain of its own unless `domain_id` / ROS_DOMAIN_ID names one
    # (ros/domain.py); chosen before --out is created: a bad ROS_DOMAIN_ID writes nothing
    domain_scope = contextlib.ExitStack()
    dom = domain_scope.enter_context(run_domain(domain_id, single_participant=processes == "single"))
    out = Path(out_dir)
    try:
        out_dir_ = _OutDir(out)
    except BaseException:
        domain_scope.close()
        raise
    scans_total = info["topics"][inputs["scan"]][1]
    remaps = topic_remaps(inputs)
    if progress:
        print(prof.line() + (f"; --params {params_file} on top" if params_file and prof.file else ""), file=sys.stderr)
        print(input_report(str(bag), info, inputs, per_node["predictor"]) + f"\n  {mount_text}", file=sys.stderr)
    for note in mount_notes:
        print(f"[pf-slam] warning: {note}", file=sys.stderr)
    for line in checks["warnings"]:  # once, with the numbers, also without progress output
        print(f"[pf-slam] warning: {line}", file=sys.stderr)
    bag_duration_s = info["duration_ns"] / 1e9
    if progress:
        print(dom.describe(), file=sys.stderr)

    ctx = None
    children: dict[str, subprocess.Popen] = {}
    stop_signal: list[str] = []  # set by SIGINT / SIGTERM while the graph runs
    result: ResultRecorder | None = None
    nodes = []  # every node of this process, destroyed at the end: a node left alive keeps its
    ex = None   # DDS readers matched by later runs on the same domain (ghost subscribers)
    t_start = time.monotonic()
    started = [False]  # the graph is up (its nodes built): from then on a failure keeps outputs
    early: list[str] = []  # why the graph failed to start (--out is then removed)
    try:
        ctx, rec_node = init_context(dom, "pf_slam_recorder")
        nodes.append(rec_node)
        ex = make_executor(executor, ctx)
        ex.add_node(rec_node)
        rec = _Recorder(rec_node, out, scans_total, bag_duration_s, snapshot_every, progress, texture)
        if record:
            result = ResultRecorder(rec_node, out / "result.mcap", inputs["scan"],
                                    record_map_every_s if record_map_every_s is not None else bag_duration_s / 20,
                                    texture, pose_feed=rec)
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
                return (m is not None and stamp_ns_of(m) == rec.stamps[-1]
                        and rec.node_status.get("predictor", {}).get("final", False))
            # paced replays (--rate N) may lose scans under load: once the bag is out and the
            # pipeline has been idle for drain_timeout_s, finish and report them as dropped
            return (rec.replay_counts is not None and m is not None
                    and time.monotonic() - state["last_progress"] > drain_timeout_s)

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
                        early.append(f"node {name} {_exit_text(c.returncode)} before the first scan: "
                                     f"{_last_line(out / 'logs' / f'{name}.log')}")
                    outcome.set_result(f"node {name} {_exit_text(c.returncode)}; log: {out / 'logs' / name}.log")
                    return
            if time.monotonic() - state["last_progress"] > idle_timeout_s:
                outcome.set_result(f"no progress for {idle_timeout_s:.0f} s: "
                                   f"{len(rec.poses)}/{scans_total} scans processed")
            elif finished():
                slam_done.setdefault("t", time.monotonic())
                # the texture node finishes on its own after the last pair (it may skip pairs
                # under load, never holds the SLAM nodes back); wait for its final texture
                if (not texture or (rec.texture_status or {}).get("final")
                        or time.monotonic() - slam_done["t"] > texture_timeout_s):
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

    extra = _write_outputs(out, rec, texture, texture_out)
    covered_s = bag_duration_s  # a stopped run: the real-time factor of the part it processed
    if stopped_by is not None:
        covered_s = (rec.stamps[-1] - info["start_ns"]) / 1e9 if rec.stamps else 0.0
    scans_published = (rec.replay_counts or {}).get(inputs["scan"])  # None: the replay did not finish
    peak = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
               resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss) / 1024.0
    summary = {
        "bag": str(bag),
        "bag_duration_s": round(bag_duration_s, 3),
        "wall_time_s": round(wall, 3),
        "real_time_factor": round(covered_s / wall, 2) if wall > 0 else None,
        "scans_in_bag": scans_total,
        "scans_published": scans_published,
        "scans_processed": len(rec.poses),
        "scans_dropped": None if scans_published is None else int(scans_published) - len(rec.poses),
        "scans_corrected": rec.updates,
        "particles": int(per_node["predictor"].get("filter.num_particles", _default_particles())),
        "processes": processes,
        "rate": rate,
        "executor": executor if processes == "single" else "single (per process)",
        "peak_rss_mb": round(peak, 1),
        "snapshots_written": rec.snapshots_written,
        "snapshots_skipped": rec.snapshots_skipped,
        "faults": {**(f := rec.faults()), "timestamps_fixed": len(checks["timestamps"]),
                   "odom_sync_fallback": f.get("odom_sync_fallback", 0) + int("requested" in checks["odom_sync"])},
        "odom_sync": checks["odom_sync"],
        **({"timestamps": checks["timestamps"]} if checks["timestamps"] else {}),
        **({"gyro": gyro} if (gyro := rec.node_status.get("predictor", {}).get("gyro")) else {}),
        "complete": stopped_by is None,
        **({} if stopped_by is None else {"stopped_by": stopped_by}),
        **extra,
    }
    if stage_split is not None:
        summary["stage_ms_per_scan"] = stage_split
    summary["inputs"] = inputs
    summary["profile"] = prof.summary()
    summary["lidar_mount"] = {"used": mount_text, "warnings": mount_notes}
    summary["ros_domain"] = dom.summary()
    if result is not None:
        summary["result_mcap"] = {"file": result.path.name, "messages": dict(result.counts)}
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return RunResult(summary, rec.stamps, rec.poses)


def _stage_split(nodes, wall_s: float, scans: int) -> dict[str, float]:
    """Wall ms per processed scan in each core stage of the single-process graph (the stages'
    own clocks) and the rest ("messaging": (de)serialisation, odometry parsing, executor and
    recorder). The texture node works on its own thread, in parallel: not part of this split
    (its ms per frame is in the texture summary)."""
    from .core.stages import stage_seconds
    seconds = stage_seconds(*[n.stage for n in nodes if hasattr(n, "stage")])[0]
    seconds["messaging"] = wall_s - sum(seconds.values())
    return {k: round(1e3 * v / max(scans, 1), 3) for k, v in seconds.items()}


def _write_outputs(out: Path, rec: _Recorder, texture: bool, texture_out) -> dict:
    """map (if one arrived), trajectory (the scans posed so far), final snapshot and texture;
    returns the summary entries they add. Also what a stopped run leaves behind."""
    from .ros import convert
    write_tum(out / "trajectory.tum", np.array(rec.stamps, dtype=np.int64) / 1e9,
              np.array(rec.poses).reshape(-1, 3))
    if rec.map_msg is None:
        return {"map": None}
    occ, res, origin = convert.msg_to_grid(rec.map_msg)
    write_map(out, occ, res, origin)
    rec.snapshot("final.png", wait=True)
    return {"texture": _write_texture(out, rec, texture_out, occ, res, origin)} if texture else {}


@contextlib.contextmanager
def _catch_stop_signals(stop: list[str]):
    """While the graph spins: SIGINT / SIGTERM append their name to `stop` (the run's check
    timer then ends it and the outputs so far are written) instead of killing the process.
    Only the main thread can set handlers; elsewhere the defaults stay."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {sig: signal.signal(getattr(signal, sig), lambda num, _frame: stop.append(signal.Signals(num).name))
           for sig in STOP_SIGNALS}
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


def _write_texture(out: Path, rec: _Recorder, rendered, occ: np.ndarray, res: float,
                   origin) -> dict:
    """texture.png (+ texture_overlay.png with the occupancy when the geometries agree) and the
    texture node's counters for summary.json."""
    from .io.texture_files import write_texture_pngs
    from .nodes.texture import image_array
    rgb = covered = None
    same_geometry = False
    if rendered is not None:  # one process: rendered here in the final /map geometry
        rgb, covered, _ = rendered
        same_geometry = True
    elif rec.texture_msg is not None:  # one process per node: the node's last texture
        rgb = np.array(image_array(rec.texture_msg))
        covered = rgb.any(axis=2)
        m = rec.texture_meta
        same_geometry = (m is not None and rgb.shape[:2] == occ.shape
                         and (int(m.height), int(m.width)) == occ.shape
                         and abs(m.resolution - res) < 1e-9
                         and abs(m.origin.position.x - origin[0]) < 1e-6
                         and abs(m.origin.position.y - origin[1]) < 1e-6)
    files: list[str] = []
    if rgb is not None:
        files = [p.name for p in write_texture_pngs(out, rgb, covered, occ if same_geometry else None)]
    status = dict(rec.texture_status or {})
    status.pop("final", None)
    status["files"] = files
    status["cells_coloured"] = int(np.count_nonzero(covered)) if covered is not None else 0
    return status


def _default_particles() -> int:
    from .core.config import FilterConfig
    return FilterConfig().num_particles


def _spawn(per_node: dict[str, dict[str, Any]], dom: RosDomain, out: Path,
           remaps: dict[str, str] | None = None) -> dict[str, subprocess.Popen]:
    """Start one process per node, each with its own parameter file, in their own session: a
    Ctrl-C in the terminal reaches only this process, which stops them in order. They also
    die with it (PF_SLAM_PARENT_PID, see nodes.common.run_node), so none is left orphaned.
    They run on the run's domain `dom` (RosDomain.child_env) and inherit its lock, so an
    isolated domain stays held until the last of them is gone."""
    logs = out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    env = dom.child_env()
    env["PF_SLAM_PARENT_PID"] = str(os.getpid())
    keep = () if dom.lock_fd is None else (dom.lock_fd,)
    procs = {}
    for name in per_node:  # parameter files next to the logs: what each process ran with
        pfile = logs / f"{name}.params.yaml"
        pfile.write_text(yaml.safe_dump({name: {"ros__parameters": unflatten(per_node[name])}}))
        with open(logs / f"{name}.log", "w") as log:
            procs[name] = subprocess.Popen(
                [sys.executable, "-m", f"pf_slam_nodes.nodes.{name}", "--ros-args", "--params-file", str(pfile)]
                + (_remap_args(remaps) or [])[1:],
                env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True, pass_fds=keep)
    return procs


def run_cli(args: Any, log: Callable[[str], None] = print) -> int:
    res = run(args.bag, args.out, params_file=args.params, rate=args.rate, processes=args.processes,
              overrides=_cli_overrides(args), snapshot_every=args.snapshot_every, executor=args.executor,
              texture=not getattr(args, "no_texture", False), record=not getattr(args, "no_record", False),
              record_map_every_s=getattr(args, "record_map_every", None), domain_id=getattr(args, "domain", None),
              input_topics={role: getattr(args, f"{role}_topic", None) for role in INPUT_TYPES},
              profile=getattr(args, "profile", None))
    s = res.summary
    dropped = "?" if s["scans_dropped"] is None else s["scans_dropped"]
    log(f"{s['scans_processed']} scans ({s['scans_corrected']} corrected), {dropped} dropped, "
        f"wall {s['wall_time_s']:.1f} s, RTF {s['real_time_factor']}x; outputs in {args.out}")
    if s["scans_dropped"]:
        log(f"warning: {s['scans_dropped']} of {s['scans_published']} scans published were dropped: the graph "
            f"fell behind --rate {s['rate']} (--rate max never drops)")
    if any(s["faults"].values()):
        log("input faults (skipped or clamped, the run went on): "
            + ", ".join(f"{k} {n}" for k, n in s["faults"].items() if n) + "; see the node logs")
    if "texture" in s:
        t = s["texture"]
        log(f"texture: {t.get('frames_processed')} of {t.get('frames_received')} stereo pairs used "
            f"({t.get('frames_skipped')} skipped under load, {t.get('frames_dropped')} without a pose), "
            f"{t['cells_coloured']} cells coloured; {', '.join(t['files']) or 'no image'}")
    if not s["complete"]:
        log(f"run incomplete: stopped by {s['stopped_by']}; the outputs hold the scans processed until then")
        return STOP_SIGNALS.get(s["stopped_by"], 1)
    return 0


def _cli_overrides(args: Any) -> dict[str, dict[str, Any]]:
    o: dict[str, Any] = {}
    if getattr(args, "particles", None) is not None:
        o["filter.num_particles"] = args.particles
    if getattr(args, "seed", None) is not None:
        o["filter.seed"] = args.seed
    return {"/**": o} if o else {}
