"""A real building's scans rewritten as a ``ROBOTLASER1``-only CARMEN log: the shape of a log
that carries its odometry inside the laser lines (no ``ODOM`` line) and says "no return" with a
range of its own (here exactly ``no_return_m``, 50 m), as some robots' loggers do.

The scans come from a corrected-pose building (``DATA/carmen_corrected``), the odometry is
synthesised from its corrected poses with a seed (:func:`pf_slam_tools.bench.worlds.synthesise_odometry`),
so the corrected poses are the reference the run is scored against.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from pf_slam_nodes.core.geometry import compose

#: the laser lines' period (s) in the written log
PERIOD_S = 0.5
#: the first line's time (s)
START_S = 1000.0


def robot_poses(laser_poses: np.ndarray, mount_x_m: float) -> np.ndarray:
    """The robot's poses ``(K, 3)`` of a laser's, the laser ``mount_x_m`` ahead of the robot."""
    return compose(np.asarray(laser_poses, dtype=np.float64), np.array([-mount_x_m, 0.0, 0.0]))


def write_robotlaser1_log(
    path: str | os.PathLike,
    ranges: list,
    angle_min: float,
    angle_increment: float,
    odom: np.ndarray,
    no_return_m: float = 50.0,
    max_range_m: float = 81.9,
    mount_x_m: float = 0.0,
) -> np.ndarray:
    """Write one ``ROBOTLASER1`` line per scan (``ranges[k]``, beams from ``angle_min`` every
    ``angle_increment``; ``odom[k]`` the laser's odometry pose, the robot's ``mount_x_m`` behind
    it), a beam without return (``inf``, or at least ``no_return_m``) as exactly
    ``no_return_m``. Returns the lines' stamps (s)."""
    stamps = START_S + PERIOD_S * np.arange(len(ranges))
    odom = np.asarray(odom, dtype=np.float64)
    robot = robot_poses(odom, mount_x_m)
    with open(path, "w") as f:
        f.write("# ROBOTLASER1 only: odometry inside the laser lines\n")
        for r, laser, base, t in zip(ranges, odom, robot, stamps):
            r = np.asarray(r, dtype=np.float64)
            text = " ".join(f"{no_return_m:.3f}" if not v < no_return_m else f"{v:.3f}" for v in r)
            lpose, rpose = (f"{p[0]:.4f} {p[1]:.4f} {p[2]:.5f}" for p in (laser, base))
            f.write(
                f"ROBOTLASER1 0 {angle_min:.6f} {len(r) * angle_increment:.6f} {angle_increment:.6f} "
                f"{max_range_m} 0.01 0 {len(r)} {text} 0 {lpose} {rpose} 0.0 0.0 0.55 0.05 0.0 "
                f"{t:.6f} logger {t:.6f}\n"
            )
    return stamps


def building_as_robotlaser1(
    data_dir: str | os.PathLike,
    name: str,
    seed: int,
    out: str | os.PathLike,
    scans: int | None = None,
    mount_x_m: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Corrected-pose building ``name``'s first ``scans`` scans (all: None) written to ``out`` as
    a ``ROBOTLASER1``-only log with odometry synthesised with ``seed``, the laser ``mount_x_m``
    ahead of the robot. Returns the stamps (s) and the robot's corrected poses ``(K, 3)``: the
    reference."""
    from pf_slam_tools.bench.worlds import building_drive

    drive = building_drive(Path(data_dir), name, seed)
    k = len(drive.truth) if scans is None else min(int(scans), len(drive.truth))
    inc = float(drive.angles[0][1] - drive.angles[0][0])
    first = float(drive.angles[0][0])
    stamps = write_robotlaser1_log(out, drive.ranges[:k], first, inc, drive.odom[:k], mount_x_m=mount_x_m)
    return stamps, robot_poses(drive.truth[:k], mount_x_m)
