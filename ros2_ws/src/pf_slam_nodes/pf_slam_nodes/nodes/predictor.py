"""predictor: owns the particle set between scans and moves it with the motion model.

Subscribes: scan (LaserScan; only its stamp and ranges are read, from the serialized bytes), odom
(nav_msgs/Odometry), /tf (odometry_source tf: the odom_frame -> base_frame transforms that the
robot's base controller publishes) or encoders (JointState wheel angles, rad) with optional fog (FogBatch or
Vector3Stamped yaw increments, which then replace the wheels' yaw), particles/updated (the
corrected set), pf_slam/replay_status (end of the bag). Publishes: pose (PoseStamped, map
frame, exactly one per scan, in scan order), particles/predicted (one per correction),
pf_slam/scan_corrected (the bytes of each scan it sends to be corrected, before its set), /tf
(odom_frame -> base_frame: the dead-reckoned odometry at every scan's stamp, REP 105; never with
odometry_source tf, and no more once another node is seen publishing odom_frame -> base_frame on
/tf: a robot's own TF tree is never fought).
With a lidar on a moving mount (laser.dynamic_frame, e.g. THOR's head) it also subscribes /tf
for base_frame -> dynamic_frame and sends each corrected scan's mount at its stamp with its set
(ParticleArray.mount); mostly-floor scans are posed from odometry (core/mount.py).

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

The decisions (which scan is posed when and how, the encoder/gyro integration, the fault
counts) are core/scheduler.py's PredictorScheduler, shared with the ROS-free loop
(core/slam.py ParticleFilterSlam.run_stream); this node parses the messages, hands them to it and
publishes what it decides, at once and in its order.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState, LaserScan
from tf2_msgs.msg import TFMessage

from pf_slam_interfaces.msg import FogBatch, ParticleArray, ReplayStatus

from ..core import scheduler as sch
from ..core.geometry import quat_to_yaw
from ..ros import cdr, convert, qos, topics
from .common import announce_when_matched, declare_config, param, run_node, status_publisher


class Predictor(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("predictor", **kwargs)
        filter_cfg, motion_cfg = declare_config(self, "filter"), declare_config(self, "motion")
        self.map_frame = param(self, "map_frame", "map")
        source = param(self, "odometry_source", "odom")
        if source not in ("odom", "encoders", "tf"):
            raise ValueError(f"parameter 'odometry_source' must be 'odom', 'encoders' or 'tf', got {source!r}")
        self.source = source
        odom_sync = param(self, "odom_sync", "interpolate")
        odom_wait_scans = param(self, "odom_wait_scans", 50)
        if odom_wait_scans < 0:
            raise ValueError(f"parameter 'odom_wait_scans' must be >= 0 (0: off), got {odom_wait_scans}")
        stamp_offset_s = param(self, "stamp_offset_s", 2.0)  # 0: off
        time_gap_s = param(self, "time_gap_s", 60.0)
        self._fault_loggers: dict = {}  # one logger per fault kind: each throttled on its own
        self.odom_topic = (
            topics.TF
            if source == "tf"
            else self.resolve_topic_name(topics.ODOM if source == "odom" else topics.ENCODERS)
        )
        self.scan_topic = self.resolve_topic_name(topics.SCAN)
        self.pub = self.create_publisher(ParticleArray, topics.PARTICLES_PREDICTED, qos.pipeline())
        self.pub_pose = self.create_publisher(PoseStamped, topics.POSE, qos.pipeline())
        self.pub_scan = self.create_publisher(LaserScan, topics.SCAN_CORRECTED, qos.pipeline())
        self.pose_cdr = cdr.PoseStampedWriter(self.map_frame)  # one pose per scan: published as bytes
        self._init_odom_tf()
        sensor_qos = str(param(self, "sensor_qos", "reliable"))

        def sensor_sub(msg_type, topic, callback, depth, raw=False):
            """A sensor input with sensor_qos; a publisher whose QoS cannot match is named once."""
            profile = qos.sensor(depth, sensor_qos)
            events = SubscriptionEventCallbacks(
                incompatible_qos=lambda _e: self.get_logger().error(
                    f"{self.resolve_topic_name(topic)}: a publisher's QoS is incompatible with this "
                    f"subscription ({sensor_qos}); nothing arrives from it. A driver that publishes with the "
                    "sensor-data QoS needs sensor_qos: best_effort (pf-slam live --sensor-qos best_effort, "
                    "launch sensor_qos:=best_effort)",
                    once=True,
                )
            )
            return self.create_subscription(msg_type, topic, callback, profile, raw=raw, event_callbacks=events)

        scan_depth = param(self, "scan_queue_depth", 1000)
        if scan_depth < 1:
            raise ValueError(f"parameter 'scan_queue_depth' must be >= 1, got {scan_depth}")
        sub_scan = sensor_sub(LaserScan, topics.SCAN, self._on_scan, scan_depth, raw=True)
        # the correlator (+ the mapper for the scans); bag_replay (paces on pose), the mapper (the
        # trajectory save_map writes) + observers
        # that must see every pose; the scans' source (the replay starts once this is matched)
        announce_when_matched(
            self,
            [
                (self.pub, 1),
                (self.pub_scan, 2),
                (self.pub_pose, 2 + param(self, "expected_observers", 0)),
                (sub_scan, 1),
            ],
        )
        self.create_subscription(ParticleArray, topics.PARTICLES_UPDATED, self._on_updated, qos.pipeline())
        self.create_subscription(ReplayStatus, topics.REPLAY_STATUS, self._on_replay_status, qos.latched())
        self.create_subscription(ReplayStatus, topics.REPLAY_STALL, self._on_stall, qos.pipeline())
        wheels_cfg = None
        if source == "odom":
            sensor_sub(Odometry, topics.ODOM, self._on_odom, 10000, raw=True)
        elif source == "tf":
            self.create_subscription(TFMessage, topics.TF, self._on_tf_odometry, qos.pipeline(10000))
        elif source == "encoders":
            wheels_cfg = declare_config(self, "wheels")
            sensor_sub(JointState, topics.ENCODERS, self._on_encoders, 10000, raw=True)
        # yaw from a gyro instead of the wheels: "none" | "batch" (FogBatch) | "vector3" | "imu" (Imu on imu)
        fog = param(self, "fog_format", "none")
        if fog not in ("none", "batch", "vector3", "imu"):
            raise ValueError(f"parameter 'fog_format' must be 'none', 'batch', 'vector3' or 'imu', got {fog!r}")
        if fog != "none" and source != "encoders":
            raise ValueError("parameter 'fog_format' needs odometry_source 'encoders'")
        self.fog_topic = self.resolve_topic_name(topics.IMU if fog == "imu" else topics.FOG)
        if fog == "batch":
            sensor_sub(FogBatch, topics.FOG, self._on_fog_batch, 10000, raw=True)
        elif fog == "vector3":
            sensor_sub(Vector3Stamped, topics.FOG, self._on_fog_vector, 100000)
        elif fog == "imu":
            sensor_sub(Imu, topics.IMU, self._on_imu, 100000)
        # a lidar on a moving mount: base_frame -> laser.dynamic_frame from /tf
        laser_cfg = declare_config(self, "laser")
        self.mount_frames = None
        if laser_cfg.dynamic_frame:
            frame = lambda name: str(self.get_parameter(name).value).lstrip("/")  # noqa: E731 (declared above)
            self.mount_frames = (frame("base_frame"), laser_cfg.dynamic_frame.lstrip("/"))
            # the graph's own /tf (the mapper's map -> odom, this node's odom -> base when it publishes
            # it) is not the bag's: not counted against the replay's /tf count
            self._own_tf = {(frame("map_frame"), frame("odom_frame"))} | (
                {(frame("odom_frame"), frame("base_frame"))} if self.pub_tf is not None else set()
            )
            self.create_subscription(TFMessage, topics.TF, self._on_tf_mount, qos.pipeline(10000), raw=True)
        # every decision is the scheduler's; its actions are published as they are decided
        self.sched = sch.PredictorScheduler(
            filter_cfg,
            motion_cfg,
            "odom" if source == "tf" else source,
            odom_sync,
            wheels_cfg,
            gyro=fog != "none",
            odom_wait_scans=odom_wait_scans,
            stamp_offset_s=stamp_offset_s,
            time_gap_s=time_gap_s,
            emit=self._act,
            laser_cfg=laser_cfg,
        )
        self.stage = self.sched.stage
        # "final" once the last scan of the bag is posed: the run's summary waits for it
        self._publish_status = status_publisher(self, self.sched.status)
        self._init_mount()

    def _init_odom_tf(self) -> None:
        """odom -> base_link on /tf, one per scan, as bytes (the car's lidar runs at 100 Hz); not
        with odometry from /tf, and no more once another node publishes it (checked every second
        while a node other than this one and the mapper publishes on /tf)."""
        self.odom_frame, self.base_frame = param(self, "odom_frame", "odom"), param(self, "base_frame", "base_link")
        publish = param(self, "publish_odom_tf", True) and self.source != "tf"
        self.pub_tf = self.create_publisher(TFMessage, topics.TF, qos.outputs()) if publish else None
        self.odom_tf_cdr = cdr.TransformWriter(self.odom_frame, self.base_frame)
        self._own_tf_stamps: deque[int] = deque(maxlen=1000)  # stamps of what this node published
        self._tf_watch = None
        self._tf_check = self.create_timer(1.0, self._check_tf_publishers) if publish else None

    def _check_tf_publishers(self) -> None:
        """Someone else on /tf? Then look at what it publishes (until odom -> base is seen)."""
        if self._tf_watch is not None:
            return
        ours = {self.get_name(), "mapper"}
        if any(i.node_name not in ours for i in self.get_publishers_info_by_topic(topics.TF)):
            self._tf_watch = self.create_subscription(TFMessage, topics.TF, self._on_foreign_tf, qos.outputs(1000))

    def _on_foreign_tf(self, msg: TFMessage) -> None:
        for t in msg.transforms:
            if (t.header.frame_id.lstrip("/"), t.child_frame_id.lstrip("/")) == (
                self.odom_frame,
                self.base_frame,
            ) and convert.stamp_to_ns(t.header.stamp) not in self._own_tf_stamps:
                self.get_logger().warn(
                    f"another node publishes {self.odom_frame} -> {self.base_frame} on /tf: "
                    "this node stops publishing it (publish_odom_tf)"
                )
                self.destroy_publisher(self.pub_tf)
                self.destroy_subscription(self._tf_watch)
                self.destroy_timer(self._tf_check)
                self.pub_tf = None
                return

    # ------------------------------------------------------------------ the scheduler's actions
    def _act(self, a) -> None:
        if isinstance(a, sch.PublishPose):
            self.pub_pose.publish(self.pose_cdr.pack(a.pose, a.stamp))
        elif isinstance(a, sch.PublishOdomTf):
            if self.pub_tf is not None:
                self._own_tf_stamps.append(a.stamp)
                self.pub_tf.publish(self.odom_tf_cdr.pack(a.odom, a.stamp))
        elif isinstance(a, sch.SendCorrection):
            self.pub_scan.publish(a.payload)
            self.pub.publish(
                convert.particles_to_msg(
                    a.particles,
                    a.log_weights,
                    stamp_ns=a.stamp,
                    frame_id=self.map_frame,
                    scan_index=a.index,
                    update=True,
                    odom_pose=a.odom,
                    mount=a.mount,
                )
            )
        elif isinstance(a, sch.SendEnd):
            self.pub.publish(
                convert.particles_to_msg(
                    np.zeros((0, 3)),
                    np.zeros(0),
                    stamp_ns=a.stamp,
                    frame_id=self.map_frame,
                    scan_index=a.index,
                    update=False,
                    odom_pose=a.odom,
                    pending_delta=a.delta,
                )
            )
        elif isinstance(a, sch.PublishStatus):
            self._publish_status()
        elif isinstance(a, sch.Fault):
            self._fault(a.kind, a.text)
        elif isinstance(a, sch.Warn):
            self.get_logger().warn(a.text)

    def _fault(self, kind: str, text: str) -> None:
        """Log a fault, throttled per kind (rclpy throttles per logger and call site)."""
        if kind not in self._fault_loggers:
            self._fault_loggers[kind] = self.get_logger().get_child(kind)
        self._fault_loggers[kind].warn(text, throttle_duration_sec=5.0)

    def faults(self) -> dict[str, int]:
        """Every fault counter of the run so far (summary.json "faults")."""
        return self.sched.faults()

    # ------------------------------------------------------------------ inputs
    def _on_odom(self, raw: bytes) -> None:
        stamp, pose = self._parse(cdr.odometry_xy_yaw, raw, "odom")
        if pose is not None:
            self.sched.add_odometry(stamp, pose)

    def _on_tf_odometry(self, msg: TFMessage) -> None:
        """Odometry from the robot's TF tree: each odom_frame -> base_frame transform."""
        for t in msg.transforms:
            if (t.header.frame_id.lstrip("/"), t.child_frame_id.lstrip("/")) == (self.odom_frame, self.base_frame):
                q, p = t.transform.rotation, t.transform.translation
                self.sched.add_odometry(
                    convert.stamp_to_ns(t.header.stamp), np.array([p.x, p.y, float(quat_to_yaw(q.x, q.y, q.z, q.w))])
                )

    def _on_encoders(self, raw: bytes) -> None:
        stamp, position = self._parse(cdr.joint_state_positions, raw, "encoders")
        if position is not None and len(position) < 2:
            self.get_logger().warn(
                "encoders: JointState with fewer than 2 positions ignored", throttle_duration_sec=5.0
            )
            position = None
        self.sched.add_encoders(stamp, position)

    def _on_fog_batch(self, raw: bytes) -> None:
        self.sched.add_gyro(*self._parse(cdr.fog_batch_yaw, raw, "fog"))

    def _on_fog_vector(self, msg: Vector3Stamped) -> None:
        self.sched.add_gyro([convert.stamp_to_ns(msg.header.stamp)], np.array([msg.vector.z]))

    def _on_imu(self, msg: Imu) -> None:
        self.sched.add_imu(convert.stamp_to_ns(msg.header.stamp), msg.angular_velocity.z)

    def _parse(self, reader, raw: bytes, topic: str):
        """Raw message -> the reader's fields, or (None, None) with an error for a bad message."""
        try:
            return reader(raw)
        except ValueError as exc:
            self.get_logger().error(f"{topic}: message dropped: {exc}", throttle_duration_sec=5.0)
            return None, None

    def _on_tf_mount(self, raw: bytes) -> None:
        """/tf: the moving mount's samples. Messages of the graph itself (odom -> base, map ->
        odom) are not counted; every other one is (the replay's count of the bag's /tf)."""
        sample, own = None, True
        try:
            transforms = cdr.tf_transforms(raw)
        except ValueError as exc:  # counted (the replay counts it), no sample
            self.get_logger().error(f"/tf: message dropped: {exc}", throttle_duration_sec=5.0)
            transforms, own = [], False
        for stamp, parent, child, t, q in transforms:
            key = (parent.lstrip("/"), child.lstrip("/"))
            own = own and key in self._own_tf
            if key == self.mount_frames:
                sample = (stamp, q, t)
        if own and sample is None:
            return
        if sample is None:
            self.sched.add_mount(0, None, None)
        else:
            self.sched.add_mount(*sample)

    def _init_mount(self) -> None:
        """mount_from_tf: scans are held until the lidar mount is decided (nodes/mount_tf.py)."""
        self.mount = None
        self._held: list[bytes] = []
        wait_s = param(self, "mount_wait_s", 5.0)
        if param(self, "mount_from_tf", False):
            from .mount_tf import MountDecider

            self.mount = MountDecider(self, self.base_frame, self.odom_frame, wait_s, self._release_held)

    def _release_held(self) -> None:
        held, self._held = self._held, []
        for raw in held:
            self._take_scan(raw)

    def _on_scan(self, raw: bytes) -> None:
        if self.mount is not None and self.mount.decided is None:
            self._held.append(raw)
            if self.mount.frame is None:
                from rclpy.serialization import deserialize_message

                try:
                    frame = deserialize_message(raw, LaserScan).header.frame_id
                except Exception:  # unreadable: the next scan names the frame
                    return
                self.mount.first_scan(frame)
            return
        self._take_scan(raw)

    def _take_scan(self, raw: bytes) -> None:
        checks = self.sched.checks
        geometry = None
        try:
            stamp, (a_min, a_max, a_inc), (r_min, r_max), ranges = cdr.laser_scan_fields(raw)
            usable, faults = checks.check(stamp, ranges, a_min, a_max, a_inc, r_min, r_max)
            if self.mount_frames is not None:
                geometry = (ranges, a_min + a_inc * np.arange(len(ranges), dtype=np.float64), r_min, r_max)
        except ValueError as exc:
            # posed from odometry at its own stamp when the header is readable and plausible, else
            # at the previous scan's stamp and odometry (without waiting)
            stamp, usable = checks.readable_stamp(raw, cdr.CdrReader), False
            faults = checks.unreadable(exc, stamp is not None)
        self.sched.add_scan(stamp, usable, raw, faults, geometry=geometry)

    def _on_updated(self, msg: ParticleArray) -> None:
        if msg.update and msg.scan_index == self.sched.waiting_for:
            particles, log_weights = convert.msg_to_particles(msg)
            self.sched.corrected(
                msg.scan_index,
                particles,
                log_weights,
                np.array(msg.pose, dtype=np.float64),
                convert.stamp_to_ns(msg.header.stamp),
            )

    def _on_replay_status(self, msg: ReplayStatus) -> None:
        counts = dict(zip(msg.topics, msg.counts))
        self.sched.end_of_stream(
            scans=int(counts.get(self.scan_topic, 0)),
            odometry=int(counts.get(self.odom_topic, 0)),
            gyro=int(counts.get(self.fog_topic, 0)),
            mount=int(counts.get(topics.TF, 0)),
        )

    def _on_stall(self, msg: ReplayStatus) -> None:
        st = dict(zip(msg.topics, msg.counts))
        self.sched.stall(
            pose=st.get(topics.POSE),
            scans=st.get(self.scan_topic, 0),
            odometry=st.get(self.odom_topic, 0),
            gyro=st.get(self.fog_topic, 0),
            mount=st.get(topics.TF, 0),
        )


def main(args: list[str] | None = None) -> int:
    return run_node(Predictor, args)


if __name__ == "__main__":
    import sys

    sys.exit(main())
