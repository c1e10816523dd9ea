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

import numpy as np
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from pf_slam_interfaces.msg import FogBatch, ParticleArray, ReplayStatus
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState, LaserScan
from tf2_msgs.msg import TFMessage

from ..core.faults import ODOMETRY_NONFINITE, ScanChecks
from ..core.motion import compose
from ..core.odometry import GyroBuffer, OdometryBuffer, WheelOdometryIntegrator
from ..core.stages import PredictionStage
from ..io.trajectory import quat_to_yaw
from ..ros import cdr, convert, qos, topics
from .common import announce_when_matched, declare_config, param, run_node, status_publisher


class Predictor(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("predictor", **kwargs)
        self.stage = PredictionStage(declare_config(self, "filter"), declare_config(self, "motion"))
        self.map_frame = param(self, "map_frame", "map")
        source = param(self, "odometry_source", "odom")
        if source not in ("odom", "encoders"):
            raise ValueError(f"parameter 'odometry_source' must be 'odom' or 'encoders', got {source!r}")
        self.odom = OdometryBuffer(param(self, "odom_sync", "interpolate"))
        self.scans: deque[tuple[int, int, bool, bytes]] = deque()  # (scan_index, stamp_ns, usable, raw)
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
        if self._finite(pose, "odom"):
            self.odom.add(convert.stamp_to_ns(msg.header.stamp), pose)
        self._drain()

    def _on_encoders(self, raw: bytes) -> None:
        stamp, position = self._parse(cdr.joint_state_positions, raw, "encoders")
        if position is None or len(position) < 2:
            if position is not None:
                self.get_logger().warn("encoders: JointState with fewer than 2 positions ignored",
                                       throttle_duration_sec=5.0)
            self.odom_received += 1  # counted: the end-of-stream count must still match
            return
        if not self._finite(position[:2], "encoders"):
            self.odom_received += 1
            return
        self.encoders.append((stamp, float(position[0]), float(position[1])))
        self._drain_odometry()

    def _on_fog_batch(self, raw: bytes) -> None:
        stamps, yaw = self._parse(cdr.fog_batch_yaw, raw, "fog")
        self.fog_received += 1  # counted even if bad: the end-of-stream count must still match
        if stamps is not None and self._finite(yaw, "fog"):
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
        if self._finite(np.array([msg.vector.z]), "fog"):
            self.gyro.add([convert.stamp_to_ns(msg.header.stamp)], [msg.vector.z])
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
        self.fog_received += 1
        self._drain_odometry()

    def _drain_odometry(self) -> None:
        """After an encoder or gyro message: drain only when the oldest wheel step can now be
        integrated (the gyro covers it, or no more gyro will come). Otherwise the odometry did
        not change, so no scan can be posed: at 100 + 100 Hz that skips half of the drains."""
        if not self.encoders:
            return
        if (self.gyro is None or self.gyro.last_stamp >= self.encoders[0][0]
                or (self.fog_expected is not None and self.fog_received >= self.fog_expected)):
            self._drain()

    def _integrate_encoders(self) -> None:
        """Wheel steps -> odometry poses, each once the gyro covers its interval (deterministic)."""
        fog_done = self.fog_expected is not None and self.fog_received >= self.fog_expected
        while self.encoders:
            t, left, right = self.encoders[0]
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
            stamp, usable, faults = self.checks.last_stamp_ns or 0, False, self.checks.unreadable(exc)
        for kind, text in faults:
            self._fault(kind, f"scan {self.scan_count}: {text}")
        self.scans.append((self.scan_count, stamp, usable, raw))
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
                   odom_time_backwards=self.odom.backward_steps, odom_missing=self.odom.missing)
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

    # ------------------------------------------------------------------ the work
    def _drain(self) -> None:
        if hasattr(self, "encoders"):
            self._integrate_encoders()
        while self.scans:
            index, stamp, usable, raw = self.scans[0]
            # a scan whose exact odometry never comes must not block the ones behind it
            # end of stream: every odometry message of the bag is here, none will follow
            final = (self.odom_expected is not None and self.odom_received >= self.odom_expected) or (
                self.odom.sync == "exact" and len(self.scans) > 1
                and self.odom.has_exact(self.scans[1][1], ahead=int(self.scans[1][1] == stamp)))
            if self.waiting_for is not None:
                # a correction is in flight: queue pass-throughs, stop at the next update
                if index == self.blocked:
                    break
                odom = self.odom.peek(stamp, final=final)
                if odom is None:
                    break
                update, delta = self.stage.gate(odom)
                if update and usable:
                    self.blocked = index  # decided: no need to look again on every message
                    break
                self.odom.lookup(stamp, final=final)  # consume what peek saw
                self.scans.popleft()
                self._publish_odom_tf(odom, stamp)
                self.deferred.append((index, stamp, odom, delta))
                continue
            odom = self.odom.lookup(stamp, final=final)
            if odom is None:
                break
            self.scans.popleft()
            self._publish_odom_tf(odom, stamp)
            self._predict(index, stamp, odom, usable, raw)
        self.odom.trim()
        self._maybe_send_end()

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
