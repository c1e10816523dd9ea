"""Dataset logs -> rosbag2 (``pf-slam convert carmen|mines``).

Topics written (default names, frames in parentheses):

* CARMEN: ``/scan`` ``sensor_msgs/LaserScan`` (``laser``), ``/odom`` ``nav_msgs/Odometry``
  (``odom`` -> ``base_link``), ``/tf_static`` ``base_link`` -> ``laser``.
* Mines: ``/encoders`` ``sensor_msgs/JointState`` (``left_wheel``, ``right_wheel`` cumulative
  angles in rad = ticks * 2 pi / ticks_per_rev), ``/scan`` (``laser``), ``/tf_static``
  ``base_link`` -> ``laser`` (identity: the data set gives no mounting offset). The robot
  parameters go to the bag's ``custom_data`` (``pf_slam.wheel_radius_m``,
  ``pf_slam.half_axle_m``, ``pf_slam.ticks_per_rev``).

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

__all__ = ['ConvertReport', 'convert_carmen', 'convert_mines', 'laser_offset']

#: Record-time step (ns) used where the log's time does not increase.
RETIME_STEP_NS = 1000

TOPIC_SCAN = '/scan'
TOPIC_ODOM = '/odom'
TOPIC_ENCODERS = '/encoders'
TOPIC_TF_STATIC = '/tf_static'


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
    odom_sync: str = ''  # CARMEN: how the scans pair with the odometry (also in the bag's custom data)

    @property
    def duration_s(self) -> float:
        """Span of record times (s)."""
        return (self.end_ns - self.start_ns) * 1e-9

    def summary(self) -> str:
        """Several human-readable lines for the CLI."""
        lines = [f'{self.source} -> {self.out_bag} ({self.storage}, {self.duration_s:.1f} s)']
        lines += [f'  {t}: {n}' for t, n in sorted(self.counts.items())]
        if self.skipped:
            lines.append(f'  skipped {sum(self.skipped.values())}: ' + ', '.join(
                f'{k} {v}' for k, v in sorted(self.skipped.items())))
        if self.retimed:
            lines.append(f'  record time moved forward for {self.retimed} log lines\' messages '
                         '(log time repeats or steps back; header stamps kept)')
        lines += [f'  warning: {w}' for w in self.warnings]
        return '\n'.join(lines)


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


def laser_offset(laser_pose: np.ndarray, odom_pose: np.ndarray) -> tuple[float, float, float]:
    """Pose of the laser in the robot frame: ``odom_pose^-1 * laser_pose`` in SE(2).

    Returns ``(x, y, yaw)`` (m, m, rad).
    """
    dx, dy = laser_pose[0] - odom_pose[0], laser_pose[1] - odom_pose[1]
    c, s = math.cos(odom_pose[2]), math.sin(odom_pose[2])
    yaw = math.atan2(math.sin(laser_pose[2] - odom_pose[2]), math.cos(laser_pose[2] - odom_pose[2]))
    return c * dx + s * dy, -s * dx + c * dy, yaw


def convert_carmen(log_path: str | os.PathLike, out_bag: str | os.PathLike,
                   storage: str = 'mcap', no_return_m: float = 80.0, laser_frame: str = 'laser',
                   base_frame: str = 'base_link', odom_frame: str = 'odom') -> ConvertReport:
    """Convert a CARMEN log (FLASER / ROBOTLASER1 / ODOM) to a rosbag2.

    ``/odom`` comes from the ``ODOM`` lines when the log has any, else from the odometry pose
    embedded in each laser line (one ``/odom`` per ``/scan``, same stamp). ``/tf_static``
    holds ``base_frame -> laser_frame`` from the first scan's laser pose relative to its
    odometry pose (identity for the Intel and MIT logs). Raises ``ValueError`` if the log has
    no usable scan, ``BagError`` if ``out_bag`` exists.
    """
    log = read_carmen(log_path, no_return_m=no_return_m)
    if not log.scans:
        raise ValueError(f'{log_path}: no usable laser scan (skipped: {log.skipped})')
    report = ConvertReport(source=str(log_path), out_bag=str(out_bag), storage=storage,
                           skipped=dict(log.skipped), warnings=list(log.warnings))
    use_odom_lines = bool(log.odoms)
    report.odom_sync = 'exact'
    if use_odom_lines:
        odom_stamps = {o.stamp_ns for o in log.odoms}
        paired = sum(s.stamp_ns in odom_stamps for s in log.scans)
        if paired < 0.9 * len(log.scans):
            report.odom_sync = 'interpolate'
            report.warnings.append(
                f'odometry from {len(log.odoms)} ODOM lines, logged at their own times ({paired} of '
                f'{len(log.scans)} scans have an ODOM line with their stamp): the bag says '
                f'odom_sync interpolate')
    events: list = [(s.line_no, s) for s in log.scans]
    if use_odom_lines:
        events += [(o.line_no, o) for o in log.odoms]
        events.sort(key=lambda e: e[0])

    first = log.scans[0]
    lx, ly, lyaw = laser_offset(first.laser_pose, first.odom_pose)
    if np.any(np.abs([lx, ly, lyaw]) > 1e-9):
        report.warnings.append(f'{base_frame} -> {laser_frame} from the first scan: '
                               f'x={lx:.4f} m y={ly:.4f} m yaw={lyaw:.4f} rad')
    clock = _Clock()
    with open_writer(out_bag, storage=storage) as bag:
        bag.add_connection(TOPIC_TF_STATIC, 'tf2_msgs/msg/TFMessage')
        bag.add_connection(TOPIC_ODOM, 'nav_msgs/msg/Odometry')
        bag.add_connection(TOPIC_SCAN, 'sensor_msgs/msg/LaserScan')
        bag.set_custom_data('pf_slam.source', os.path.basename(str(log_path)))
        bag.set_custom_data('pf_slam.odom_source', 'ODOM' if use_odom_lines else 'laser lines')
        # how the scans pair with the odometry (pf-slam run uses it: the laser lines' own
        # odometry shares their stamps; ODOM lines are logged at their own times)
        bag.set_custom_data('pf_slam.odom_sync', report.odom_sync)
        t0 = events[0][1].stamp_ns
        bag.write(TOPIC_TF_STATIC, t0, tf_static(
            t0, [(base_frame, laser_frame, (lx, ly, 0.0), yaw_to_quat(lyaw))]))
        for _, ev in events:
            t_rec = clock(ev.stamp_ns)
            if hasattr(ev, 'ranges'):
                if not use_odom_lines:
                    twist = (ev.tv, ev.rv) if ev.kind == 'ROBOTLASER1' else None
                    bag.write(TOPIC_ODOM, t_rec, odometry(
                        ev.stamp_ns, odom_frame, base_frame, ev.odom_pose, twist))
                bag.write(TOPIC_SCAN, t_rec, laser_scan(
                    ev.stamp_ns, laser_frame, ev.angle_min, ev.angle_increment, ev.ranges,
                    0.0, ev.range_max))
            else:
                bag.write(TOPIC_ODOM, t_rec, odometry(
                    ev.stamp_ns, odom_frame, base_frame, ev.pose, (ev.tv, ev.rv)))
        report.counts = dict(bag.counts)
    report.retimed = clock.retimed
    report.start_ns, report.end_ns = t0, clock.last
    return report


def convert_mines(dat_path: str | os.PathLike, out_bag: str | os.PathLike,
                  storage: str = 'mcap', ticks_per_rev: int = 2000,
                  wheel_radius_m: float = 0.077, half_axle_m: float = 0.165,
                  laser_frame: str = 'laser', base_frame: str = 'base_link') -> ConvertReport:
    """Convert a Mines ``.dat`` log to a rosbag2 (``/encoders``, ``/scan``, ``/tf_static``).

    One ``/encoders`` and one ``/scan`` message per line, same stamp, encoders first.
    Raises ``ValueError`` if the file has no usable line, ``BagError`` if ``out_bag`` exists.
    """
    log = read_mines(dat_path, ticks_per_rev=ticks_per_rev, wheel_radius_m=wheel_radius_m,
                     half_axle_m=half_axle_m)
    n = len(log.stamps_us)
    if n == 0:
        raise ValueError(f'{dat_path}: no usable line (skipped: {log.skipped})')
    report = ConvertReport(source=str(dat_path), out_bag=str(out_bag), storage=storage,
                           skipped=dict(log.skipped), warnings=list(log.warnings))
    stamps = log.stamps_ns
    left, right = log.left_wheel_rad, log.right_wheel_rad
    clock = _Clock()
    with open_writer(out_bag, storage=storage) as bag:
        bag.add_connection(TOPIC_TF_STATIC, 'tf2_msgs/msg/TFMessage')
        bag.add_connection(TOPIC_ENCODERS, 'sensor_msgs/msg/JointState')
        bag.add_connection(TOPIC_SCAN, 'sensor_msgs/msg/LaserScan')
        bag.set_custom_data('pf_slam.source', os.path.basename(str(dat_path)))
        bag.set_custom_data('pf_slam.ticks_per_rev', str(int(ticks_per_rev)))
        bag.set_custom_data('pf_slam.wheel_radius_m', repr(float(wheel_radius_m)))
        bag.set_custom_data('pf_slam.half_axle_m', repr(float(half_axle_m)))
        t0 = int(stamps[0])
        bag.write(TOPIC_TF_STATIC, t0, tf_static(
            t0, [(base_frame, laser_frame, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))]))
        for i in range(n):
            st = int(stamps[i])
            t_rec = clock(st)
            bag.write(TOPIC_ENCODERS, t_rec, joint_state_wheels(st, left[i], right[i]))
            bag.write(TOPIC_SCAN, t_rec, laser_scan(
                st, laser_frame, log.angle_min, log.angle_increment, log.ranges[i],
                log.range_min, log.range_max))
        report.counts = dict(bag.counts)
    report.retimed = clock.retimed
    report.start_ns, report.end_ns = t0, clock.last
    return report
