"""World and drive of the car simulator (``pf_slam_tools.sim.car``): a seeded city block grid.

Everything is built in a "grid" frame and then translated so that the vehicle's true start
pose is the origin with heading 0 (``+x`` = east along the start street): that frame is the
world frame of the ground truth.

* **Streets** -- ``N_STREETS`` north-south and ``N_STREETS`` east-west street centre lines, 55-75 m
  apart, each 9-12 m wide between the kerbs, 3 m sidewalks, and a ring of outer blocks.
* **Obstacles** -- axis-aligned boxes ``[xmin, ymin, zmin, xmax, ymax, zmax]``: buildings (1-3 x
  1-3 lots per block, 6-40 m tall), parked cars and vans along the kerbs (parking lane 2.2 m),
  lamp poles and trees (trunk + crown) on the sidewalks.
* **Floor texture** -- asphalt noise, a dashed centre line, solid edge lines at the parking
  lane, zebra crossings at every intersection, paved sidewalks, greenish ground elsewhere.
* **Drive** -- right-hand traffic in the right lane; a first loop around 1-2 x 1-2 blocks
  that comes back through the start street, then a seeded random walk on the street graph;
  8-12 m/s per leg, 2.5 m/s^2 lateral acceleration in turns, stops before intersections.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .car_variation import CarVariation
from .paths import pose_on_path

_DEFAULT = CarVariation()

__all__ = [
    "CarWorld",
    "Drive",
    "KIND_BUILDING",
    "KIND_CAR",
    "KIND_CROWN",
    "KIND_POLE",
    "KIND_TRUNK",
    "build_world",
    "occupancy_grid",
    "plan_route",
    "pose_on_path",
    "shift_world",
]

N_STREETS = 5
SIDEWALK_M = 3.0
OUTER_BLOCK_M = 35.0
PARKING_LANE_M = 2.2
TEXTURE_RES_M = 0.1
KIND_BUILDING, KIND_CAR, KIND_POLE, KIND_TRUNK, KIND_CROWN = 0, 1, 2, 3, 4

_BUILDING_RGB = np.array(
    [
        [150, 150, 150],
        [190, 180, 160],
        [150, 80, 60],
        [90, 110, 140],
        [200, 200, 195],
        [120, 115, 105],
        [170, 140, 110],
    ],
    dtype=np.float64,
)
_CAR_RGB = np.array(
    [[235, 235, 235], [170, 172, 175], [30, 30, 32], [30, 45, 90], [150, 25, 25], [95, 95, 100]], dtype=np.float64
)


@dataclass(frozen=True)
class CarWorld:
    """Static world in the start frame (x east, y north, z up; ground plane ``z = 0``).

    Attributes
    ----------
    boxes : np.ndarray
        ``(M, 6)`` float64 ``[xmin, ymin, zmin, xmax, ymax, zmax]`` (m).
    kinds : np.ndarray
        ``(M,)`` int8 ``KIND_*``.
    colours : np.ndarray
        ``(M, 3)`` float32 base RGB (0..255).
    bounds : np.ndarray
        ``(4,)`` ``[xmin, ymin, xmax, ymax]`` of the world (m).
    texture : np.ndarray
        ``(H, W, 3)`` uint8 RGB floor texture, row 0 = lowest y.
    texture_origin : np.ndarray
        ``(2,)`` world position of the lower-left corner of texel ``(0, 0)`` (m).
    texture_res_m : float
        Texel size (m).
    street_x, street_y, width_x, width_y : np.ndarray
        ``(N_STREETS,)`` centre lines of the north-south (``x = street_x``) and east-west
        (``y = street_y``) streets and their kerb-to-kerb widths (m).
    """

    boxes: np.ndarray
    kinds: np.ndarray
    colours: np.ndarray
    bounds: np.ndarray
    texture: np.ndarray
    texture_origin: np.ndarray
    texture_res_m: float
    street_x: np.ndarray
    street_y: np.ndarray
    width_x: np.ndarray
    width_y: np.ndarray


@dataclass(frozen=True)
class Drive:
    """The true drive: a path of constant-curvature pieces and its timing.

    ``pieces`` ``(P, 5)`` ``[x0, y0, theta0, curvature, length]`` (theta unwrapped);
    ``t_knots`` / ``s_knots`` (s, m): arc length against time since the start, piecewise
    linear (repeated ``s`` = standing still).
    """

    pieces: np.ndarray
    t_knots: np.ndarray
    s_knots: np.ndarray

    def s_at(self, t_s: np.ndarray) -> np.ndarray:
        """Arc length (m) at times ``t_s`` (s since the start)."""
        return np.interp(t_s, self.t_knots, self.s_knots)

    def poses_at(self, t_s: np.ndarray) -> np.ndarray:
        """``(N, 3)`` true poses ``[x, y, theta]`` at ``t_s``, theta unwrapped."""
        return pose_on_path(self.pieces, self.s_at(np.asarray(t_s, dtype=np.float64)))


def _intervals(lo: float, hi: float, n: int, min_len: float, rng: np.random.Generator) -> list[tuple[float, float]]:
    """Split ``[lo, hi]`` into up to ``n`` lots no shorter than ``min_len``."""
    n = max(1, min(n, int((hi - lo) // min_len)))
    cuts = np.sort(rng.uniform(0.25, 0.75, n - 1) + np.arange(n - 1)) / n if n > 1 else []
    edges = [lo] + [lo + c * (hi - lo) for c in cuts] + [hi]
    return list(zip(edges[:-1], edges[1:]))


def _street_layout(rng: np.random.Generator, var: CarVariation = _DEFAULT) -> tuple[np.ndarray, ...]:
    pitch_x = rng.uniform(*var.pitch_x_m, N_STREETS - 1)
    pitch_y = rng.uniform(*var.pitch_y_m, N_STREETS - 1)
    sx = np.concatenate([[0.0], np.cumsum(pitch_x)])
    sy = np.concatenate([[0.0], np.cumsum(pitch_y)])
    wx = rng.uniform(9.0, 12.0, N_STREETS)
    wy = rng.uniform(9.0, 12.0, N_STREETS)
    return sx, sy, wx, wy


def _block_edges(s: np.ndarray, w: np.ndarray) -> list[tuple[float, float]]:
    """Along one axis: the block intervals between (and outside) the streets."""
    m = SIDEWALK_M
    lo = [s[0] - w[0] / 2 - m - OUTER_BLOCK_M] + list(s + w / 2 + m)
    hi = list(s - w / 2 - m) + [s[-1] + w[-1] / 2 + m + OUTER_BLOCK_M]
    return list(zip(lo, hi))


def _parking_lot(x0: float, y0: float, x1: float, y1: float, rng: np.random.Generator) -> list[tuple]:
    """Rows of parked cars (east-west rows 6 m apart, 2.6 m stalls, 70 % taken) in a lot."""
    out = []
    y = y0 + 2.0
    while y + 2.0 < y1 - 2.0:
        x = x0 + 2.0
        while x + 1.9 < x1 - 2.0:
            if rng.random() < 0.7:
                length, width = rng.uniform(4.2, 4.9), rng.uniform(1.7, 1.9)
                rgb = _CAR_RGB[rng.integers(len(_CAR_RGB))] + rng.uniform(-8, 8, 3)
                out.append(((x, y, 0.0, x + width, y + length, rng.uniform(1.4, 1.6)), KIND_CAR, rgb))
            x += 2.6
        y += 6.0
    return out


def _buildings(
    sx: np.ndarray,
    sy: np.ndarray,
    wx: np.ndarray,
    wy: np.ndarray,
    rng: np.random.Generator,
    var: CarVariation = _DEFAULT,
) -> list[tuple]:
    out = []
    for bx0, bx1 in _block_edges(sx, wx):
        for by0, by1 in _block_edges(sy, wy):
            for lx0, lx1 in _intervals(bx0, bx1, int(rng.integers(1, 4)), 14.0, rng):
                for ly0, ly1 in _intervals(by0, by1, int(rng.integers(1, 4)), 14.0, rng):
                    if rng.random() < var.open_lot_p:  # a plaza / parking lot
                        if var.parking_lot_p > 0 and rng.random() < var.parking_lot_p:
                            out += _parking_lot(lx0, ly0, lx1, ly1, rng)
                        continue
                    inset = rng.uniform(0.0, var.inset_max_m, 4)
                    h = 6.0 + 34.0 * rng.random() ** 1.6
                    rgb = _BUILDING_RGB[rng.integers(len(_BUILDING_RGB))] + rng.uniform(-12, 12, 3)
                    out.append(
                        ((lx0 + inset[0], ly0 + inset[1], 0.0, lx1 - inset[2], ly1 - inset[3], h), KIND_BUILDING, rgb)
                    )
    return out


def _street_furniture(
    sx: np.ndarray,
    sy: np.ndarray,
    wx: np.ndarray,
    wy: np.ndarray,
    rng: np.random.Generator,
    var: CarVariation = _DEFAULT,
) -> list[tuple]:
    """Parked cars along both kerbs and poles / trees on both sidewalks of every segment."""
    out = []
    for axis, (s_along, w_along, s_line, w_line) in enumerate(((sx, wx, sy, wy), (sy, wy, sx, wx))):
        # axis 0: east-west streets (along x at y = s_line); axis 1: north-south streets
        for c, w in zip(s_line, w_line):
            for i in range(N_STREETS - 1):
                a0 = s_along[i] + w_along[i] / 2 + 8.0
                a1 = s_along[i + 1] - w_along[i + 1] / 2 - 8.0
                for side in (-1.0, 1.0):
                    p = a0 + rng.uniform(0.0, 6.0)
                    while True:
                        if rng.random() < var.parked_car_p:
                            van = rng.random() < 0.12
                            length = rng.uniform(5.0, 6.5) if van else rng.uniform(4.2, 4.9)
                            width = rng.uniform(1.9, 2.1) if van else rng.uniform(1.7, 1.9)
                            height = rng.uniform(2.2, 2.8) if van else rng.uniform(1.4, 1.6)
                            if p + length > a1:
                                break
                            off = c + side * (w / 2 - 1.1 + rng.uniform(-0.1, 0.1))
                            box = [p, off - width / 2, 0.0, p + length, off + width / 2, height]
                            rgb = _CAR_RGB[rng.integers(len(_CAR_RGB))] + rng.uniform(-8, 8, 3)
                            out.append((_axis_box(box, axis), KIND_CAR, rgb))
                            p += length + rng.uniform(0.8, 2.5)
                        else:
                            p += rng.uniform(5.0, 15.0)
                        if p > a1:
                            break
                    # sidewalk: poles and trees 0.6 m behind the kerb
                    q = s_along[i] + w_along[i] / 2 + rng.uniform(4.0, 15.0)
                    e = c + side * (w / 2 + 0.6)
                    while q < s_along[i + 1] - w_along[i + 1] / 2 - 4.0:
                        if rng.random() < 1.0 - var.tree_p:
                            hgt = rng.uniform(7.0, 9.0)
                            out.append(
                                (
                                    _axis_box([q - 0.125, e - 0.125, 0.0, q + 0.125, e + 0.125, hgt], axis),
                                    KIND_POLE,
                                    np.array([120.0, 122.0, 125.0]),
                                )
                            )
                        else:
                            top = rng.uniform(2.6, 3.2)
                            out.append(
                                (
                                    _axis_box([q - 0.18, e - 0.18, 0.0, q + 0.18, e + 0.18, top], axis),
                                    KIND_TRUNK,
                                    np.array([90.0, 65.0, 45.0]),
                                )
                            )
                            r = rng.uniform(1.1, 1.5)
                            out.append(
                                (
                                    _axis_box([q - r, e - r, top, q + r, e + r, top + rng.uniform(2.2, 3.5)], axis),
                                    KIND_CROWN,
                                    np.array([60.0, 110.0, 45.0]) + rng.uniform(-15, 15, 3),
                                )
                            )
                        q += rng.uniform(*var.furniture_gap_m)
    return out


def _axis_box(box: list[float], axis: int) -> tuple[float, ...]:
    """``box`` given as (along, across) -> (x, y); axis 1 swaps x and y."""
    if axis == 0:
        return tuple(box)
    a0, c0, z0, a1, c1, z1 = box
    return (c0, a0, z0, c1, a1, z1)


def _paint(
    tex: np.ndarray, origin: np.ndarray, res: float, x0: float, y0: float, x1: float, y1: float, value: int
) -> None:
    c0 = max(int(round((x0 - origin[0]) / res)), 0)
    c1 = min(int(round((x1 - origin[0]) / res)), tex.shape[1])
    r0 = max(int(round((y0 - origin[1]) / res)), 0)
    r1 = min(int(round((y1 - origin[1]) / res)), tex.shape[0])
    if c1 > c0 and r1 > r0:
        tex[r0:r1, c0:c1] = value


def _noise(shape: tuple[int, int], sigma: float, cell: int, rng: np.random.Generator) -> np.ndarray:
    """Smooth-ish noise: white noise at ``cell`` texels, bilinear upsampled (float32)."""
    import cv2

    small = rng.standard_normal((shape[0] // cell + 2, shape[1] // cell + 2)).astype(np.float32)
    big = cv2.resize(small, (small.shape[1] * cell, small.shape[0] * cell), interpolation=cv2.INTER_LINEAR)
    return sigma * big[: shape[0], : shape[1]]


def _floor_texture(
    sx: np.ndarray,
    sy: np.ndarray,
    wx: np.ndarray,
    wy: np.ndarray,
    bounds: np.ndarray,
    rng: np.random.Generator,
    res: float = TEXTURE_RES_M,
) -> tuple[np.ndarray, np.ndarray]:
    """RGB floor texture (row 0 = lowest y) and the world position of its lower-left corner."""
    origin = np.array([bounds[0], bounds[1]])
    w = int(round((bounds[2] - bounds[0]) / res))
    h = int(round((bounds[3] - bounds[1]) / res))
    # class map: 0 ground, 1 sidewalk, 2 road, 3 white marking
    cls = np.zeros((h, w), dtype=np.uint8)
    xlo, ylo, xhi, yhi = bounds
    for c, wd in zip(sy, wy):
        _paint(cls, origin, res, xlo, c - wd / 2 - SIDEWALK_M, xhi, c + wd / 2 + SIDEWALK_M, 1)
    for c, wd in zip(sx, wx):
        _paint(cls, origin, res, c - wd / 2 - SIDEWALK_M, ylo, c + wd / 2 + SIDEWALK_M, yhi, 1)
    for c, wd in zip(sy, wy):
        _paint(cls, origin, res, xlo, c - wd / 2, xhi, c + wd / 2, 2)
    for c, wd in zip(sx, wx):
        _paint(cls, origin, res, c - wd / 2, ylo, c + wd / 2, yhi, 2)
    # markings, segment by segment (none inside the intersections)
    lw = 0.2
    for axis, (s_along, w_along, s_line, w_line) in enumerate(((sx, wx, sy, wy), (sy, wy, sx, wx))):

        def rect(a0: float, a1: float, b0: float, b1: float, axis: int = axis) -> None:
            if axis == 0:
                _paint(cls, origin, res, a0, b0, a1, b1, 3)
            else:
                _paint(cls, origin, res, b0, a0, b1, a1, 3)

        ends = [s_along[0] - w_along[0] / 2 - SIDEWALK_M - OUTER_BLOCK_M] + list(s_along + w_along / 2)
        starts_next = list(s_along - w_along / 2) + [s_along[-1] + w_along[-1] / 2 + SIDEWALK_M + OUTER_BLOCK_M]
        for c, wd in zip(s_line, w_line):
            edge = wd / 2 - PARKING_LANE_M
            for a0, a1 in zip(ends, starts_next):
                inner0, inner1 = a0 + 5.0, a1 - 5.0  # leave room for the crossings
                for sgn in (-1.0, 1.0):
                    rect(inner0, inner1, c + sgn * edge - lw / 2, c + sgn * edge + lw / 2)
                p = inner0 + 1.0
                while p + 3.0 < inner1:
                    rect(p, p + 3.0, c - lw / 2, c + lw / 2)
                    p += 8.0
                # zebra crossings 1..4 m before each intersection
                for z0, z1 in ((a0 + 1.0, a0 + 4.0), (a1 - 4.0, a1 - 1.0)):
                    b = c - wd / 2 + 0.5
                    while b + 0.5 < c + wd / 2 - 0.3:
                        rect(z0, z1, b, b + 0.5)
                        b += 1.0
    tex = np.empty((h, w, 3), dtype=np.float32)
    tex[:] = (105.0, 112.0, 80.0)  # ground: dusty grass
    grain = _noise((h, w), 1.0, 4, rng)  # 0.4 m cells: compresses well in PNG
    blotch = _noise((h, w), 1.0, 20, rng)
    side = cls == 1
    road = cls == 2
    mark = cls == 3
    tex[side] = (168.0, 165.0, 160.0)
    tex[road] = (78.0, 78.0, 82.0)
    tex[mark] = (225.0, 225.0, 220.0)
    amp = np.where(road, 11.0, np.where(side, 7.0, np.where(mark, 6.0, 14.0))).astype(np.float32)
    tex += (amp * grain + 8.0 * blotch)[..., None]
    # sidewalk tiles: darker joints every 0.6 m
    xs = origin[0] + (np.arange(w) + 0.5) * res
    ys = origin[1] + (np.arange(h) + 0.5) * res
    joint_x = (np.mod(xs, 0.6) < res)[None, :]
    joint_y = (np.mod(ys, 0.6) < res)[:, None]
    tex[side & (joint_x | joint_y)] -= 25.0
    return np.clip(np.rint(tex), 0, 255).astype(np.uint8), origin


def build_world(rng: np.random.Generator, var: CarVariation = _DEFAULT) -> tuple[CarWorld, dict]:
    """Seeded city world in the GRID frame (``shift_world`` moves it to the start frame).

    Returns the world and a dict of the street layout (``sx, sy, wx, wy``) for ``plan_route``.
    """
    sx, sy, wx, wy = _street_layout(rng, var)
    objs = _buildings(sx, sy, wx, wy, rng, var) + _street_furniture(sx, sy, wx, wy, rng, var)
    boxes = np.array([o[0] for o in objs], dtype=np.float64)
    kinds = np.array([o[1] for o in objs], dtype=np.int8)
    colours = np.clip(np.array([o[2] for o in objs]), 0, 255).astype(np.float32)
    bx = _block_edges(sx, wx)
    by = _block_edges(sy, wy)
    bounds = np.array([bx[0][0], by[0][0], bx[-1][1], by[-1][1]])
    tex, origin = _floor_texture(sx, sy, wx, wy, bounds, rng)
    world = CarWorld(
        boxes=boxes,
        kinds=kinds,
        colours=colours,
        bounds=bounds,
        texture=tex,
        texture_origin=origin,
        texture_res_m=TEXTURE_RES_M,
        street_x=sx,
        street_y=sy,
        width_x=wx,
        width_y=wy,
    )
    return world, {"sx": sx, "sy": sy, "wx": wx, "wy": wy}


def shift_world(world: CarWorld, shift_xy: np.ndarray) -> CarWorld:
    """``world`` translated by ``shift_xy`` (m)."""
    d = np.asarray(shift_xy, dtype=np.float64)
    boxes = world.boxes.copy()
    boxes[:, [0, 3]] += d[0]
    boxes[:, [1, 4]] += d[1]
    return CarWorld(
        boxes=boxes,
        kinds=world.kinds,
        colours=world.colours,
        bounds=world.bounds + np.tile(d, 2),
        texture=world.texture,
        texture_origin=world.texture_origin + d,
        texture_res_m=world.texture_res_m,
        street_x=world.street_x + d[0],
        street_y=world.street_y + d[1],
        width_x=world.width_x,
        width_y=world.width_y,
    )


def occupancy_grid(
    world: CarWorld,
    resolution_m: float,
    band_m: tuple[float, float] = (0.2, 2.0),
) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth occupancy: footprints of the boxes that overlap the height band ``band_m``.

    Returns ``(H, W)`` int8 (row 0 = lowest y; 100 occupied, 0 free; every cell of the world
    is known) and the origin (lower-left corner of cell ``(0, 0)``).
    """
    xmin, ymin, xmax, ymax = world.bounds
    origin = np.array([xmin, ymin])
    w = int(math.ceil((xmax - xmin) / resolution_m))
    h = int(math.ceil((ymax - ymin) / resolution_m))
    occ = np.zeros((h, w), dtype=np.int8)
    b = world.boxes
    keep = (b[:, 2] < band_m[1]) & (b[:, 5] > band_m[0])
    for x0, y0, _, x1, y1, _ in b[keep]:
        c0 = int(math.floor((x0 - origin[0]) / resolution_m + 0.5))
        c1 = max(int(math.floor((x1 - origin[0]) / resolution_m + 0.5)), c0 + 1)
        r0 = int(math.floor((y0 - origin[1]) / resolution_m + 0.5))
        r1 = max(int(math.floor((y1 - origin[1]) / resolution_m + 0.5)), r0 + 1)
        occ[max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] = 100
    return occ, origin


# --------------------------------------------------------------------------------------------
# route and drive

_DIRS = ((1, 0), (0, 1), (-1, 0), (0, -1))  # east, north, west, south


def _route_nodes(
    n_min_m: float,
    layout: dict,
    rng: np.random.Generator,
) -> list[tuple[int, int]]:
    """Start position and the list of grid nodes ``(i, j)`` to drive through."""
    n = N_STREETS
    sx, sy = layout["sx"], layout["sy"]
    ccw = bool(rng.random() < 0.5)
    w, h = int(rng.integers(1, 3)), int(rng.integers(1, 3))
    i0 = int(rng.integers(w - 1, n - 1))  # start on segment (i0, j0) -> (i0 + 1, j0)
    j0 = int(rng.integers(0, n - h)) if ccw else int(rng.integers(h, n))
    dy = 1 if ccw else -1
    nodes = [(i0, j0), (i0 + 1, j0)]
    nodes += [(i0 + 1, j0 + dy * k) for k in range(1, h + 1)]
    nodes += [(i0 + 1 - k, j0 + dy * h) for k in range(1, w + 1)]
    nodes += [(i0 + 1 - w, j0 + dy * (h - k)) for k in range(1, h + 1)]
    nodes += [(i0 + 1 - w + k, j0) for k in range(1, w + 1)]  # back through the start street
    length = 0.0
    for a, b in zip(nodes[:-1], nodes[1:]):
        length += abs(sx[a[0]] - sx[b[0]]) + abs(sy[a[1]] - sy[b[1]])
    while length < n_min_m:
        a, b = nodes[-2], nodes[-1]
        d = (b[0] - a[0], b[1] - a[1])
        k = _DIRS.index(d)
        options, weights = [], []
        for turn, wgt in ((0, 0.5), (1, 0.25), (-1, 0.25)):
            nd = _DIRS[(k + turn) % 4]
            nb = (b[0] + nd[0], b[1] + nd[1])
            if 0 <= nb[0] < n and 0 <= nb[1] < n:
                options.append(nb)
                weights.append(wgt)
        p = np.array(weights) / sum(weights)
        nb = options[int(rng.choice(len(options), p=p))]
        length += abs(sx[nb[0]] - sx[b[0]]) + abs(sy[nb[1]] - sy[b[1]])
        nodes.append(nb)
    return nodes


def plan_route(
    duration_s: float,
    layout: dict,
    rng: np.random.Generator,
    var: CarVariation = _DEFAULT,
) -> tuple[Drive, np.ndarray, np.ndarray]:
    """The seeded drive, in the GRID frame.

    Returns the drive, the start position (grid frame, the start heading is ``+x``) and the
    arc lengths of the stop points.
    """
    sx, sy, wx, wy = layout["sx"], layout["sy"], layout["wx"], layout["wy"]
    nodes = _route_nodes(max(12.0, var.speed_mps[1]) * duration_s + 300.0, layout, rng)

    def node_xy(nd: tuple[int, int]) -> np.ndarray:
        return np.array([sx[nd[0]], sy[nd[1]]])

    def lane_off(a: tuple[int, int], b: tuple[int, int]) -> float:
        # offset of the right lane from the centre line of the street a -> b
        wd = wy[a[1]] if a[1] == b[1] else wx[a[0]]
        return 0.5 * (wd / 2 - PARKING_LANE_M)

    def unit(a: tuple[int, int], b: tuple[int, int]) -> np.ndarray:
        d = node_xy(b) - node_xy(a)
        return d / np.linalg.norm(d)

    def right(u: np.ndarray) -> np.ndarray:
        return np.array([u[1], -u[0]])

    u0 = unit(nodes[0], nodes[1])
    frac = rng.uniform(0.3, 0.45)
    start = (
        node_xy(nodes[0]) + frac * (node_xy(nodes[1]) - node_xy(nodes[0])) + lane_off(nodes[0], nodes[1]) * right(u0)
    )
    pieces = []
    pos, heading = start.copy(), 0.0
    node_s = []  # arc length where the path passes each node
    s_acc = 0.0
    for k in range(1, len(nodes) - 1):
        u_in, u_out = unit(nodes[k - 1], nodes[k]), unit(nodes[k], nodes[k + 1])
        cross = u_in[0] * u_out[1] - u_in[1] * u_out[0]
        if abs(cross) < 1e-9:
            node_s.append(s_acc + float(np.dot(node_xy(nodes[k]) - pos, u_in)))
            continue
        turn = math.copysign(0.5 * math.pi, cross)
        radius = rng.uniform(8.0, 11.0) if cross > 0 else rng.uniform(4.5, 6.0)
        corner = (
            node_xy(nodes[k])
            + lane_off(nodes[k - 1], nodes[k]) * right(u_in)
            + lane_off(nodes[k], nodes[k + 1]) * right(u_out)
        )
        a_start = corner - radius * u_in
        line = float(np.dot(a_start - pos, u_in))
        pieces.append((pos[0], pos[1], heading, 0.0, line))
        pieces.append((a_start[0], a_start[1], heading, math.copysign(1.0 / radius, turn), radius * abs(turn)))
        node_s.append(s_acc + line + 0.5 * radius * abs(turn))
        s_acc += line + radius * abs(turn)
        heading += turn
        pos = corner + radius * u_out
    u_last = unit(nodes[-2], nodes[-1])
    end = node_xy(nodes[-1]) + lane_off(nodes[-2], nodes[-1]) * right(u_last)
    pieces.append((pos[0], pos[1], heading, 0.0, float(np.dot(end - pos, u_last))))
    pieces_a = np.array(pieces, dtype=np.float64)
    total = float(pieces_a[:, 4].sum())

    # speed limit along s: cruise speed per leg, lateral acceleration in the turns
    ds = 0.1
    s = np.arange(0.0, total, ds)
    s0 = np.concatenate([[0.0], np.cumsum(pieces_a[:, 4])[:-1]])
    idx = np.clip(np.searchsorted(s0, s, side="right") - 1, 0, len(pieces_a) - 1)
    kappa = np.abs(pieces_a[idx, 3])
    leg_v = rng.uniform(*var.speed_mps, len(pieces_a))
    vlim = np.minimum(leg_v[idx], np.sqrt(2.5 / np.maximum(kappa, 1e-9)))
    # stops: before the intersection nearest to each target distance
    n_stops = max(1, int(round(duration_s / var.stop_every_s)))
    node_s_a = np.array(node_s)
    stops = []
    for k in range(n_stops):
        target = (k + 0.4) / n_stops * duration_s * (0.9 * float(np.mean(var.speed_mps)))
        cand = node_s_a[node_s_a > 40.0]
        ns = cand[np.argmin(np.abs(cand - target))]
        stops.append(ns - 14.0)
    stops_a = np.unique(np.array(stops))
    stop_idx = np.searchsorted(s, stops_a)
    vlim[0] = 0.0
    vlim[stop_idx] = 0.0
    a_acc, a_dec = 1.8, 2.5
    v = vlim.copy()
    for i in range(1, len(v)):  # forward pass (acceleration limit)
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2 * a_acc * ds))
    for i in range(len(v) - 2, -1, -1):  # backward pass (braking limit)
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * a_dec * ds))
    dt = 2.0 * ds / np.maximum(v[1:] + v[:-1], 1e-6)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    # holds: 1 s at the start, 3-8 s at each stop
    holds = {0: 1.0}
    for i in stop_idx:
        holds[int(i)] = float(rng.uniform(*var.stop_hold_s))
    t_k, s_k, shift = [], [], 0.0
    for i in range(len(s)):
        t_k.append(t[i] + shift)
        s_k.append(s[i])
        if i in holds:
            shift += holds[i]
            t_k.append(t[i] + shift)
            s_k.append(s[i])
    drive = Drive(pieces=pieces_a, t_knots=np.array(t_k), s_knots=np.array(s_k))
    return drive, start, s[stop_idx]
