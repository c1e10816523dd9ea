"""Dataset logs -> rosbag2 (``pf-slam convert carmen|mines``).

Topics written (default names, frames in parentheses):

* CARMEN: ``/scan`` ``sensor_msgs/LaserScan`` (``laser``), ``/odom`` ``nav_msgs/Odometry``
  (``odom`` -> ``base_link``), ``/tf_static`` ``base_link`` -> ``laser``.
* Mines: ``/encoders`` ``sensor_msgs/JointState`` (``left_wheel``, ``right_wheel`` cumulative
  angles in rad = ticks * 2 pi / ticks_per_rev), ``/scan`` (``laser``), ``/tf_static``
  ``base_link`` -> ``laser`` (identity: the data set gives no mounting offset). The robot
  parameters go to the bag's ``custom_data`` (``pf_slam.wheel_radius_m``,
  ``pf_slam.half_axle_m``, ``pf_slam.ticks_per_rev``).
* Both: ``custom_data`` ``pf_slam.format`` (``carmen`` / ``mines``: `pf-slam run` picks its
  parameter profile from it, see profiles.py) and ``pf_slam.source`` (the log's file name).

Time stamps
-----------
Header stamps are the log's own times, exactly (CARMEN ``ipc_timestamp``; Mines microseconds).
The bag record time of a message is its header stamp, except where the log's time repeats or
steps back (the Intel logs do both): there the record time is the previous record time + 1 us,
so that record times strictly increase in file order and a player replays the log in file
order. The header stamp is never changed. ``ConvertReport.retimed`` counts the moved ones.

Within one log line the odometry / encoder message is written before the scan, at the same
record time; readers return equal record times in write order (MCAP and sqlite3 both), so a
consumer has the motion before the scan it belongs to.

The ``/tf_static`` message is written first, at the first record time.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from ..core.geometry import yaw_to_quat
from .bag import joint_state_wheels, laser_scan, odometry, open_writer, tf_static
from .carmen import read_carmen
from .mines import read_mines

__all__ = ["ConvertReport", "convert_carmen", "convert_mines", "laser_offset"]

#: Record-time step (ns) used where the log's time does not increase.
RETIME_STEP_NS = 1000

TOPIC_SCAN = "/scan"
TOPIC_ODOM = "/odom"
TOPIC_ENCODERS = "/encoders"
TOPIC_TF_STATIC = "/tf_static"


@dataclass
class ConvertReport:
    """What a conversion wrote.

    ``counts``: messages per topic; ``skipped``: input lines skipped per reason; ``warnings``:
    human-readable lines from the reader and the converter; ``retimed``: log lines whose
    messages' record time was moved forward (header stamps kept); ``start_ns`` / ``end_ns``:
    first / last record time; ``out_bag``, ``storage``, ``source``; ``odom_sync``.
    """

    source: str
    out_bag: str
    storage: str
    counts: dict = field(default_factory=dict)
    skipped: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    retimed: int = 0
    start_ns: int = 0
    end_ns: int = 0
    odom_sync: str = ""  # CARMEN: how the scans pair with the odometry (also in the bag's custom data)
    time_source: str = "log"  # CARMEN: 'log', 'log, N by line order' or 'line order' (LogTimes)
    line_order: int = 0  # CARMEN: messages whose header stamp was taken from their line's place
    #: CARMEN: a "no return" range inferred from the data (m) and its beams, written as +inf
    sentinel_m: float | None = None
    sentinel_count: int = 0

    @property
    def duration_s(self) -> float:
        """Span of record times (s)."""
        return (self.end_ns - self.start_ns) * 1e-9

    def summary(self) -> str:
        """Several human-readable lines for the CLI."""
        lines = [f"{self.source} -> {self.out_bag} ({self.storage}, {self.duration_s:.1f} s)"]
        lines += [f"  {t}: {n}" for t, n in sorted(self.counts.items())]
        if self.sentinel_m is not None:
            lines.append(
                f"  no return: {self.sentinel_count} beams at exactly {self.sentinel_m:g} m (inferred "
                f"from the data: the log's largest range, far more frequent than any other) "
                f"written as +inf, range_max {self.sentinel_m:g} m"
            )
        if self.skipped:
            lines.append(
                f"  skipped {sum(self.skipped.values())}: "
                + ", ".join(f"{k} {v}" for k, v in sorted(self.skipped.items()))
            )
        if self.time_source != "log":
            lines.append(f"  header stamps: {self.time_source}")
        if self.retimed:
            lines.append(
                f"  record time moved forward for {self.retimed} log lines' messages "
                "(log time repeats or steps back; header stamps kept)"
            )
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)


class _Clock:
    """Strictly increasing record times from possibly non-monotonic stamps."""

    def __init__(self) -> None:
        self.last = -1
        self.retimed = 0

    def __call__(self, stamp_ns: int) -> int:
        if stamp_ns > self.last:
            self.last = stamp_ns
        else:
            self.last += RETIME_STEP_NS
            self.retimed += 1
        return self.last


#: a stamp this close (ns) to the time its place in the file implies is the log's own, kept
#: exactly: the bursty Intel logger's stamps are up to 1.7 s off their neighbours' (intel_2726),
#: the garbage stamps of the carmen_corrected logs (0, 3.4e-86, negative) at least 18 s
TIME_TOLERANCE_NS = 5_000_000_000
#: scans per second of the line-order clock, for a log whose scan times do not order it
LINE_ORDER_PERIOD_NS = 1_000_000_000


@dataclass
class LogTimes:
    """The header stamp of each CARMEN message (``ns``: id(message) -> ns), and how they came:
    ``source`` "log" (the log's own), "log, N by line order", or "line order"; ``retimed``:
    messages whose stamp is not the log's; ``warnings``: what was done, with file:line and counts."""

    ns: dict
    source: str = "log"
    retimed: int = 0
    warnings: list = field(default_factory=list)


def _nondecreasing_run(t: np.ndarray) -> np.ndarray:
    """Mask of one longest non-decreasing subsequence of `t` (patience sorting, O(n log n))."""
    import bisect

    tails: list = []
    tail_idx: list = []
    prev = np.full(len(t), -1, dtype=np.int64)
    for i, v in enumerate(t.tolist()):
        k = bisect.bisect_right(tails, v)
        if k == len(tails):
            tails.append(v)
            tail_idx.append(i)
        else:
            tails[k] = v
            tail_idx[k] = i
        prev[i] = tail_idx[k - 1] if k > 0 else -1
    mask = np.zeros(len(t), dtype=bool)
    i = tail_idx[-1] if tail_idx else -1
    while i >= 0:
        mask[i] = True
        i = int(prev[i])
    return mask


def log_times(
    scans: list, odoms: list, name: str, tolerance_ns: int = TIME_TOLERANCE_NS, period_ns: int = LINE_ORDER_PERIOD_NS
) -> LogTimes:
    """Header stamps for a CARMEN log's messages, in the log's time where it orders the file.

    * Scan times that do not order the log (fewer than half the steps between consecutive scans
      go forward: constant, zero): every stamp from the line order, scan i at
      ``max(first stamp, 0) + i * period_ns``; the odometry then comes from the laser lines
      (the ODOM lines' times cannot be placed). Warned with the counts and the first line.
    * Otherwise the log's times, except a stamp that is negative or that breaks the file's time
      order: not in the longest non-decreasing run of stamps (file order) and more than
      `tolerance_ns` from the time its place between the nearest good lines implies (zero,
      garbage like 3.4e-86, a jump). Those take the implied time (linear in the line number
      between the good lines around them). Warned: count per type, the first file:line and value.
    """
    out = LogTimes(ns={})
    sc = np.array([s.stamp_ns for s in scans], dtype=np.int64)
    forward = int(np.count_nonzero(np.diff(sc) > 0))
    # no forward step at all (constant, zero), or most steps not forward over enough scans for
    # that to mean something (a handful of scans with a repeat and a step back keep their times)
    if len(sc) > 1 and (forward == 0 or (len(sc) > 10 and forward < 0.5 * (len(sc) - 1))):
        base = max(int(sc[0]), 0)
        for i, s in enumerate(scans):
            out.ns[id(s)] = base + i * period_ns
        rep = int(np.count_nonzero(np.diff(sc) == 0))
        out.source, out.retimed = "line order", len(scans)
        out.warnings.append(
            f"{name}:{scans[0].line_no}: scan timestamps do not order the log (only {forward} of "
            f"{len(sc) - 1} steps go forward, {rep} repeat; first {sc[0] / 1e9:g} s, last {sc[-1] / 1e9:g} s): "
            f"stamps from the line order, one scan per {period_ns / 1e9:g} s from {base / 1e9:g} s"
            + (
                f"; odometry from the laser lines, the {len(odoms)} ODOM lines not used (their times cannot be placed)"
                if odoms
                else ""
            )
        )
        return out
    events = sorted([(s.line_no, s) for s in scans] + [(o.line_no, o) for o in odoms], key=lambda e: e[0])
    t = np.array([e[1].stamp_ns for e in events], dtype=np.int64)
    lines = np.array([e[0] for e in events], dtype=np.float64)
    good = np.zeros(len(t), dtype=bool)
    nonneg = np.flatnonzero(t >= 0)
    good[nonneg[_nondecreasing_run(t[nonneg])]] = True
    if not good.any():  # cannot happen with scans in order; keep the conversion defined
        good[:] = True
    gi = np.flatnonzero(good)
    implied = np.interp(lines, lines[gi], t[gi].astype(np.float64)).astype(np.int64)
    ok = good | ((t >= 0) & (np.abs(t - implied) <= tolerance_ns))
    bad = np.flatnonzero(~ok)
    final = np.where(ok, t, implied)
    for (_, ev), v in zip(events, final.tolist()):
        out.ns[id(ev)] = int(v)
    if len(bad):
        out.retimed = len(bad)
        out.source = f"log, {len(bad)} by line order"
        kinds: dict = {}
        for i in bad:
            kind = "scan" if hasattr(events[i][1], "ranges") else "ODOM"
            kinds[kind] = kinds.get(kind, 0) + 1
        i0 = int(bad[0])
        what = " and ".join(f"{n} {k}" for k, n in sorted(kinds.items()))
        out.warnings.append(
            f"{name}:{events[i0][0]}: {what} timestamps out of the log's time order (negative, or more "
            f"than {tolerance_ns / 1e9:g} s off the time of the lines around them; first: {t[i0] / 1e9:g} s "
            f"where {implied[i0] / 1e9:.3f} s fits): their stamps from their place in the file, between the "
            "neighbouring lines' times"
        )
    return out


def laser_offset(laser_pose: np.ndarray, odom_pose: np.ndarray) -> tuple[float, float, float]:
    """Pose of the laser in the robot frame: ``odom_pose^-1 * laser_pose`` in SE(2).

    Returns ``(x, y, yaw)`` (m, m, rad).
    """
    dx, dy = laser_pose[0] - odom_pose[0], laser_pose[1] - odom_pose[1]
    c, s = math.cos(odom_pose[2]), math.sin(odom_pose[2])
    yaw = math.atan2(math.sin(laser_pose[2] - odom_pose[2]), math.cos(laser_pose[2] - odom_pose[2]))
    return c * dx + s * dy, -s * dx + c * dy, yaw


def convert_carmen(
    log_path: str | os.PathLike,
    out_bag: str | os.PathLike,
    storage: str = "mcap",
    no_return_m: float = 80.0,
    laser_frame: str = "laser",
    base_frame: str = "base_link",
    odom_frame: str = "odom",
) -> ConvertReport:
    """Convert a CARMEN log (FLASER / ROBOTLASER1 / ODOM) to a rosbag2.

    ``/odom`` comes from the ``ODOM`` lines when the log has any, else from the odometry pose
    embedded in each laser line (one ``/odom`` per ``/scan``, same stamp). ``/tf_static``
    holds ``base_frame -> laser_frame`` from the first scan's laser pose relative to its
    odometry pose (identity for the Intel and MIT logs). Raises ``ValueError`` if the log has
    no usable scan, ``BagError`` if ``out_bag`` exists.
    """
    log = read_carmen(log_path, no_return_m=no_return_m)
    if not log.scans:
        why = f"; {log.warnings[0]}" if log.warnings else ""
        raise ValueError(f"{log_path}: no usable laser scan (skipped: {log.skipped}){why}")
    report = ConvertReport(
        source=str(log_path),
        out_bag=str(out_bag),
        storage=storage,
        skipped=dict(log.skipped),
        warnings=list(log.warnings),
        sentinel_m=log.sentinel_m,
        sentinel_count=log.sentinel_count,
    )
    name = os.path.basename(str(log_path))
    times = log_times(log.scans, log.odoms, name)
    report.warnings += times.warnings
    report.time_source = times.source
    report.line_order = times.retimed
    use_odom_lines = bool(log.odoms) and times.source != "line order"
    if log.odoms and not use_odom_lines:
        report.skipped["ODOM (log times unusable)"] = len(log.odoms)
    stamp = times.ns  # id(message) -> header stamp (ns)
    report.odom_sync = "exact"
    if use_odom_lines:
        odom_stamps = {stamp[id(o)] for o in log.odoms}
        paired = sum(stamp[id(s)] in odom_stamps for s in log.scans)
        if paired < 0.9 * len(log.scans):
            report.odom_sync = "interpolate"
            report.warnings.append(
                f"odometry from {len(log.odoms)} ODOM lines, logged at their own times ({paired} of "
                f"{len(log.scans)} scans have an ODOM line with their stamp): the bag says "
                f"odom_sync interpolate"
            )
    events: list = [(s.line_no, s) for s in log.scans]
    if use_odom_lines:
        events += [(o.line_no, o) for o in log.odoms]
        events.sort(key=lambda e: e[0])

    first = log.scans[0]
    lx, ly, lyaw = laser_offset(first.laser_pose, first.odom_pose)
    if np.any(np.abs([lx, ly, lyaw]) > 1e-9):
        report.warnings.append(
            f"{base_frame} -> {laser_frame} from the first scan: x={lx:.4f} m y={ly:.4f} m yaw={lyaw:.4f} rad"
        )
    clock = _Clock()
    with open_writer(out_bag, storage=storage) as bag:
        bag.add_connection(TOPIC_TF_STATIC, "tf2_msgs/msg/TFMessage")
        bag.add_connection(TOPIC_ODOM, "nav_msgs/msg/Odometry")
        bag.add_connection(TOPIC_SCAN, "sensor_msgs/msg/LaserScan")
        bag.set_custom_data("pf_slam.format", "carmen")  # pf-slam run: the indoor profile
        bag.set_custom_data("pf_slam.source", os.path.basename(str(log_path)))
        bag.set_custom_data("pf_slam.odom_source", "ODOM" if use_odom_lines else "laser lines")
        # how the scans pair with the odometry (pf-slam run uses it: the laser lines' own
        # odometry shares their stamps; ODOM lines are logged at their own times)
        bag.set_custom_data("pf_slam.odom_sync", report.odom_sync)
        # where the header stamps come from: the log's times ("log"), the log's with some taken
        # from their line's place ("log, N by line order"), or the line order alone
        bag.set_custom_data("pf_slam.time_source", times.source)
        t0 = stamp[id(events[0][1])]
        bag.write(TOPIC_TF_STATIC, t0, tf_static(t0, [(base_frame, laser_frame, (lx, ly, 0.0), yaw_to_quat(lyaw))]))
        for _, ev in events:
            st = stamp[id(ev)]
            t_rec = clock(st)
            if hasattr(ev, "ranges"):
                if not use_odom_lines:
                    twist = (ev.tv, ev.rv) if ev.kind == "ROBOTLASER1" else None
                    bag.write(TOPIC_ODOM, t_rec, odometry(st, odom_frame, base_frame, ev.odom_pose, twist))
                bag.write(
                    TOPIC_SCAN,
                    t_rec,
                    laser_scan(st, laser_frame, ev.angle_min, ev.angle_increment, ev.ranges, 0.0, ev.range_max),
                )
            else:
                bag.write(TOPIC_ODOM, t_rec, odometry(st, odom_frame, base_frame, ev.pose, (ev.tv, ev.rv)))
        report.counts = dict(bag.counts)
    report.retimed = clock.retimed
    report.start_ns, report.end_ns = t0, clock.last
    return report


def convert_mines(
    dat_path: str | os.PathLike,
    out_bag: str | os.PathLike,
    storage: str = "mcap",
    ticks_per_rev: int = 2000,
    wheel_radius_m: float = 0.077,
    half_axle_m: float = 0.165,
    laser_frame: str = "laser",
    base_frame: str = "base_link",
) -> ConvertReport:
    """Convert a Mines ``.dat`` log to a rosbag2 (``/encoders``, ``/scan``, ``/tf_static``).

    One ``/encoders`` and one ``/scan`` message per line, same stamp, encoders first.
    Raises ``ValueError`` if the file has no usable line, ``BagError`` if ``out_bag`` exists.
    """
    log = read_mines(dat_path, ticks_per_rev=ticks_per_rev, wheel_radius_m=wheel_radius_m, half_axle_m=half_axle_m)
    n = len(log.stamps_us)
    if n == 0:
        raise ValueError(f"{dat_path}: no usable line (skipped: {log.skipped})")
    report = ConvertReport(
        source=str(dat_path),
        out_bag=str(out_bag),
        storage=storage,
        skipped=dict(log.skipped),
        warnings=list(log.warnings),
    )
    stamps = log.stamps_ns
    left, right = log.left_wheel_rad, log.right_wheel_rad
    clock = _Clock()
    with open_writer(out_bag, storage=storage) as bag:
        bag.add_connection(TOPIC_TF_STATIC, "tf2_msgs/msg/TFMessage")
        bag.add_connection(TOPIC_ENCODERS, "sensor_msgs/msg/JointState")
        bag.add_connection(TOPIC_SCAN, "sensor_msgs/msg/LaserScan")
        bag.set_custom_data("pf_slam.format", "mines")  # pf-slam run: the mines profile
        bag.set_custom_data("pf_slam.source", os.path.basename(str(dat_path)))
        bag.set_custom_data("pf_slam.ticks_per_rev", str(int(ticks_per_rev)))
        bag.set_custom_data("pf_slam.wheel_radius_m", repr(float(wheel_radius_m)))
        bag.set_custom_data("pf_slam.half_axle_m", repr(float(half_axle_m)))
        t0 = int(stamps[0])
        bag.write(
            TOPIC_TF_STATIC, t0, tf_static(t0, [(base_frame, laser_frame, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))])
        )
        for i in range(n):
            st = int(stamps[i])
            t_rec = clock(st)
            bag.write(TOPIC_ENCODERS, t_rec, joint_state_wheels(st, left[i], right[i]))
            bag.write(
                TOPIC_SCAN,
                t_rec,
                laser_scan(
                    st, laser_frame, log.angle_min, log.angle_increment, log.ranges[i], log.range_min, log.range_max
                ),
            )
        report.counts = dict(bag.counts)
    report.retimed = clock.retimed
    report.start_ns, report.end_ns = t0, clock.last
    return report
