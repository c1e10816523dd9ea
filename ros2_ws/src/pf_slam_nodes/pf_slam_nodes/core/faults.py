"""Run-time checks of the input messages: what is wrong with a scan or a stamp, counted by kind.

Real logs are messy (the Intel log repeats timestamps and steps back by up to 0.8 s). The
filter keeps going on bad input, skipping or clamping what it cannot use; these checks name each
fault once so the predictor can log it (throttled) and the run can count it in summary.json.
ROS-free: the predictor reads the scan's fields from its CDR bytes and calls these.
"""

from __future__ import annotations

import math

import numpy as np

from .scan import scan_limits_ok

#: the counters of summary.json "faults" (the odometry buffers count theirs: odom_time_backwards,
#: odom_missing, fog_out_of_order; WheelOdometryIntegrator counts encoder_jump)
SCAN_BAD_RANGES = "scan_bad_ranges"  # a scan with NaN or negative ranges: those beams ignored
SCAN_COUNT_MISMATCH = "scan_count_mismatch"  # range count != what the angles say: not corrected with
SCAN_BAD_LIMITS = "scan_bad_limits"  # range_min/range_max unusable (max <= 0, min > max, NaN, min < 0): not used
TIME_BACKWARDS = "time_backwards"  # a scan stamped before the previous one
TIME_GAP = "time_gap"  # a scan more than time_gap_s after the previous one
SCAN_UNREADABLE = "scan_unreadable"  # bytes that are not a LaserScan: posed from odometry
ODOMETRY_NONFINITE = "odometry_nonfinite"  # an odometry / encoder / FOG message with NaN or inf: dropped


class ScanChecks:
    """Checks each scan's ranges, beam count and stamp against the previous scan; counts faults.

    ``time_gap_s``: a forward step longer than this is a gap (the odometry increment over it is
    still used: the motion model's noise grows with it).
    """

    def __init__(self, time_gap_s: float = 60.0) -> None:
        if not time_gap_s > 0:
            raise ValueError(f"time_gap_s must be > 0, got {time_gap_s!r}")
        self.gap_ns = int(time_gap_s * 1e9)
        self.counts = {
            SCAN_BAD_RANGES: 0,
            SCAN_COUNT_MISMATCH: 0,
            SCAN_BAD_LIMITS: 0,
            SCAN_UNREADABLE: 0,
            TIME_BACKWARDS: 0,
            TIME_GAP: 0,
        }
        self.last_stamp_ns: int | None = None

    def check(
        self,
        stamp_ns: int,
        ranges: np.ndarray,
        angle_min: float,
        angle_max: float,
        angle_increment: float,
        range_min: float = 0.0,
        range_max: float = math.inf,
    ) -> tuple[bool, list[tuple[str, str]]]:
        """One scan -> (usable for a correction?, [(fault kind, what was wrong)]).

        NaN and negative ranges (``-inf`` included) are faults; ``+inf`` is "no return" (REP 117)
        and a range below ``range_min`` is the sensor's own "no reading": neither is counted. The
        downstream stages already ignore such beams, so the scan stays usable. A beam count that
        differs by more than one from ``(angle_max - angle_min) / angle_increment + 1`` (drivers
        differ on whether ``angle_max`` is the last beam) makes the beam angles ambiguous: the
        scan is posed from odometry and not corrected with.

        Values outside ``[range_min, range_max]`` are no returns (REP 117: the stages ignore
        them) and not counted. Limits that cannot gate anything (``range_max <= 0``,
        ``range_min > range_max``, ``range_min < 0`` or not finite, ``range_max`` NaN:
        :func:`~pf_slam_nodes.core.scan.scan_limits_ok`; ``range_max = +inf`` is no limit) leave
        no valid range: a ``scan_bad_limits`` fault, and the scan is posed from odometry, neither
        corrected nor mapped with (as a beam count mismatch).
        """
        faults: list[tuple[str, str]] = []
        r = np.asarray(ranges)
        low = r.min() if r.size else 0.0  # NaN if any is NaN: one pass for the clean scans
        if not low >= 0:
            with np.errstate(invalid="ignore"):
                bad = int(np.count_nonzero(np.isnan(r) | (r < 0)))
            faults.append((SCAN_BAD_RANGES, f"{bad} of {r.size} ranges NaN or negative, ignored"))
        limits_ok = scan_limits_ok(range_min, range_max)
        if not limits_ok:
            faults.append(
                (
                    SCAN_BAD_LIMITS,
                    f"range_min {range_min:g}, range_max {range_max:g}: no range can be "
                    "valid (needs 0 <= range_min <= range_max, range_max > 0, not NaN); not corrected "
                    "or mapped with, posed from odometry",
                )
            )
        count_ok = True
        if angle_increment != 0 and math.isfinite(angle_min + angle_max + angle_increment):
            expected = (angle_max - angle_min) / angle_increment + 1.0
            if abs(expected - r.size) > 1.5:  # rounding of float32 angles: well under half a beam
                count_ok = False
        else:
            expected, count_ok = float("nan"), False
        usable = limits_ok and count_ok
        if not count_ok:
            faults.append(
                (
                    SCAN_COUNT_MISMATCH,
                    f"{r.size} ranges but angle_min {angle_min:.4f}, angle_max "
                    f"{angle_max:.4f}, increment {angle_increment:.6f} give {expected:.1f}: "
                    "not corrected with, posed from odometry",
                )
            )
        last = self.last_stamp_ns
        if last is not None and stamp_ns < last:
            faults.append(
                (
                    TIME_BACKWARDS,
                    f"stamp {(last - stamp_ns) / 1e9:.3f} s before the previous scan's "
                    "(odometry looked up at it, clamped to what has arrived)",
                )
            )
        elif last is not None and stamp_ns - last > self.gap_ns:
            faults.append(
                (
                    TIME_GAP,
                    f"{(stamp_ns - last) / 1e9:.1f} s since the previous scan (odometry increment over the gap used)",
                )
            )
        self.last_stamp_ns = stamp_ns  # a step is counted once, not every scan until time catches up
        for kind, _ in faults:
            self.counts[kind] += 1
        return usable, faults

    def unreadable(self, error: Exception, own_stamp: bool = False) -> list[tuple[str, str]]:
        """A scan whose bytes cannot be read: counted; the caller poses it from odometry, at its
        own stamp if that could be read (``own_stamp``), else at the previous scan's (it keeps its
        place: the other nodes number scans by arrival)."""
        self.counts[SCAN_UNREADABLE] += 1
        where = "its own stamp" if own_stamp else "the previous scan's stamp"
        return [(SCAN_UNREADABLE, f"unreadable ({error}): posed from odometry at {where}")]

    def readable_stamp(self, raw: bytes, reader) -> int | None:
        """The header stamp of an otherwise unreadable scan (``reader``: a CDR reader class with
        ``stamp_ns()``), if it can be read and lies within ``time_gap_s`` of the previous scan's;
        else None. The previous stamp is not updated: an unreadable scan does not count for the
        stamp checks."""
        try:
            stamp = int(reader(raw, "sensor_msgs/LaserScan").stamp_ns())
        except (ValueError, OverflowError):
            return None
        last = self.last_stamp_ns
        if stamp < 0 or (last is not None and abs(stamp - last) > self.gap_ns):
            return None
        return stamp
