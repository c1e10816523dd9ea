"""A building drawn from the seed, for the worlds bench: every seed is another floor plan.

The floor is a lattice of corridors (3-5 north-south by 2-4 east-west, 10-30 m apart, each
1.8-3.5 m wide). Each block between them is one of:

* **rooms** -- a row of rooms (3-6 m wide, a door each at a random place, some with a desk)
  along its south and its north face, back to back;
* **solid** -- a closed block (plain walls);
* **hall** -- no walls, a grid of pillars (4-7 m apart) and a few tables: open space whose
  structure is sparse (at most one per floor).

Some corridors have pillars along one wall (4-8 m apart). The robot starts in the south-west
corridor heading east and drives the lattice without turning back, preferring corridors it has
not driven yet, until it has covered 300-600 m; then it takes the shortest way home and closes
the loop where it started (3 % past the start, as the other worlds): several loops of different
sizes, junctions passed more than once, corridors that look alike. Speed 1-2 m/s.

:func:`maze_layout` draws the floor plan, :func:`maze_route` the drive's turns; the builder
``maze`` of :data:`pf_slam_tools.sim.worlds.WORLDS` puts them together (the world in the start
frame and the true poses, as the other worlds).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from .indoor import IndoorWorld
from .worlds import _hwall, _segments_of_boxes

__all__ = ["maze_layout", "maze_route"]

_DIRS = ((1, 0), (0, 1), (-1, 0), (0, -1))  # east, north, west, south


def _box_outline(x0: float, y0: float, x1: float, y1: float) -> list[tuple]:
    """The four walls of the rectangle ``[x0, x1] x [y0, y1]``."""
    box = [(0.5 * (x0 + x1), 0.5 * (y0 + y1), x1 - x0, y1 - y0, 0.0)]
    return [tuple(seg) for seg in _segments_of_boxes(np.array(box))]


def _rooms(x0: float, y0: float, x1: float, y1: float, rng: np.random.Generator) -> tuple[list, list]:
    """A block of rooms along its south and north faces (back wall at mid-depth)."""
    segs: list[tuple] = [(x0, y0, x0, y1), (x1, y0, x1, y1)]
    boxes: list[tuple] = []
    mid = 0.5 * (y0 + y1)
    segs.append((x0, mid, x1, mid))
    for face, inner in ((y0, mid), (y1, mid)):
        edges = [x0]
        while x1 - edges[-1] > 9.0:
            edges.append(edges[-1] + rng.uniform(3.0, 6.0))
        edges.append(x1)
        gaps = []
        for a, b in zip(edges[:-1], edges[1:]):
            dw = rng.uniform(0.9, 1.3)
            gaps.append((rng.uniform(a + 0.3 + 0.5 * dw, b - 0.3 - 0.5 * dw), dw))
            if rng.random() < 0.5:  # a desk somewhere in the room
                lx, ly = rng.uniform(0.6, 1.6), rng.uniform(0.5, 0.8)
                cx = rng.uniform(a + 0.4 + 0.5 * lx, max(b - 0.4 - 0.5 * lx, a + 0.4 + 0.5 * lx + 1e-6))
                lo, hi = sorted((face, inner))
                cy = rng.uniform(lo + 0.4 + 0.5 * ly, max(hi - 0.4 - 0.5 * ly, lo + 0.4 + 0.5 * ly + 1e-6))
                boxes.append((cx, cy, lx, ly, 0.0))
        segs += _hwall(face, x0, x1, [c for c, _ in gaps], [w for _, w in gaps])
        segs += [(x, face, x, inner) for x in edges[1:-1]]
    return segs, boxes


def _hall(x0: float, y0: float, x1: float, y1: float, rng: np.random.Generator) -> list[tuple]:
    """Pillars on a grid inside the block and a few tables: no walls."""
    step = rng.uniform(4.0, 7.0)
    xs = np.arange(x0 + 1.5, x1 - 1.0, step)
    ys = np.arange(y0 + 1.5, y1 - 1.0, step)
    boxes = [(float(x), float(y), 0.5, 0.5, 0.0) for x in xs for y in ys]
    for _ in range(int(rng.integers(1, 4))):
        boxes.append(
            (
                rng.uniform(x0 + 2, x1 - 2),
                rng.uniform(y0 + 2, y1 - 2),
                rng.uniform(0.8, 2.0),
                0.8,
                rng.uniform(0, math.pi),
            )
        )
    return boxes


def _corridor_pillars(a: np.ndarray, b: np.ndarray, half_w: float, rng: np.random.Generator) -> list[tuple]:
    """Pillars (0.4 m) along one wall of the corridor from node ``a`` to node ``b``, clear of the
    junctions."""
    u = (b - a) / np.linalg.norm(b - a)
    nrm = np.array([-u[1], u[0]]) * rng.choice([-1.0, 1.0])
    off = half_w - 0.25
    out, t, n = [], 3.0 + rng.uniform(0.0, 3.0), float(np.linalg.norm(b - a))
    while t < n - 3.0:
        p = a + u * t + nrm * off
        out.append((float(p[0]), float(p[1]), 0.4, 0.4, 0.0))
        t += rng.uniform(4.0, 8.0)
    return out


def maze_layout(rng: np.random.Generator) -> tuple[IndoorWorld, np.ndarray, np.ndarray]:
    """The floor plan: ``(world, xs (nx,), ys (ny,))``, the corridors' centre lines (floor-plan
    coordinates, the south-west junction at the origin)."""
    nx, ny = int(rng.integers(3, 6)), int(rng.integers(2, 5))
    xs = np.concatenate([[0.0], np.cumsum(rng.uniform(10.0, 30.0, nx - 1))])
    ys = np.concatenate([[0.0], np.cumsum(rng.uniform(10.0, 24.0, ny - 1))])
    wx, wy = rng.uniform(1.8, 3.5, nx), rng.uniform(1.8, 3.5, ny)
    bx0, bx1 = xs[0] - 0.5 * wx[0], xs[-1] + 0.5 * wx[-1]
    by0, by1 = ys[0] - 0.5 * wy[0], ys[-1] + 0.5 * wy[-1]
    segs: list[tuple] = _box_outline(bx0, by0, bx1, by1)
    boxes: list[tuple] = []
    halls = 0
    for i in range(nx - 1):
        for j in range(ny - 1):
            x0, x1 = xs[i] + 0.5 * wx[i], xs[i + 1] - 0.5 * wx[i + 1]
            y0, y1 = ys[j] + 0.5 * wy[j], ys[j + 1] - 0.5 * wy[j + 1]
            kind = rng.choice(["rooms", "solid", "hall"], p=[0.5, 0.3, 0.2])
            if kind == "hall" and halls:
                kind = "rooms"
            if kind == "rooms":
                s, b = _rooms(x0, y0, x1, y1, rng)
                segs += s
                boxes += b
            elif kind == "solid":
                segs += _box_outline(x0, y0, x1, y1)
            else:
                halls += 1
                boxes += _hall(x0, y0, x1, y1, rng)
    # pillars along some corridors: every north-south stretch between junctions, then every east-west one
    stretches = [((xs[i], ys[j]), (xs[i], ys[j + 1]), wx[i]) for i in range(nx) for j in range(ny - 1)]
    stretches += [((xs[i], ys[j]), (xs[i + 1], ys[j]), wy[j]) for j in range(ny) for i in range(nx - 1)]
    for a, b, width in stretches:
        if rng.random() < 0.3:
            boxes += _corridor_pillars(np.array(a), np.array(b), 0.5 * width, rng)
    b = np.array(boxes, dtype=np.float64).reshape(-1, 5)
    segments = np.concatenate([np.array(segs, dtype=np.float64).reshape(-1, 4), _segments_of_boxes(b)])
    return IndoorWorld(segments=segments, boxes=b, bounds=np.array([bx0, by0, bx1, by1])), xs, ys


def maze_route(xs: np.ndarray, ys: np.ndarray, target_m: float, rng: np.random.Generator) -> list[tuple[int, int]]:
    """Lattice nodes (indices into the corridors' centre lines ``xs``, ``ys``) where the route
    turns, from the start (on the south-west corridor, heading east to node (1, 0)) back to node
    (0, 0), which it enters heading south. No U-turns; corridors not yet driven are 4x as likely;
    it heads home once it has driven ``target_m``."""
    nx, ny = len(xs), len(ys)

    def nbr(node, d):
        i, j = node[0] + _DIRS[d][0], node[1] + _DIRS[d][1]
        return (i, j) if 0 <= i < nx and 0 <= j < ny else None

    node, head, length = (1, 0), 0, 0.0
    path = [((0, 0), 0), (node, head)]
    driven = {((0, 0), (1, 0))}
    while length < target_m:
        opts = [d for d in range(4) if d != (head + 2) % 4 and nbr(node, d) is not None]
        w = np.array([4.0 if tuple(sorted((node, nbr(node, d)))) not in driven else 1.0 for d in opts])
        d = opts[int(rng.choice(len(opts), p=w / w.sum()))]
        nxt = nbr(node, d)
        driven.add(tuple(sorted((node, nxt))))
        length += abs(xs[nxt[0]] - xs[node[0]]) + abs(ys[nxt[1]] - ys[node[1]])
        node, head = nxt, d
        path.append((node, head))
    # shortest way home without U-turns: enter (0, 0) heading south
    start = (node, head)
    prev = {start: None}
    q = deque([start])
    goal = ((0, 0), 3)
    while q and goal not in prev:
        s = q.popleft()
        for d in range(4):
            if d == (s[1] + 2) % 4 or nbr(s[0], d) is None:
                continue
            t = (nbr(s[0], d), d)
            if t not in prev:
                prev[t] = s
                q.append(t)
    home = []
    s = goal
    while s != start:
        home.append(s)
        s = prev[s]
    path += home[::-1]
    # the turning nodes: where the heading changes (and (0, 0), the last turn onto the start leg)
    return [path[k][0] for k in range(1, len(path)) if k + 1 >= len(path) or path[k + 1][1] != path[k][1]]
