"""The predictor's scheduling, ROS-free: which scan is posed when, and how.

:class:`PredictorScheduler` is what the predictor node runs between its message parsing and its
publishers, and what :meth:`~pf_slam_nodes.core.slam.ParticleFilterSlam.run_stream` runs without
ROS: the same object, fed the same events in the same order, takes the same decisions, so the
node graph and the ROS-free loop give the same trajectory.

Events (one method each, in arrival order): a scan (:meth:`add_scan`), odometry
(:meth:`add_odometry`: a pose; :meth:`add_encoders`: cumulative wheel angles; :meth:`add_gyro` /
:meth:`add_imu`: yaw increments / rates that replace the wheels' yaw), a corrected set coming back
(:meth:`corrected`), the end of the input with its message counts (:meth:`end_of_stream`) and,
from a replay that paces on the poses, "stopped, waiting for your next pose" (:meth:`stall`).

Each event returns the *actions* it caused, in order (or hands each to ``emit`` at once, so
that a node publishes exactly where the decision is taken): :class:`PublishPose` (exactly one per
scan, in scan order), :class:`SendCorrection` (the scan's payload and the predicted set, to be
corrected; its pose comes with :meth:`corrected`), :class:`SendEnd` (the last scan of the input
when it is a pass-through: the end of the run for the correlator and the mapper),
:class:`PublishOdomTf` (the dead-reckoned odometry at each scan's stamp), :class:`PublishStatus`
(the last scan is posed), :class:`Fault` (a counted fault, to be logged throttled per kind) and
:class:`Warn` (a one-off warning with numbers).

What it schedules:

* **Pass-throughs.** A scan whose odometry moved less than ``filter.min_travel_m`` /
  ``filter.min_rotation_rad`` since the last correction is posed at once as the last corrected
  pose composed with the odometry increment. Others are predicted and sent to be corrected.
* **Deferred pass-throughs.** While a correction is in flight, the pass-through scans behind it
  are gated (:meth:`PredictionStage.gate`, no side effects) and queued: their poses need the
  corrected pose, their increments do not. They go out, in order, once it comes back.
* **The blocked index.** The next scan that needs a correction while one is in flight is
  remembered, so it is not gated again on every message; it waits for the correction.
* **Encoders + gyro.** Wheel steps are integrated into odometry poses in stamp order, each once
  the gyro's samples cover its interval (or no more gyro will come): the result depends only on
  the data, not on how the two streams interleave on arrival.
* **Odometry that is bad, missing or on another clock** (see :class:`OdometryBuffer`): NaN/inf
  messages keep their place without a pose (``odometry_nonfinite``); a scan whose odometry will not
  come is posed from the nearest earlier one at the end of the input, once a later scan's own
  partner arrived (exact pairing), when the replay stalled for its pose, or live when
  ``odom_wait_scans`` scans wait behind it (``odom_not_arrived``); exact pairing without partners
  falls back to interpolation; odometry stamps seconds away from the scans' for 3 scans in a row
  are counted (``odom_stamp_offset``).
* **A moving mount** (``laser.dynamic_frame``, a lidar on a humanoid's head; core/mount.py): a
  scan that may be corrected waits until the mount's samples (:meth:`add_mount`) reach its
  stamp (or no more will come: end of input, a stall), is projected with the mount interpolated
  there (:class:`SendCorrection` ``mount``), and is posed from odometry when it is mostly floor
  (``scan_mostly_floor``: counted once per scan that would have been corrected).
* **End of stream.** The last scan of the input is always sent on (:class:`SendEnd` when it is a
  pass-through) so the correlator and the mapper see the end of the run.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Callable
from itertools import islice
from typing import Any

import numpy as np

from .config import FilterConfig, LaserConfig, OdometryMotionConfig, WheelsConfig
from .faults import ODOMETRY_NONFINITE, ScanChecks
from .geometry import compose
from .mount import MOSTLY_FLOOR, MountBuffer, compose_extrinsic, kept_fraction
from .odometry import GyroBuffer, OdometryBuffer, WheelOdometryIntegrator, gyro_heading_sigma
from .stages import PredictionStage

LOOK_AHEAD = 200  # queued scans looked at for evidence about the head scan's odometry


@dataclasses.dataclass
class PublishPose:
    """The pose (map frame) of the next scan, at its stamp (ns)."""

    pose: np.ndarray
    stamp: int


@dataclasses.dataclass
class SendCorrection:
    """Correct scan ``index`` (``payload``: what :meth:`PredictorScheduler.add_scan` was given)
    starting from this predicted set; answer with :meth:`PredictorScheduler.corrected`."""

    index: int
    stamp: int
    payload: Any
    particles: np.ndarray
    log_weights: np.ndarray
    odom: np.ndarray
    mount: np.ndarray | None = None  # (12,) the lidar's mount at the scan's stamp (moving mount)


@dataclasses.dataclass
class SendEnd:
    """The last scan of the input was a pass-through: the end of the run (no particles)."""

    index: int
    stamp: int
    odom: np.ndarray
    delta: np.ndarray


@dataclasses.dataclass
class PublishOdomTf:
    """The odometry (odom -> base) at a scan's stamp."""

    odom: np.ndarray
    stamp: int


@dataclasses.dataclass
class PublishStatus:
    """The last scan of the input is posed: publish :meth:`PredictorScheduler.status` now."""


@dataclasses.dataclass
class Fault:
    """A counted fault (``kind``: its summary.json "faults" key) with what was wrong."""

    kind: str
    text: str


@dataclasses.dataclass
class Warn:
    """A one-off warning (with its numbers)."""

    text: str


class PredictorScheduler:
    """The predictor's state between messages and the rules that pose each scan.

    Parameters
    ----------
    filter_cfg, motion_cfg : FilterConfig, OdometryMotionConfig
        The prediction stage's (gate and motion model).
    odometry_source : str
        ``'odom'`` (poses, :meth:`add_odometry`) or ``'encoders'`` (wheel angles, :meth:`add_encoders`).
    odom_sync : str
        ``'interpolate'`` or ``'exact'`` (see :class:`OdometryBuffer`).
    wheels_cfg : WheelsConfig, optional
        Wheel geometry and gyro calibration (``odometry_source='encoders'``).
    gyro : bool
        Yaw from a gyro (:meth:`add_gyro` / :meth:`add_imu`) instead of the wheels (encoders only).
    odom_wait_scans : int
        Live inputs: a scan whose odometry has not come while this many scans wait behind it is
        posed with the nearest earlier odometry; 0: off (a replay says when it stalled instead).
    stamp_offset_s : float
        Live clock check (see :meth:`_check_offset`); 0: off.
    time_gap_s : float
        Scan stamp gap counted as a fault (:class:`ScanChecks`).
    emit : callable, optional
        Called with each action as it is decided; without it, each event returns its actions.
    stage : PredictionStage, optional
        The prediction stage to drive (default: a new one from the two configs).
    laser_cfg : LaserConfig, optional
        With ``dynamic_frame`` set: a moving mount (:meth:`add_mount`, scans' geometry in
        :meth:`add_scan`); otherwise unused.
    """

    def __init__(
        self,
        filter_cfg: FilterConfig,
        motion_cfg: OdometryMotionConfig,
        odometry_source: str = "odom",
        odom_sync: str = "interpolate",
        wheels_cfg: WheelsConfig | None = None,
        gyro: bool = False,
        odom_wait_scans: int = 50,
        stamp_offset_s: float = 2.0,
        time_gap_s: float = 60.0,
        emit: Callable[[Any], None] | None = None,
        stage: PredictionStage | None = None,
        laser_cfg: LaserConfig | None = None,
    ) -> None:
        if odometry_source not in ("odom", "encoders"):
            raise ValueError(f"odometry_source must be 'odom' or 'encoders', got {odometry_source!r}")
        if gyro and odometry_source != "encoders":
            raise ValueError("a gyro (fog_format) needs odometry_source 'encoders'")
        if isinstance(odom_wait_scans, bool) or not isinstance(odom_wait_scans, int) or odom_wait_scans < 0:
            raise ValueError(f"odom_wait_scans must be >= 0 (0: off), got {odom_wait_scans}")
        self.stage = stage if stage is not None else PredictionStage(filter_cfg, motion_cfg)
        self.odom = OdometryBuffer(odom_sync)
        self.checks = ScanChecks(time_gap_s)
        self.odom_wait_scans = odom_wait_scans
        self.stamp_offset_ns = int(stamp_offset_s * 1e9)  # 0: off
        self._emit_fn = emit
        self._out: list = []
        # (scan_index, stamp_ns or None (unreadable), usable, payload, odometry messages received before it)
        self.scans: deque[tuple[int, int | None, bool, Any, int]] = deque()
        self.odom_forced = 0  # scans posed without waiting longer for odometry that did not come
        self.stamp_offset = 0  # scans whose stamp was seconds away from the odometry's
        self._offset_run = 0  # scans in a row so far away
        self._odom_arrived_at_scan = 0
        self.prev_odom: tuple[int, np.ndarray] | None = None  # (stamp, odometry) of the last scan posed
        self.odometry_nonfinite = 0
        self.poses_published = 0
        self.scan_count = 0
        self.waiting_for: int | None = None  # scan index of the update in flight
        self.odom_received = 0  # odometry messages once integrated (odom_arrived: as they arrive)
        self.odom_arrived = 0
        self.odom_expected: int | None = None  # from the input's final counts
        self.scans_expected: int | None = None
        self.corrected_pose = np.zeros(3)  # pose of the last corrected scan
        self.last_pass_through: tuple | None = None  # (index, stamp, odom, delta)
        self.deferred: deque[tuple] = deque()  # pass-throughs behind the correction in flight
        self.end_sent = False
        self.blocked = -1  # index of the scan known to need a correction while one is in flight
        self._stall: dict[str, int | None] | None = None  # the replay's counts when it last stalled
        self.encoders_used = odometry_source == "encoders"
        self.wheels: WheelOdometryIntegrator | None = None
        if self.encoders_used:
            w = wheels_cfg or WheelsConfig()
            self.wheels = WheelOdometryIntegrator(
                w.left_diameter_m, w.right_diameter_m, w.base_m, w.max_speed_mps, w.gyro_rest_bias, w.rest_min_s
            )
            self.encoders: deque[tuple[int, float | None, float | None]] = deque()
            self.last_encoder_ns: int | None = None
        self.gyro = GyroBuffer() if gyro else None
        # motion.gyro_noise_scale: (stamp of the wheel step that ended a rest, q, bias std) after each
        # calibration, so a scan's heading noise depends on its stamp only, not on how far the wheels
        # were integrated when it came; and the stamp of the last prediction
        self._gyro_noise: list[tuple[int, float, float]] = []
        self._gyro_calibrations = 0
        self._t_update: int | None = None
        self.fog_received = 0
        self.fog_expected: int | None = None
        self.last_imu_ns: int | None = None
        # a moving mount: its samples, the scans' geometry, the per-scan decision (once per scan)
        self.laser_cfg = laser_cfg
        self.mount = MountBuffer() if laser_cfg is not None and laser_cfg.dynamic_frame else None
        self.mount_arrived = 0
        self.mount_expected: int | None = None
        self.mostly_floor = 0
        self._geometry: dict[int, tuple] = {}
        self._mount_decided: tuple[int, bool, np.ndarray | None] | None = None

    # ------------------------------------------------------------------ plumbing
    def _emit(self, action: Any) -> None:
        if self._emit_fn is not None:
            self._emit_fn(action)
        else:
            self._out.append(action)

    def _done(self) -> list:
        out, self._out = self._out, []
        return out

    def _fault(self, kind: str, text: str) -> None:
        self._emit(Fault(kind, text))

    def _finite(self, values: np.ndarray, topic: str) -> bool:
        """False (message dropped, counted) when odometry holds NaN or inf: it would poison the pose."""
        if np.isfinite(values).all():
            return True
        self.odometry_nonfinite += 1
        self._fault(ODOMETRY_NONFINITE, f"{topic}: message with NaN/inf values dropped")
        return False

    # ------------------------------------------------------------------ events
    def add_odometry(self, stamp: int, pose: np.ndarray) -> list:
        """An odometry pose ``(x, y, yaw)`` (odometry frame) at ``stamp`` (ns)."""
        self.odom_received += 1
        self.odom_arrived += 1
        self.odom.add(stamp, pose if self._finite(pose, "odom") else None)  # a bad one keeps its place
        self._drain()
        return self._done()

    def add_encoders(self, stamp: int | None, wheels_rad: np.ndarray | None) -> list:
        """Cumulative (left, right) wheel angles (rad) at ``stamp``; ``wheels_rad=None``: a message
        that could not be read (counted, so the end-of-stream count still matches; the caller
        says what was wrong)."""
        self.odom_arrived += 1
        if wheels_rad is None:
            self.odom_received += 1
            return self._done()
        if not self._finite(wheels_rad[:2], "encoders"):
            self.encoders.append((stamp, None, None))  # dropped, but keeps its place in the stream
        else:
            self.encoders.append((stamp, float(wheels_rad[0]), float(wheels_rad[1])))
        self._drain_odometry()
        return self._done()

    def add_gyro(self, stamps: np.ndarray | None, dyaw: np.ndarray | None, topic: str = "fog") -> list:
        """One gyro message: yaw increments (rad) at their stamps (ns); ``None``: unreadable
        (counted, its samples are no yaw)."""
        self.fog_received += 1  # counted even if bad: the end-of-stream count must still match
        if stamps is not None:
            dyaw = np.asarray(dyaw, dtype=np.float64)
            if not self._finite(dyaw, topic):  # its samples count as no yaw: the stream goes on
                dyaw = np.where(np.isfinite(dyaw), dyaw, 0.0)
            self.gyro.add(stamps, dyaw)
        self._drain_odometry()
        return self._done()

    def add_imu(self, stamp: int, yaw_rate: float) -> list:
        """A yaw rate (rad/s, sensor_msgs/Imu mounted level): the increment is the rate times the
        time since the previous sample (the first sample adds none)."""
        if self._finite(np.array([yaw_rate]), "imu"):
            dt = 0.0 if self.last_imu_ns is None else max(stamp - self.last_imu_ns, 0) / 1e9
            self.gyro.add([stamp], [yaw_rate * dt])
            self.last_imu_ns = stamp
        else:  # the stream goes on; the next good rate covers the time since the last good one
            self.gyro.add([stamp], [0.0])
        self.fog_received += 1
        self._drain_odometry()
        return self._done()

    def add_mount(self, stamp: int, quat_xyzw, translation) -> list:
        """A sample of the moving mount (``base_frame -> laser.dynamic_frame``) at ``stamp``
        (ns); ``quat_xyzw=None``: a message without it (counted only, so the end-of-stream count
        still matches)."""
        self.mount_arrived += 1
        if self.mount is not None and quat_xyzw is not None:
            self.mount.add(stamp, quat_xyzw, translation)
        self._drain()
        return self._done()

    def add_scan(
        self,
        stamp: int | None,
        usable: bool,
        payload: Any,
        faults: list[tuple[str, str]] = (),
        geometry: tuple | None = None,
    ) -> list:
        """A scan at ``stamp`` (ns; None: unreadable, posed at the previous scan's stamp and
        odometry). ``usable``: it can be corrected with (see :attr:`checks`, which also gives
        ``faults``). ``payload`` is handed back in :class:`SendCorrection`. ``geometry``:
        ``(ranges, angles, range_min, range_max)``, needed with a moving mount only."""
        if self.mount is not None and geometry is not None:
            self._geometry[self.scan_count] = geometry
        for kind, text in faults:
            self._fault(kind, f"scan {self.scan_count}: {text}")
        if stamp is not None and self.stamp_offset_ns > 0:
            self._check_offset(stamp)
        self.scans.append((self.scan_count, stamp, usable, payload, self.odom.received))
        self.scan_count += 1
        self._drain()
        return self._done()

    def corrected(
        self, index: int, particles: np.ndarray, log_weights: np.ndarray, pose: np.ndarray, stamp: int
    ) -> list:
        """The corrected set of scan ``index`` (``pose``: its pose, map frame) is back."""
        if index == self.waiting_for:
            self.stage.set_corrected(particles, log_weights)
            self.corrected_pose = np.array(pose, dtype=np.float64)
            self._publish_pose(self.corrected_pose, stamp)
            self.waiting_for = None
            while self.deferred:
                self._pass_through(*self.deferred.popleft())
            self._drain()
        return self._done()

    def end_of_stream(self, scans: int, odometry: int, gyro: int = 0, mount: int = 0) -> list:
        """The input ended after this many scan, odometry (or encoder), gyro and mount messages."""
        self.mount_expected = int(mount)
        self.odom_expected = int(odometry)
        self.fog_expected = int(gyro)
        self.scans_expected = int(scans)
        if self.poses_published == self.scans_expected:
            self._emit(PublishStatus())
        self._drain()
        return self._done()

    def stall(self, pose: int | None, scans: int, odometry: int, gyro: int = 0, mount: int = 0) -> list:
        """The replay stopped (max_in_flight) after publishing this many messages, waiting for
        pose number ``pose``."""
        self._stall = {"pose": pose, "scans": scans, "odometry": odometry, "gyro": gyro, "mount": mount}
        self._drain()
        return self._done()

    # ------------------------------------------------------------------ status
    def faults(self) -> dict[str, int]:
        """Every fault counter of the run so far (summary.json "faults")."""
        out = dict(
            self.checks.counts,
            odometry_nonfinite=self.odometry_nonfinite,
            odom_time_backwards=self.odom.backward_steps,
            odom_missing=self.odom.missing,
            odom_not_arrived=self.odom_forced,
            odom_stamp_offset=self.stamp_offset,
            odom_sync_fallback=int(self.odom.fallback is not None),
        )
        if self.wheels is not None:
            out["encoder_jump"] = self.wheels.jumps
        if self.gyro is not None:
            out["fog_out_of_order"] = self.gyro.out_of_order
        if self.mount is not None:
            out[MOSTLY_FLOOR] = self.mostly_floor
            out["mount_out_of_order"] = self.mount.out_of_order
        return out

    def gyro_status(self) -> dict:
        """The gyro's rest-calibrated bias (summary.json "gyro"), when wheels + gyro are used."""
        w = self.wheels
        if w is None or self.gyro is None or not w.gyro_rest_bias:
            return {}
        return {"gyro": {"bias_rad_s": w.gyro_bias_rad_s, "rest_s": round(w.rest_s, 3)}}

    def status(self) -> dict:
        """``final`` (the last scan of the input is posed), scans, faults (+ gyro)."""
        return {
            "final": self.poses_published == self.scans_expected,
            "scans": self.scan_count,
            "faults": self.faults(),
            **self.gyro_status(),
        }

    # ------------------------------------------------------------------ encoders + gyro
    def _gyro_done(self) -> bool:
        return (self.fog_expected is not None and self.fog_received >= self.fog_expected) or self._stalled()

    def _drain_odometry(self) -> None:
        """After an encoder or gyro message: drain only when the oldest wheel step can now be
        integrated (the gyro covers it, or no more gyro will come). Otherwise the odometry did
        not change, so no scan can be posed: at 100 + 100 Hz that skips half of the drains."""
        if not self.encoders:
            return
        if self.gyro is None or self.gyro.last_stamp >= self.encoders[0][0] or self._gyro_done():
            self._drain()

    def _integrate_encoders(self) -> None:
        """Wheel steps -> odometry poses, each once the gyro covers its interval (deterministic)."""
        fog_done = self._gyro_done()
        while self.encoders:
            t, left, right = self.encoders[0]
            if left is None:  # a bad message: no wheel step, its stamp resolves the scans at it
                self.encoders.popleft()
                self.odom.add_bad(t)
                self.odom_received += 1
                continue
            if self.gyro is not None:
                if self.gyro.last_stamp < t and not fog_done:
                    return  # the gyro samples of this step are not all here yet
                if self.last_encoder_ns is not None:
                    self.wheels.add_gyro(self.gyro.yaw_between(self.last_encoder_ns, t))
                    self.gyro.trim(self.last_encoder_ns)
            self.encoders.popleft()
            jumps = self.wheels.jumps
            dt = None if self.last_encoder_ns is None else (t - self.last_encoder_ns) / 1e9
            self.odom.add(t, self.wheels.step(left, right, dt))
            if self.wheels.calibrations != self._gyro_calibrations:
                self._gyro_calibrations = self.wheels.calibrations
                if (noise := self.wheels.gyro_noise) is not None:
                    self._gyro_noise.append((t, *noise))
            if self.wheels.jumps > jumps:
                self._fault(
                    "encoder_jump",
                    f"encoders: wheel angles jumped by more than the wheels can turn "
                    f"in {dt:.3f} s at wheels.max_speed_mps; that step's wheel motion discarded",
                )
            self.last_encoder_ns = t
            self.odom_received += 1

    # ------------------------------------------------------------------ the work
    def _stalled(self) -> bool:
        """The replay stopped at max_in_flight, everything it published is here and no correction
        is in flight: nothing more comes until a scan is posed (deterministic: the stall point
        depends only on the data)."""
        st = self._stall
        return (
            st is not None
            and self.waiting_for is None
            and not self.deferred
            and st["pose"] == self.poses_published  # it waits for our next pose
            and st["scans"] == self.scan_count
            and st["odometry"] == self.odom_arrived
            and (self.gyro is None or st["gyro"] == self.fog_received)
            and (self.mount is None or st["mount"] == self.mount_arrived)
        )

    def _drain(self) -> None:
        if self.encoders_used:
            self._integrate_encoders()
        while self.scans:
            index, stamp, usable, payload, _ = self.scans[0]
            if self.waiting_for is not None and index == self.blocked:
                break  # a correction is in flight and this scan needs the next one
            peek = self.waiting_for is not None or self.mount is not None
            odom = self._odom_at(peek=peek)
            if odom is None:
                break
            # without its own odometry the scan's pose is a guess: posed, not corrected or mapped with
            usable = usable and not (self.odom.peek_missing if peek else self.odom.last_missing)
            mount = None
            if self.mount is not None and stamp is not None and usable and self.stage.gate(odom)[0]:
                decided = self._mount_decision(index, stamp)
                if decided is None:
                    break  # the mount's samples do not reach this scan's stamp yet
                usable, mount = decided
            if stamp is None:  # unreadable: the previous scan's stamp (0 for a first scan)
                stamp = self.prev_odom[0] if self.prev_odom is not None else 0
            if self.waiting_for is not None:
                # a correction is in flight: queue pass-throughs, stop at the next update
                update, delta = self.stage.gate(odom)
                if update and usable:
                    self.blocked = index  # decided: no need to look again on every message
                    break
                self._odom_at(peek=False)  # consume what peek saw
                self.scans.popleft()
                self._geometry.pop(index, None)
                self._emit(PublishOdomTf(odom, stamp))
                self.deferred.append((index, stamp, odom, delta))
                continue
            if peek:
                self._odom_at(peek=False)  # consume what peek saw
            self.scans.popleft()
            self._geometry.pop(index, None)
            self._emit(PublishOdomTf(odom, stamp))
            self._predict(index, stamp, odom, usable, payload, mount)
        self.odom.trim()
        self._maybe_send_end()

    def _mount_decision(self, index: int, stamp: int) -> tuple[bool, np.ndarray | None] | None:
        """(usable, the mount (12,) at the stamp) for a scan that would be corrected, or None while
        the mount's samples may still reach its stamp. Decided once per scan (a mostly-floor scan
        is counted once, however often the queue is looked at)."""
        if self._mount_decided is not None and self._mount_decided[0] == index:
            return self._mount_decided[1:]
        final = (
            (self.mount_expected is not None and self.mount_arrived >= self.mount_expected)
            or self._stalled()
            or 0 < self.odom_wait_scans < len(self.scans)
        )
        if not self.mount.covers(stamp) and not final:
            return None
        dyn = self.mount.at(stamp)
        if dyn is None:  # no sample at all: the static part alone (the mount frame at the base)
            dyn = (np.eye(3), np.zeros(3))
        cfg = self.laser_cfg
        ext = compose_extrinsic(dyn[0], dyn[1], cfg.extrinsic)
        usable = True
        geometry = self._geometry.get(index)
        if cfg.min_kept_fraction > 0 and geometry is not None:
            kept = kept_fraction(geometry[0], geometry[1], cfg, ext, geometry[2], geometry[3])
            if kept < cfg.min_kept_fraction:
                usable = False
                self.mostly_floor += 1
                self._fault(
                    MOSTLY_FLOOR,
                    f"scan {index}: {kept:.0%} of its returns are above the floor "
                    f"(laser.min_kept_fraction {cfg.min_kept_fraction:g}): posed from odometry",
                )
        self._mount_decided = (index, usable, ext)
        return usable, ext

    def _odom_at(self, peek: bool) -> np.ndarray | None:
        """The odometry of the scan at the head of the queue, or None while it may still come.

        It is known not to come (a pose is then always returned, see OdometryBuffer, counted in
        odom_missing): at the end of the input; in exact pairing, once a later scan's own
        odometry message has arrived; when the replay stopped at max_in_flight and all it sent is
        here (_stalled; without this --rate max would wait for ever) or, live, ``odom_wait_scans``
        scans wait behind it (both counted in odom_not_arrived). Exact pairing that finds no
        partner while odometry stamped between the scans arrives falls back to interpolation,
        with one warning."""
        index, stamp = self.scans[0][:2]
        if stamp is None:  # an unreadable scan: the previous scan's odometry, without waiting
            if self.prev_odom is not None:
                self.odom.last_missing = self.odom.peek_missing = False
                return self.prev_odom[1].copy()
            stamp = 0  # the first scan: the first odometry that arrives
        end = self.odom_expected is not None and self.odom_received >= self.odom_expected
        final = end or self.odom.later_paired([stamp] + [s[1] for s in islice(self.scans, 1, LOOK_AHEAD)])
        lookup = self.odom.peek if peek else self.odom.lookup
        odom = lookup(stamp, final=final)
        if odom is None and not final and self.scans[0][1] is not None:
            why = self.odom.no_partner([s[1] for s in islice(self.scans, LOOK_AHEAD)])
            if why is not None:
                self.odom.fall_back(scan=index, scans_without_partner=why[0], odometry_between=why[1])
                self._emit(
                    Warn(
                        f"odom_sync exact: scans {index}..: {why[0]} scans have no odometry message with their "
                        f"stamp while {why[1]} odometry messages stamped between them arrived (the odometry "
                        f"is not recorded with each scan); pairing by interpolation from scan {index} on. "
                        f"Set odom_sync: interpolate for this input"
                    )
                )
                odom = lookup(stamp, final=False)
        if odom is None and not final and (self._stalled() or 0 < self.odom_wait_scans < len(self.scans)):
            odom = lookup(stamp, final=True)
            if not peek:
                self.odom_forced += 1
                newest = self.odom.progress_ns
                why = (
                    "the replay waits for its pose (max_in_flight)"
                    if self._stalled()
                    else f"{len(self.scans) - 1} scans wait behind it (odom_wait_scans)"
                )
                self._fault(
                    "odom_not_arrived",
                    f"scan {index}: no odometry at or after its stamp while {why}; "
                    "newest odometry "
                    + ("none" if newest is None else f"{(newest - stamp) / 1e9:+.3f} s from it")
                    + ": posed with the nearest earlier odometry",
                )
        if odom is not None and not peek and self.scans[0][1] is not None:
            self.prev_odom = (self.scans[0][1], odom)
        return odom

    def _check_offset(self, stamp: int) -> None:
        """Live check of the two clocks, at each scan: the newest odometry stamped more than
        stamp_offset_s after the scan, or (while odometry keeps arriving) before it, for 3 scans
        in a row (one scan is a race between the topics, or a stamp step of the Intel log)."""
        newest, arriving = self.odom.progress_ns, self.odom_arrived > self._odom_arrived_at_scan
        self._odom_arrived_at_scan = self.odom_arrived
        how = None
        if newest is not None and newest - stamp > self.stamp_offset_ns:
            how = "ahead of"
        elif newest is not None and arriving and stamp - newest > self.stamp_offset_ns:
            how = "behind"
        self._offset_run = self._offset_run + 1 if how else 0
        if self._offset_run >= 3:
            self._stamp_offset(stamp, abs(newest - stamp), how)

    def _stamp_offset(self, stamp: int, by_ns: int, how: str) -> None:
        self.stamp_offset += 1
        if self.stamp_offset == 1:  # once, with the numbers (then throttled like every fault)
            self._emit(
                Warn(
                    f"odometry stamps {by_ns / 1e9:.3f} s {how} the scan stamps (scan {self.scan_count}, "
                    f"stamp {stamp / 1e9:.3f} s): the two clocks disagree, pairing is wrong by that much; "
                    f"counted in faults.odom_stamp_offset"
                )
            )
        else:
            self._fault("odom_stamp_offset", f"odometry {by_ns / 1e9:.3f} s {how} scan stamp {stamp / 1e9:.3f} s")

    def _predict(
        self, index: int, stamp: int, odom: np.ndarray, usable: bool, payload: Any, mount: np.ndarray | None = None
    ) -> None:
        if not usable:  # a scan the correlator cannot use: posed from odometry
            self._pass_through(index, stamp, odom, self.stage.gate(odom)[1])
            return
        update, delta = self.stage.predict(odom, self._heading_sigma(stamp))
        if update:
            self._t_update = stamp
            self.waiting_for = index
            self._emit(SendCorrection(index, stamp, payload, self.stage.particles, self.stage.log_weights, odom, mount))
            return
        self._pass_through(index, stamp, odom, delta)

    def _heading_sigma(self, stamp: int) -> float | None:
        """``motion.gyro_noise_scale`` times the calibrated gyro's heading uncertainty since the last
        prediction, from the calibrations at or before ``stamp``; None (the profile's heading noise)
        when off, without a rest-calibrated gyro, or before the first calibration."""
        scale = self.stage.motion_cfg.gyro_noise_scale
        if scale <= 0 or self._t_update is None or not self._gyro_noise:  # _gyro_noise: a rest-calibrated gyro
            return None
        for t, q, bias_std in reversed(self._gyro_noise):
            if t <= stamp:
                return scale * gyro_heading_sigma(q, bias_std, (stamp - self._t_update) / 1e9)
        return None

    def _pass_through(self, index: int, stamp: int, odom: np.ndarray, delta: np.ndarray) -> None:
        self._publish_pose(compose(self.corrected_pose, delta), stamp)
        self.last_pass_through = (index, stamp, odom, delta)

    def _publish_pose(self, pose: np.ndarray, stamp: int) -> None:
        self.poses_published += 1
        self._emit(PublishPose(pose, stamp))
        if self.poses_published == self.scans_expected:
            self._emit(PublishStatus())

    def _maybe_send_end(self) -> None:
        """Once the last scan of the input is posed as a pass-through, send it on as the end of
        the run: a set without particles (update=false) that the correlator and mapper pass on."""
        last = self.last_pass_through
        if (
            self.waiting_for is not None
            or self.end_sent
            or self.scans_expected is None
            or last is None
            or last[0] != self.scans_expected - 1
        ):
            return
        self.end_sent = True
        self._emit(SendEnd(*last))
