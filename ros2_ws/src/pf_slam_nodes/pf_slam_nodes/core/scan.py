"""Laser scan geometry: beam angles, endpoints, frame transforms."""

from __future__ import annotations

import math

import numpy as np


def beam_angles(angle_min: float, angle_increment: float, n: int) -> np.ndarray:
    """Angles of ``n`` beams, ``angle_min + i * angle_increment`` (sensor_msgs/LaserScan).

    Parameters
    ----------
    angle_min : float
        Angle of the first beam (rad).
    angle_increment : float
        Angle between consecutive beams (rad).
    n : int
        Number of beams.

    Returns
    -------
    numpy.ndarray
        ``(n,)`` float64 angles (rad).
    """
    return float(angle_min) + float(angle_increment) * np.arange(int(n), dtype=np.float64)


def valid_beams(ranges: np.ndarray, range_min: float, range_max: float) -> np.ndarray:
    """Mask of finite beams with ``range_min <= r <= range_max``.

    Parameters
    ----------
    ranges : numpy.ndarray
        ``(B,)`` ranges (m); inf/NaN allowed.

    Returns
    -------
    numpy.ndarray
        ``(B,)`` bool.
    """
    r = np.asarray(ranges, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.isfinite(r) & (r >= range_min) & (r <= range_max)


def sparse_scan_range(ranges: np.ndarray, cut_m: float, range_max: float, min_fraction: float) -> float:
    """The range cut for one scan: ``cut_m``, raised (up to the sensor's ``range_max``) until at
    least ``min_fraction`` of the scan's beams return within it (fewer returns in all: all of
    them). Indoors a quarter of the beams always return within 20 m; in open outdoor spaces a
    scan may return only a few beams that close, and the match then needs the far ones.

    Parameters
    ----------
    ranges : numpy.ndarray
        ``(B,)`` ranges (m); inf/NaN allowed (no return).
    cut_m : float
        The configured cut (m).
    range_max : float
        The sensor's maximum range (m): returns beyond it are not returns.
    min_fraction : float
        0 (or less): the cut is ``cut_m``.
    """
    r = np.asarray(ranges, dtype=np.float64)
    if min_fraction <= 0.0 or r.size == 0:
        return float(cut_m)
    ret = r[valid_beams(r, 0.0, range_max) & (r > 0.0)]
    k = min(int(math.ceil(min_fraction * r.size)), ret.size)
    if k == 0 or np.count_nonzero(ret <= cut_m) >= k:
        return float(cut_m)
    return float(np.partition(ret, k - 1)[k - 1])


def shadow_beams(ranges: np.ndarray, jump_m: float, beams: int = 1) -> np.ndarray:
    """``(B,)`` bool: the beams on the far side of an occluding edge, those with a neighbour
    within ``beams`` beams (in scan order) whose range is shorter by more than ``jump_m``. Beams
    without a finite range are never such a neighbour and never flagged. ``jump_m <= 0``: none."""
    r = np.asarray(ranges, dtype=np.float64)
    out = np.zeros(r.shape, dtype=bool)
    if jump_m <= 0.0 or r.size < 2:
        return out
    f = np.where(np.isfinite(r), r, np.inf)
    for j in range(1, min(int(beams), r.size - 1) + 1):
        closer = f[:-j] < f[j:] - jump_m  # beam i - j in front of beam i
        out[j:] |= closer
        out[:-j] |= f[j:] < f[:-j] - jump_m  # beam i + j in front of beam i
    return out & np.isfinite(r)


def shadow_neighbours(angles: np.ndarray, beams: int, angle_rad: float) -> int:
    """The beams on each side that :func:`shadow_beams` looks at: ``beams``, or as many as lie
    within ``angle_rad`` of a beam at the scan's beam spacing (the median step of ``angles``)
    if that is more; ``angle_rad <= 0``: ``beams``."""
    a = np.asarray(angles, dtype=np.float64).reshape(-1)
    if angle_rad <= 0.0 or a.size < 2:
        return int(beams)
    step = float(np.median(np.abs(np.diff(a))))
    return max(int(beams), int(math.floor(angle_rad / step + 1e-9)) if step > 0.0 else 0)


def scan_to_points(
    ranges: np.ndarray,
    angles: np.ndarray,
    range_min: float,
    range_max: float,
    stride: int = 1,
) -> np.ndarray:
    """Beam endpoints in the sensor frame for valid beams.

    Parameters
    ----------
    ranges : numpy.ndarray
        ``(B,)`` ranges (m). inf, NaN, ``< range_min`` and ``> range_max`` are dropped.
    angles : numpy.ndarray
        ``(B,)`` beam angles (rad).
    range_min, range_max : float
        Valid range interval (m), inclusive.
    stride : int
        Keep every ``stride``-th beam (applied before the validity filter).

    Returns
    -------
    numpy.ndarray
        ``(M, 2)`` float64 endpoints ``[x, y]`` (m), M <= ceil(B / stride).
    """
    r = np.asarray(ranges, dtype=np.float64)[::stride]
    a = np.asarray(angles, dtype=np.float64)[::stride]
    if r.shape != a.shape:
        raise ValueError(f"ranges and angles must have the same length, got {r.shape} and {a.shape}")
    m = valid_beams(r, range_min, range_max)
    r = r[m]
    a = a[m]
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=-1)


def on_line(px: np.ndarray, py: np.ndarray, max_deg: float = 5.0):
    """Which beam ends (in scan order) lie on one line with their previous and next ends (within
    ``max_deg``): a smooth surface, not a range jump at an edge or clutter. Returns ``(K,)`` bool
    (the first and last ends: False) and the tangents to the previous and to the next end
    ``tpx, tpy, tnx, tny`` (``(K,)``, zero at the first and last)."""
    tpx, tpy = np.zeros(px.size), np.zeros(px.size)
    tnx, tny = np.zeros(px.size), np.zeros(px.size)
    tpx[1:-1], tpy[1:-1] = px[1:-1] - px[:-2], py[1:-1] - py[:-2]
    tnx[1:-1], tny[1:-1] = px[2:] - px[1:-1], py[2:] - py[1:-1]
    dot = tpx * tnx + tpy * tny
    crs = np.abs(tpx * tny - tpy * tnx)
    line = (dot > 0) & (crs <= math.sin(math.radians(max_deg)) * np.hypot(tpx, tpy) * np.hypot(tnx, tny))
    return line, tpx, tpy, tnx, tny


def line_incidence(px: np.ndarray, py: np.ndarray, sx: float = 0.0, sy: float = 0.0):
    """For beam ends ``px, py`` (``(K,)``, scan order) seen from a sensor at ``(sx, sy)``: which
    lie on one line with their neighbours (:func:`on_line`), ``1 / sin`` of the angle between the
    beam and that line (the previous to the next end; 1 head-on, large when grazing; 1 where the
    end is on no line) and the distance from the previous to the next end, each ``(K,)``."""
    line, tpx, tpy, tnx, tny = on_line(px, py)
    tx, ty = tpx + tnx, tpy + tny
    span = np.hypot(tx, ty)
    ux, uy = px - sx, py - sy
    cross = np.abs(ux * ty - uy * tx)
    norm = np.hypot(ux, uy) * span
    with np.errstate(invalid="ignore", divide="ignore"):
        inv_sin = np.where(norm > 0, norm / np.maximum(cross, 1e-12), 1.0)
    return line, np.where(line, inv_sin, 1.0), span


def grazing_samples(points: np.ndarray, min_span_m: float, min_incidence_deg: float = 70.0) -> np.ndarray:
    """``(M,)`` bool: the returns (``points`` ``(M, 2)`` in scan order, sensor frame) that sample a
    straight surface sparsely at a grazing angle: the return lies on one line with its previous
    and next ones (:func:`line_incidence`), those two are more than ``min_span_m`` apart, and the
    line meets the beam more than ``min_incidence_deg`` from the surface normal. Along a corridor
    these are the far returns from its side walls; a map keeps them only as dots that later rays
    graze away, so where its walls end moves with the estimate."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    line, inv_sin, span = line_incidence(pts[:, 0], pts[:, 1])
    return line & (span > min_span_m) & (inv_sin > 1.0 / math.cos(math.radians(min_incidence_deg)))


def transform_points(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Map points from the frame of ``pose`` into the parent frame.

    Parameters
    ----------
    points : numpy.ndarray
        ``(M, 2)`` points in the local frame.
    pose : numpy.ndarray
        ``(3,)`` pose of the local frame in the parent frame.

    Returns
    -------
    numpy.ndarray
        ``(M, 2)`` float64 points in the parent frame.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    x, y, th = (float(v) for v in np.asarray(pose, dtype=np.float64).reshape(3))
    c, s = np.cos(th), np.sin(th)
    out = np.empty_like(p)
    out[:, 0] = x + c * p[:, 0] - s * p[:, 1]
    out[:, 1] = y + s * p[:, 0] + c * p[:, 1]
    return out


def transform_points_batch(points: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Map one point set through many poses.

    Parameters
    ----------
    points : numpy.ndarray
        ``(M, 2)`` points in the local frame.
    poses : numpy.ndarray
        ``(N, 3)`` poses.

    Returns
    -------
    numpy.ndarray
        ``(N, M, 2)`` float64 points in the parent frame.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    q = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    c = np.cos(q[:, 2])[:, None]
    s = np.sin(q[:, 2])[:, None]
    out = np.empty((q.shape[0], p.shape[0], 2))
    out[..., 0] = q[:, 0:1] + c * p[None, :, 0] - s * p[None, :, 1]
    out[..., 1] = q[:, 1:2] + s * p[None, :, 0] + c * p[None, :, 1]
    return out


def scan_limits_ok(range_min: float, range_max: float) -> bool:
    """Whether a scan's ``range_min`` / ``range_max`` can gate its ranges: ``range_min`` finite,
    ``0 <= range_min <= range_max``, ``range_max > 0`` and not NaN (``+inf``: no upper limit,
    the core's default). A scan that fails this has no valid range (REP 117: values outside the
    limits are no returns), so nothing of it is used."""
    return math.isfinite(range_min) and 0.0 <= range_min <= range_max and range_max > 0.0 and not math.isnan(range_max)


def gate_ranges(ranges: np.ndarray, range_min: float, range_max: float) -> np.ndarray:
    """A scan's ranges gated by its own limits (sensor_msgs/LaserScan, REP 117), float64 ``(B,)``.

    Finite values outside ``[range_min, range_max]`` are not measurements (an RPLidar reports
    up to 22 m with ``range_max`` 12): they become NaN, which every stage ignores (never a hit,
    never free space). ``+inf`` stays: "nothing within range", traced as free space by the
    mapper. ``-inf`` (too close) and NaN stay ignored. Bad limits (:func:`scan_limits_ok`
    false) gate every beam out.
    """
    r = np.asarray(ranges, dtype=np.float64)
    if not scan_limits_ok(range_min, range_max):
        return np.full(r.shape, np.nan)
    with np.errstate(invalid="ignore"):
        outside = (r < range_min) | ((r > range_max) & (r != np.inf))
    if not outside.any():
        return r
    return np.where(outside, np.nan, r)


def planar_scan(
    ranges: np.ndarray,
    angles: np.ndarray,
    laser,
    planar_offset: np.ndarray,
    range_min: float = 0.0,
    range_max: float = math.inf,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A scan as a planar sensor in the vehicle frame sees it: ``(ranges, angles, offset (3,))``.

    First the scan's own limits gate its ranges (:func:`gate_ranges`; ``range_min``,
    ``range_max``: the message's fields): a finite value outside them is NaN, ignored
    downstream. For a planar laser (``laser.is_3d`` false) the scan is then returned with
    ``planar_offset`` (its mount ``[x, y, yaw]`` in the base frame), gated by
    ``laser.min_range_m`` (below: NaN) and ``laser.max_range_m`` (beyond: ``+inf``, no return).
    For a 3D mount (see :class:`~pf_slam_nodes.core.config.LaserConfig`: a tilted laser, or an
    upside-down one, whose scan is mirrored) every return is projected into the vehicle frame,
    gated by range and height, and re-expressed as range/bearing from the sensor's ground
    projection ``(T_x, T_y)``; dropped beams become NaN (ignored downstream, never "free
    space"). Vectorised over beams.
    """
    r = gate_ranges(ranges, range_min, range_max)
    a = np.asarray(angles, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        out_of_gate = (r < laser.min_range_m) | (r > laser.max_range_m)
    if not laser.is_3d:
        # beyond max_range_m: no return (inf), below min_range_m: ignored (NaN)
        r = np.where(r < laser.min_range_m, np.nan, np.where(r > laser.max_range_m, np.inf, r))
        return r, a, np.asarray(planar_offset, dtype=np.float64).reshape(3)
    ext = np.asarray(laser.extrinsic, dtype=np.float64)
    rot, t = ext[:9].reshape(3, 3), ext[9:]
    if abs(abs(rot[2, 2]) - 1.0) < 1e-9:
        # scan plane horizontal (upside down: rot[2, 2] = -1, a mirrored scan): exact 2D, the
        # ranges as they are, each beam at yaw +- its angle; no-returns stay free space
        keep_all = laser.min_height_m <= t[2] <= laser.max_height_m
        r = np.where(r < laser.min_range_m, np.nan, np.where(r > laser.max_range_m, np.inf, r))
        if not keep_all:
            r = np.full(r.shape, np.nan)
        yaw = math.atan2(rot[1, 0], rot[0, 0])
        return r, yaw + math.copysign(1.0, rot[2, 2]) * a, np.array([t[0], t[1], 0.0])
    with np.errstate(invalid="ignore"):
        local = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)])  # (3, B)
        p = rot @ local + t[:, None]
        keep = np.isfinite(r) & ~out_of_gate & (p[2] >= laser.min_height_m) & (p[2] <= laser.max_height_m)
    dx, dy = p[0] - t[0], p[1] - t[1]
    r2 = np.where(keep, np.hypot(dx, dy), np.nan)
    a2 = np.where(keep, np.arctan2(dy, dx), 0.0)
    return r2, a2, np.array([t[0], t[1], 0.0])


def range_noise(ranges: np.ndarray, angles: np.ndarray, max_span_m: float = 0.5) -> float:
    """The scan's range noise (m, std), from the beams themselves: each middle beam of three
    consecutive returns against the chord of its two neighbours (its range minus where its ray
    meets the chord), over triplets that are close (< ``max_span_m``) and not grazing (the
    chord at most twice the beams' arc); robust (median absolute deviation), divided by
    sqrt(1.5) (the chord's own noise). NaN with fewer than 20 such triplets."""
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    if r.size < 3:
        return math.nan
    return _chord_noise(r, a, *_returns_xy(r, a), max_span_m)


def _returns_xy(r: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(ok, x, y)``: the beams with a return (finite, > 0) and their end points (0 elsewhere)."""
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(r) & (r > 0.0)
        return ok, np.where(ok, r * np.cos(a), 0.0), np.where(ok, r * np.sin(a), 0.0)


def _chord_noise(r, a, ok, x, y, max_span_m: float = 0.5) -> float:
    """:func:`range_noise` of a scan whose :func:`_returns_xy` are computed (``r.size >= 3``)."""
    with np.errstate(invalid="ignore"):
        m = ok[:-2] & ok[1:-1] & ok[2:]
        dx, dy = x[2:] - x[:-2], y[2:] - y[:-2]
        span = np.hypot(dx, dy)
        arc = np.abs(a[2:] - a[:-2]) * np.where(ok[1:-1], r[1:-1], 0.0)
        ux, uy = np.cos(a[1:-1]), np.sin(a[1:-1])
        den = ux * dy - uy * dx
        m &= (span > 1e-9) & (span < max_span_m) & (span < 2.0 * arc) & (np.abs(den) > 1e-12)
        if m.sum() < 20:
            return math.nan
        t = (x[:-2] * dy - y[:-2] * dx)[m] / den[m]
        res = r[1:-1][m] - t
    return float(1.4826 * np.median(np.abs(res - np.median(res))) / math.sqrt(1.5))


#: lattices a log may round its ranges to (m), coarsest last
ROUNDING_STEPS_M = (0.02, 0.025, 0.05, 0.1)


def range_rounding(ranges: np.ndarray, steps=ROUNDING_STEPS_M, concentration: float = 0.5) -> float:
    """The coarsest of ``steps`` (m) the scan's ranges are rounded to, whatever the lattice's
    offset: the ranges' phases ``2 pi r / step`` concentrate (mean resultant length above
    ``concentration``; about 1 / sqrt(beams) for ranges that are not rounded to it). 0.0: none."""
    r = np.asarray(ranges, dtype=np.float64)
    r = r[np.isfinite(r)]
    if r.size < 10:
        return 0.0
    found = 0.0
    for q in steps:
        if abs(np.exp(2j * np.pi * r / q).mean()) > concentration:
            found = q
    return found


def smooth_scan(
    ranges: np.ndarray, angles: np.ndarray, half: int, min_noise_m: float = 0.0, gate: float = 2.0
) -> tuple[np.ndarray, float, str]:
    """``(ranges, noise, verdict)``: the ranges with each return moved onto the line fitted (total least squares) to it and its
    ``half`` neighbours on each side, where those ``2 half + 1`` returns lie on one line within
    the scan's own noise: RMS distance to the line at most ``gate`` times :func:`range_noise`,
    the beam not grazing it (incidence < 75 deg) and the move at most 3 noise std. Elsewhere
    (edges, corners, clutter, no returns) the range is unchanged.

    The scan is returned unchanged when ``half`` is 0, when its noise is below ``min_noise_m``
    (a precise laser loses more at corners than it gains), or when its ranges are rounded to a
    lattice of 2 cm or coarser (:func:`range_rounding`): the chords then hold the
    staircase of the rounding, not independent noise (measured: three real logs rounded to
    2.5 cm and simulated worlds rounded to 5 cm map worse smoothed). ``noise``: the scan's
    :func:`range_noise` (NaN where not estimated); ``verdict``: ``smoothed``, ``precise`` (below
    ``min_noise_m``), ``rounded``, or ``unknown`` (too few beams to tell, or ``half`` 0).
    Vectorised over beams."""
    r = np.asarray(ranges, dtype=np.float64)
    if half <= 0 or r.size < 2 * half + 1:
        return r, math.nan, "unknown"
    a = np.asarray(angles, dtype=np.float64)
    ok, x, y = _returns_xy(r, a)  # shared by the noise estimate and the line fits
    sigma = _chord_noise(r, a, ok, x, y)
    if not math.isfinite(sigma):
        return r, sigma, "unknown"
    if sigma < min_noise_m or sigma <= 0.0:
        return r, sigma, "precise"
    if range_rounding(r) > 0.0:
        return r, sigma, "rounded"
    w = 2 * half + 1
    with np.errstate(invalid="ignore"):
        view = np.lib.stride_tricks.sliding_window_view
        okw = view(ok, w).all(axis=1)
        xw, yw = view(x, w), view(y, w)
        cx, cy = xw.mean(axis=1), yw.mean(axis=1)
        ex, ey = xw - cx[:, None], yw - cy[:, None]
        sxx, syy, sxy = (ex * ex).mean(axis=1), (ey * ey).mean(axis=1), (ex * ey).mean(axis=1)
        # the line's direction: the principal axis; its normal n
        phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
        nx, ny = -np.sin(phi), np.cos(phi)
        resid = ex * nx[:, None] + ey * ny[:, None]
        rms = np.sqrt((resid * resid).mean(axis=1))
        c = a[half : r.size - half]
        ux, uy = np.cos(c), np.sin(c)
        dot = ux * nx + uy * ny
        t = (cx * nx + cy * ny) / np.where(np.abs(dot) > 1e-12, dot, np.nan)
        rc = r[half : r.size - half]
        use = okw & (rms <= gate * sigma) & (np.abs(dot) > math.cos(math.radians(75.0)))
        use &= np.abs(t - rc) <= 3.0 * sigma
    out = r.copy()
    out[half : r.size - half] = np.where(use, t, rc)
    return out, sigma, "smoothed"


class NoiseTally:
    """What :func:`smooth_scan` found over a run: scans per verdict and the median noise
    (summary.json ``laser_noise``)."""

    def __init__(self) -> None:
        self.counts = {"smoothed": 0, "precise": 0, "rounded": 0, "unknown": 0}
        self.noise: list[float] = []
        self.last = math.nan  # the latest scan's noise

    def add(self, noise: float, verdict: str) -> None:
        self.counts[verdict] += 1
        self.last = noise
        if math.isfinite(noise):
            self.noise.append(noise)

    def status(self) -> dict:
        med = float(np.median(self.noise)) if self.noise else None
        return {"scans": self.counts, "noise_m_median": None if med is None else round(med, 4)}
