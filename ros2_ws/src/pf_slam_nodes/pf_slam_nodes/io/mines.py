"""Reader for the Paris Mines robot logs (``exp1.dat``, ``exp2.dat``): wheel ticks + Hokuyo scans.

One line per scan, 707 space-separated numbers:

* field 0: timestamp (microseconds);
* fields 2 and 3: left and right wheel encoder ticks (cumulative, 2000 ticks per wheel turn;
  both grow when the robot drives forward);
* fields 24 .. 705: the 682 ranges of a Hokuyo URG-04LX, in millimetres.

Beam geometry (URG-04LX / SCIP 2.0 ``PP`` values): 1024 steps per turn
(``angle_increment = 2*pi/1024`` = 0.3515625 deg), the 682 measured steps are 44 .. 725 and the
front is step 384, so ``angle_min = (44 - 384) * 2*pi/1024`` = -119.53 deg and the last beam is at
+119.88 deg, counter-clockwise (right to left). These are the values ``urg_node`` publishes
for this sensor.

Ranges: 0 is "no return"; values 1 .. 19 mm are URG error codes, not distances. Both become
``+inf`` (REP 117: no valid return), and ``range_min`` is 0.02 m. ``range_max`` is 5.6 m
(the largest distance an URG-04LX reports; the files' maximum is 5.562 m).

Malformed lines (wrong field count, non-numeric or non-finite values) are skipped, counted in
``MinesLog.skipped`` and named ``file:line`` in ``MinesLog.warnings``; timestamps that do not
increase are kept in file order and reported in one warning.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from .skips import SkipLog

__all__ = [
    "MINES_ANGLE_INCREMENT",
    "MINES_ANGLE_MIN",
    "MinesLog",
    "read_mines",
]

N_FIELDS = 707
N_BEAMS = 682
FIRST_RANGE_FIELD = 24
MINES_ANGLE_INCREMENT = 2.0 * math.pi / 1024.0
MINES_ANGLE_MIN = (44 - 384) * MINES_ANGLE_INCREMENT


@dataclass
class MinesLog:
    """Content of a Mines ``.dat`` file, one row per scan, in file order.

    Attributes
    ----------
    stamps_s : np.ndarray
        ``(S,)`` float64 timestamps (s).
    stamps_us : np.ndarray
        ``(S,)`` int64 timestamps as written (microseconds).
    left_ticks, right_ticks : np.ndarray
        ``(S,)`` int64 cumulative encoder ticks.
    ranges : np.ndarray
        ``(S, 682)`` float32 ranges (m), no return / error code = ``+inf``.
    angle_min, angle_increment : float
        Beam geometry (rad), see the module docstring.
    range_min, range_max : float
        Valid range interval (m).
    ticks_per_rev : int
        Encoder ticks per wheel revolution.
    wheel_radius_m, half_axle_m : float
        Robot geometry (m): wheel radius, half of the distance between the wheels.
    line_nos : np.ndarray
        ``(S,)`` 1-based line number of each scan.
    """

    stamps_s: np.ndarray
    stamps_us: np.ndarray
    left_ticks: np.ndarray
    right_ticks: np.ndarray
    ranges: np.ndarray
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ticks_per_rev: int
    wheel_radius_m: float
    half_axle_m: float
    line_nos: np.ndarray
    skipped: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    path: str = ""

    @property
    def left_wheel_rad(self) -> np.ndarray:
        """``(S,)`` cumulative left wheel angle (rad) = ticks * 2 pi / ticks_per_rev."""
        return self.left_ticks.astype(np.float64) * (2.0 * math.pi / self.ticks_per_rev)

    @property
    def right_wheel_rad(self) -> np.ndarray:
        """``(S,)`` cumulative right wheel angle (rad)."""
        return self.right_ticks.astype(np.float64) * (2.0 * math.pi / self.ticks_per_rev)

    @property
    def stamps_ns(self) -> np.ndarray:
        """``(S,)`` int64 timestamps (ns)."""
        return self.stamps_us * 1000


def read_mines(
    path: str | os.PathLike,
    ticks_per_rev: int = 2000,
    wheel_radius_m: float = 0.077,
    half_axle_m: float = 0.165,
    range_min_m: float = 0.02,
    range_max_m: float = 5.6,
) -> MinesLog:
    """Read a Mines ``.dat`` log (see the module docstring for the format and conventions).

    Parameters
    ----------
    path : str or PathLike
        The ``.dat`` file.
    ticks_per_rev : int
        Encoder ticks per wheel revolution.
    wheel_radius_m, half_axle_m : float
        Robot geometry (m), carried in the result for the motion model.
    range_min_m, range_max_m : float
        Valid range interval (m); readings below ``range_min_m`` (0 and error codes) become
        ``+inf``; readings above ``range_max_m`` are kept (the LaserScan consumer clips them).
    """
    for name, val in (
        ("ticks_per_rev", ticks_per_rev),
        ("wheel_radius_m", wheel_radius_m),
        ("half_axle_m", half_axle_m),
        ("range_max_m", range_max_m),
    ):
        if not val > 0:
            raise ValueError(f"{name} must be > 0, got {val}")
    base = os.path.basename(str(path))
    rows: list[np.ndarray] = []
    line_nos: list[int] = []
    skipped: dict[str, int] = {}
    warnings: list[str] = []
    bad = SkipLog(skipped, warnings)
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line_no, line in enumerate(fh, start=1):
            tok = line.split()
            if not tok or tok[0].startswith("#"):
                continue
            why = None
            if len(tok) != N_FIELDS:
                why = f"expected {N_FIELDS} fields, got {len(tok)}"
            else:
                try:
                    row = np.array(tok, dtype=np.float64)
                except ValueError:
                    why = "non-numeric field"
                else:
                    if not np.all(np.isfinite(row)):
                        why = "NaN or inf field"
                    elif row[0] != int(row[0]) or row[2] != int(row[2]) or row[3] != int(row[3]):
                        why = "timestamp or ticks not integers"
            if why is not None:
                bad.skip(base, line_no, why, key="malformed")
                continue
            rows.append(row)
            line_nos.append(line_no)
    bad.finish()

    data = np.array(rows, dtype=np.float64).reshape(-1, N_FIELDS)
    stamps_us = data[:, 0].astype(np.int64)
    mm = data[:, FIRST_RANGE_FIELD : FIRST_RANGE_FIELD + N_BEAMS]
    ranges = (mm * 1e-3).astype(np.float32)
    ranges[mm < range_min_m * 1000.0] = np.inf
    d = np.diff(stamps_us)
    if np.any(d <= 0):
        first = line_nos[int(np.flatnonzero(d <= 0)[0]) + 1]
        warnings.append(
            f"{base}: {int(np.count_nonzero(d == 0))} timestamps repeat and "
            f"{int(np.count_nonzero(d < 0))} step back (first at line {first}); "
            "kept in file order"
        )
    return MinesLog(
        stamps_s=stamps_us.astype(np.float64) * 1e-6,
        stamps_us=stamps_us,
        left_ticks=data[:, 2].astype(np.int64),
        right_ticks=data[:, 3].astype(np.int64),
        ranges=ranges,
        angle_min=MINES_ANGLE_MIN,
        angle_increment=MINES_ANGLE_INCREMENT,
        range_min=float(range_min_m),
        range_max=float(range_max_m),
        ticks_per_rev=int(ticks_per_rev),
        wheel_radius_m=float(wheel_radius_m),
        half_axle_m=float(half_axle_m),
        line_nos=np.array(line_nos, dtype=np.int64),
        skipped=skipped,
        warnings=warnings,
        path=str(path),
    )
