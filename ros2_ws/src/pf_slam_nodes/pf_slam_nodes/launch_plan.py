"""What launch/pf_slam.launch.py starts, as plain data (the `launch` package is not in the pip venv,
so the launch file's decisions live here, where they are unit-tested).

With `bag:=PATH` the graph replays it (bag_replay, /clock from the bag); without, it runs on live
topics (a robot, or `ros2 bag play --clock` elsewhere) and bag_replay is not started.
"""

from __future__ import annotations

import os
from typing import Any

SLAM_NODES = ("predictor", "correlator", "mapper")
ODOMETRY_SOURCES = ("", "odom", "encoders", "tf")


def _bool_arg(name: str, value: str, allowed=("auto", "true", "false")) -> str:
    v = value.strip().lower()
    if v not in allowed:
        raise ValueError(f"launch argument {name}:={value!r}: one of {', '.join(allowed)}")
    return v


def graph_nodes(
    bag: str = "",
    use_sim_time: str = "auto",
    texture: str = "false",
    odometry_source: str = "",
    publish_sensor_tf: str = "auto",
    scan_topic: str = "/scan",
    map: str = "",
    sensor_qos: str = "",
) -> dict[str, dict[str, Any]]:
    """Node name -> the parameters the launch file adds for it (on top of the parameter files), in
    start order. use_sim_time auto: not set, so each node switches to /clock at its first message
    (nodes.common.follow_clock); bag_replay, the clock's source, never gets it.
    publish_sensor_tf auto: only with a bag (a robot's TF tree has its lidar's mount already).
    Without a bag the nodes take the lidar mount from /tf_static + /tf (mount_from_tf).
    map: localization only on that saved map (map_server .yaml), as `pf-slam run --localize`.
    sensor_qos: the predictor's sensor subscriptions (reliable | best_effort; empty: the parameters')."""
    sim = _bool_arg("use_sim_time", use_sim_time)
    sensor_tf = _bool_arg("publish_sensor_tf", publish_sensor_tf)
    if odometry_source not in ODOMETRY_SOURCES:
        raise ValueError(
            f"launch argument odometry_source:={odometry_source!r}: one of odom, encoders, tf "
            "(empty: the parameter files')"
        )
    names = (
        (("bag_replay",) if bag else ())
        + SLAM_NODES
        + (("texture",) if _bool_arg("texture", texture, ("true", "false")) == "true" else ())
    )
    out: dict[str, dict[str, Any]] = {n: {} for n in names}
    for n in names:
        if n != "bag_replay" and sim != "auto":
            out[n]["use_sim_time"] = sim == "true"
    if bag:
        out["bag_replay"].update(bag=bag, scan_topic=scan_topic)
    if odometry_source:
        out["predictor"]["odometry_source"] = odometry_source
    out["mapper"]["publish_sensor_tf"] = sensor_tf == "true" or (sensor_tf == "auto" and bool(bag))
    if not bag:  # live: the lidar mount from the robot's /tf_static + /tf (nodes/mount_tf.py)
        for n in SLAM_NODES:
            out[n]["mount_from_tf"] = True
    if sensor_qos:
        out["predictor"]["sensor_qos"] = _bool_arg("sensor_qos", sensor_qos, ("reliable", "best_effort"))
    if map:
        out["correlator"]["mode"] = "localization"
        out["mapper"].update(mode="localization", map_file=os.path.abspath(map))
    return out
