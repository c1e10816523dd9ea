"""Bag inspection, bring your own bag: which topics feed the graph, their header stamps against
the record times, and the parameters the bag implies."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..io.bag import BagError, bag_info, check_run_inputs, deserialize, stamp_ns_of
from .common import DEFAULT_INPUTS, INPUT_TYPES, RunError
from .mount import LidarMount, lidar_mount
from .sample import BagSample, sample_bag

ROLE_WORDS = {
    "scan": "lidar (LaserScan)",
    "odom": "odometry (Odometry)",
    "encoders": "wheel encoders (JointState)",
    "fog": "gyro yaw (fog)",
    "imu": "gyro yaw (Imu angular_velocity.z)",
    "stereo_left": "stereo left (texture)",
    "stereo_right": "stereo right (texture)",
    "rgbd_rgb": "RGB-D colour (texture)",
    "rgbd_depth": "RGB-D depth (texture)",
}


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
        raise _no_input(
            bag,
            info,
            "needs nav_msgs/msg/Odometry (--odom-topic) or sensor_msgs/msg/JointState "
            f"wheel angles (--encoders-topic) for the motion model; found: {found}",
        )
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


def topic_remaps(inputs: dict[str, str]) -> dict[str, str]:
    """The nodes' relative input names remapped to the bag's topics (as `ros2 launch ... scan_topic:=`)."""
    return {
        role: t for role, t in inputs.items() if role in ("scan", "odom", "encoders", "fog", "imu") and t != f"/{role}"
    }


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


def inspect_stamps(bag: str | BagSample, inputs: dict[str, str], max_scans: int = 200) -> dict[str, Any]:
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
    "scan_range_max" (the first scan's)}, the pairing counted on the stamps as they will be replayed.
    `bag`: a path, or the run's one-pass BagSample (runner/sample.py)."""
    scan_topic = inputs["scan"]
    odom_topic = inputs["odom" if "odom" in inputs else "encoders"]
    sample = bag if isinstance(bag, BagSample) else sample_bag(bag, bag_info(bag), inputs, max_scans)
    rows: dict[str, list[tuple[int, int]]] = {scan_topic: [], odom_topic: []}
    scan_frame = None
    scan_range_max = None
    for t in rows:
        for msgtype, rec, raw in sample.of(t):
            try:
                msg = deserialize(raw, msgtype)
            except Exception:  # an unreadable message: the predictor counts it at run time
                continue
            rows[t].append((stamp_ns_of(msg), rec))
            if t == scan_topic:
                scan_frame = msg.header.frame_id
                if scan_range_max is None:
                    scan_range_max = float(msg.range_max)
    if sample.error is not None and not rows[scan_topic]:
        raise sample.error  # damaged before the first scan: nothing to run
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
            notes[topic] = (
                f"header stamps stuck: {stuck} of {steps} equal to the previous one while the "
                f"record time advances ({(rec[-1] - rec[0]) / 1e9:.1f} s); replayed with the record times"
            )
        elif jumps >= 0.05 * steps:
            restamp[topic] = "record"
            notes[topic] = (
                f"header stamps do not follow the record time: {jumps} of {steps} steps jump by "
                f"more than {STAMP_JUMP_NS / 1e9:.0f} s against it; replayed with the record times"
            )

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
                + (
                    "shifted onto the scans' clock"
                    if fix
                    else "NOT corrected (a gyro stream is used); the pairing is wrong by that much"
                )
            )
            if fix:
                restamp[odom_topic] = int(off) if restamp.get(odom_topic) != "record" else "record"

    scans = replayed(scan_topic)
    odom = set(replayed(odom_topic).tolist())
    paired = int(sum(int(s) in odom for s in scans))
    return {
        "restamp": restamp,
        "notes": notes,
        "pairing": (paired, len(scans)),
        "scan_frame": scan_frame,
        "scan_range_max": scan_range_max,
    }


def restamp_param(restamp: dict[str, Any]) -> str:
    """{'/scan': 'record', '/odom': 3000000000} -> '/scan=record,/odom=3000000000' (bag_replay's `restamp`)."""
    return ",".join(f"{t}={v}" for t, v in sorted(restamp.items()))


def detect_inputs(
    bag: str,
    info: dict,
    inputs: dict[str, str] | None = None,
    mount: LidarMount | None = None,
    stamps: dict[str, Any] | None = None,
) -> dict[str, dict[str, Any]]:
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
            predictor.update(
                {
                    "wheels.left_diameter_m": d,
                    "wheels.right_diameter_m": d,
                    "wheels.base_m": 2.0 * float(custom["pf_slam.half_axle_m"]),
                }
            )
        elif "pf_slam.wheel_base_m" in custom:  # written by `convert kaist`
            predictor.update(
                {
                    "wheels.left_diameter_m": float(custom["pf_slam.left_wheel_diameter_m"]),
                    "wheels.right_diameter_m": float(custom["pf_slam.right_wheel_diameter_m"]),
                    "wheels.base_m": float(custom["pf_slam.wheel_base_m"]),
                }
            )
        if "fog" in inputs:
            predictor["fog_format"] = {
                "pf_slam_interfaces/msg/FogBatch": "batch",
                "geometry_msgs/msg/Vector3Stamped": "vector3",
            }[topics[inputs["fog"]][0]]
        elif "imu" in inputs:
            predictor["fog_format"] = "imu"
    out: dict[str, dict[str, Any]] = {"predictor": predictor, "bag_replay": {"scan_topic": scan_topic}}
    if "stereo_left" in inputs and "stereo_right" in inputs:
        left, right = inputs["stereo_left"], inputs["stereo_right"]
        out["texture"] = {
            "left_topic": left,
            "right_topic": right,
            "left_info_topic": left.rsplit("/", 1)[0] + "/camera_info",
            "right_info_topic": right.rsplit("/", 1)[0] + "/camera_info",
        }
    elif "rgbd_rgb" in inputs and "rgbd_depth" in inputs:  # an RGB-D camera: the depth mode
        rgb, depth = inputs["rgbd_rgb"], inputs["rgbd_depth"]
        out["texture"] = {
            "camera": "depth",
            "rgb_topic": rgb,
            "depth_topic": depth,
            "rgb_info_topic": rgb.rsplit("/", 1)[0] + "/camera_info",
            "depth_info_topic": depth.rsplit("/", 1)[0] + "/camera_info",
        }
    lm = mount if mount is not None else lidar_mount(bag, info, inputs, scan_frame=scan_frame)
    out["/**"] = dict(lm.params())
    if lm.base_from_tf:
        out["/**"]["base_frame"] = lm.base_frame
    for node, params in tf_inputs(topics, lm).items():
        out.setdefault(node, {}).update(params)
    return out


def _check_stamps_and_pairing(
    bag: str, stamps: dict[str, Any], per_node: dict[str, dict[str, Any]], params_file: str | None
) -> dict[str, Any]:
    """Apply inspect_stamps()'s fixes to the replay, and refuse a pairing that cannot work on
    this bag: odom_sync exact (from a parameter file or a flag) where fewer than 90 % of the
    scans checked have an odometry message with their stamp would pair nothing; interpolate is
    used instead. Returns {"warnings": [...], "odom_sync": {...}, "timestamps": {...}} for the
    run's output and summary.json."""
    warnings, timestamps = [], {}
    for topic, why in sorted(stamps["notes"].items()):
        fix = stamps["restamp"].get(topic)
        timestamps[topic] = {
            "fix": ("record time" if fix == "record" else None if fix is None else f"{fix / 1e9:+.3f} s"),
            "why": why,
        }
        warnings.append(f"{bag}: {topic}: {why}")
    if stamps["restamp"]:
        per_node["bag_replay"]["restamp"] = restamp_param(stamps["restamp"])
    pred = per_node["predictor"]
    paired, checked = stamps["pairing"]
    sync = {"used": pred.get("odom_sync", "interpolate"), "scans_checked": checked, "with_odometry_stamp": paired}
    if sync["used"] == "exact" and checked and paired < 0.9 * checked:
        where = f" (from {params_file} or a flag)" if params_file else " (from a flag)"
        warnings.append(
            f"{bag}: odom_sync exact{where} cannot work on this bag: only {paired} of the first "
            f"{checked} scans have an odometry message with their stamp (the odometry is logged "
            f"at its own times); pairing by interpolation instead. Set odom_sync: interpolate "
            f"(or leave it out: pf-slam run picks it from the bag)"
        )
        pred["odom_sync"] = "interpolate"
        sync.update(requested="exact", used="interpolate")
    return {"warnings": warnings, "odom_sync": sync, "timestamps": timestamps}


def tf_inputs(topics: dict, mount: LidarMount | None) -> dict[str, dict[str, Any]]:
    """REP-105 transforms the bag already has, so the graph does not publish them twice: its
    own /tf (odom -> base_link from the robot) turns the predictor's off, a /tf_static mount of
    the scan's frame (`mount` from /tf_static, see lidar_mount) the mapper's."""
    out: dict[str, dict[str, Any]] = {}
    if "/tf" in topics:
        out["predictor"] = {"publish_odom_tf": False}
    if mount is not None and mount.source == "/tf_static":
        out["mapper"] = {"publish_sensor_tf": False}
    return out
