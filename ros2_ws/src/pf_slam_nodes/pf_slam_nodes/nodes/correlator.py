"""correlator: corrects each predicted particle set against the map with the scan.

Subscribes: pf_slam/scan_corrected (LaserScan: the predictor forwards the bytes of exactly the
scans it sends to be corrected; the n-th belongs to the n-th set with update=true),
particles/predicted (ParticleArray: one per correction, plus the pass-through end-of-run set),
pf_slam/grid (after each integration, the mapper's patch: occupancy of the cells that scan
touched; a patch with resolution 0 is the mapper's reset: the field is dropped and starts again,
as at the first scan, with the next patch; a patch with a negative resolution is a closed
loop's frame change (loops.*): its origin pose is the transform the next set follows, and the
next patch, the whole re-rendered map, becomes the field). Publishes: particles/updated (one per predicted set, carrying the
pose estimate: the best particle or the weighted mean, filter.pose_estimate).

A corrected set (update=true) is scored against the map that holds every scan corrected before
it: the node waits for the grid of the previous correction, so the result does not depend on
message timing (same trajectory in one process or many, at any replay rate).

Publishes particlecloud (geometry_msgs/PoseArray, map frame) after each correction.

worker: process (default) -- with correlation.odom_scale, the scan pairs that measure the
odometry's scale are matched in a worker process the node owns (nodes/worker.py), beside the
correlation: a scan's measurement is taken at the next correction, exactly where the estimate
would read it anyway, so the trajectory is the same as with ``worker: thread`` (in the node).
A worker that dies is one error (status ``worker_error``); the node goes on without it.

mode: localization -- the map is fixed: it comes from /map (latched; the mapper loads it from a
map_server file, or any map_server publishes it), the node waits for it before its first
correction and never for a grid patch. That correction replaces the set with an initial one
(global over the map's free space, or around localization.initial_pose_* with
localization.use_initial_pose); an initialpose message (PoseWithCovarianceStamped, rviz2's
"2D Pose Estimate") re-initialises the set around it at the next correction (core/localization.py).
"""

from __future__ import annotations

from collections import deque

import numpy as np
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid
from rclpy.node import Node
from sensor_msgs.msg import LaserScan

from pf_slam_interfaces.msg import ParticleArray

from ..core.geometry import compose, quat_to_yaw
from ..core.stages import CorrectionStage, MapPatch
from ..ros import cdr, convert, qos, topics
from .common import (
    ScanQueue,
    SideWork,
    announce_when_matched,
    close_on_failure,
    declare_config,
    mount_of,
    param,
    run_node,
    scan_fields,
    status_publisher,
)


class Correlator(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("correlator", **kwargs)
        filter_cfg = declare_config(self, "filter")
        # worker: process -- the scan pairs of correlation.odom_scale are measured in a worker
        # process beside the correlation (the same numbers: core/deferred.py)
        self.side = SideWork(self, "the measurement it owed is lost", lambda: self._publish_status())
        self.stage = CorrectionStage(
            filter_cfg,
            declare_config(self, "grid"),
            declare_config(self, "correlation"),
            declare_config(self, "resample"),
            declare_config(self, "laser"),
            declare_config(self, "localization"),
            offload=self.side.offload,
        )
        close_on_failure(self._setup, self.stage.close)

    def _setup(self) -> None:
        self.mode = param(self, "mode", "slam")
        if self.mode not in ("slam", "localization"):
            raise ValueError(f"node correlator: parameter 'mode' must be 'slam' or 'localization', got {self.mode!r}")
        self.map_frame = param(self, "map_frame", "map")
        self.fixed_map: bytes | None = None  # localization: the map's cells, to notice a new one
        self.pub_cloud = self.create_publisher(PoseArray, topics.PARTICLE_CLOUD, qos.outputs(5))
        self.cloud_cdr = cdr.PoseArrayWriter(self.map_frame)
        if self.mode == "localization":
            self.create_subscription(OccupancyGrid, topics.MAP, self._on_map, qos.latched())
            self.create_subscription(
                PoseWithCovarianceStamped, topics.INITIAL_POSE, self._on_initial_pose, qos.outputs(5)
            )
        self.scans = ScanQueue()
        self.predicted: deque[ParticleArray] = deque()
        self.grids_received = 0
        self.corrections_sent = 0
        self.pub_updated = self.create_publisher(ParticleArray, topics.PARTICLES_UPDATED, qos.pipeline())
        # predictor, mapper (+ observers that must see every set, e.g. a recorder)
        announce_when_matched(self, [(self.pub_updated, 2 + param(self, "expected_observers", 0))])
        self.create_subscription(LaserScan, topics.SCAN_CORRECTED, self._on_scan, qos.pipeline(), raw=True)
        self.create_subscription(ParticleArray, topics.PARTICLES_PREDICTED, self._on_predicted, qos.pipeline())
        self.create_subscription(OccupancyGrid, topics.GRID, self._on_grid, qos.pipeline(10))
        self.particles_now = 0
        self._scale_pairs = 0  # correlation.odom_scale: the pairs in the last status published
        self._recoveries = 0  # correlation.recover_search_m: the shifts in the last status published
        self._publish_status = status_publisher(self, self._status)
        self.mount_ready = not param(self, "mount_from_tf", False)  # else: wait for the predictor's decision
        if not self.mount_ready:
            from .mount_tf import receive_mount

            receive_mount(self, self._on_mount)

    def destroy_node(self) -> None:
        self.stage.close()
        super().destroy_node()

    def _status(self) -> dict:
        out = {"faults": {"scans_lost_correlator": self.scans.lost}}
        if self.side.error:
            out["worker_error"] = self.side.error
        if self.mode == "localization":
            out["localization"] = self.stage.localization_status(self.particles_now)
        if (scale := self.stage.scale_status()) is not None:
            out["odom_scale"] = scale
        if (rec := self.stage.recovery) is not None:
            out["recoveries"] = {"count": rec.fired, "last": rec.last}
        if (noise := self.stage.noise) is not None:
            out["laser_noise"] = noise.status()
        return out

    def _on_mount(self, decision: dict) -> None:
        from .mount_tf import apply_to_stage

        if not self.mount_ready:
            apply_to_stage(self.stage, decision["params"])
            self.mount_ready = True
            self._drain()

    def _on_scan(self, raw: bytes) -> None:
        self.scans.append(raw)
        self._drain()

    def _on_predicted(self, msg: ParticleArray) -> None:
        self.predicted.append(msg)
        self._drain()

    def _on_grid(self, msg: OccupancyGrid) -> None:
        if msg.info.resolution == 0.0:  # the mapper's reset: a new map from its next patch on
            self.stage.field = self.stage.known = None
            return
        if msg.info.resolution < 0.0:  # a closed loop moved the map: the next patch is all of it
            self.stage.frame_change(convert.frame_change_transform(msg))
            return
        occ, res, origin = convert.msg_to_grid(msg)
        self.stage.apply_patch(MapPatch(occ, res, np.asarray(origin)))
        self.grids_received += 1
        self._drain()

    def _on_map(self, msg: OccupancyGrid) -> None:
        """Localization: the fixed map (again: used only if its cells or geometry changed)."""
        occ, res, origin = convert.msg_to_grid(msg)
        key = bytes(msg.data) + repr((res, origin, occ.shape)).encode()
        if key == self.fixed_map:
            return
        q = msg.info.origin.orientation
        if abs(quat_to_yaw(q.x, q.y, q.z, q.w)) > 1e-9:
            self.get_logger().error("map: an OccupancyGrid whose origin is rotated is not supported; map ignored")
            return
        self.stage.set_map(occ, res, origin)
        self.fixed_map = key
        self.get_logger().info(
            f"fixed map: {occ.shape[1]} x {occ.shape[0]} cells of {res:g} m, "
            f"{self.stage.localizer.free_area_m2:.0f} m^2 free"
        )
        self._drain()

    def _on_initial_pose(self, msg: PoseWithCovarianceStamped) -> None:
        """rviz2's "2D Pose Estimate": re-initialise the set around it at the next correction."""
        frame = msg.header.frame_id.lstrip("/")
        if frame and frame != self.map_frame:
            self.get_logger().warn(f"initialpose: frame {msg.header.frame_id!r} is not {self.map_frame!r}; ignored")
            return
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        mean = np.array([p.x, p.y, quat_to_yaw(q.x, q.y, q.z, q.w)])
        cov = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6)[np.ix_([0, 1, 5], [0, 1, 5])]
        if not (np.isfinite(mean).all() and np.isfinite(cov).all()):
            self.get_logger().warn("initialpose: NaN/inf in the pose or its covariance; ignored")
            return
        if not cov.any():  # no covariance given: the parameters' spread
            from ..core.localization import initial_cov

            cov = initial_cov(self.stage.loc_cfg)
        self.stage.request_init(mean, cov)
        self.get_logger().info(
            f"initialpose x {mean[0]:.3f} y {mean[1]:.3f} yaw {np.degrees(mean[2]):.1f} deg: "
            "particles re-initialised around it at the next correction"
        )

    def _drain(self) -> None:
        # scans and sets both arrive in scan order; the n-th scan is the n-th update's
        while self.predicted and self.mount_ready:
            pa = self.predicted[0]
            stamp = convert.stamp_to_ns(pa.header.stamp)  # the scan's
            if pa.update:
                if self.mode == "localization":
                    if self.stage.localizer is None:  # the fixed map is not here yet
                        self.get_logger().warn(
                            "mode localization: no map on /map yet (mapper map_file, or a "
                            "map_server); corrections wait for it",
                            throttle_duration_sec=10.0,
                        )
                        return
                elif self.grids_received < self.corrections_sent:
                    return  # the map of the previous correction is not here yet
                if not self.scans.has(self.corrections_sent, stamp):
                    return
            self.predicted.popleft()
            particles, log_w = convert.msg_to_particles(pa)
            if pa.update:
                scan = self.scans.take(self.corrections_sent, stamp)
                if scan is None:
                    self.get_logger().warn(
                        f"scan {pa.scan_index} was lost on the way here (a replay faster "
                        "than the graph): its set is not corrected",
                        throttle_duration_sec=5.0,
                    )
                res = self.stage.correct(
                    particles, log_w, *scan_fields(scan), extrinsic=mount_of(pa), odom_pose=np.asarray(pa.odom_pose)
                )
                particles, log_w, pose = res.particles, res.log_weights, res.pose
                scale = res.odom_scale
                self.corrections_sent += 1
                if self.stage.scale_measurements != self._scale_pairs:  # each new pair, not only once a second
                    self._scale_pairs = self.stage.scale_measurements
                    self._publish_status()
                if (rec := self.stage.recovery) is not None and rec.fired != self._recoveries:
                    self._recoveries = rec.fired
                    self.get_logger().info(
                        f"scan {pa.scan_index}: the set had slid off the map; shifted by {rec.last['shift']} "
                        f"(x m, y m, yaw rad) where {self.stage.corr_cfg.recover_corrections} wide searches agreed, "
                        f"best fit {rec.last['score_before']} -> {rec.last['score_after']}"
                    )
                    self._publish_status()
                self.pub_cloud.publish(self.cloud_cdr.pack(particles, stamp))
                if self.mode == "localization" and particles.shape[0] != self.particles_now:
                    self.particles_now = particles.shape[0]
                    self._publish_status()
            else:
                pose, scale = compose(self.stage.pose, pa.pending_delta), 1.0
            self.pub_updated.publish(
                convert.particles_to_msg(
                    particles,
                    log_w,
                    stamp_ns=stamp,
                    frame_id=self.map_frame,
                    scan_index=pa.scan_index,
                    update=pa.update,
                    odom_pose=pa.odom_pose,
                    pending_delta=pa.pending_delta,
                    pose=pose,
                    mount=pa.mount,
                    odom_scale=scale,
                )
            )


def main(args: list[str] | None = None) -> int:
    return run_node(Correlator, args)


if __name__ == "__main__":
    import sys

    sys.exit(main())
