"""Reader for CARMEN log files (``.clf``): 2D laser scans and odometry.

Handled message types
---------------------
``FLASER`` (old style, front laser)::

    FLASER n r1 .. rn x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname logger_timestamp

``x y theta`` is the pose of the laser and ``odom_x odom_y odom_theta`` the robot's odometry pose
at the scan, both in the odometry frame. The line carries no angles; the convention of CARMEN
and GMapping is a 180 deg field of view, beams from right to left starting at -90 deg:

* ``angle_min = -pi/2``;
* ``angle_increment = pi / n`` if ``n`` is even (180 beams -> 1 deg, -90 .. +89 deg),
  ``pi / (n - 1)`` if ``n`` is odd (181 -> 1 deg, 361 -> 0.5 deg, both -90 .. +90 deg).

``ROBOTLASER1``::

    ROBOTLASER1 laser_type start_angle fov angular_res max_range accuracy remission_mode
                n r1 .. rn m rem1 .. remm laser_x laser_y laser_theta robot_x robot_y robot_theta
                tv rv forward_safety_dist side_safety_dist turn_axis timestamp host logger_timestamp

with ``angle_min = start_angle`` and ``angle_increment = angular_res`` (radians), as written.

``ODOM``::

    ODOM x y theta tv rv accel timestamp host logger_timestamp

The stamp of every message is its ``ipc_timestamp`` (the third field from the end), in seconds.

Everything else
---------------
* A gzip-compressed log (``.log.gz``) is read directly; a cut-off or damaged stream keeps the
  lines before the damage (one warning, skipped ``"damaged gzip"``).
* ``#`` lines are comments; empty lines are ignored.
* Other message types (``PARAM``, ``SYNC``, ``RAWLASER1`` ...) are skipped and counted in
  ``CarmenLog.skipped`` under their type name, with one warning per type naming its first line.
* A malformed line (wrong number of fields for its beam count, a ``ROBOTLASER1`` beam count
  that does not fill the header's fov, a non-numeric field, NaN/inf, a negative range) is
  skipped, counted under ``"malformed <TYPE>"`` and reported in ``CarmenLog.warnings`` as
  ``file:line: TYPE: what is wrong`` (``io.skips``). The reader never raises on the content of
  a line; it raises ``OSError`` only when the file cannot be read.
* Ranges ``>= no_return_m`` (CARMEN writes 81.83 / 81.91 m for "no echo") become ``+inf``
  (REP 117). For ``ROBOTLASER1`` the threshold is ``min(max_range, no_return_m)``.
* Loggers also say "no return" with other values (one log writes exactly 50.0 m): a single
  exact range that is the largest of the log and occurs very often (:func:`infer_no_return`)
  is taken as such a sentinel; its beams become ``+inf``, the scans' ``range_max`` that value,
  and a warning says so with the count (``CarmenLog.sentinel_m`` / ``sentinel_count``).
* Timestamps that repeat or step back (the Intel logs have both) are kept in file order; the
  number of such scans is in ``CarmenLog.stamp_repeats`` / ``stamp_steps_back`` and in one
  summary warning.
* When a log has both ``FLASER`` and ``ROBOTLASER1`` lines (the same scans written twice by a
  CARMEN logger), only the ``ROBOTLASER1`` scans are kept; the ``FLASER`` ones are counted as
  skipped under ``"FLASER (ROBOTLASER1 present)"``.
"""

from __future__ import annotations

import gzip
import math
import os
import zlib
from dataclasses import dataclass, field
from decimal import Decimal, InvalidOperation

import numpy as np

from .skips import SkipLog

__all__ = [
    "CarmenLog",
    "CarmenOdom",
    "CarmenScan",
    "flaser_angles",
    "infer_no_return",
    "read_carmen",
    "stamp_str_to_ns",
]

#: The message types read; every other type is skipped (counted, one warning per type).
USED_TYPES = ("FLASER", "ROBOTLASER1", "ODOM")


@dataclass
class CarmenScan:
    """One laser scan of a CARMEN log.

    Attributes
    ----------
    stamp_s : float
        ``ipc_timestamp`` of the line (s).
    ranges : np.ndarray
        ``(B,)`` float32 ranges (m), beams right to left; no return = ``+inf``.
    angle_min, angle_increment : float
        Angle of the first beam and step between beams (rad), counter-clockwise positive.
    range_max : float
        Largest valid range (m); readings at or above it were turned into ``+inf``.
    laser_pose : np.ndarray
        ``(3,)`` ``[x, y, theta]`` of the laser in the odometry frame.
    odom_pose : np.ndarray
        ``(3,)`` ``[x, y, theta]`` robot odometry pose.
    line_no : int
        1-based line number in the file.
    stamp_ns : int
        ``ipc_timestamp`` in integer nanoseconds, parsed exactly from the text.
    kind : str
        ``"FLASER"`` or ``"ROBOTLASER1"``.
    tv, rv : float
        Translational (m/s) and rotational (rad/s) velocity (``ROBOTLASER1`` only, else 0).
    """

    stamp_s: float
    ranges: np.ndarray
    angle_min: float
    angle_increment: float
    range_max: float
    laser_pose: np.ndarray
    odom_pose: np.ndarray
    line_no: int
    stamp_ns: int = 0
    kind: str = "FLASER"
    tv: float = 0.0
    rv: float = 0.0


@dataclass
class CarmenOdom:
    """One ``ODOM`` line: pose ``(3,)`` ``[x, y, theta]``, ``tv`` (m/s), ``rv`` (rad/s)."""

    stamp_s: float
    pose: np.ndarray
    tv: float
    rv: float
    line_no: int
    stamp_ns: int = 0


@dataclass
class CarmenLog:
    """Content of a CARMEN log, in file order.

    ``skipped`` maps a reason (a message type name, or ``"malformed <TYPE>"``) to a count;
    ``warnings`` are human-readable lines naming ``file:line`` where one line is concerned.
    """

    scans: list = field(default_factory=list)
    odoms: list = field(default_factory=list)
    skipped: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    stamp_repeats: int = 0
    stamp_steps_back: int = 0
    path: str = ""
    #: a "no return" value inferred from the data (:func:`infer_no_return`), or None
    sentinel_m: float | None = None
    sentinel_count: int = 0


def flaser_angles(n_beams: int) -> tuple[float, float]:
    """``(angle_min, angle_increment)`` (rad) of an old-style FLASER line with ``n_beams`` beams.

    180 deg field of view starting at -90 deg: increment ``pi/n`` for even ``n`` and
    ``pi/(n-1)`` for odd ``n`` (so that 181 and 361 beams end exactly at +90 deg).
    """
    if n_beams < 2:
        raise ValueError(f"n_beams must be >= 2, got {n_beams}")
    inc = math.pi / n_beams if n_beams % 2 == 0 else math.pi / (n_beams - 1)
    return -math.pi / 2.0, inc


def stamp_str_to_ns(text: str) -> int:
    """Seconds written as decimal text -> integer nanoseconds, without float rounding.

    ``"976052856.538170"`` -> ``976052856538170000``. Raises ``ValueError`` on bad text.
    """
    try:
        d = Decimal(text)
    except InvalidOperation:
        raise ValueError(f"not a number: {text!r}") from None
    if not d.is_finite():
        raise ValueError(f"not a finite time: {text!r}")
    return int((d * 1_000_000_000).to_integral_value())


class _BadLine(ValueError):
    """Internal: a line that cannot be used; the message says why."""


def _floats(tokens: list[str], what: str) -> np.ndarray:
    try:
        arr = np.array(tokens, dtype=np.float64)
    except ValueError:
        bad = next((t for t in tokens if not _is_float(t)), "?")
        raise _BadLine(f"non-numeric {what} {bad!r}") from None
    if not np.all(np.isfinite(arr)):
        raise _BadLine(f"NaN or inf in {what}")
    return arr


def _is_float(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def _int(tok: str, what: str) -> int:
    try:
        return int(tok)
    except ValueError:
        raise _BadLine(f"{what} is not an integer: {tok!r}") from None


def _stamp(tok: str) -> tuple[float, int]:
    try:
        ns = stamp_str_to_ns(tok)
    except ValueError:
        raise _BadLine(f"bad timestamp {tok!r}") from None
    return float(tok), ns


def _ranges(raw: np.ndarray, no_return_m: float) -> np.ndarray:
    if np.any(raw < 0.0):
        raise _BadLine(f"negative range {raw[raw < 0.0][0]!r}")
    out = raw.astype(np.float32)
    out[raw >= no_return_m] = np.inf
    return out


def _parse_flaser(tok: list[str], line_no: int, no_return_m: float) -> CarmenScan:
    if len(tok) < 2:
        raise _BadLine("no beam count")
    n = _int(tok[1], "beam count")
    if n < 2:
        raise _BadLine(f"beam count {n} < 2")
    expected = n + 11
    if len(tok) != expected:
        raise _BadLine(f"expected {expected} fields for {n} beams, got {len(tok)}")
    raw = _floats(tok[2 : 2 + n], "range")
    poses = _floats(tok[2 + n : 8 + n], "pose")
    stamp_s, stamp_ns = _stamp(tok[8 + n])
    angle_min, inc = flaser_angles(n)
    return CarmenScan(
        stamp_s=stamp_s,
        ranges=_ranges(raw, no_return_m),
        angle_min=angle_min,
        angle_increment=inc,
        range_max=float(no_return_m),
        laser_pose=poses[:3].copy(),
        odom_pose=poses[3:].copy(),
        line_no=line_no,
        stamp_ns=stamp_ns,
        kind="FLASER",
    )


def _parse_robotlaser1(tok: list[str], line_no: int, no_return_m: float) -> CarmenScan:
    # ROBOTLASER1 type start fov res max_range accuracy remission_mode n r.. m rem.. 14 fields + 3
    if len(tok) < 9:
        raise _BadLine(f"too few fields ({len(tok)})")
    head = _floats(tok[2:7], "header field")
    start_angle, fov, res, max_range, _acc = (float(v) for v in head)
    n = _int(tok[8], "beam count")
    if n < 1 or len(tok) < 9 + n + 1:
        raise _BadLine(f"{n} beams announced but only {len(tok)} fields")
    m = _int(tok[9 + n], "remission count")
    expected = n + m + 24
    if m < 0 or len(tok) != expected:
        raise _BadLine(f"expected {expected} fields for {n} beams and {m} remissions, got {len(tok)}")
    if not res > 0.0 or not max_range > 0.0:
        raise _BadLine(f"angular_res {res} and max_range {max_range} must be > 0")
    if min(abs(fov - n * res), abs(fov - (n - 1) * res)) > 0.5 * res:
        raise _BadLine(f"{n} beams at angular_res {res} do not cover the header fov {fov}")
    raw = _floats(tok[9 : 9 + n], "range")
    rest = _floats(tok[10 + n + m : 10 + n + m + 11], "pose/velocity")
    stamp_s, stamp_ns = _stamp(tok[10 + n + m + 11])
    threshold = min(max_range, no_return_m)
    return CarmenScan(
        stamp_s=stamp_s,
        ranges=_ranges(raw, threshold),
        angle_min=start_angle,
        angle_increment=res,
        range_max=float(threshold),
        laser_pose=rest[0:3].copy(),
        odom_pose=rest[3:6].copy(),
        line_no=line_no,
        stamp_ns=stamp_ns,
        kind="ROBOTLASER1",
        tv=float(rest[6]),
        rv=float(rest[7]),
    )


def _parse_odom(tok: list[str], line_no: int) -> CarmenOdom:
    if len(tok) != 10:
        raise _BadLine(f"expected 10 fields, got {len(tok)}")
    vals = _floats(tok[1:7], "value")
    stamp_s, stamp_ns = _stamp(tok[7])
    return CarmenOdom(
        stamp_s=stamp_s, pose=vals[:3].copy(), tv=float(vals[3]), rv=float(vals[4]), line_no=line_no, stamp_ns=stamp_ns
    )


def read_carmen(path: str | os.PathLike, no_return_m: float = 80.0, infer_sentinel: bool = True) -> CarmenLog:
    """Read a CARMEN log.

    Parameters
    ----------
    path : str or PathLike
        The ``.clf`` / ``.log`` file, plain or gzip-compressed (``.log.gz``).
    no_return_m : float
        Readings at or above this range (m) are "no return" and become ``+inf``.
    infer_sentinel : bool
        Also take a "no return" value inferred from the data (:func:`infer_no_return`).

    Returns
    -------
    CarmenLog
        Scans (``FLASER`` or ``ROBOTLASER1``) and ``ODOM`` messages in file order, skip counts
        and warnings. See the module docstring for the conventions.
    """
    if not no_return_m > 0.0:
        raise ValueError(f"no_return_m must be > 0, got {no_return_m}")
    log = CarmenLog(path=str(path))
    name = os.path.basename(str(path))
    bad = SkipLog(log.skipped, log.warnings)
    unused: dict[str, int] = {}  # type -> first line

    with _open_text(path) as fh:
        for line_no, line in _lines(fh, name, log):
            tok = line.split()
            if not tok or tok[0].startswith("#"):
                continue
            kind = tok[0] if tok[0].isprintable() else ascii(tok[0])  # binary junk, named safely
            try:
                if kind == "FLASER":
                    log.scans.append(_parse_flaser(tok, line_no, no_return_m))
                elif kind == "ROBOTLASER1":
                    log.scans.append(_parse_robotlaser1(tok, line_no, no_return_m))
                elif kind == "ODOM":
                    log.odoms.append(_parse_odom(tok, line_no))
                else:
                    unused.setdefault(kind, line_no)
                    log.skipped[kind] = log.skipped.get(kind, 0) + 1
            except _BadLine as exc:
                bad.skip(name, line_no, f"{kind}: {exc}", key=f"malformed {kind}")
    bad.finish()
    for kind, first in unused.items():
        log.warnings.append(
            f"{name}:{first}: message type {kind} is not read (only "
            f"{', '.join(USED_TYPES)}); its {log.skipped[kind]} lines skipped"
        )

    kinds = {s.kind for s in log.scans}
    if len(kinds) > 1:
        n_fl = sum(1 for s in log.scans if s.kind == "FLASER")
        log.scans = [s for s in log.scans if s.kind == "ROBOTLASER1"]
        log.skipped["FLASER (ROBOTLASER1 present)"] = n_fl
        log.warnings.append(
            f"{name}: has both FLASER and ROBOTLASER1 lines; kept the "
            f"{len(log.scans)} ROBOTLASER1 scans, skipped {n_fl} FLASER"
        )

    _check_stamps(log, name)
    if infer_sentinel:
        _apply_sentinel(log, name)
    return log


def _open_text(path: str | os.PathLike):
    """The log as text lines: gzip-compressed (``.gz``, recognised by its magic bytes, whatever
    the name) or plain."""
    with open(path, "rb") as fh:
        magic = fh.read(2)
    if magic == b"\x1f\x8b":
        return gzip.open(path, "rt", encoding="utf-8", errors="replace")
    return open(path, encoding="utf-8", errors="replace")


def _lines(fh, name: str, log: CarmenLog):
    """(line number, line) of `fh`; a gzip stream that is cut off or damaged ends the log there:
    the lines before it are kept, one warning names the last line read (skipped: "damaged gzip")."""
    line_no = 0
    try:
        for line_no, line in enumerate(fh, start=1):
            yield line_no, line
    except (EOFError, OSError, zlib.error) as exc:
        log.skipped["damaged gzip"] = log.skipped.get("damaged gzip", 0) + 1
        log.warnings.append(
            f"{name}:{line_no + 1}: compressed stream damaged after line {line_no} "
            f"({type(exc).__name__}: {exc}); the {line_no} lines before it are read, "
            "the rest is lost"
        )


#: a sentinel occurs at least this often (beams), and at least this fraction of the finite beams
SENTINEL_MIN_COUNT = 50
SENTINEL_MIN_FRACTION = 1e-3
#: ... and this many times more often than any other exact value in its upper half
SENTINEL_DOMINANCE = 5


def infer_no_return(ranges: np.ndarray) -> tuple[float | None, int]:
    """A "no return" sentinel in a log's ranges, inferred from the data.

    The largest finite range ``v`` is a sentinel when it occurs exactly at least
    ``SENTINEL_MIN_COUNT`` times and in ``SENTINEL_MIN_FRACTION`` of the finite beams, and
    ``SENTINEL_DOMINANCE`` times more often than any other exact value in ``[v / 2, v)``: real
    ranges are spread out, and a real longest return is rare, while a logger that writes its
    range limit for "no echo" piles them all on one value (one held-out log: 50.0 m, 11 139
    times). Returns ``(v, count)`` or ``(None, 0)``.
    """
    r = np.asarray(ranges, dtype=np.float32).reshape(-1)
    r = r[np.isfinite(r)]
    if r.size == 0:
        return None, 0
    v = r.max()
    n = int(np.count_nonzero(r == v))
    if n < SENTINEL_MIN_COUNT or n < SENTINEL_MIN_FRACTION * r.size:
        return None, 0
    upper = r[(r >= 0.5 * v) & (r < v)]
    if upper.size:
        other = int(np.unique(upper, return_counts=True)[1].max())
        if n < SENTINEL_DOMINANCE * other:
            return None, 0
    return float(v), n


def _apply_sentinel(log: CarmenLog, name: str) -> None:
    if not log.scans:
        return
    v, n = infer_no_return(np.concatenate([s.ranges for s in log.scans]))
    if v is None:
        return
    v32 = np.float32(v)
    for s in log.scans:
        hit = s.ranges == v32
        if hit.any():
            s.ranges = s.ranges.copy()
            s.ranges[hit] = np.inf
        s.range_max = min(float(s.range_max), v)
    log.sentinel_m, log.sentinel_count = v, n
    log.warnings.append(
        f"{name}: {n} beams read exactly {v:g} m, the largest range of the log: taken as the "
        f'logger\'s "no return" and written as +inf (REP 117), range_max {v:g} m'
    )


def _check_stamps(log: CarmenLog, name: str) -> None:
    for what, items in (("scan", log.scans), ("ODOM", log.odoms)):
        if len(items) < 2:
            continue
        ns = np.array([s.stamp_ns for s in items], dtype=np.int64)
        d = np.diff(ns)
        repeats = int(np.count_nonzero(d == 0))
        back = int(np.count_nonzero(d < 0))
        if what == "scan":
            log.stamp_repeats, log.stamp_steps_back = repeats, back
        if repeats or back:
            first = items[int(np.flatnonzero(d <= 0)[0]) + 1].line_no
            worst = float(-d.min()) * 1e-9 if back else 0.0
            log.warnings.append(
                f"{name}: {repeats} {what} timestamps repeat the previous one and {back} step "
                f"back (by up to {worst:.3f} s; first at line {first}); kept in file order"
            )
