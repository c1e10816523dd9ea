"""What each node of the graph declares, as a static table (no rclpy, no node started), so that
`pf-slam run` checks a parameter file and every value before it creates anything: unknown names
(with the nearest known one) and values the nodes would refuse.

The nodes declare these names themselves (``nodes.common.declare_config`` / ``param``);
``tests/ros/test_paramdoc.py`` builds every node and checks that this table says the same
(names, nodes, defaults).
"""

from __future__ import annotations

import dataclasses
import difflib
import re
from typing import Any

from ..core import config as cfg

#: Dotted parameter prefix -> core config class (kiss-icp style: `grid.resolution_m`); the
#: texture node's section is section_class's (its config lives with OpenCV's code)
CONFIG_SECTIONS: dict[str, type] = {
    "filter": cfg.FilterConfig,
    "motion": cfg.OdometryMotionConfig,
    "diff_drive": cfg.DiffDriveConfig,
    "wheels": cfg.WheelsConfig,
    "grid": cfg.GridConfig,
    "correlation": cfg.CorrelationConfig,
    "resample": cfg.ResampleConfig,
    "laser": cfg.LaserConfig,
    "localization": cfg.LocalizationConfig,
    "loops": cfg.LoopClosureConfig,
}

#: Config sections each node declares (``<section>.<field>`` for every field of the class).
NODE_SECTIONS: dict[str, tuple[str, ...]] = {
    "bag_replay": (),
    "predictor": ("filter", "motion", "wheels", "laser"),  # wheels: with odometry_source encoders only
    "correlator": ("filter", "grid", "correlation", "resample", "laser", "localization"),
    "mapper": ("filter", "grid", "laser", "loops"),
    "texture": ("texture",),
}

_FRAMES = {"map_frame": "map", "odom_frame": "odom", "base_frame": "base_link"}
#: Plain (non-config) parameters each node declares, with their defaults.
NODE_PLAIN: dict[str, dict[str, Any]] = {
    "bag_replay": {
        "bag": "",
        "rate": "max",
        "max_in_flight": 100,
        "scan_topic": "/scan",
        "image_topic": "",
        "max_pairs_in_flight": 1,
        "clock_period_s": 0.01,
        "wait_for": ["predictor", "correlator", "mapper"],
        "restamp": "",
        "start_delay_s": 0.0,
    },
    "predictor": {
        "map_frame": "map",
        "odometry_source": "odom",
        "odom_sync": "interpolate",
        "time_gap_s": 60.0,
        "expected_observers": 0,
        "fog_format": "none",
        "odom_frame": "odom",
        "base_frame": "base_link",
        "publish_odom_tf": True,
        "odom_wait_scans": 50,
        "stamp_offset_s": 2.0,
        "mount_from_tf": False,
        "mount_wait_s": 5.0,
        "sensor_qos": "reliable",
        "scan_queue_depth": 1000,
    },
    "correlator": {
        "map_frame": "map",
        "expected_observers": 0,
        "mode": "slam",
        "mount_from_tf": False,
        "worker": "process",
    },
    "mapper": {
        **_FRAMES,
        "occupied_thresh": 0.65,
        "free_thresh": 0.25,
        "map_publish_period_s": 1.0,
        "publish_sensor_tf": True,
        "mode": "slam",
        "map_file": "",
        "mount_from_tf": False,
        "worker": "process",
    },
    "texture": {
        "map_frame": "map",
        "base_frame": "base_link",
        "publish_period_s": 1.0,
        "calibration_dir": "",
        "camera_extrinsic": [0.0] * 12,
        "queue_depth": 1,
        "max_pending_pairs": 10,
        "final_idle_s": 2.0,
        "await_trajectory": False,
        "trajectory_timeout_s": 60.0,
        "worker_nice": 10,
        "worker": "process",
        "pose_buffer_size": 3000,
        "left_topic": "/stereo/left/image_raw",
        "right_topic": "/stereo/right/image_raw",
        "left_info_topic": "/stereo/left/camera_info",
        "right_info_topic": "/stereo/right/camera_info",
        "use_map_metadata": True,
        "expected_observers": 0,
        "camera": "stereo",
        "rgb_topic": "/kinect/rgb/image_raw",
        "depth_topic": "/kinect/depth/image_raw",
        "rgb_info_topic": "/kinect/rgb/camera_info",
        "depth_info_topic": "/kinect/depth/camera_info",
        "depth_pair_tol_s": 0.05,
        "floor_height_m": 0.0,
    },
}

#: Keys of a parameter file's '/**' section that no node declares: `pf-slam run` reads them.
RUN_KEYS_PREFIXES = ("topics.",)


def section_class(section: str) -> type:
    """The config dataclass of a parameter section ('filter' -> FilterConfig)."""
    if section == "texture":
        from ..core.texture import TextureConfig

        return TextureConfig
    return CONFIG_SECTIONS[section]


def _field_default(f: dataclasses.Field) -> Any:
    return f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]


def declared(node: str) -> dict[str, Any]:
    """name -> default of every parameter `node` declares (config tuples as lists, as declared)."""
    out: dict[str, Any] = {}
    for section in NODE_SECTIONS[node]:
        for f in dataclasses.fields(section_class(section)):
            d = _field_default(f)
            out[f"{section}.{f.name}"] = list(d) if isinstance(d, tuple) else d
    out.update(NODE_PLAIN[node])
    return out


def declared_by() -> dict[str, list[str]]:
    """name -> the nodes that declare it."""
    out: dict[str, list[str]] = {}
    for node in NODE_SECTIONS:
        for name in declared(node):
            out.setdefault(name, []).append(node)
    return out


def nearest(name: str, known) -> str | None:
    """The known name most like `name` (whole dotted name or its last part: `num_partcles` ->
    `filter.num_particles`); None if nothing is alike."""
    known = sorted(known)
    if not known:
        return None
    leaf = name.rsplit(".", 1)[-1]

    def score(k: str) -> float:
        whole = difflib.SequenceMatcher(None, name, k).ratio()
        part = difflib.SequenceMatcher(None, leaf, k.rsplit(".", 1)[-1]).ratio()
        return max(whole, 0.95 * part)

    best = max(known, key=score)
    return best if score(best) >= 0.5 else None


def as_default_type(default: Any, value: Any) -> Any:
    """An int given where the default is a float becomes a float (YAML `100` for `100.0`)."""
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _ros_value_ok(v: Any) -> bool:
    """Whether rclpy can carry `v` as a parameter value (bool, int, float, str, or a list of one
    of them; not None, not a mixed list)."""
    if isinstance(v, (bool, int, float, str)):
        return True
    if isinstance(v, (list, tuple)) and v:
        kinds = {bool if isinstance(x, bool) else (float if isinstance(x, (int, float)) else type(x)) for x in v}
        return len(kinds) == 1 and kinds <= {bool, float, str}
    return isinstance(v, (list, tuple))


def check_values(node: str, params: dict[str, Any]) -> tuple[str, str] | None:
    """The first value of `params` (a node's merged parameters) that `node` would refuse at
    start-up: (parameter name, what is wrong), or None. Checks what the node checks when it is
    built: every config section (its dataclass validates itself) and the plain parameters' types.
    Names the node does not declare are not its concern here (a '/**' value for other nodes)."""
    for name, v in params.items():
        if not _ros_value_ok(v):
            return name, f"{v!r} is not a parameter value (a bool, int, float, string or a list of one kind)"
    for section in NODE_SECTIONS[node]:
        cls = section_class(section)
        values: dict[str, Any] = {}
        given: list[str] = []
        for f in dataclasses.fields(cls):
            d = _field_default(f)
            name = f"{section}.{f.name}"
            if name not in params:
                continue
            v = params[name]
            given.append(name)
            if isinstance(d, tuple):
                if not isinstance(v, (list, tuple)):
                    return name, f"must be a list, got {v!r}"
                v = tuple(as_default_type(0.0, x) for x in v)
            values[f.name] = as_default_type(d, v)
        try:
            cls.from_dict(values)
        except (ValueError, TypeError) as e:
            msg = str(e)
            leaves = [(n, n.rsplit(".", 1)[1]) for n in given]
            culprit = next(
                (n for n, leaf in leaves if msg.startswith(leaf + " ")),
                next((n for n, leaf in leaves if re.search(rf"\b{leaf}\b", msg)), f"{section}.*"),
            )
            return culprit, msg
    for name, d in NODE_PLAIN[node].items():
        if name in params and d is not None:
            v = as_default_type(d, params[name])
            if isinstance(d, list):
                ok = isinstance(v, (list, tuple))
            else:
                ok = type(v) is type(d)
            if not ok:
                return name, f"must be {type(d).__name__}, got {params[name]!r}"
    return None
