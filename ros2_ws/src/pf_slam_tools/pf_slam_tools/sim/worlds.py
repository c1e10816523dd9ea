"""Simulated buildings with ground truth for the worlds bench, as arrays (no bag written).

Three worlds, each driven on a closed loop (the drive ends where it started, so the filter must
close the loop) with the office simulator's laser (181 beams, 20 m, 0.01 m noise, 1 % dropouts)
and wheel odometry (``indoor.simulate_odometry``: 1-2 % scale error, 0.3-0.6 deg/m heading drift,
slip); the seed draws the drive's details, the odometry errors and the laser noise:

* ``office`` -- the 20 m x 15 m office of the sample bag, 120 s (two laps of its ~21 m loop).
* ``corridors`` -- 64 m x 34 m: four parallel east-west corridors (2.4 m) joined by a west and an
  east spine, the blocks between them rows of identical 4 m rooms (a door each, the same desk in
  each), driven in a serpentine through all four corridors and back down the west spine
  (~300 m at 1.5 m/s): aliasing along every corridor (doors every 4 m) and between corridors.
* ``ring`` -- the 300 m x 150 m ring-corridor floor of :mod:`.floor` driven once around
  (~880 m at 3 m/s, 3 % past the start): a long loop.
* ``maze`` -- a floor plan drawn from the seed (:mod:`.maze`: a lattice of corridors, blocks of
  rooms, closed blocks, a pillared hall), 300-600 m through it with several loops: every seed is
  another building, so nothing can be tuned to one.

Everything is in the start frame (the robot's true start pose is the origin).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import indoor
from .floor import CORRIDOR_M, floor_world
from .indoor import SCAN_RATE_HZ, SIM_RATE_HZ, IndoorWorld, _box_corners, _loop_primitives, simulate_odometry
from .paths import pose_on_path

__all__ = ["SimDrive", "WORLDS", "corridors_world", "laser_geometry", "simulate_world"]


@dataclass
class SimDrive:
    """One simulated drive sampled at the scans: ``truth``, ``odom`` ``(K, 3)``, ``ranges``
    ``(K, B)`` float32 (+inf = no return), ``angles`` ``(B,)``, ``range_max``; ``world``."""

    name: str
    seed: int
    truth: np.ndarray
    odom: np.ndarray
    ranges: np.ndarray
    angles: np.ndarray
    range_max: float
    world: IndoorWorld


def _segments_of_boxes(boxes: np.ndarray) -> np.ndarray:
    if not len(boxes):
        return np.zeros((0, 4))
    c = _box_corners(boxes)
    return np.concatenate([c, np.roll(c, -1, axis=1)], axis=-1).reshape(-1, 4)


def _hwall(y: float, x0: float, x1: float, doors: list[float], door_w) -> list[tuple]:
    """Segments along x at ``y`` from ``x0`` to ``x1`` with gaps of ``door_w`` at ``doors``
    (one width for all, or one per door)."""
    widths = [door_w] * len(doors) if np.isscalar(door_w) else list(door_w)
    out, x = [], x0
    for d, w in sorted(zip(doors, widths)):
        out.append((x, y, d - 0.5 * w, y))
        x = d + 0.5 * w
    out.append((x, y, x1, y))
    return out


#: corridors world: corridor centre lines (y), corridor width, spine width, room width, floor length
_CORR_Y = (1.2, 10.8, 20.4, 30.0)
_CORR_W = 2.4
_SPINE_W = 2.4
_ROOM_W = 4.0
_LEN = 2 * 2.4 + 14 * 4.0  # 60.8 m: 14 rooms per row
_DOOR_W = 1.0


def corridors_world() -> IndoorWorld:
    """Four parallel corridors, two spines, blocks of identical rooms (floor-plan coordinates with
    the first corridor's centre line at y = 1.2 and the west wall at x = 0; the start frame shift
    is applied by :func:`simulate_world`)."""
    h = 0.5 * _CORR_W
    y_lo, y_hi = _CORR_Y[0] - h, _CORR_Y[-1] + h
    segs: list[tuple] = [(0, y_lo, _LEN, y_lo), (_LEN, y_lo, _LEN, y_hi), (_LEN, y_hi, 0, y_hi), (0, y_hi, 0, y_lo)]
    boxes = []
    xa, xb = _SPINE_W, _LEN - _SPINE_W
    n_rooms = int((xb - xa) // _ROOM_W)
    xs = xa + _ROOM_W * np.arange(n_rooms + 1)
    xb = float(xs[-1])
    for k in range(len(_CORR_Y) - 1):
        b0, b1 = _CORR_Y[k] + h, _CORR_Y[k + 1] - h  # the block between corridor k and k+1
        mid = 0.5 * (b0 + b1)
        centres = list(0.5 * (xs[:-1] + xs[1:]))
        segs += _hwall(b0, xa, xb, centres, _DOOR_W)  # south rooms open onto corridor k
        segs += _hwall(b1, xa, xb, centres, _DOOR_W)  # north rooms onto corridor k+1
        segs.append((xa, b0, xa, b1))
        segs.append((xb, b0, xb, b1))
        segs.append((xa, mid, xb, mid))  # back walls of both rows
        for x in xs[1:-1]:
            segs.append((x, b0, x, b1))  # partitions
        for c in centres:  # the same desk in every room
            boxes.append((c + 0.9, mid - 1.2, 1.2, 0.6, 0.0))
            boxes.append((c - 0.9, mid + 1.2, 1.2, 0.6, 0.0))
    # a few pillars in the spines (the only features that are not repeated)
    boxes += [(0.35, 6.0, 0.4, 0.4, 0.0), (_LEN - 0.35, 15.6, 0.4, 0.4, 0.0), (0.35, 25.2, 0.4, 0.4, 0.0)]
    b = np.array(boxes, dtype=np.float64)
    segments = np.concatenate([np.array(segs, dtype=np.float64), _segments_of_boxes(b)])
    return IndoorWorld(segments=segments, boxes=b, bounds=np.array([0.0, y_lo, _LEN, y_hi]))


def _shift(world: IndoorWorld, dx: float, dy: float) -> IndoorWorld:
    s = np.array([dx, dy, dx, dy])
    b = world.boxes.copy()
    if len(b):
        b[:, :2] += s[:2]
    return IndoorWorld(segments=world.segments + s, boxes=b, bounds=world.bounds + s)


def _drive(pieces: np.ndarray, speed: float, laps: float, rng: np.random.Generator, weave_m: float) -> np.ndarray:
    """Poses at SIM_RATE_HZ along a closed path: ramp up, cruise at ``speed`` (seeded +-5 %,
    slow +-5 % modulation), ``laps`` times around, a seeded sideways weave."""
    total = float(pieces[:, 4].sum()) * laps
    v = speed * (1.0 + rng.uniform(-0.05, 0.05))
    period, phase = rng.uniform(20.0, 40.0), rng.uniform(0, 2 * math.pi)
    n = int(total / v * SIM_RATE_HZ * 1.02)
    t = np.arange(n) / SIM_RATE_HZ
    sp = v * np.minimum(1.0, t / 2.0) * (1.0 + 0.05 * np.sin(2 * math.pi * t / period + phase))
    s = np.concatenate([[0.0], np.cumsum(0.5 * (sp[1:] + sp[:-1]) / SIM_RATE_HZ)])
    s = s[s < total]
    p = pose_on_path(pieces, np.mod(s, pieces[:, 4].sum()))
    w_period, w_phase = rng.uniform(15.0, 30.0), rng.uniform(0, 2 * math.pi)
    weave = weave_m * np.sin(2 * math.pi * s / w_period + w_phase) * np.minimum(1.0, s / 5.0)
    p[:, 0] -= np.sin(p[:, 2]) * weave
    p[:, 1] += np.cos(p[:, 2]) * weave
    p -= p[0]  # start exactly at the origin
    p[:, 2] = np.arctan2(np.sin(p[:, 2]), np.cos(p[:, 2]))
    return p


def _scan(
    truth: np.ndarray, world: IndoorWorld, rng: np.random.Generator, range_sigma_m: float, angles, range_max: float
) -> np.ndarray:
    """Laser ranges at ``truth`` poses, ray cast against the segments near each chunk of poses."""
    seg = world.segments
    out = np.empty((len(truth), len(angles)), dtype=np.float32)
    for k0 in range(0, len(truth), 50):
        pk = truth[k0 : k0 + 50]
        lo = pk[:, :2].min(axis=0) - range_max - 1
        hi = pk[:, :2].max(axis=0) + range_max + 1
        near = (
            (np.maximum(seg[:, 0], seg[:, 2]) >= lo[0])
            & (np.minimum(seg[:, 0], seg[:, 2]) <= hi[0])
            & (np.maximum(seg[:, 1], seg[:, 3]) >= lo[1])
            & (np.minimum(seg[:, 1], seg[:, 3]) <= hi[1])
        )
        out[k0 : k0 + 50] = indoor.simulate_scans(pk, seg[near], rng, None, range_sigma_m, angles, range_max)
    return out


def _office(rng: np.random.Generator) -> tuple[IndoorWorld, np.ndarray]:
    _, truth = indoor.plan_drive(120.0, rng)
    return indoor.office_world(), truth


def _corridors(rng: np.random.Generator) -> tuple[IndoorWorld, np.ndarray]:
    e, w = _LEN - 0.5 * _SPINE_W, 0.5 * _SPINE_W
    c = _CORR_Y
    start = np.array([6.0, c[0]])
    corners = np.array([(e, c[0]), (e, c[1]), (w, c[1]), (w, c[2]), (e, c[2]), (e, c[3]), (w, c[3]), (w, c[0])])
    pieces = _loop_primitives(corners - start, np.full(len(corners), 0.8), np.zeros(2))
    return _shift(corridors_world(), -start[0], -start[1]), _drive(pieces, 1.5, 1.03, rng, 0.2)


def _ring(rng: np.random.Generator) -> tuple[IndoorWorld, np.ndarray]:
    L, W, c = 300.0, 150.0, CORRIDOR_M
    start = np.array([20.0, 0.0])  # floor_world's frame: the ring's south-west corner is (0, 0)
    corners = np.array([(L - c, 0.0), (L - c, W - c), (0.0, W - c), (0.0, 0.0)])
    pieces = _loop_primitives(corners - start, np.full(4, 2.0), np.zeros(2))
    return _shift(floor_world(L, W), -start[0], -start[1]), _drive(pieces, 3.0, 1.03, rng, 0.3)


def _maze(rng: np.random.Generator) -> tuple[IndoorWorld, np.ndarray]:
    from .maze import maze_layout, maze_route

    world, xs, ys = maze_layout(rng)
    nodes = maze_route(xs, ys, rng.uniform(300.0, 600.0), rng)
    start = np.array([min(5.0, xs[1] / 3.0), 0.0])
    corners = np.array([(xs[i], ys[j]) for i, j in nodes]) - start
    pieces = _loop_primitives(corners, np.full(len(corners), 0.8), np.zeros(2))
    return _shift(world, -start[0], -start[1]), _drive(pieces, rng.uniform(1.0, 2.0), 1.03, rng, 0.15)


#: world name -> builder(rng) -> (world in the start frame, true poses at SIM_RATE_HZ)
WORLDS = {"office": _office, "corridors": _corridors, "ring": _ring, "maze": _maze}


def laser_geometry(laser: tuple | None) -> tuple[np.ndarray, float]:
    """``(angles (B,) rad, range_max m)`` of ``laser`` ``(beams, fov_deg, range_max_m)``: the beams
    spread evenly over ``fov_deg`` centred ahead (a full circle: ``beams`` steps around it, no beam
    twice); None: the simulator's own (181 beams over 180 deg, 20 m). ValueError for a laser that
    cannot be."""
    if laser is None:
        return indoor.beam_angles(), indoor.RANGE_MAX_M
    beams, fov_deg, range_max = laser
    if not (isinstance(beams, int) and beams >= 2 and math.isfinite(fov_deg) and 0.0 < fov_deg <= 360.0):
        raise ValueError(f"a laser needs >= 2 beams over 0-360 deg, got {beams!r} beams over {fov_deg!r} deg")
    if not (math.isfinite(range_max) and range_max > 1.0):
        raise ValueError(f"the laser's range must be a finite number > 1 (m), got {range_max!r}")
    fov = math.radians(fov_deg)
    step = fov / beams if fov_deg == 360.0 else fov / (beams - 1)
    return -0.5 * fov + step * np.arange(beams, dtype=np.float64), float(range_max)


def simulate_world(
    name: str, seed: int, range_sigma_m: float = indoor.RANGE_SIGMA_M, laser: tuple | None = None
) -> SimDrive:
    """Drive world ``name`` with ``seed`` (drive, odometry, laser: independent streams); the
    laser's range noise has std ``range_sigma_m`` (m; the same drive and odometry at any value).
    ``laser``: ``(beams, fov_deg, range_max_m)`` of another laser (default the simulator's 181
    beams over 180 deg, 20 m)."""
    if not (math.isfinite(range_sigma_m) and range_sigma_m >= 0):
        raise ValueError(f"range_sigma_m must be a finite number >= 0 (m), got {range_sigma_m!r}")
    angles, range_max = laser_geometry(laser)
    if name not in WORLDS:
        raise ValueError(f"unknown simulated world {name!r}; known: {', '.join(WORLDS)}")
    drive_rng, odom_rng, laser_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(3))
    # (maze: the drive's stream draws the floor plan too)
    world, truth = WORLDS[name](drive_rng)
    odom = simulate_odometry(truth, odom_rng)
    idx = np.arange(0, len(truth), SIM_RATE_HZ // SCAN_RATE_HZ)
    return SimDrive(
        name=name,
        seed=int(seed),
        truth=truth[idx],
        odom=odom[idx],
        ranges=_scan(truth[idx], world, laser_rng, range_sigma_m, angles, range_max),
        angles=angles,
        range_max=range_max,
        world=world,
    )
