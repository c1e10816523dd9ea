"""A large simulated floor (default 300 m x 150 m): a ring corridor with pillars and alcoves,
driven along two of its sides, from one corner to the opposite one.

For the map that grows (``grid.size_*`` is only where it starts): the drive explores the whole
bounding box of the floor, far beyond a 100 m grid. Same laser, odometry model and bag layout as
:mod:`pf_slam_tools.sim.indoor` (``pf-slam simulate-indoor --world floor``); the office sample is
not touched by this module.
"""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

import numpy as np

from pf_slam_nodes.io.bag import BagError
from pf_slam_nodes.io.mapfile import write_map
from pf_slam_nodes.io.trajectory import write_tum

from . import indoor
from .indoor import (
    BASE_FRAME,
    EPOCH_NS,
    LASER_FRAME,
    RANGE_MAX_M,
    SCAN_RATE_HZ,
    SIM_RATE_HZ,
    IndoorWorld,
    SimResult,
    _box_corners,
    _loop_primitives,
    rasterise_world,
    simulate_odometry,
    simulate_scans,
)
from .paths import pose_on_path

__all__ = ["FLOOR_BAG_NAME", "floor_world", "plan_floor_drive", "simulate_floor"]

FLOOR_BAG_NAME = "large_floor"
CORRIDOR_M = 6.0
#: the world's features come from this seed (the floor is the same for every drive seed)
WORLD_SEED = 18


def floor_world(length_m: float = 300.0, width_m: float = 150.0, corridor_m: float = CORRIDOR_M) -> IndoorWorld:
    """Outer walls ``length_m x width_m``, an inner block ``corridor_m`` inside them (a ring
    corridor), pillars (0.6 m) and cabinets every 5-11 m along both walls of the corridor.
    Start-frame coordinates: the robot starts at ``(corridor/2, corridor/2)`` of the floor,
    heading east; the floor spans ``[-corridor/2, length - corridor/2] x [-corridor/2, ...]``."""
    rng = np.random.default_rng(WORLD_SEED)
    L, W, c = float(length_m), float(width_m), float(corridor_m)
    segs = [
        (0, 0, L, 0),
        (L, 0, L, W),
        (L, W, 0, W),
        (0, W, 0, 0),  # outer
        (c, c, L - c, c),
        (L - c, c, L - c, W - c),
        (L - c, W - c, c, W - c),
        (c, W - c, c, c),
    ]
    boxes = []
    # along each side of the ring: features on the outer wall (inside) and the inner wall
    sides = [((0, 0), (L, 0), (0, 1)), ((L, 0), (L, W), (-1, 0)), ((L, W), (0, W), (0, -1)), ((0, W), (0, 0), (1, 0))]
    for (x0, y0), (x1, y1), (nx, ny) in sides:
        length = math.hypot(x1 - x0, y1 - y0)
        ux, uy = (x1 - x0) / length, (y1 - y0) / length
        for wall_off, sign in ((0.0, 1.0), (c, -1.0)):
            s = c + rng.uniform(0, 4)
            while s < length - c:
                depth = rng.uniform(0.3, 0.8)
                size = rng.uniform(0.4, 1.6)
                d = wall_off + sign * 0.5 * depth
                boxes.append(
                    (x0 + ux * s + nx * d, y0 + uy * s + ny * d, size if ux else depth, depth if ux else size, 0.0)
                )
                s += rng.uniform(5.0, 11.0)
    b = np.array(boxes, dtype=np.float64)
    corners = _box_corners(b)
    box_segs = np.concatenate([corners, np.roll(corners, -1, axis=1)], axis=-1).reshape(-1, 4)
    shift = np.array([0.5 * c, 0.5 * c] * 2)
    segments = np.concatenate([np.array(segs, dtype=np.float64), box_segs]) - shift
    b[:, :2] -= shift[:2]
    return IndoorWorld(segments=segments, boxes=b, bounds=np.array([0.0, 0.0, L, W]) - shift)


def plan_floor_drive(
    length_m: float,
    width_m: float,
    speed_mps: float,
    rng: np.random.Generator,
    corridor_m: float = CORRIDOR_M,
    rate_hz: int = SIM_RATE_HZ,
) -> np.ndarray:
    """True poses ``(N, 3)`` at ``rate_hz``: east along the south corridor, a 2 m-radius turn,
    north along the east corridor to the far corner (centre lines, seeded +-0.3 m weave)."""
    c = corridor_m
    end = np.array([length_m - c, width_m - c])
    corners = np.array([[length_m - c, 0.0], end + np.array([0.0, 1.0])])
    pieces = _loop_primitives(corners, np.array([2.0, 0.5]), np.zeros(2))[:3]  # leg, turn, leg
    total = float(pieces[:, 4].sum())
    v = speed_mps * (1.0 + rng.uniform(-0.05, 0.05))
    n = int(total / v * rate_hz)
    t = np.arange(n) / rate_hz
    ramp = np.minimum(1.0, t / 2.0)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (ramp[1:] + ramp[:-1]) * v / rate_hz)])
    s = np.minimum(s, total - 1e-6)
    p = pose_on_path(pieces, s)
    weave = 0.3 * np.sin(2 * math.pi * s / rng.uniform(30.0, 50.0) + rng.uniform(0, 2 * math.pi))
    p[:, 0] -= np.sin(p[:, 2]) * weave * np.minimum(1.0, s / 5.0)
    p[:, 1] += np.cos(p[:, 2]) * weave * np.minimum(1.0, s / 5.0)
    p[:, 2] = np.arctan2(np.sin(p[:, 2]), np.cos(p[:, 2]))
    return p


def simulate_floor(
    out_dir: str | os.PathLike,
    seed: int = 0,
    length_m: float = 300.0,
    width_m: float = 150.0,
    speed_mps: float = 3.0,
    odom_rate_hz: int = 20,
    overwrite: bool = False,
    storage: str = "mcap",
) -> SimResult:
    """Write ``out_dir/large_floor`` (rosbag2 as the office sample's: /scan 10 Hz, /odom, /tf_static),
    ``out_dir/large_floor_ground_truth.tum`` and ``large_floor_map.pgm/.yaml`` (0.5 m)."""
    if not (length_m >= 2 * CORRIDOR_M + 10 and width_m >= 2 * CORRIDOR_M + 10):
        raise ValueError(f"the floor must be at least {2 * CORRIDOR_M + 10} m on each side")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    bag_path = out / FLOOR_BAG_NAME
    if bag_path.exists() and overwrite:
        if not (bag_path.is_dir() and (bag_path / "metadata.yaml").is_file()):
            raise BagError(f"{bag_path}: exists and is not a rosbag2 directory; not removing it")
        shutil.rmtree(bag_path)
    drive_rng, odom_rng, laser_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(3))
    world = floor_world(length_m, width_m)
    truth = plan_floor_drive(length_m, width_m, speed_mps, drive_rng)
    odom = simulate_odometry(truth, odom_rng)
    scan_step, odom_step = SIM_RATE_HZ // SCAN_RATE_HZ, SIM_RATE_HZ // odom_rate_hz
    scan_idx = np.arange(0, len(truth), scan_step)
    # ray cast against the segments near each pose only (the floor has thousands)
    seg = world.segments
    ranges = np.empty((len(scan_idx), indoor.N_BEAMS), dtype=np.float32)
    for k0 in range(0, len(scan_idx), 50):
        ks = scan_idx[k0 : k0 + 50]
        lo = truth[ks, :2].min(axis=0) - RANGE_MAX_M - 1
        hi = truth[ks, :2].max(axis=0) + RANGE_MAX_M + 1
        near = (
            (np.maximum(seg[:, 0], seg[:, 2]) >= lo[0])
            & (np.minimum(seg[:, 0], seg[:, 2]) <= hi[0])
            & (np.maximum(seg[:, 1], seg[:, 3]) >= lo[1])
            & (np.minimum(seg[:, 1], seg[:, 3]) <= hi[1])
        )
        ranges[k0 : k0 + 50] = simulate_scans(truth[ks], seg[near], laser_rng)
    stamps_ns = EPOCH_NS + np.arange(len(truth), dtype=np.int64) * (1_000_000_000 // SIM_RATE_HZ)
    n_odom = indoor.write_sim_bag(
        bag_path,
        storage,
        stamps_ns,
        odom,
        ranges,
        odom_step,
        scan_step,
        [(BASE_FRAME, LASER_FRAME, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))],
        LASER_FRAME,
        f"floor {length_m:g}x{width_m:g} m seed={int(seed)}",
    )
    gt_path = out / f"{FLOOR_BAG_NAME}_ground_truth.tum"
    write_tum(gt_path, stamps_ns[scan_idx] / 1e9, truth[scan_idx])
    occ, origin = rasterise_world(world, 0.5)
    map_yaml = write_map(out, occ, 0.5, origin, name=f"{FLOOR_BAG_NAME}_map")
    last = scan_idx[-1]
    return SimResult(
        bag_path=bag_path,
        ground_truth_path=gt_path,
        map_yaml_path=Path(map_yaml),
        seed=int(seed),
        duration_s=len(scan_idx) / SCAN_RATE_HZ,
        n_scans=len(scan_idx),
        n_odom=n_odom,
        path_length_m=float(np.hypot(*np.diff(truth[:, :2], axis=0).T).sum()),
        odom_drift_m=float(np.hypot(*(odom[last, :2] - truth[last, :2]))),
    )
