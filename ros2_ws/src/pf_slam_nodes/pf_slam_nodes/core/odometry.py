"""Odometry bookkeeping between scans: a buffer of odometry poses and its lookup at scan times.

ROS-free so that the predictor node stays thin and the pairing rules are unit-tested.
"""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from .geometry import wrap_angle
from .motion import integrate_diff_drive, wheel_odometry


class OdometryBuffer:
    """Odometry poses in arrival order, looked up at scan stamps.

    Two pairing rules (``sync``):

    ``'exact'``
        Logs whose odometry is recorded with each scan (CARMEN laser lines, the Mines log): the
        n-th scan with stamp ``t`` pairs with the n-th odometry message with stamp ``t``. This
        survives repeated and backward-stepping timestamps (the Intel log has both).
    ``'interpolate'``
        Asynchronous streams (wheel encoders at 100 Hz): linear interpolation between the two
        odometry poses that bracket the scan stamp (yaw interpolated on the circle).

    Stamps are integer nanoseconds.

    Bad messages (NaN odometry, a bad encoder message) are added with :meth:`add_bad`: they keep
    their place in the stream without a pose. A scan whose own odometry message was bad (in
    *exact* its partner, in *interpolate* the first message at or after its stamp), or whose
    partner will not come (``final``), gets the interpolation between the good poses around it
    in the stream, once the next good one is here, else (``final``) the nearest earlier good
    pose; counted in ``missing``. The result depends only on the stream, not on arrival times.

    Exact pairing that finds no partner while odometry stamped later than the scan keeps
    arriving (a log whose odometry comes in separate messages at other times) cannot work:
    :meth:`no_partner` detects it and :meth:`fall_back` switches to interpolation for good
    (``fallback`` then says when and why).
    """

    #: exact pairing is given up when this many queued scans that the odometry has passed have no
    #: partner while at least NO_PARTNER_BETWEEN odometry messages stamped between them arrived
    #: (looked for among the last NO_PARTNER_LOOK messages)
    NO_PARTNER_SCANS = 5
    NO_PARTNER_BETWEEN = 2
    NO_PARTNER_LOOK = 1000

    def __init__(self, sync: str = "interpolate") -> None:
        if sync not in ("exact", "interpolate"):
            raise ValueError(f"odom_sync must be 'exact' or 'interpolate', got {sync!r}")
        self.sync = sync
        self._stamps: list[int] = []
        self._poses: list[np.ndarray | None] = []  # None: a bad message (kept for its stamp)
        self._exact: dict[int, list[int]] = defaultdict(list)
        self._scan_seen: dict[int, int] = defaultdict(int)
        self._cursor = 0
        self._dropped = 0  # messages trimmed off the front (received = dropped + len)
        self.backward_steps = 0
        self.missing = 0
        self.progress_ns: int | None = None  # the latest stamp of any message, good or bad
        self.fallback: dict | None = None
        self.last_missing = self.peek_missing = False
        self._unpaired: list[int] = []  # exact: stamps of the scans just resolved without a partner

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def received(self) -> int:
        """Messages added so far (good and bad), trimmed ones included."""
        return self._dropped + len(self._stamps)

    def add(self, stamp_ns: int, pose: np.ndarray | None) -> None:
        stamp_ns = int(stamp_ns)
        if self._stamps and stamp_ns < self._stamps[-1]:
            self.backward_steps += 1
        self._exact[stamp_ns].append(len(self._stamps))
        self._stamps.append(stamp_ns)
        self._poses.append(None if pose is None else np.asarray(pose, dtype=np.float64).reshape(3))
        self.progress_ns = stamp_ns if self.progress_ns is None else max(self.progress_ns, stamp_ns)

    def add_bad(self, stamp_ns: int) -> None:
        """A message that arrived but cannot be used (NaN/inf): its stamp keeps its place."""
        self.add(stamp_ns, None)

    @property
    def last(self) -> np.ndarray | None:
        i = self._good_at_or_before(len(self._poses) - 1)
        return None if i is None else self._poses[i]

    def _good_at_or_before(self, i: int) -> int | None:
        while i >= 0 and self._poses[i] is None:
            i -= 1
        return i if i >= 0 else None

    def _nearest_good(self, i: int) -> np.ndarray | None:
        """The good pose at or before index i, else the first good one after it."""
        j = self._good_at_or_before(min(i, len(self._poses) - 1))
        if j is None:
            j = next((k for k in range(max(i, 0), len(self._poses)) if self._poses[k] is not None), None)
        return None if j is None else self._poses[j].copy()

    def has_exact(self, stamp_ns: int, ahead: int = 0) -> bool:
        """True when the odometry for the next (+ ``ahead``) scan with this stamp has arrived."""
        return self._scan_seen[stamp_ns] + ahead < len(self._exact.get(stamp_ns, ()))

    def later_paired(self, stamps: list) -> bool:
        """Exact: True when a scan behind the head (``stamps``: the queued scans' stamps, head
        first, None for a scan without one) has its own odometry message already, so the head's
        will not come (odometry arrives in order). Unreadable scans (None) are skipped."""
        if self.sync != "exact" or len(stamps) < 2:
            return False
        seen: dict[int, int] = defaultdict(int)
        seen[stamps[0]] += 1
        for t in stamps[1:]:
            if t is None:
                continue
            if self.has_exact(t, ahead=seen[t]):
                return True
            seen[t] += 1
        return False

    def no_partner(self, stamps: list) -> tuple[int, int] | None:
        """Exact: is the pairing impossible for this input? ``stamps``: the queued scans' stamps,
        head first (None: a scan without one). True evidence, not a delay: at least
        ``NO_PARTNER_SCANS`` scans (the queued ones and those just resolved without a partner,
        e.g. because the replay waited for their poses) that the odometry has passed (stamped before
        its newest message) have no odometry message with their stamp, while odometry messages
        stamped *between* them did arrive (a log whose odometry comes in its own messages at
        other times). A stretch without any odometry (messages lost) is not this: nothing
        arrived between those scans. Returns (scans without a partner, odometry messages between
        them), or None."""
        if self.sync != "exact" or self.progress_ns is None:
            return None
        covered = self._unpaired + [t for t in stamps if t is not None and t < self.progress_ns]
        if len(covered) < self.NO_PARTNER_SCANS or any(self.has_exact(t) for t in covered):
            return None
        lo, hi = min(covered), max(covered)
        between = sum(1 for t in self._stamps[-self.NO_PARTNER_LOOK :] if lo < t < hi)
        return (len(covered), between) if between >= self.NO_PARTNER_BETWEEN else None

    def fall_back(self, **why) -> None:
        """Exact -> interpolate for the rest of the run (``why``: numbers for the report)."""
        if self.sync == "exact":
            self.sync = "interpolate"
            self.fallback = dict(why)
            self._cursor = 0  # stamps are searched from the start once, then the cursor moves on

    def peek(self, stamp_ns: int, final: bool = False) -> np.ndarray | None:
        """What :meth:`lookup` would return now, without consuming anything (``peek_missing``:
        whether it would count as missing)."""
        pose, self.peek_missing = self._resolve(stamp_ns, final, commit=False)
        return pose

    def lookup(self, stamp_ns: int, final: bool = False) -> np.ndarray | None:
        """Odometry pose at a scan stamp, or None when it has not arrived yet.

        Call once per scan, in scan order (the exact rule counts occurrences). With
        ``final=True`` (end of stream, or the odometry is known not to come) a pose is always
        returned: the best available (see the class), counted in ``missing``; the origin if no
        good odometry arrived at all. ``last_missing``: whether this scan's was.
        """
        pose, missing = self._resolve(stamp_ns, final, commit=True)
        if pose is not None:
            self.last_missing = missing
            self.missing += int(missing)
        return pose

    def _next_good(self, i: int, after_ns: int | None = None) -> int | None:
        """Index of the first good pose after index i (stream order; stamped after ``after_ns``
        if given), or None (not arrived yet)."""
        return next(
            (
                k
                for k in range(i + 1, len(self._poses))
                if self._poses[k] is not None and (after_ns is None or self._stamps[k] > after_ns)
            ),
            None,
        )

    #: a scan interpolated from odometry more than this far away on both sides lies in a gap of
    #: the odometry: its pose is a guess (counted as missing)
    GAP_MIN_NS = 500_000_000

    def _in_gap(self, stamp_ns: int, i: int, k: int) -> bool:
        return min(stamp_ns - self._stamps[i], self._stamps[k] - stamp_ns) > self.GAP_MIN_NS

    def _between(self, stamp_ns: int, i: int | None, k: int | None) -> np.ndarray | None:
        """Interpolation between the good poses i and k when the stamp lies strictly between
        their stamps, else None."""
        if i is None or k is None:
            return None
        t0, t1 = self._stamps[i], self._stamps[k]
        if not t0 < stamp_ns < t1:
            return None
        a = (stamp_ns - t0) / (t1 - t0)
        p0, p1 = self._poses[i], self._poses[k]
        out = p0 + a * (p1 - p0)
        out[2] = float(wrap_angle(p0[2] + a * float(wrap_angle(p1[2] - p0[2]))))
        return out

    def _resolve(self, stamp_ns: int, final: bool, commit: bool) -> tuple[np.ndarray | None, bool]:
        """(pose or None, whether the scan's own odometry was missing)."""
        if not self._stamps:
            return (np.zeros(3), True) if final else (None, False)
        if self.sync == "exact":
            n = self._scan_seen[stamp_ns] if stamp_ns in self._scan_seen else 0
            hits = self._exact.get(stamp_ns, [])
            if n < len(hits) and self._poses[hits[n]] is not None:
                if commit:
                    self._scan_seen[stamp_ns] += 1
                    self._cursor = hits[n]
                    self._unpaired.clear()
                return self._poses[hits[n]].copy(), False
            if n >= len(hits) and not final:
                return None, False
            # the partner was bad, or will not come: interpolated between the good poses around
            # it in the stream (once the next one stamped after it is here), else the nearest
            # earlier good pose
            after = hits[n] if n < len(hits) else self._cursor
            nxt = self._next_good(after, stamp_ns)
            if nxt is None and not final:
                return None, False
            pose = self._between(stamp_ns, self._good_at_or_before(after), nxt)
            if pose is None:
                pose = self._nearest_good(self._cursor)
            if commit:
                self._scan_seen[stamp_ns] += 1
                if n >= len(hits):  # no partner at all (not a bad one): evidence for no_partner
                    self._unpaired = self._unpaired[-self.NO_PARTNER_SCANS :] + [stamp_ns]
            return (np.zeros(3) if pose is None else pose), True
        # interpolate: first odometry message at or after the stamp, from the cursor on
        j = self._cursor
        stamps = self._stamps
        while j < len(stamps) and stamps[j] < stamp_ns:
            j += 1
        g = j if j < len(stamps) and self._poses[j] is not None else self._next_good(j)
        if g is None:  # no good odometry at or after the stamp yet
            if not final:
                return None, False
            pose = self._nearest_good(len(stamps) - 1)
            if commit:
                self._cursor = max(j - 1, 0)
            return (np.zeros(3) if pose is None else pose), True
        if commit:
            self._cursor = max(j - 1, 0)
        missing = g != j  # its own message was bad: bracketed across the bad ones
        p1 = self._poses[g]
        i = None if j == 0 else self._good_at_or_before(j - 1)
        if i is not None and self._in_gap(stamp_ns, i, g):
            missing = True  # bracketed across a stretch without odometry: a guess
        if i is None or stamps[g] == stamp_ns:
            return p1.copy(), missing
        pose = self._between(stamp_ns, i, g)
        return (p1.copy() if pose is None else pose), missing

    def trim(self) -> None:
        """Forget poses before the cursor (keeps memory bounded on long runs)."""
        if self.sync == "interpolate" and self._cursor > 1000:
            k = self._good_at_or_before(self._cursor - 1)  # keep the good pose interpolation starts from
            if not k:
                return
            del self._stamps[:k], self._poses[:k]
            self._cursor -= k
            self._dropped += k
            self._exact.clear()


class WheelOdometryIntegrator:
    """Integrates cumulative wheel angles (rad) and optional gyro yaw increments into a pose.

    Differential drive, midpoint rule (:func:`integrate_diff_drive`). When gyro increments are
    given (FOG), the yaw change of a step is their sum instead of the wheels' difference.

    ``max_speed_mps``: a step in which a wheel would have covered more than
    ``max_speed_mps * max(dt, 0.1 s)`` is an encoder counter jump (a reset, a wrap, a glitch):
    its wheel motion is discarded (the counters are re-based there; a gyro's yaw still applies)
    and counted in ``jumps``. Only checked when :meth:`step` is given ``dt_s``.

    ``gyro_rest_bias``: standstill calibration of the gyro's yaw bias (a zero-velocity update).
    A step in which neither wheel counter moved is a rest step: its yaw change is zero, whatever
    the gyro says. Once the vehicle has been at rest for ``rest_min_s`` in a row, what the gyro
    integrated over those steps is its bias; ``gyro_bias_rad_s`` is the mean over all rest time so
    far, and each moving step's gyro yaw is corrected by ``gyro_bias_rad_s * dt_s``. Causal (only
    rest seen before a step corrects it); needs ``dt_s``. Shorter rests (a wheel that happens not to
    tick in one step while creeping) only get the zero yaw. The same rest steps measure the gyro's
    noise (``gyro_noise``: the spread of its increments about the bias, and so the bias
    estimate's own std).
    """

    def __init__(
        self,
        left_diameter_m: float,
        right_diameter_m: float,
        wheel_base_m: float,
        max_speed_mps: float = math.inf,
        gyro_rest_bias: bool = False,
        rest_min_s: float = 0.5,
    ) -> None:
        for name, v in (
            ("left_diameter_m", left_diameter_m),
            ("right_diameter_m", right_diameter_m),
            ("wheel_base_m", wheel_base_m),
        ):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be > 0, got {v!r}")
        self.left_diameter_m = float(left_diameter_m)
        self.right_diameter_m = float(right_diameter_m)
        self.wheel_base_m = float(wheel_base_m)
        if not max_speed_mps > 0:
            raise ValueError(f"max_speed_mps must be > 0, got {max_speed_mps!r}")
        self.max_speed_mps = float(max_speed_mps)
        if not (math.isfinite(rest_min_s) and rest_min_s > 0):
            raise ValueError(f"rest_min_s must be > 0, got {rest_min_s!r}")
        self.gyro_rest_bias = bool(gyro_rest_bias)
        self.rest_min_s = float(rest_min_s)
        # rest sums (gyro yaw, seconds, yaw^2 / dt, steps): the current run, and the finished rests of
        # rest_min_s or longer
        self._run = np.zeros(4)
        self._done = np.zeros(4)
        self.calibrations = 0
        self.jumps = 0
        self.pose = np.zeros(3)
        self._last: tuple[float, float] | None = None
        self._pending_gyro_yaw = 0.0
        self.use_gyro = False

    def add_gyro(self, dyaw_rad: float) -> None:
        """Accumulate a gyro yaw increment (rad) to be used by the next wheel step."""
        self.use_gyro = True
        self._pending_gyro_yaw += float(dyaw_rad)

    def _rest(self) -> np.ndarray:
        """(gyro yaw, seconds, sum of yaw^2 / dt, steps) over the rests that count: the finished
        ones and the current run once it is long enough (a rest, not a wheel that did not tick
        while creeping)."""
        return self._done + self._run if self._run[1] >= self.rest_min_s else self._done

    @property
    def gyro_bias_rad_s(self) -> float:
        """The gyro's yaw bias estimated at rest (rad/s; 0 before the first rest)."""
        yaw, seconds = self._rest()[:2]
        return float(yaw / seconds) if seconds > 0 else 0.0

    @property
    def rest_s(self) -> float:
        """Rest time the bias estimate is based on (s)."""
        return float(self._rest()[1])

    @property
    def gyro_noise(self) -> tuple[float, float] | None:
        """What the finished rests measured of the gyro's noise: ``(q, s_b)``, ``q`` its
        white-noise density (rad^2/s: a rest step of ``dt`` s integrates ``bias * dt`` plus noise
        of variance ``q * dt``) and ``s_b = sqrt(q / rest time)`` the bias estimate's std (rad/s);
        None before a finished rest of two steps or more. ``calibrations`` counts the finished
        rests, so a caller can note when this changes."""
        yaw, seconds, sq, n = self._done
        if n < 2 or seconds <= 0:
            return None
        q = float(max(sq - yaw * yaw / seconds, 0.0) / (n - 1))
        return q, math.sqrt(q / seconds)

    def _gyro_yaw(self, yaw: float, rest: bool, dt_s: float | None) -> float:
        """A step's yaw from the gyro's increments: zero at rest, bias-corrected when moving."""
        if not self.gyro_rest_bias or dt_s is None:
            return yaw
        if rest:
            self._run += (yaw, dt_s, yaw * yaw / dt_s, 1.0) if dt_s > 0 else (yaw, dt_s, 0.0, 0.0)
            return 0.0
        if self._run[1] >= self.rest_min_s:  # the run counts, and ends here
            self._done = self._done + self._run
            self.calibrations += 1
        if self._run.any():
            self._run = np.zeros(4)
        return yaw - self.gyro_bias_rad_s * dt_s

    def step(self, left_rad: float, right_rad: float, dt_s: float | None = None) -> np.ndarray:
        """Advance with new cumulative wheel angles (``dt_s`` since the previous step, for the
        counter-jump check and the gyro's rest bias); returns the pose (odometry frame)."""
        if self._last is None:
            self._last = (left_rad, right_rad)
            return self.pose.copy()
        dl, dr = left_rad - self._last[0], right_rad - self._last[1]
        if dt_s is not None and max(
            abs(dl) * self.left_diameter_m, abs(dr) * self.right_diameter_m
        ) / 2 > self.max_speed_mps * max(dt_s, 0.1):
            self.jumps += 1
            dl = dr = 0.0
        d, w = wheel_odometry(dl, dr, self.left_diameter_m, self.right_diameter_m, self.wheel_base_m)
        if self.use_gyro:
            w = self._gyro_yaw(self._pending_gyro_yaw, left_rad == self._last[0] and right_rad == self._last[1], dt_s)
            self._pending_gyro_yaw = 0.0
        self.pose = integrate_diff_drive(self.pose, float(d), float(w))
        self._last = (left_rad, right_rad)
        return self.pose.copy()


class GyroBuffer:
    """Gyro (FOG) yaw increments in stamp order; sums them over a time interval.

    The car's FOG runs at 1 kHz and its samples do not line up with the 100 Hz encoders: the
    yaw change of an encoder step ``(t0, t1]`` is the sum of the increments stamped in it. The
    buffer keeps the increments themselves and sums each interval's slice, so the result
    depends only on the samples, not on how they were batched into messages (a bag written
    with ``--fog-batch 10`` or ``50`` gives the same trajectory, bit for bit).
    """

    def __init__(self) -> None:
        # stamps and increments in growing buffers (capacity doubles; O(1) amortised add)
        self._st_buf = np.zeros(1024, dtype=np.int64)
        self._dy_buf = np.zeros(1024)
        self._n = 0
        self.out_of_order = 0

    @property
    def _stamps(self) -> np.ndarray:
        return self._st_buf[: self._n]

    @property
    def last_stamp(self) -> int:
        return int(self._st_buf[self._n - 1]) if self._n else -1

    def add(self, stamps_ns: np.ndarray, dyaw_rad: np.ndarray) -> None:
        st = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        dy = np.asarray(dyaw_rad, dtype=np.float64).reshape(-1)
        if st.shape != dy.shape:
            raise ValueError(f"gyro batch: {st.size} stamps but {dy.size} increments")
        n, k = self._n, st.size
        if k == 0:
            return
        # the usual batch (after the last stamp, increasing, room left) goes straight to the copies
        if not (
            n + k <= self._st_buf.size
            and (n == 0 or st[0] > self._st_buf[n - 1])
            and (k == 1 or bool((st[1:] > st[:-1]).all()))
        ):
            if n:
                keep = st > self.last_stamp
                if not keep.all():
                    self.out_of_order += int((~keep).sum())  # a stamp at or before the last one: dropped
                    st, dy = st[keep], dy[keep]
            if st.size > 1 and np.any(np.diff(st) <= 0):
                order = np.argsort(st, kind="stable")
                st, dy = st[order], dy[order]
            k = st.size
            if n + k > self._st_buf.size:
                cap = max(2 * self._st_buf.size, n + k)
                self._st_buf = np.concatenate([self._st_buf[:n], np.zeros(cap - n, dtype=np.int64)])
                self._dy_buf = np.concatenate([self._dy_buf[:n], np.zeros(cap - n)])
        self._st_buf[n : n + k] = st
        self._dy_buf[n : n + k] = dy
        self._n = n + k

    def yaw_between(self, t0_ns: int, t1_ns: int) -> float:
        """Sum of the increments stamped in ``(t0, t1]`` (rad)."""
        i0 = int(np.searchsorted(self._stamps, t0_ns, side="right"))
        i1 = int(np.searchsorted(self._stamps, t1_ns, side="right"))
        return float(self._dy_buf[i0:i1].sum())

    def trim(self, before_ns: int) -> None:
        """Forget increments stamped at or before ``before_ns`` (keeps memory bounded)."""
        k = int(np.searchsorted(self._stamps, before_ns, side="right"))
        if k > 10000:
            n = self._n - k
            self._st_buf[:n] = self._st_buf[k : self._n]
            self._dy_buf[:n] = self._dy_buf[k : self._n]
            self._n = n


class OdomScaleEstimator:
    """Online estimate of the odometry's translation scale (true travel / odometry travel).

    A wheel-diameter calibration error scales every odometry increment's translation by the same
    factor. Each measurement is a pair of scans matched against each other (core/scanpair.py):
    :meth:`add` takes the pair's odometry travel ``d`` and the travel the match measured ``m``;
    the estimate is ``sum m / sum d`` over the last ``window_m`` of measured travel (exponential
    forgetting by distance), clamped to ``1 +- max_error``, and optionally phased in over the
    first ``ramp_m`` of it (its departure from 1 applied in proportion to the travel measured).
    Causal: a step is scaled by what earlier pairs measured. A pair measures the scale directly,
    not relative to the estimate applied (it does not go through the map the filter builds), and
    where a street has no along-track structure it measures nothing rather than the prediction.

    A pair can still be wrong by tens of centimetres now and then: a measurement counts at most
    ``max_error`` away from the current ratio, and the ratio's departure from 1 is shrunk by its
    own standard error ``se`` (from the spread of the measurements' ratios and the effective
    number of them in the window): ``1 + e * max(0, 1 - (SHRINK_Z * se / e)^2)``, ``e = ratio -
    1``. Well-calibrated wheels (``|e|`` within the noise) thus stay at 1.
    """

    #: how many standard errors of the ratio shrink its departure from 1 to nothing
    SHRINK_Z = 1.0

    def __init__(self, window_m: float = 1000.0, ramp_m: float = 0.0, max_error: float = 0.03) -> None:
        if not (math.isfinite(window_m) and window_m > 0):
            raise ValueError(f"window_m must be > 0, got {window_m!r}")
        if not (math.isfinite(ramp_m) and ramp_m >= 0):
            raise ValueError(f"ramp_m must be >= 0, got {ramp_m!r}")
        if not (math.isfinite(max_error) and max_error >= 0):
            raise ValueError(f"max_error must be >= 0, got {max_error!r}")
        self.window_m = float(window_m)
        self.ramp_m = float(ramp_m)
        self.max_error = float(max_error)
        self._sum_d = self._sum_m = 0.0
        self._sum_r2 = self._sum_d2 = 0.0  # sum d r^2 (r = m / d) and sum d^2: the spread
        self.travel_m = 0.0  # odometry travel measured so far
        self.steps = 0

    @property
    def raw(self) -> float:
        """The unclamped ratio (1 before any travel)."""
        return self._sum_m / self._sum_d if self._sum_d > 0 else 1.0

    @property
    def std_error(self) -> float:
        """Standard error of :attr:`raw` (inf before two steps)."""
        if self._sum_d <= 0 or self._sum_d2 <= 0:
            return math.inf
        r = self.raw
        var = max(self._sum_r2 / self._sum_d - r * r, 0.0)
        n_eff = self._sum_d**2 / self._sum_d2
        return math.sqrt(var / n_eff) if n_eff > 1.0 else math.inf

    @property
    def scale(self) -> float:
        """The scale to apply to odometry translation (1 before any travel, phased in over
        ``ramp_m``)."""
        if self._sum_d <= 0:
            return 1.0
        e = self.raw - 1.0
        if e == 0.0:
            return 1.0
        e *= max(0.0, 1.0 - (self.SHRINK_Z * self.std_error / e) ** 2)
        e = min(max(e, -self.max_error), self.max_error)
        phase = min(1.0, self.travel_m / self.ramp_m) if self.ramp_m > 0 else 1.0
        return float(1.0 + e * phase)

    def add(self, odom_m: float, measured_m: float) -> None:
        """One step: odometry travel ``odom_m`` (> 0) and the travel measured along it (m)."""
        d, m = float(odom_m), float(measured_m)
        if not (math.isfinite(d) and math.isfinite(m)) or d <= 0:
            return
        # one bad match (a jump of tens of centimetres) would outweigh many good ones: a step
        # counts at most max_error away from the current ratio
        r = self.raw
        m = min(max(m, (r - self.max_error) * d), (r + self.max_error) * d)
        keep = math.exp(-d / self.window_m)
        self._sum_d = self._sum_d * keep + d
        self._sum_m = self._sum_m * keep + m
        self._sum_r2 = self._sum_r2 * keep + m * m / d
        self._sum_d2 = self._sum_d2 * keep * keep + d * d
        self.travel_m += d
        self.steps += 1


def gyro_heading_sigma(q: float, bias_std_rad_s: float, dt_s: float) -> float:
    """A calibrated gyro's heading uncertainty over ``dt_s`` of driving (rad): its white noise
    (density ``q``, rad^2/s) and its bias estimate's error, ``sqrt(q dt + (s_b dt)^2)``."""
    dt = max(float(dt_s), 0.0)
    return math.sqrt(q * dt + (bias_std_rad_s * dt) ** 2)
