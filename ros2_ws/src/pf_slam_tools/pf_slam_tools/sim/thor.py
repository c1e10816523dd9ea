"""Seeded THOR humanoid simulator: a walk on an office floor, written in the THOR ``.mat`` layout.

``pf-slam simulate thor --out DIR --seed N [--duration S] [--kinect-rate HZ]`` writes::

    DIR/lidar.mat  joint.mat  rgb.mat  depth.mat      the THOR layout (docs/thor.md)
    DIR/ground_truth.tum                              base_link in the world, one pose per scan
    DIR/ground_truth_map.pgm + .yaml                  the true occupancy (map_server, 0.05 m)
    DIR/floor_colour.png + .yaml                      the true floor colour (RGB, same grid)
    DIR/sim_info.yaml                                 seed, layout, rates, dead-reckoning drift

* **World** (``office_layout``): a seeded office floor, 18-26 m x 12-17 m: an east-west corridor
  (2.0-2.6 m), 2-4 rooms on each side with a 1.2 m door onto it, 1-3 cabinets / pillars per room
  (full height). Each room and the corridor have their own floor (checker tiles, stripes, carpet
  with blotches, tiles with grout lines; seeded colours) on the 0.05 m map grid. Walls and
  ceiling are 2.6 m high.
* **Walk**: from the corridor's west end east along it, into and out of two or three rooms
  (door, room centre, back), to the east end and back west (revisit), repeated while time lasts;
  straight legs at 0.35-0.45 m/s and turns in place, each with smooth start and stop. The body
  sways with the gait (+-2-3 cm sideways, +-1.5 deg yaw at ~0.9 Hz per stride).
* **Odometry** (the lidar records' ``pose``): the robot's own estimate, integrated from the true
  (swaying) body increments with a scale error (2-5 %), a heading drift (0.3-0.8 deg per metre),
  foot slip at every step (N(0, 8 mm) forward, N(0, 5 mm) sideways, N(0, 0.3 deg)) and an
  occasional bigger slip (3 %: 3 cm, 2 deg).
* **Head**: neck yaw +-0.5-0.7 rad (period 7-11 s), head pitch 0.15 +- 0.2 rad (period 4-6 s);
  positive pitch looks down, so the lidar (1.41 m above the ground) sees the floor 3-10 m ahead
  at the largest pitch: those returns are in the scans, as on the real robot.
* **Lidar**: 40 Hz, 1081 beams (-135..135 deg, 0.25 deg), walls, boxes, floor and ceiling hit in
  3D from the head's pose at the scan's stamp; N(0, 1 cm), 0.5 % dropouts; no return (nothing
  within 30 m, a dropout) is 0. **Joints**: 100 Hz, exact angles, own clock (offset 3 ms).
* **Kinect**: depth (512x424, z in mm, N(0, 1.5 mm + 0.1 % z), 0 outside 400-4500 mm) and RGB
  (1920x1080 in 2x2 blocks rendered at 960x540, the exact floor / wall / ceiling colours: a
  noiseless camera) rendered with the
  intrinsics and the depth->RGB extrinsics of ``pf_slam_nodes.io.thor``, RGB 15 ms after depth,
  at ``--kinect-rate`` (default 2 Hz); stored mirrored left-right, as the real files.

The world frame is the robot's true starting pose (as in ``sim.indoor``): the odometry starts at
the identity there, so |odometry - ground truth| is the dead-reckoning drift. Times are UNIX
seconds from ``EPOCH_S``. A seed and options give the same data (the .mat headers carry the write time).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pf_slam_nodes.io import thor as th
from pf_slam_nodes.io.mapfile import write_map
from pf_slam_nodes.io.trajectory import write_tum

from .indoor import IndoorWorld, rasterise_world, ray_cast

__all__ = [
    "EPOCH_S",
    "OfficeLayout",
    "ThorSimResult",
    "office_layout",
    "plan_walk",
    "simulate_thor",
    "lidar_ranges",
    "render_kinect",
    "head_angles_at",
]

EPOCH_S = 1_700_000_000.0
SIM_RATE_HZ = 200
SCAN_RATE_HZ = 40
JOINT_RATE_HZ = 100
JOINT_OFFSET_S = 0.003
RGB_LAG_S = 0.015
CEILING_M = 2.6
RES_M = 0.05  #: map and floor-colour grid
DOOR_W_M = 1.2
RANGE_SIGMA_M = 0.01
DROPOUT_PROB = 0.005
WALL_RGB = np.array([222, 216, 200], dtype=np.uint8)
BASEBOARD_RGB = np.array([96, 84, 72], dtype=np.uint8)
CEILING_RGB = np.array([242, 242, 238], dtype=np.uint8)
OUTSIDE_RGB = np.array([40, 40, 40], dtype=np.uint8)

_PALETTE = np.array(
    [
        (52, 72, 120),
        (120, 126, 134),
        (196, 178, 140),
        (164, 84, 60),
        (70, 110, 76),
        (140, 96, 58),
        (210, 206, 196),
        (36, 36, 44),
        (150, 60, 90),
        (96, 150, 170),
        (180, 150, 60),
        (230, 230, 226),
    ],
    dtype=np.float64,
)


# --------------------------------------------------------------------------------------------
# world


@dataclass(frozen=True)
class OfficeLayout:
    """A generated floor in the start frame: ``world`` (segments, boxes, bounds),
    ``floor_rgb`` (H, W, 3) uint8 on ``grid_origin`` / ``RES_M`` (row 0 = lowest y, the
    ``rasterise_world`` grid), ``route`` (P, 2) waypoints of one lap, ``rooms`` (R, 4) x0 y0 x1 y1,
    ``styles``: the floor style of the corridor then each room."""

    world: IndoorWorld
    floor_rgb: np.ndarray
    grid_origin: np.ndarray
    route: np.ndarray
    rooms: np.ndarray
    styles: tuple


def _split(length: float, n: int, rng: np.random.Generator, min_w: float = 4.0) -> list[float]:
    for _ in range(200):
        cuts = np.sort(rng.uniform(0.0, length, n - 1))
        edges = np.concatenate([[0.0], cuts, [length]])
        if np.diff(edges).min() >= min_w:
            return [float(round(e / RES_M) * RES_M) for e in edges]
    return [length * i / n for i in range(n + 1)]


def _box_segments(boxes: np.ndarray) -> np.ndarray:
    half = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=np.float64) * 0.5
    local = half[None] * boxes[:, None, 2:4]
    c, s = np.cos(boxes[:, 4])[:, None], np.sin(boxes[:, 4])[:, None]
    x = boxes[:, None, 0] + c * local[..., 0] - s * local[..., 1]
    y = boxes[:, None, 1] + s * local[..., 0] + c * local[..., 1]
    corners = np.stack([x, y], axis=-1)
    return np.concatenate([corners, np.roll(corners, -1, axis=1)], axis=-1).reshape(-1, 4)


def _seg_dist(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    e = b - a
    u = float(np.clip((p - a) @ e / max(e @ e, 1e-12), 0.0, 1.0))
    return float(np.linalg.norm(p - (a + u * e)))


def _floor_pattern(
    shape: tuple[int, int], xs: np.ndarray, ys: np.ndarray, rng: np.random.Generator, style: str
) -> np.ndarray:
    """(h, w, 3) float colours of one floor style over cell centres ``xs`` (w,), ``ys`` (h,)."""
    i, j = rng.choice(len(_PALETTE), 2, replace=False)
    a, b = _PALETTE[i], _PALETTE[j]
    X, Y = np.meshgrid(xs, ys)
    if style == "checker":
        tile = float(rng.choice([0.4, 0.5, 0.6]))
        m = (np.floor(X / tile + 1e-6) + np.floor(Y / tile + 1e-6)) % 2 == 0
    elif style == "stripes":
        period = float(rng.choice([0.5, 0.8, 1.0]))
        m = np.mod((X if rng.random() < 0.5 else Y) + 1e-6, period) < 0.5 * period
    elif style == "tiles":
        tile = float(rng.choice([0.5, 0.6]))
        m = ~((np.mod(X + 1e-6, tile) < RES_M) | (np.mod(Y + 1e-6, tile) < RES_M))
    else:  # carpet: one colour, 0.25 m blotches
        m = np.ones(shape, dtype=bool)
        coarse = rng.normal(0.0, 1.0, (shape[0] // 5 + 2, shape[1] // 5 + 2))
        blot = np.kron(coarse, np.ones((5, 5)))[: shape[0], : shape[1]]
        return a[None, None] + 22.0 * blot[..., None]
    return np.where(m[..., None], a[None, None], b[None, None])


def office_layout(rng: np.random.Generator) -> OfficeLayout:
    """A seeded office floor (see the module doc), shifted so the walk starts at the origin."""
    W = round(float(rng.uniform(18.0, 26.0)) / RES_M) * RES_M
    H = round(float(rng.uniform(12.0, 17.0)) / RES_M) * RES_M
    cw = round(float(rng.uniform(2.0, 2.6)) / RES_M) * RES_M
    yc = round(float(rng.uniform(0.42, 0.58) * H) / RES_M) * RES_M
    ys, yn = yc - 0.5 * cw, yc + 0.5 * cw
    segs: list[tuple[float, float, float, float]] = [(0, 0, W, 0), (0, H, W, H), (0, 0, 0, H), (W, 0, W, H)]
    rooms, doors = [], []  # rooms: x0 y0 x1 y1; doors: (x, side)
    for side, (y0, y1) in (("s", (0.0, ys)), ("n", (yn, H))):
        edges = _split(W, int(rng.integers(2, 5)), rng)
        for x0, x1 in zip(edges[:-1], edges[1:]):
            rooms.append((x0, y0, x1, y1))
            doors.append((round(float(rng.uniform(x0 + 1.2, x1 - 1.2)) / RES_M) * RES_M, side))
        for x in edges[1:-1]:
            segs.append((x, y0, x, y1))
        wall_y = ys if side == "s" else yn
        cuts = sorted(d for d, s in doors if s == side)
        starts = [0.0] + [c + 0.5 * DOOR_W_M for c in cuts]
        ends = [c - 0.5 * DOOR_W_M for c in cuts] + [W]
        segs += [(a, wall_y, b, wall_y) for a, b in zip(starts, ends)]
    rooms_a = np.array(rooms)
    # the route: west end -> east along the corridor, into some rooms -> east end -> back west
    start = np.array([1.5, yc])
    n_visit = int(rng.integers(2, 4))
    visit = sorted(
        rng.choice(len(rooms), size=min(n_visit, len(rooms)), replace=False).tolist(), key=lambda k: doors[k][0]
    )
    route = [start]
    legs: list[tuple[np.ndarray, np.ndarray]] = []
    for k in visit:
        x0, y0, x1, y1 = rooms[k]
        dx = doors[k][0]
        inner = np.array([dx, 0.5 * (y0 + y1)])
        centre = np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1)])
        pts = [np.array([dx, yc]), inner]
        if abs(centre[0] - dx) > 1.0:
            pts.append(centre)
        route += pts + pts[-2::-1]
        legs += list(zip(pts[:-1], pts[1:]))
    route += [np.array([W - 1.5, yc]), start]
    route_a = np.array(route)
    legs += [(start, np.array([W - 1.5, yc]))]
    # boxes: 1-3 per room, clear of the walk (0.8 m), the doors (1 m) and each other
    boxes: list[tuple[float, float, float, float, float]] = []
    for k, (x0, y0, x1, y1) in enumerate(rooms):
        for _ in range(int(rng.integers(1, 4))):
            for _try in range(60):
                if rng.random() < 0.3:  # pillar
                    lx = wy = float(rng.uniform(0.3, 0.5))
                    cx, cy = rng.uniform(x0 + 0.8, x1 - 0.8), rng.uniform(y0 + 0.8, y1 - 0.8)
                    yaw = 0.0
                else:  # cabinet / shelf against a side wall
                    lx, wy = float(rng.uniform(0.5, 1.6)), float(rng.uniform(0.4, 0.7))
                    cx = rng.uniform(x0 + 0.1 + lx / 2, x1 - 0.1 - lx / 2)
                    far = y1 if doors[k][1] == "n" else y0  # the wall opposite the door
                    near_wall = far + (wy / 2 + 0.02) * (1 if far == y0 else -1)
                    cy = near_wall if rng.random() < 0.6 else rng.uniform(y0 + 0.8, y1 - 0.8)
                    yaw = math.radians(float(rng.choice([0.0, 0.0, 20.0, -15.0])))
                c = np.array([cx, cy])
                r = 0.5 * math.hypot(lx, wy)
                if any(_seg_dist(c, a, b) < r + 0.8 for a, b in legs):
                    continue
                if abs(cy - (ys if doors[k][1] == "s" else yn)) < r + 1.0 and abs(cx - doors[k][0]) < r + 1.2:
                    continue
                if any(
                    math.hypot(cx - bx, cy - by) < r + 0.5 * math.hypot(bl, bw) + 0.4 for bx, by, bl, bw, _ in boxes
                ):
                    continue
                boxes.append((float(cx), float(cy), lx, wy, yaw))
                break
    boxes_a = np.array(boxes, dtype=np.float64).reshape(-1, 5)
    segments = np.concatenate([np.array(segs, dtype=np.float64), _box_segments(boxes_a)])
    shift = np.concatenate([start, start])
    world = IndoorWorld(
        segments=segments - shift,
        boxes=np.concatenate([boxes_a[:, :2] - start, boxes_a[:, 2:]], axis=1),
        bounds=np.array([0.0, 0.0, W, H]) - shift,
    )
    occ, origin = rasterise_world(world, RES_M)
    # floor colours on the occupancy grid: corridor, then each room (cells inside the floor)
    h, w = occ.shape
    xs = origin[0] + (np.arange(w) + 0.5) * RES_M + start[0]  # floor-plan coordinates
    ysg = origin[1] + (np.arange(h) + 0.5) * RES_M + start[1]
    floor = np.empty((h, w, 3))
    floor[:] = OUTSIDE_RGB
    styles = ["tiles" if rng.random() < 0.5 else "checker"]
    areas = [(0.0, ys, W, yn)] + list(rooms)
    # door gaps belong to the corridor's floor: paint rooms first, then the corridor band
    order = list(range(1, len(areas))) + [0]
    style_of = {0: styles[0]}
    for k in range(1, len(areas)):
        style_of[k] = str(rng.choice(["checker", "stripes", "tiles", "carpet"]))
    for k in order:
        x0, y0, x1, y1 = areas[k]
        cols = (xs > x0) & (xs < x1)
        grow = RES_M if k == 0 else 0.0  # the corridor's floor runs through the door gaps
        rows = (ysg > y0 - grow) & (ysg < y1 + grow)
        pat = _floor_pattern((int(rows.sum()), int(cols.sum())), xs[cols], ysg[rows], rng, style_of[k])
        floor[np.ix_(rows, cols)] = pat
    styles = tuple(style_of[k] for k in range(len(areas)))
    floor += rng.normal(0.0, 3.0, floor.shape)  # a little texel-to-texel variation
    inside = (xs[None, :] > 0) & (xs[None, :] < W) & (ysg[:, None] > 0) & (ysg[:, None] < H)
    floor[~inside] = OUTSIDE_RGB
    floor_rgb = np.clip(np.rint(floor), 0, 255).astype(np.uint8)
    return OfficeLayout(
        world=world,
        floor_rgb=floor_rgb,
        grid_origin=origin,
        route=route_a - start,
        rooms=rooms_a - shift,
        styles=styles,
    )


# --------------------------------------------------------------------------------------------
# the walk


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def plan_walk(
    route: np.ndarray, duration_s: float, rng: np.random.Generator, rate_hz: int = SIM_RATE_HZ
) -> tuple[np.ndarray, np.ndarray, float]:
    """The path pose (no sway) along ``route`` (repeated), sampled at ``rate_hz``:
    ``(t (N,), poses (N, 3) with theta unwrapped, stride frequency Hz)``."""
    v = float(rng.uniform(0.35, 0.45))
    w = float(rng.uniform(0.5, 0.7))
    n = int(round(duration_s * rate_hz)) + 1
    t_all = np.arange(n) / rate_hz
    out = np.empty((n, 3))
    pos, yaw, t_now, k = route[0].astype(np.float64), 0.0, 0.0, 0
    filled = 0
    while filled < n:
        a, b = route[k % (len(route) - 1)], route[k % (len(route) - 1) + 1]
        k += 1
        d = b - a
        dist = float(np.linalg.norm(d))
        if dist < 1e-6:
            continue
        want = math.atan2(d[1], d[0])
        turn = (want - yaw + math.pi) % (2 * math.pi) - math.pi
        for kind, dur in (("turn", abs(turn) / w * 1.5 + 0.2), ("walk", dist / v * 1.5 + 0.4)):
            m = (t_all >= t_now) & (t_all < t_now + dur)
            u = _smoothstep((t_all[m] - t_now) / dur)
            if kind == "turn":
                out[m] = np.stack([np.full(u.shape, pos[0]), np.full(u.shape, pos[1]), yaw + turn * u], 1)
            else:
                p = a[None] + u[:, None] * d[None]
                out[m] = np.stack([p[:, 0], p[:, 1], np.full(u.shape, yaw + turn)], 1)
            filled += int(m.sum())
            t_now += dur
        yaw, pos = yaw + turn, b.astype(np.float64)
    return t_all, out, float(rng.uniform(0.85, 0.95))


def add_sway(t: np.ndarray, path: np.ndarray, stride_hz: float, rng: np.random.Generator) -> np.ndarray:
    """True body poses: the path pose with the gait's sideways sway and yaw wobble (body frame)."""
    amp = float(rng.uniform(0.02, 0.03))
    yaw_amp = math.radians(1.5)
    ph = 2 * math.pi * stride_hz * t + float(rng.uniform(0, 2 * math.pi))
    lat, dyaw = amp * np.sin(ph), yaw_amp * np.sin(ph + 0.6)
    lat, dyaw = lat - lat[0], dyaw - dyaw[0]  # the walk starts exactly at the path's start
    c, s = np.cos(path[:, 2]), np.sin(path[:, 2])
    return np.stack([path[:, 0] - s * lat, path[:, 1] + c * lat, path[:, 2] + dyaw], axis=1)


def simulate_odometry(t: np.ndarray, truth: np.ndarray, stride_hz: float, rng: np.random.Generator) -> np.ndarray:
    """The robot's own odometry (see the module doc), starting at the identity, theta unwrapped."""
    scale = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.02, 0.05))
    drift = float(rng.choice([-1.0, 1.0]) * math.radians(rng.uniform(0.3, 0.8)))  # rad per metre
    dxy = np.diff(truth[:, :2], axis=0)
    c, s = np.cos(truth[:-1, 2]), np.sin(truth[:-1, 2])
    fwd, side = c * dxy[:, 0] + s * dxy[:, 1], -s * dxy[:, 0] + c * dxy[:, 1]
    dth = np.diff(truth[:, 2])
    fwd, side = fwd * (1 + scale), side * (1 + scale)
    dth = dth + drift * np.hypot(fwd, side)
    # foot slip at every step (two steps per stride), and when moving
    step = np.floor(2 * stride_hz * t[1:]).astype(np.int64)
    new_step = np.concatenate([[False], np.diff(step) > 0])
    moving = np.hypot(*dxy.T) + np.abs(np.diff(truth[:, 2])) > 1e-5
    m = new_step & moving
    k = int(m.sum())
    big = rng.random(k) < 0.03
    fwd[m] += rng.normal(0, 0.008, k) + big * rng.normal(0, 0.03, k)
    side[m] += rng.normal(0, 0.005, k) + big * rng.normal(0, 0.03, k)
    dth[m] += rng.normal(0, math.radians(0.3), k) + big * rng.normal(0, math.radians(2.0), k)
    th = np.concatenate([[0.0], np.cumsum(dth)])
    c, s = np.cos(th[:-1]), np.sin(th[:-1])
    x = np.concatenate([[0.0], np.cumsum(c * fwd - s * side)])
    y = np.concatenate([[0.0], np.cumsum(s * fwd + c * side)])
    return np.stack([x, y, th], axis=1)


def head_angles_at(t: np.ndarray, params: tuple) -> tuple[np.ndarray, np.ndarray]:
    """``(neck yaw, head pitch)`` (rad) at times ``t`` (s since the start)."""
    ya, yp, yph, p0, pa, pp, pph = params
    return ya * np.sin(2 * math.pi * t / yp + yph), p0 + pa * np.sin(2 * math.pi * t / pp + pph)


def _interp_pose(t_q: np.ndarray, t: np.ndarray, poses: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(t_q, t, poses[:, j]) for j in range(3)], axis=1)


# --------------------------------------------------------------------------------------------
# sensors


def _sensor_pose(
    body: np.ndarray, neck: np.ndarray, pitch: np.ndarray, above_head: float
) -> tuple[np.ndarray, np.ndarray]:
    """World position (K, 3) and rotation (K, 3, 3) of a frame ``above_head`` m over the head joint."""
    c, s = np.cos(body[:, 2]), np.sin(body[:, 2])
    z = np.zeros_like(c)
    rz = np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, z + 1], -1)], -2)
    rot = rz @ th.head_rotation(neck, pitch)
    pos = np.stack([body[:, 0], body[:, 1], np.full_like(c, th.HEAD_HEIGHT_M)], 1) + rot[:, :, 2] * above_head
    return pos, rot


def _hit_distance(
    pos: np.ndarray, dirs: np.ndarray, segments: np.ndarray, max_m: float, fan_step: float | None = None
) -> np.ndarray:
    """Ray parameter s of the first hit (walls/boxes full height, floor z=0, ceiling) of rays
    ``pos + s * dirs`` (dirs (N, 3), not necessarily unit); inf if none within ``max_m`` along
    the horizontal. ``fan_step``: look the wall distances up in a fan of horizontal angles of
    that step (rad) instead of casting every ray (images)."""
    h = np.hypot(dirs[:, 0], dirs[:, 1])
    phi = np.arctan2(dirs[:, 1], dirs[:, 0])
    if fan_step is None:
        r_h = ray_cast(np.array([pos[0], pos[1], 0.0]), phi, segments, max_m)
    else:
        ref = float(np.arctan2(np.sin(phi).mean(), np.cos(phi).mean()))
        rel = (phi - ref + math.pi) % (2 * math.pi) - math.pi
        lo = float(rel.min())
        n = int((float(rel.max()) - lo) / fan_step) + 2
        fan = ray_cast(np.array([pos[0], pos[1], ref]), lo + fan_step * np.arange(n), segments, max_m)
        r_h = fan[np.clip(np.rint((rel - lo) / fan_step).astype(np.int64), 0, n - 1)]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(h > 1e-9, r_h / h, np.inf)
        s_floor = np.where(dirs[:, 2] < 0, -pos[2] / dirs[:, 2], np.inf)
        s_ceil = np.where(dirs[:, 2] > 0, (CEILING_M - pos[2]) / dirs[:, 2], np.inf)
    return np.minimum(s, np.minimum(s_floor, s_ceil))


def lidar_ranges(
    body: np.ndarray, neck: np.ndarray, pitch: np.ndarray, segments: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """(K, 1081) float32 Hokuyo ranges (m; 0 = no return) from the head's pose at each scan."""
    pos, rot = _sensor_pose(body, neck, pitch, th.LIDAR_ABOVE_HEAD_M)
    a = th.ANGLE_MIN_RAD + th.ANGLE_INCREMENT_RAD * np.arange(th.N_BEAMS)
    beams = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    out = np.empty((len(body), th.N_BEAMS), dtype=np.float32)
    for k in range(len(body)):
        d = beams @ rot[k].T
        r = _hit_distance(pos[k], d, segments, 40.0)
        r = r + RANGE_SIGMA_M * rng.normal(size=r.shape)
        r[(r > th.RANGE_MAX_M) | (rng.random(r.shape) < DROPOUT_PROB)] = 0.0
        out[k] = r
    return out


def _pixel_rays(k: tuple, size: tuple[int, int], scale: float = 1.0) -> np.ndarray:
    """(N, 3) optical rays (z = 1) through the pixel centres of an image of ``size`` shrunk by
    ``scale`` (same field of view)."""
    fx, fy, cx, cy = k
    fx, fy, cx, cy = fx * scale, fy * scale, (cx + 0.5) * scale - 0.5, (cy + 0.5) * scale - 0.5
    h, w = int(round(size[0] * scale)), int(round(size[1] * scale))
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.stack([((u - cx) / fx).ravel(), ((v - cy) / fy).ravel(), np.ones(u.size)], axis=1)


#: the RGB image is rendered at this scale and enlarged (nearest) to 1920x1080: 2x2 pixel blocks
RGB_RENDER_SCALE = 0.5


def render_kinect(
    body: np.ndarray,
    neck: float,
    pitch: float,
    layout: OfficeLayout,
    kind: str,
    rays: np.ndarray,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """One un-mirrored frame at body pose ``body`` (3,): ``'depth'`` (424, 512) uint16 mm (z),
    0 = invalid; ``'rgb'`` (1080, 1920, 3) uint8 (rendered at ``RGB_RENDER_SCALE``, 2x2 blocks).
    ``rays``: ``_pixel_rays`` of that camera (RGB: at ``RGB_RENDER_SCALE``)."""
    pos, rot = _sensor_pose(body[None], np.array([neck]), np.array([pitch]), th.KINECT_ABOVE_HEAD_M)
    pos, r_wo = pos[0], rot[0] @ th.OPTICAL_R  # rgb optical in the world
    if kind == "depth":
        pos = pos + r_wo @ np.asarray(th.DEPTH_TO_RGB_T_M)
        r_wo = r_wo @ th.DEPTH_TO_RGB_R
    dirs = rays @ r_wo.T
    s = _hit_distance(pos, dirs, layout.world.segments, 30.0, fan_step=2e-4)
    if kind == "depth":
        z = s * 1000.0
        if rng is not None:
            z = z + rng.normal(size=z.shape) * (1.5 + 0.001 * np.where(np.isfinite(z), z, 0.0))
        ok = np.isfinite(z) & (z >= th.DEPTH_VALID_MM[0]) & (z <= th.DEPTH_VALID_MM[1])
        return np.where(ok, np.rint(np.where(ok, z, 0.0)), 0).astype(np.uint16).reshape(th.DEPTH_SIZE)
    hz = pos[2] + s * dirs[:, 2]
    rgb = np.empty((len(s), 3), dtype=np.uint8)
    rgb[:] = WALL_RGB
    rgb[hz < 0.12] = BASEBOARD_RGB
    rgb[hz > CEILING_M - 1e-6] = CEILING_RGB
    floor = np.flatnonzero(hz < 1e-6)
    fr = layout.floor_rgb
    col = np.floor((pos[0] + s[floor] * dirs[floor, 0] - layout.grid_origin[0]) / RES_M).astype(np.int64)
    row = np.floor((pos[1] + s[floor] * dirs[floor, 1] - layout.grid_origin[1]) / RES_M).astype(np.int64)
    inside = (col >= 0) & (col < fr.shape[1]) & (row >= 0) & (row < fr.shape[0])
    c = np.empty((len(col), 3), dtype=np.uint8)
    c[:] = OUTSIDE_RGB
    c[inside] = fr[row[inside], col[inside]]
    rgb[floor] = c
    rgb[~np.isfinite(s)] = OUTSIDE_RGB
    h = int(round(th.RGB_SIZE[0] * RGB_RENDER_SCALE))
    small = rgb.reshape(h, -1, 3)
    if small.shape[:2] == th.RGB_SIZE:
        return small
    k = int(round(1.0 / RGB_RENDER_SCALE))
    return np.ascontiguousarray(np.repeat(np.repeat(small, k, axis=0), k, axis=1))


# --------------------------------------------------------------------------------------------
# the run


@dataclass(frozen=True)
class ThorSimResult:
    """What ``simulate_thor`` wrote: the folder, counts and the dead-reckoning drift at the end."""

    out_dir: Path
    seed: int
    duration_s: float
    n_scans: int
    n_joints: int
    n_kinect: int
    path_length_m: float
    odom_drift_m: float
    styles: tuple


def _cell(records: list[dict]) -> np.ndarray:
    c = np.empty((1, len(records)), dtype=object)
    for i, r in enumerate(records):
        c[0, i] = r
    return c


def simulate_thor(
    out_dir: str | os.PathLike,
    seed: int = 0,
    duration_s: float = 60.0,
    kinect_rate_hz: float = 2.0,
    overwrite: bool = False,
) -> ThorSimResult:
    """Simulate a THOR walk and write the ``.mat`` files and ground truth (module doc)."""
    import scipy.io

    if not (isinstance(duration_s, (int, float)) and 1.0 <= duration_s <= 3600.0):
        raise ValueError(f"duration_s must be in [1, 3600] s, got {duration_s!r}")
    if not 0.0 <= kinect_rate_hz <= 30.0:
        raise ValueError(f"kinect_rate_hz must be in [0, 30], got {kinect_rate_hz!r}")
    out = Path(out_dir)
    names = ("lidar.mat", "joint.mat", "rgb.mat", "depth.mat", "ground_truth.tum")
    if not overwrite and any((out / n).exists() for n in names):
        raise FileExistsError(f"{out}: already holds a THOR simulation (--force replaces it)")
    out.mkdir(parents=True, exist_ok=True)
    world_rng, walk_rng, odom_rng, head_rng, lidar_rng, cam_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(6)
    )
    layout = office_layout(world_rng)
    t, path, stride_hz = plan_walk(layout.route, duration_s + 1.0, walk_rng)
    truth = add_sway(t, path, stride_hz, walk_rng)
    odom = simulate_odometry(t, truth, stride_hz, odom_rng)
    head = (
        float(head_rng.uniform(0.5, 0.7)),
        float(head_rng.uniform(7.0, 11.0)),
        float(head_rng.uniform(0, 2 * math.pi)),
        0.15,
        0.2,
        float(head_rng.uniform(4.0, 6.0)),
        float(head_rng.uniform(0, 2 * math.pi)),
    )

    # lidar: 40 Hz with 1 ms jitter
    n_scan = int(duration_s * SCAN_RATE_HZ)
    ts = np.arange(n_scan) / SCAN_RATE_HZ + 0.001 + lidar_rng.uniform(-0.001, 0.001, n_scan)
    body = _interp_pose(ts, t, truth)
    neck, pitch = head_angles_at(ts, head)
    ranges = lidar_ranges(body, neck, pitch, layout.world.segments, lidar_rng)
    pose = _interp_pose(ts, t, odom)
    wrap = lambda a: np.arctan2(np.sin(a), np.cos(a))  # noqa: E731
    delta = np.diff(pose, axis=0, prepend=pose[:1])
    lidar_recs = []
    for k in range(n_scan):
        rpy = np.array([0.02 * math.sin(2 * math.pi * stride_hz * ts[k]), 0.01, wrap(pose[k, 2])])
        lidar_recs.append(
            {
                "t": np.array([[EPOCH_S + ts[k]]]),
                "delta_pose": np.array([[delta[k, 0], delta[k, 1], wrap(delta[k, 2])]]),
                "pose": np.array([[pose[k, 0], pose[k, 1], wrap(pose[k, 2])]]),
                "res": np.array([[0.0044]]),
                "rpy": rpy[None],
                "scan": ranges[k][None],
            }
        )
    scipy.io.savemat(out / "lidar.mat", {"lidar": _cell(lidar_recs)}, do_compression=True)

    # joints: 100 Hz on their own clock
    n_joint = int(duration_s * JOINT_RATE_HZ)
    tj = np.arange(n_joint) / JOINT_RATE_HZ + JOINT_OFFSET_S
    jn, jp = head_angles_at(tj, head)
    step = 2 * math.pi * stride_hz * tj
    zeros3 = np.zeros((3, n_joint))
    pos35 = np.zeros((35, n_joint))
    pos35[0], pos35[1] = jn, jp
    fz = 0.5 * 60.0 * 9.81 * (1.0 + np.sin(step))
    ft_l, ft_r = np.zeros((6, n_joint)), np.zeros((6, n_joint))
    ft_l[2], ft_r[2] = fz, 60.0 * 9.81 - fz
    scipy.io.savemat(
        out / "joint.mat",
        {
            "ts": (EPOCH_S + tj)[None],
            "head_angles": np.stack([jn, jp]),
            "acc": zeros3 + np.array([[0.0], [0.0], [1.0]]),
            "rpy": zeros3,
            "gyro": zeros3,
            "pos": pos35,
            "ft_l": ft_l,
            "ft_r": ft_r,
        },
        do_compression=True,
    )

    # kinect
    n_kin = int(duration_s * kinect_rate_hz)
    td = (np.arange(n_kin) + 0.5) / kinect_rate_hz if n_kin else np.zeros(0)
    for kind, tk, var, fld, k, size in (
        ("depth", td, "DEPTH", "depth", th.DEPTH_K, th.DEPTH_SIZE),
        ("rgb", td + RGB_LAG_S, "RGB", "image", th.RGB_K, th.RGB_SIZE),
    ):
        rays = (_pixel_rays(k, size, RGB_RENDER_SCALE if kind == "rgb" else 1.0)) if n_kin else None
        recs = []
        for i, tt in enumerate(tk.tolist()):
            b = _interp_pose(np.array([tt]), t, truth)[0]
            o = _interp_pose(np.array([tt]), t, odom)[0]
            yn, pn = head_angles_at(np.array([tt]), head)
            img = render_kinect(b, float(yn[0]), float(pn[0]), layout, kind, rays, cam_rng if kind == "depth" else None)
            recs.append(
                {
                    "t": np.array([[EPOCH_S + tt]]),
                    "width": np.array([[size[1]]], dtype=np.float64),
                    "imu_rpy": np.array([[0.0, 0.01, wrap(o[2])]]),
                    "id": np.array([[i]], dtype=np.float64),
                    "odom": np.array([[o[0], o[1], wrap(o[2])]]),
                    "head_angles": np.array([[yn[0], pn[0]]]),
                    "c": np.array([[3 if kind == "rgb" else 1]], dtype=np.float64),
                    "sz": np.array([[float(img.nbytes)]]),
                    "vel": np.zeros((1, 3)),
                    "rsz": np.array([[float(img.nbytes)]]),
                    "body_height": np.array([[th.COM_HEIGHT_M]]),
                    "tr": np.eye(4),
                    "bpp": np.array([[3.0 if kind == "rgb" else 2.0]]),
                    "name": kind,
                    "height": np.array([[size[0]]], dtype=np.float64),
                    fld: np.ascontiguousarray(img[:, ::-1]),
                }
            )
        scipy.io.savemat(out / f"{kind}.mat", {var: _cell(recs)}, do_compression=True)

    # ground truth
    gt = body.copy()
    gt[:, 2] = wrap(gt[:, 2])
    write_tum(out / "ground_truth.tum", EPOCH_S + ts, gt)
    occ, origin = rasterise_world(layout.world, RES_M)
    write_map(out, occ, RES_M, origin, name="ground_truth_map")
    import cv2

    cv2.imwrite(str(out / "floor_colour.png"), np.ascontiguousarray(layout.floor_rgb[::-1, :, ::-1]))
    (out / "floor_colour.yaml").write_text(
        "image: floor_colour.png\n"
        f"resolution: {RES_M:.6g}\n"
        f"origin: [{origin[0]:.6f}, {origin[1]:.6f}, 0]\n"
        "# RGB image, the ground_truth_map grid: row 0 = north (largest y); texel (col, row) covers\n"
        "# x = origin_x + col * resolution .. + resolution. Outside the floor: (40, 40, 40).\n",
        encoding="utf-8",
    )
    drift = float(np.hypot(*(pose[-1, :2] - body[-1, :2])))
    walked = truth[t <= ts[-1], :2]
    length = float(np.hypot(*np.diff(walked, axis=0).T).sum())
    (out / "sim_info.yaml").write_text(
        f"simulator: pf_slam_tools.sim.thor\nseed: {int(seed)}\nduration_s: {duration_s:g}\n"
        f"scan_rate_hz: {SCAN_RATE_HZ}\njoint_rate_hz: {JOINT_RATE_HZ}\nkinect_rate_hz: {kinect_rate_hz:g}\n"
        f"floor_styles: [{', '.join(layout.styles)}]\nrooms: {len(layout.rooms)}\n"
        f"boxes: {len(layout.world.boxes)}\nstride_hz: {stride_hz:.3f}\n"
        f"odom_drift_m: {drift:.3f}\n",
        encoding="utf-8",
    )
    return ThorSimResult(
        out_dir=out,
        seed=int(seed),
        duration_s=float(duration_s),
        n_scans=n_scan,
        n_joints=n_joint,
        n_kinect=n_kin,
        path_length_m=length,
        odom_drift_m=drift,
        styles=layout.styles,
    )


# --------------------------------------------------------------------------------------------
# command line


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Options of ``pf-slam simulate thor``."""
    parser.add_argument("--out", required=True, help="output folder (the .mat files and ground truth)")
    parser.add_argument("--seed", type=int, default=0, help="random seed: layout, walk, noise (default: 0)")
    parser.add_argument("--duration", type=float, default=60.0, help="simulated seconds (default: 60)")
    parser.add_argument(
        "--kinect-rate",
        type=float,
        default=2.0,
        help="RGB-D frames per second, 0 = none (default: 2; each RGB frame is 6 MB)",
    )
    parser.add_argument("--force", action="store_true", help="replace the files of an earlier simulation")
    return parser


def run_args(args: argparse.Namespace) -> int:
    """Run from parsed ``add_arguments`` options; prints a summary."""
    try:
        res = simulate_thor(
            args.out, seed=args.seed, duration_s=args.duration, kinect_rate_hz=args.kinect_rate, overwrite=args.force
        )
    except (FileExistsError, ValueError) as exc:
        print(f"simulate thor: error: {exc}", file=sys.stderr)
        return 2
    print(
        f"{res.out_dir}: {res.n_scans} scans, {res.n_joints} joint samples, {res.n_kinect} RGB-D frames, "
        f"{res.duration_s:g} s; walked {res.path_length_m:.1f} m, dead-reckoning drift at the end "
        f"{res.odom_drift_m:.2f} m; floors: {', '.join(res.styles)}"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m pf_slam_tools.sim.thor --out DIR --seed N``."""
    return run_args(
        add_arguments(
            argparse.ArgumentParser(
                prog="python -m pf_slam_tools.sim.thor", description="Simulate a THOR humanoid walk (.mat files)."
            )
        ).parse_args(argv)
    )


if __name__ == "__main__":
    sys.exit(main())
