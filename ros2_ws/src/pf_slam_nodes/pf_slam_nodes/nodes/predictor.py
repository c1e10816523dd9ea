"""predictor: owns the particle set between scans and moves it with the motion model.

Subscribes: scan (LaserScan; only its stamp and ranges are read, from the serialized bytes), odom
(nav_msgs/Odometry) or encoders (JointState wheel angles, rad) with optional fog (FogBatch or
Vector3Stamped yaw increments, which then replace the wheels' yaw), particles/updated (the
corrected set), pf_slam/replay_status (end of the bag). Publishes: pose (PoseStamped, map
frame, exactly one per scan, in scan order), particles/predicted (one per correction),
pf_slam/scan_corrected (the bytes of each scan it sends to be corrected, before its set), /tf
(odom_frame -> base_frame: the dead-reckoned odometry at every scan's stamp, REP 105).

Per scan, in order: the odometry pose at the scan stamp is looked up; if the robot moved less
than filter.min_travel_m / filter.min_rotation_rad since the last correction, the scan is a
*pass-through*: its pose is the last corrected pose composed with the odometry increment, and
it goes out on pose at once, without a message to the correlator (the car's 100 Hz lidar is
corrected every ~2 m: most scans are pass-throughs). Otherwise the particles are moved by the
noisy odometry increment and sent with update=true; the scan's pose goes out when the corrected
set comes back on particles/updated. While a correction is in flight, the pass-through scans
behind it are gated and queued (their poses need the corrected pose, their increments do not);
only the next scan that needs a correction waits. So with one process per node the replay and
the predictor keep going while the correlator works. The last scan of the bag
is always sent on particles/predicted (update=false if it is a pass-through) so the correlator
and the mapper see the end of the run.

Bad input is checked here, where every scan and odometry message passes (core/faults.py): NaN or
negative ranges, a beam count that disagrees with the angles or range limits that leave no valid
range (range_max <= 0, range_min > range_max; that scan is posed from odometry, not corrected
or mapped with), scan stamps stepping back or jumping ahead by more than time_gap_s, encoder
counter jumps (wheels.max_speed_mps), NaN/inf odometry (dropped). Each is logged (throttled, per
kind) and counted; the counts go out on pf_slam/status (latched JSON, on change at most once a
second, and once more, "final", when the last scan of the bag is posed) for summary.json.
"""
from __future__ import annotations

from collections import deque
from itertools import islice

import numpy as np
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from pf_slam_interfaces.msg import FogBatch, ParticleArray, ReplayStatus
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState, LaserScan
from tf2_msgs.msg import TFMessage

from ..core.faults import ODOMETRY_NONFINITE, ScanChecks
from ..core.geometry import compose, quat_to_yaw
from ..core.odometry import GyroBuffer, OdometryBuffer, WheelOdometryIntegrator
from ..core.stages import PredictionStage
from ..ros import cdr, convert, qos, topics
from .common import announce_when_matched, declare_config, param, run_node, status_publisher

LOOK_AHEAD = 200  # queued scans looked at for evidence about the head scan's odometry


class Predictor(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("predictor", **kwargs)
        self.stage = PredictionStage(declare_config(self, "filter"), declare_config(self, "motion"))
        self.map_frame = param(self, "map_frame", "map")
        source = param(self, "odometry_source", "odom")
        if source not in ("odom", "encoders"):
            raise ValueError(f"parameter 'odometry_source' must be 'odom' or 'encoders', got {source!r}")
        self.odom = OdometryBuffer(param(self, "odom_sync", "interpolate"))
        # (scan_index, stamp_ns or None (unreadable), usable, raw, odometry messages received before it)
        self.scans: deque[tuple[int, int | None, bool, bytes, int]] = deque()
        self.odom_wait_scans = param(self, "odom_wait_scans", 50)
        if self.odom_wait_scans < 0:
            raise ValueError(f"parameter 'odom_wait_scans' must be >= 0 (0: off), got {self.odom_wait_scans}")
        self.stamp_offset_ns = int(param(self, "stamp_offset_s", 2.0) * 1e9)  # 0: off
        self.odom_forced = 0  # scans posed without waiting longer for odometry that did not come
        self.stamp_offset = 0  # scans whose stamp was seconds away from the odometry's
        self._offset_run = 0  # scans in a row so far away
        self._odom_arrived_at_scan = 0
        self.prev_odom: tuple[int, np.ndarray] | None = None  # (stamp, odometry) of the last scan posed
        self.checks = ScanChecks(param(self, "time_gap_s", 60.0))
        self.odometry_nonfinite = 0
        self.poses_published = 0
        self._fault_loggers: dict = {}  # one logger per fault kind: each throttled on its own
        self.scan_count = 0
        self.waiting_for: int | None = None  # scan index of the update in flight
        self.odom_received = 0
        self.odom_expected: int | None = None  # from the replay's final counts
        self.scans_expected: int | None = None
        self.corrected_pose = np.zeros(3)  # pose of the last corrected scan
        self.last_pass_through: tuple | None = None  # (index, stamp, odom, delta)
        self.deferred: deque[tuple] = deque()  # pass-throughs behind the correction in flight
        self.end_sent = False
        self.blocked = -1  # index of the scan known to need a correction while one is in flight
        self.odom_topic = self.resolve_topic_name(topics.ODOM if source == "odom" else topics.ENCODERS)
        self.scan_topic = self.resolve_topic_name(topics.SCAN)
        self.pub = self.create_publisher(ParticleArray, topics.PARTICLES_PREDICTED, qos.pipeline())
        self.pub_pose = self.create_publisher(PoseStamped, topics.POSE, qos.pipeline())
        self.pub_scan = self.create_publisher(LaserScan, topics.SCAN_CORRECTED, qos.pipeline())
        self.pose_cdr = cdr.PoseStampedWriter(self.map_frame)  # one pose per scan: published as bytes
        self._init_odom_tf()
        sub_scan = self.create_subscription(LaserScan, topics.SCAN, self._on_scan, qos.pipeline(), raw=True)
        # the correlator (+ the mapper for the scans); bag_replay (paces on pose) + observers
        # that must see every pose; the scans' source (the replay starts once this is matched)
        announce_when_matched(self, [(self.pub, 1), (self.pub_scan, 2),
                                     (self.pub_pose, 1 + param(self, "expected_observers", 0)), (sub_scan, 1)])
        self.create_subscription(ParticleArray, topics.PARTICLES_UPDATED, self._on_updated, qos.pipeline())
        self.create_subscription(ReplayStatus, topics.REPLAY_STATUS, self._on_replay_status, qos.latched())
        self.stall: dict[str, int] | None = None  # the replay's counts when it last stopped at max_in_flight
        self.odom_arrived = 0  # odometry messages as they arrive (odom_received: once integrated)
        self.create_subscription(ReplayStatus, topics.REPLAY_STALL, self._on_stall, qos.pipeline())
        if source == "odom":
            self.create_subscription(Odometry, topics.ODOM, self._on_odom, qos.pipeline(10000))
        elif source == "encoders":
            self.wheels = WheelOdometryIntegrator(param(self, "wheels.left_diameter_m", 0.154),
                                                  param(self, "wheels.right_diameter_m", 0.154),
                                                  param(self, "wheels.base_m", 0.33),
                                                  param(self, "wheels.max_speed_mps", 50.0),
                                                  param(self, "wheels.gyro_rest_bias", True),
                                                  param(self, "wheels.rest_min_s", 0.5))
            self.encoders: deque[tuple[int, float, float]] = deque()
            self.last_encoder_ns: int | None = None
            self.create_subscription(JointState, topics.ENCODERS, self._on_encoders, qos.pipeline(10000),
                                     raw=True)
        # yaw from a gyro instead of the wheels: "none" | "batch" (FogBatch) | "vector3" | "imu" (Imu on imu)
        fog = param(self, "fog_format", "none")
        if fog not in ("none", "batch", "vector3", "imu"):
            raise ValueError(f"parameter 'fog_format' must be 'none', 'batch', 'vector3' or 'imu', got {fog!r}")
        if fog != "none" and source != "encoders":
            raise ValueError("parameter 'fog_format' needs odometry_source 'encoders'")
        self.gyro = GyroBuffer() if fog != "none" else None
        self.fog_received = 0
        self.fog_expected: int | None = None
        self.fog_topic = self.resolve_topic_name(topics.IMU if fog == "imu" else topics.FOG)
        self.last_imu_ns: int | None = None
        if fog == "batch":
            self.create_subscription(FogBatch, topics.FOG, self._on_fog_batch, qos.pipeline(10000), raw=True)
        elif fog == "vector3":
            self.create_subscription(Vector3Stamped, topics.FOG, self._on_fog_vector, qos.pipeline(100000))
        elif fog == "imu":
            self.create_subscription(Imu, topics.IMU, self._on_imu, qos.pipeline(100000))
        # "final" once the last scan of the bag is posed: the run's summary waits for it
        self._publish_status = status_publisher(self, lambda: {
            "final": self.poses_published == self.scans_expected, "scans": self.scan_count,
            "faults": self.faults(), **self._gyro_status()})

    def _init_odom_tf(self) -> None:
        """odom -> base_link on /tf, one per scan, as bytes (the car's lidar runs at 100 Hz)."""
        odom_frame, base_frame = param(self, "odom_frame", "odom"), param(self, "base_frame", "base_link")
        self.pub_tf = (self.create_publisher(TFMessage, topics.TF, qos.outputs())
                       if param(self, "publish_odom_tf", True) else None)
        self.odom_tf_cdr = cdr.TransformWriter(odom_frame, base_frame)

    def _publish_odom_tf(self, odom: np.ndarray, stamp: int) -> None:
        if self.pub_tf is not None:
            self.pub_tf.publish(self.odom_tf_cdr.pack(odom, stamp))

    # ------------------------------------------------------------------ inputs
    def _on_odom(self, msg: Odometry) -> None:
        o = msg.pose.pose.orientation
        pose = np.array([msg.pose.pose.position.x, msg.pose.pose.position.y, float(quat_to_yaw(o.x, o.y, o.z, o.w))])
        self.odom_received += 1
        self.odom_arrived += 1
        stamp = convert.stamp_to_ns(msg.header.stamp)
        self.odom.add(stamp, pose if self._finite(pose, "odom") else None)  # a bad one keeps its place
        self._drain()

    def _on_encoders(self, raw: bytes) -> None:
        self.odom_arrived += 1
        stamp, position = self._parse(cdr.joint_state_positions, raw, "encoders")
        if position is None or len(position) < 2:
            if position is not None:
                self.get_logger().warn("encoders: JointState with fewer than 2 positions ignored",
                                       throttle_duration_sec=5.0)
            self.odom_received += 1  # counted: the end-of-stream count must still match
            return
        if not self._finite(position[:2], "encoders"):
            self.encoders.append((stamp, None, None))  # dropped, but keeps its place in the stream
        else:
            self.encoders.append((stamp, float(position[0]), float(position[1])))
        self._drain_odometry()

    def _on_fog_batch(self, raw: bytes) -> None:
        stamps, yaw = self._parse(cdr.fog_batch_yaw, raw, "fog")
        self.fog_received += 1  # counted even if bad: the end-of-stream count must still match
        if stamps is not None:
            if not self._finite(yaw, "fog"):  # its samples count as no yaw: the stream goes on
                yaw = np.where(np.isfinite(yaw), yaw, 0.0)
            self.gyro.add(stamps, yaw)
        self._drain_odometry()

    def _parse(self, reader, raw: bytes, topic: str):
        """Raw message -> the reader's fields, or (None, None) with an error for a bad message."""
        try:
            return reader(raw)
        except ValueError as exc:
            self.get_logger().error(f"{topic}: message dropped: {exc}", throttle_duration_sec=5.0)
            return None, None

    def _finite(self, values: np.ndarray, topic: str) -> bool:
        """False (message dropped, counted) when odometry holds NaN or inf: it would poison the pose."""
        if np.isfinite(values).all():
            return True
        self.odometry_nonfinite += 1
        self._fault(ODOMETRY_NONFINITE, f"{topic}: message with NaN/inf values dropped")
        return False

    def _on_fog_vector(self, msg: Vector3Stamped) -> None:
        ok = self._finite(np.array([msg.vector.z]), "fog")
        self.gyro.add([convert.stamp_to_ns(msg.header.stamp)], [msg.vector.z if ok else 0.0])
        self.fog_received += 1
        self._drain_odometry()

    def _on_imu(self, msg: Imu) -> None:
        """sensor_msgs/Imu (mounted level): yaw increment angular_velocity.z * the time since the
        previous sample (the first sample adds none)."""
        t = convert.stamp_to_ns(msg.header.stamp)
        rate = msg.angular_velocity.z
        if self._finite(np.array([rate]), "imu"):
            dt = 0.0 if self.last_imu_ns is None else max(t - self.last_imu_ns, 0) / 1e9
            self.gyro.add([t], [rate * dt])
            self.last_imu_ns = t
        else:  # the stream goes on; the next good rate covers the time since the last good one
            self.gyro.add([t], [0.0])
        self.fog_received += 1
        self._drain_odometry()

    def _drain_odometry(self) -> None:
        """After an encoder or gyro message: drain only when the oldest wheel step can now be
        integrated (the gyro covers it, or no more gyro will come). Otherwise the odometry did
        not change, so no scan can be posed: at 100 + 100 Hz that skips half of the drains."""
        if not self.encoders:
            return
        if (self.gyro is None or self.gyro.last_stamp >= self.encoders[0][0]
                or (self.fog_expected is not None and self.fog_received >= self.fog_expected) or self._stalled()):
            self._drain()

    def _integrate_encoders(self) -> None:
        """Wheel steps -> odometry poses, each once the gyro covers its interval (deterministic)."""
        fog_done = (self.fog_expected is not None and self.fog_received >= self.fog_expected) or self._stalled()
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
            if self.wheels.jumps > jumps:
                self._fault("encoder_jump", f"encoders: wheel angles jumped by more than the wheels can turn "
                            f"in {dt:.3f} s at wheels.max_speed_mps; that step's wheel motion discarded")
            self.last_encoder_ns = t
            self.odom_received += 1

    def _on_scan(self, raw: bytes) -> None:
        try:
            stamp, (a_min, a_max, a_inc), (r_min, r_max), ranges = cdr.laser_scan_fields(raw)
            usable, faults = self.checks.check(stamp, ranges, a_min, a_max, a_inc, r_min, r_max)
        except ValueError as exc:
            # posed from odometry at its own stamp when the header is readable and plausible, else
            # at the previous scan's stamp and odometry (without waiting)
            stamp, usable = self.checks.readable_stamp(raw, cdr.CdrReader), False
            faults = self.checks.unreadable(exc, stamp is not None)
        for kind, text in faults:
            self._fault(kind, f"scan {self.scan_count}: {text}")
        if stamp is not None and self.stamp_offset_ns > 0:
            self._check_offset(stamp)
        self.scans.append((self.scan_count, stamp, usable, raw, self.odom.received))
        self.scan_count += 1
        self._drain()

    # ------------------------------------------------------------------ faults
    def _fault(self, kind: str, text: str) -> None:
        """Log a fault, throttled per kind (rclpy throttles per logger and call site)."""
        if kind not in self._fault_loggers:
            self._fault_loggers[kind] = self.get_logger().get_child(kind)
        self._fault_loggers[kind].warn(text, throttle_duration_sec=5.0)

    def _gyro_status(self) -> dict:
        """The gyro's rest-calibrated bias (summary.json "gyro"), when wheels + gyro are used."""
        w = getattr(self, "wheels", None)
        if w is None or self.gyro is None or not w.gyro_rest_bias:
            return {}
        return {"gyro": {"bias_rad_s": w.gyro_bias_rad_s, "rest_s": round(w.rest_s, 3)}}

    def faults(self) -> dict[str, int]:
        """Every fault counter of the run so far (summary.json "faults")."""
        out = dict(self.checks.counts, odometry_nonfinite=self.odometry_nonfinite,
                   odom_time_backwards=self.odom.backward_steps, odom_missing=self.odom.missing,
                   odom_not_arrived=self.odom_forced, odom_stamp_offset=self.stamp_offset,
                   odom_sync_fallback=int(self.odom.fallback is not None))
        if hasattr(self, "wheels"):
            out["encoder_jump"] = self.wheels.jumps
        if self.gyro is not None:
            out["fog_out_of_order"] = self.gyro.out_of_order
        return out

    def _on_updated(self, msg: ParticleArray) -> None:
        if msg.update and msg.scan_index == self.waiting_for:
            self.stage.set_corrected(*convert.msg_to_particles(msg))
            self.corrected_pose = np.array(msg.pose, dtype=np.float64)
            self._publish_pose(self.corrected_pose, convert.stamp_to_ns(msg.header.stamp))
            self.waiting_for = None
            while self.deferred:
                self._pass_through(*self.deferred.popleft())
            self._drain()

    def _on_replay_status(self, msg: ReplayStatus) -> None:
        counts = dict(zip(msg.topics, msg.counts))
        self.odom_expected = int(counts.get(self.odom_topic, 0))
        self.fog_expected = int(counts.get(self.fog_topic, 0))
        self.scans_expected = int(counts.get(self.scan_topic, 0))
        if self.poses_published == self.scans_expected:
            self._publish_status()
        self._drain()

    def _on_stall(self, msg: ReplayStatus) -> None:
        self.stall = dict(zip(msg.topics, msg.counts))
        self._drain()

    def _stalled(self) -> bool:
        """The replay stopped at max_in_flight, everything it published is here and no correction
        is in flight: nothing more comes until a scan is posed (deterministic: the stall point
        depends only on the data)."""
        st = self.stall
        return (st is not None and self.waiting_for is None and not self.deferred
                and st.get(topics.POSE) == self.poses_published  # it waits for our next pose
                and st.get(self.scan_topic, 0) == self.scan_count
                and st.get(self.odom_topic, 0) == self.odom_arrived
                and (self.gyro is None or st.get(self.fog_topic, 0) == self.fog_received))

    # ------------------------------------------------------------------ the work
    def _drain(self) -> None:
        if hasattr(self, "encoders"):
            self._integrate_encoders()
        while self.scans:
            index, stamp, usable, raw, _ = self.scans[0]
            if self.waiting_for is not None and index == self.blocked:
                break  # a correction is in flight and this scan needs the next one
            odom = self._odom_at(peek=self.waiting_for is not None)
            if odom is None:
                break
            # without its own odometry the scan's pose is a guess: posed, not corrected or mapped with
            usable = usable and not (self.odom.peek_missing if self.waiting_for is not None else self.odom.last_missing)
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
                self._publish_odom_tf(odom, stamp)
                self.deferred.append((index, stamp, odom, delta))
                continue
            self.scans.popleft()
            self._publish_odom_tf(odom, stamp)
            self._predict(index, stamp, odom, usable, raw)
        self.odom.trim()
        self._maybe_send_end()

    def _odom_at(self, peek: bool) -> np.ndarray | None:
        """The odometry of the scan at the head of the queue, or None while it may still come.

        It is known not to come (a pose is then always returned, see OdometryBuffer, counted in
        odom_missing): at the end of the bag; in exact pairing, once a later scan's own odometry
        message has arrived; when the replay stopped at max_in_flight and all it sent is here
        (_stalled; without this --rate max would wait for ever) or, live, ``odom_wait_scans``
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
                self.get_logger().warn(
                    f"odom_sync exact: scans {index}..: {why[0]} scans have no odometry message with their "
                    f"stamp while {why[1]} odometry messages stamped between them arrived (the odometry "
                    f"is not recorded with each scan); pairing by interpolation from scan {index} on. "
                    f"Set odom_sync: interpolate for this input")
                odom = lookup(stamp, final=False)
        if odom is None and not final and (
                self._stalled() or 0 < self.odom_wait_scans < len(self.scans)):
            odom = lookup(stamp, final=True)
            if not peek:
                self.odom_forced += 1
                newest = self.odom.progress_ns
                why = ("the replay waits for its pose (max_in_flight)" if self._stalled() else
                       f"{len(self.scans) - 1} scans wait behind it (odom_wait_scans)")
                self._fault("odom_not_arrived", f"scan {index}: no odometry at or after its stamp while {why}; "
                            "newest odometry " + ("none" if newest is None else
                                                  f"{(newest - stamp) / 1e9:+.3f} s from it")
                            + ": posed with the nearest earlier odometry")
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
            self.get_logger().warn(
                f"odometry stamps {by_ns / 1e9:.3f} s {how} the scan stamps (scan {self.scan_count}, "
                f"stamp {stamp / 1e9:.3f} s): the two clocks disagree, pairing is wrong by that much; "
                f"counted in faults.odom_stamp_offset")
        else:
            self._fault("odom_stamp_offset", f"odometry {by_ns / 1e9:.3f} s {how} scan stamp {stamp / 1e9:.3f} s")

    def _predict(self, index: int, stamp: int, odom: np.ndarray, usable: bool, raw: bytes) -> None:
        if not usable:  # a scan the correlator cannot use: posed from odometry
            self._pass_through(index, stamp, odom, self.stage.gate(odom)[1])
            return
        update, delta = self.stage.predict(odom)
        if update:
            self.pub_scan.publish(raw)
            self.pub.publish(convert.particles_to_msg(
                self.stage.particles, self.stage.log_weights, stamp_ns=stamp,
                frame_id=self.map_frame, scan_index=index, update=True, odom_pose=odom))
            self.waiting_for = index
            return
        self._pass_through(index, stamp, odom, delta)

    def _pass_through(self, index: int, stamp: int, odom: np.ndarray, delta: np.ndarray) -> None:
        self._publish_pose(compose(self.corrected_pose, delta), stamp)
        self.last_pass_through = (index, stamp, odom, delta)

    def _publish_pose(self, pose: np.ndarray, stamp: int) -> None:
        self.pub_pose.publish(self.pose_cdr.pack(pose, stamp))
        self.poses_published += 1
        if self.poses_published == self.scans_expected:
            self._publish_status()

    def _maybe_send_end(self) -> None:
        """Once the last scan of the bag is posed as a pass-through, send it on as the end of
        the run: a set without particles (update=false) that the correlator and mapper pass on."""
        last = self.last_pass_through
        if (self.waiting_for is not None or self.end_sent or self.scans_expected is None or last is None
                or last[0] != self.scans_expected - 1):
            return
        index, stamp, odom, delta = last
        self.pub.publish(convert.particles_to_msg(
            np.zeros((0, 3)), np.zeros(0), stamp_ns=stamp, frame_id=self.map_frame,
            scan_index=index, update=False, odom_pose=odom, pending_delta=delta))
        self.end_sent = True


def main(args: list[str] | None = None) -> int:
    return run_node(Predictor, args)


if __name__ == "__main__":
    import sys
    sys.exit(main())
