"""mapper: integrates each corrected scan into the log-odds grid and publishes the map.

Subscribes: pf_slam/scan_corrected (LaserScan: the bytes of exactly the scans that are corrected,
forwarded by the predictor; the n-th belongs to the n-th set with update=true),
particles/updated (ParticleArray: every corrected set, and the end-of-run pass-through set),
pf_slam/replay_status (messages per topic, at the end of the bag).
Publishes: pf_slam/grid (after every integration, the patch of cells the scan touched, for
the correlator), map + map_metadata (latched, on a timer and once more after the last scan),
path (on the timer: the poses of the corrected scans), pf_slam/trajectory (with loops.enabled,
latched, once every scan's pose has arrived after the last one: every pose in the final frame
of the loop closure), pf_slam/loop_trajectory (latched, at every closed loop that re-renders the
map: every scan's pose received so far, in the new frame), /tf (map -> odom = map_T_base *
odom_T_base^-1, at every correction: between corrections map -> odom does not change, since scan
poses are then the corrected pose composed with the odometry increment), /tf_static (base_frame ->
the scan's frame from filter.sensor_offset_* / laser.extrinsic, once, if publish_sensor_tf).
/map holds map_server trinary values: 100 / 0 / -1 by occupied_thresh / free_thresh.

loops.enabled -- the loop closure (core/loops.py) runs on the integrated scans. A closed loop that
moves the map re-renders it from the optimised poses: the correlator gets a frame-change marker
(pf_slam/grid, resolution -1, the transform as its origin) and then the whole new map, and the
filter goes on in that frame. After the last scan the map is re-rendered once more if the final
solution moved it, and the trajectory (and /path) go out in the final frame. With ``worker:
process`` (default) a keyframe's loop match runs in a worker process the node owns
(nodes/worker.py) while the graph goes on with the scans that pass through: the scan's patch
(and the frame change) goes out once the match has answered (a 0.2 ms timer looks while it runs),
and the correlator waits for it before its next correction, as it waits for any patch. So the
trajectory is the same as with ``worker: thread`` (the match in the node, waited for).

mode: localization -- the map is map_file (a map_server .yaml), loaded at start-up and published
latched on /map as loaded (at once, for the correlator, then like a built map); without map_file
another node (nav2's map_server) publishes /map and this node publishes none. No scan is
integrated and no grid patch is sent. map -> odom, /path and /tf_static as in SLAM.

It also keeps every scan's pose (pose, from the predictor) for the trajectory, and serves (live use,
no end of bag needed): pf_slam/save_map (pf_slam_interfaces/SaveMap: map.pgm + map.yaml in map_server
format and trajectory.tum into a folder), pf_slam/pause_mapping (std_srvs/SetBool: true freezes the
map, the filter goes on localising against it; false resumes), pf_slam/reset (std_srvs/Trigger: a new,
empty map from the next corrected scan on, at the filter's pose then; the trajectory kept so far is
dropped). A reset reaches the correlator in order on pf_slam/grid (a patch with resolution 0 just
before the new map's first patch), so it drops its likelihood field at the same scan.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import MapMetaData, OccupancyGrid, Path
from rclpy.node import Node
from sensor_msgs.msg import LaserScan
from std_srvs.srv import SetBool, Trigger
from tf2_msgs.msg import TFMessage

from pf_slam_interfaces.msg import ParticleArray, ReplayStatus
from pf_slam_interfaces.srv import SaveMap

from ..core.deferred import inline
from ..core.geometry import compose, matrix_to_quat, relative_pose
from ..core.stages import MappingStage
from ..io.mapfile import read_map, trinary
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


class PoseLog:
    """Stamped (x, y, yaw) poses in growing arrays: 32 bytes a pose, for live runs of hours."""

    def __init__(self) -> None:
        self._t = np.empty(1024, np.int64)
        self._p = np.empty((1024, 3))
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def append(self, stamp_ns: int, pose) -> None:
        if self._n == len(self._t):
            self._t = np.concatenate([self._t, np.empty_like(self._t)])
            self._p = np.concatenate([self._p, np.empty_like(self._p)])
        self._t[self._n], self._p[self._n] = stamp_ns, pose
        self._n += 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return self._t[: self._n].copy(), self._p[: self._n].copy()

    def set(self, stamps_ns: np.ndarray, poses: np.ndarray) -> None:
        """Replace the log's contents."""
        n = len(stamps_ns)
        self._t = np.empty(max(n, 1024), np.int64)
        self._p = np.empty((max(n, 1024), 3))
        self._t[:n], self._p[:n], self._n = stamps_ns, poses, n

    def drop_before(self, stamp_ns: int) -> None:
        keep = self._t[: self._n] >= stamp_ns
        k = int(keep.sum())
        self._t[:k], self._p[:k] = self._t[: self._n][keep], self._p[: self._n][keep]
        self._n = k


class Mapper(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("mapper", **kwargs)
        self.side = SideWork(self, "the loop match it owed is lost")  # worker: process -- the loop matches
        self.mode = param(self, "mode", "slam")
        self.stage = MappingStage(
            declare_config(self, "filter"),
            declare_config(self, "grid"),
            declare_config(self, "laser"),
            declare_config(self, "loops"),
            # a worker process only where loops are matched (not on a fixed map)
            offload=self.side.offload if self.mode == "slam" else inline,
        )
        close_on_failure(self._setup, self.stage.close)

    def _setup(self) -> None:
        self._open: tuple[int, int] | None = None  # (scan index, stamp) of the scan whose loop match runs
        self._poll = self.create_timer(0.0002, self._finish_open)  # while one runs: is its answer here?
        self._poll.cancel()
        self.map_frame = param(self, "map_frame", "map")
        self.odom_frame = param(self, "odom_frame", "odom")
        self.base_frame = param(self, "base_frame", "base_link")
        self.thresholds = (param(self, "occupied_thresh", 0.65), param(self, "free_thresh", 0.25))
        trinary(np.zeros((1, 1)), *self.thresholds)  # bad thresholds fail at start-up
        period = param(self, "map_publish_period_s", 1.0)
        map_file = param(self, "map_file", "")
        self.fixed_map: OccupancyGrid | None = None
        if self.mode not in ("slam", "localization"):
            raise ValueError(f"node mapper: parameter 'mode' must be 'slam' or 'localization', got {self.mode!r}")
        self.localize = self.mode == "localization"
        if self.localize and map_file:
            occ, res, origin = read_map(map_file)
            if abs(origin[2]) > 1e-9:
                raise ValueError(f"{map_file}: origin yaw {origin[2]!r}: a rotated map is not supported")
            self.fixed_map = convert.grid_to_msg(occ, res, origin[:2], 0, self.map_frame)
        self.scan_topic = self.resolve_topic_name(topics.SCAN)
        self.scans = ScanQueue()
        self.updates: deque[ParticleArray] = deque()
        self.integrated = 0  # sets with update=true taken (= corrected scans taken)
        self.last_index = -1
        self.total: int | None = None
        self.last_stamp = 0
        self.path = PoseLog()  # /path: the corrected scans' poses
        self.pub_grid = self.create_publisher(OccupancyGrid, topics.GRID, qos.pipeline(10))
        self.pub_map = self.create_publisher(OccupancyGrid, topics.MAP, qos.latched())
        self.pub_meta = self.create_publisher(MapMetaData, topics.MAP_METADATA, qos.latched())
        self.pub_path = self.create_publisher(Path, topics.PATH, qos.outputs(10))
        self.pub_trajectory = self.create_publisher(Path, topics.TRAJECTORY, qos.latched())
        self.pub_loop_trajectory = self.create_publisher(Path, topics.LOOP_TRAJECTORY, qos.latched())
        self.loop_trajectories = 0  # pf_slam/loop_trajectory messages sent
        self.poses_seen = 0  # /pose messages received (the final trajectory waits for all of them)
        self.final_map_sent = self.final_trajectory_sent = False
        self.scans_total = 0  # the bag's scans, once the final map went out
        self.pub_tf = self.create_publisher(TFMessage, topics.TF, qos.outputs())
        self.pub_tf_static = (
            self.create_publisher(TFMessage, topics.TF_STATIC, qos.latched())
            if param(self, "publish_sensor_tf", True)
            else None
        )
        announce_when_matched(self, [(self.pub_grid, 1)])  # the correlator
        self.create_subscription(LaserScan, topics.SCAN_CORRECTED, self._on_scan, qos.pipeline(), raw=True)
        self.create_subscription(ParticleArray, topics.PARTICLES_UPDATED, self._on_updated, qos.pipeline())
        self.create_subscription(ReplayStatus, topics.REPLAY_STATUS, self._on_replay_status, qos.latched())
        self.create_timer(period, self.publish_map)
        if self.fixed_map is not None:
            self.publish_map()  # latched: the correlator needs it before the first correction
        self.paused = False
        self.reset_pending = False
        self.trajectory = PoseLog()  # every scan's pose (pose): the trajectory save_map writes
        self.trajectory_from = -(1 << 62)
        self.create_subscription(PoseStamped, topics.POSE, self._on_pose, qos.pipeline(), raw=True)
        self.create_service(SaveMap, topics.SAVE_MAP, self._srv_save_map)
        self.create_service(SetBool, topics.PAUSE_MAPPING, self._srv_pause)
        self.create_service(Trigger, topics.RESET, self._srv_reset)
        self.publish_status = status_publisher(self, self._status)
        self._warned_bound = False
        self.mount_ready = not param(self, "mount_from_tf", False)  # else: wait for the predictor's decision
        if not self.mount_ready:
            from .mount_tf import receive_mount

            receive_mount(self, self._on_mount)

    def _on_mount(self, decision: dict) -> None:
        from .mount_tf import apply_to_stage

        if not self.mount_ready:
            apply_to_stage(self.stage, decision["params"])
            if decision["source"] != "parameters":
                self.pub_tf_static = None  # the robot's TF tree has base -> lidar
            self.mount_ready = True
            self._drain()

    def destroy_node(self) -> None:
        self.stage.close()
        super().destroy_node()

    def _status(self) -> dict:
        out = {"faults": {"scans_lost_mapper": self.scans.lost, "map_beyond_bound": self._beyond_bound()}}
        if self.side.error:
            out["worker_error"] = self.side.error
        lc = self.stage.loops
        if lc is not None:
            out["loops"] = {
                "keyframes": len(lc),
                "attempts": lc.attempts,
                "closed": len(lc.loops),
                "rejected": lc.rejected,
                "dropped": lc.dropped,
                "pair_edges": len(lc.pairs),  # loops.pair_baseline_m: scan-pair edges of the final solve
                "map_renders": self.stage.rebuilds,
                "loop_trajectories": self.loop_trajectories,  # pf_slam/loop_trajectory messages
                "matched_in": lc.matcher.kind,  # "process" (worker: process) or "inline" (in the node)
            }
        return out

    def _beyond_bound(self) -> int:
        """Scans with cells the grid could not grow to (grid.max_cells)."""
        return 0 if self.stage.grid is None else int(self.stage.grid.scans_beyond_bound)

    def _on_pose(self, raw: bytes) -> None:
        stamp, pose = cdr.pose_stamped_xy_yaw(raw)
        self.poses_seen += 1
        if stamp >= self.trajectory_from:  # not a scan before the last reset
            self.trajectory.append(stamp, pose)
        if self.final_map_sent:
            self._maybe_finish()

    def corrected_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Every scan's stamp (ns) and pose so far, in the loop closure's optimised frame."""
        stamps, poses = self.trajectory.arrays()
        return stamps, self.stage.corrected(stamps / 1e9, poses)

    # ------------------------------------------------------------------ services
    def _srv_save_map(self, req: SaveMap.Request, res: SaveMap.Response) -> SaveMap.Response:
        from ..io.mapfile import write_map
        from ..io.trajectory import write_tum

        res.success = False
        if not req.directory:
            res.message = "save_map: 'directory' is empty"
        elif not self.stage.ready:
            res.message = "save_map: no map yet (no scan has been corrected)"
        else:
            import os
            from pathlib import Path

            out = Path(os.path.expanduser(req.directory)).resolve()
            try:
                out.mkdir(parents=True, exist_ok=True)
                occ, resolution, origin = self.stage.map_occupancy()
                yaml_path = write_map(
                    out, occ, resolution, origin, occupied_thresh=self.thresholds[0], free_thresh=self.thresholds[1]
                )
                tum = out / "trajectory.tum"
                stamps, poses = self.corrected_trajectory()
                write_tum(tum, stamps / 1e9, poses)
            except OSError as e:
                res.message = f"save_map: cannot write into {out}: {e}"
            else:
                res.success = True
                res.files = [str(yaml_path.with_suffix(".pgm")), str(yaml_path), str(tum)]
                res.message = (
                    f"map {occ.shape[1]} x {occ.shape[0]} cells ({resolution} m), "
                    f"{len(self.trajectory)} poses saved in {out}"
                )
        if res.success:
            self.get_logger().info(res.message)
        else:
            self.get_logger().error(res.message)
        return res

    def _srv_pause(self, req: SetBool.Request, res: SetBool.Response) -> SetBool.Response:
        was, self.paused = self.paused, bool(req.data)
        if was and not self.paused and not self.stage.ready and self.integrated:
            self.reset_pending = True  # paused since before the first map: start it as after a reset
        res.success = True
        res.message = (
            "mapping paused: the map is frozen, the filter localises against it" if self.paused else "mapping resumed"
        ) + ("" if was != self.paused else " (no change)")
        self.get_logger().info(res.message)
        return res

    def _srv_reset(self, _req: Trigger.Request, res: Trigger.Response) -> Trigger.Response:
        self.reset_pending = True
        res.success = True
        res.message = "map reset: a new map starts at the next corrected scan; trajectory cleared"
        self.get_logger().info(res.message)
        return res

    def _reset_map(self, stamp: int) -> None:
        """A new, empty map (built from the next integrated scan on); the correlator is told first."""
        self.reset_pending = False
        self.stage.grid = self.stage._occ = self.stage.pose = None
        self._warned_bound = False
        self.path = PoseLog()
        self.trajectory.drop_before(stamp)  # kept from this scan on
        self.trajectory_from = stamp
        marker = convert.grid_to_msg(np.zeros((0, 0), np.int8), 0.0, (0.0, 0.0), stamp, self.map_frame)
        self.pub_grid.publish(marker)  # resolution 0: "reset" (ordered before the new map's first patch)

    def _on_scan(self, raw: bytes) -> None:
        self.scans.append(raw)
        self._drain()

    def _on_updated(self, msg: ParticleArray) -> None:
        self.updates.append(msg)
        self._drain()

    def _on_replay_status(self, msg: ReplayStatus) -> None:
        self.total = int(dict(zip(msg.topics, msg.counts)).get(self.scan_topic, 0))
        self._maybe_finish()

    def _drain(self) -> None:
        if self._open is not None and self.stage.answered():
            self._finish_open()
            return  # (which drains)
        while self.updates and self.mount_ready:
            pa = self.updates[0]
            stamp = convert.stamp_to_ns(pa.header.stamp)  # the scan's
            if pa.update and (self._open is not None or not self.scans.has(self.integrated, stamp)):
                return  # the previous scan's loop match is still running, or this scan is not here
            self.updates.popleft()
            pose = np.asarray(pa.pose, dtype=np.float64)
            if pa.update:
                scan = self.scans.take(self.integrated, stamp)
                self.integrated += 1
                if scan is None:
                    self.get_logger().warn(
                        f"scan {pa.scan_index} was lost on the way here (a replay faster than the graph): not mapped",
                        throttle_duration_sec=5.0,
                    )
                elif self.pub_tf_static is not None:
                    self._publish_sensor_tf(scan.header.frame_id, stamp)
                if not self.localize:
                    if self.reset_pending and not self.paused:
                        self._reset_map(stamp)
                    if self.paused:  # the map is frozen: an empty patch keeps the correlator in step
                        g = self.stage.grid
                        self.pub_grid.publish(
                            convert.grid_to_msg(
                                np.zeros((0, 0), np.int8),
                                g.resolution if g is not None else self.stage.grid_cfg.resolution_m,
                                g.origin if g is not None else (0.0, 0.0),
                                stamp,
                                self.map_frame,
                            )
                        )
                    else:
                        self._integrate(pa, pose, scan, stamp)
            map_to_odom = compose(pose, relative_pose(np.asarray(pa.odom_pose), np.zeros(3)))
            self.pub_tf.publish(
                TFMessage(transforms=[convert.transform(self.map_frame, self.odom_frame, map_to_odom, stamp)])
            )
            self.path.append(stamp, pose)
            self.last_index = pa.scan_index
            self.last_stamp = stamp
        self._maybe_finish()

    def _integrate(self, pa: ParticleArray, pose: np.ndarray, scan, stamp: int) -> None:
        """SLAM: the scan into the grid at the pose; its patch to the correlator once its loop
        match (if any, in the worker process) has answered: the correlator waits for that patch
        before its next correction, the pass-through scans go on meanwhile."""
        self.stage.start_integrate(
            pose,
            *scan_fields(scan),
            extrinsic=mount_of(pa),
            key=stamp / 1e9,
            odom=np.asarray(pa.odom_pose),
            odom_scale=pa.odom_scale if pa.odom_scale > 0.0 else 1.0,
        )
        if not self.stage.answered():
            self._open = (pa.scan_index, stamp)
            self._poll.reset()
            return
        self._finish_integrate(pa.scan_index, stamp)

    def _finish_open(self) -> None:
        """The running loop match answered: finish its scan, then go on with what waited."""
        if self._open is None or not self.stage.answered():
            return
        self._poll.cancel()
        (index, stamp), self._open = self._open, None
        self._finish_integrate(index, stamp)
        self._drain()

    def _finish_integrate(self, index: int, stamp: int) -> None:
        patch = self.stage.finish_integrate()
        if patch.transform is not None:  # a closed loop re-rendered the map: the filter's frame follows
            self.pub_grid.publish(convert.frame_change_msg(patch.transform, stamp, self.map_frame))
            t = patch.transform
            if len(self.trajectory):  # the poses so far in the new frame: the live texture moves with them
                stamps, poses = self.corrected_trajectory()
                self.pub_loop_trajectory.publish(cdr.path_bytes(stamps, poses, stamp, self.map_frame))
                self.loop_trajectories += 1
            self.get_logger().info(
                f"scan {index}: loop closed ({len(self.stage.loops.loops)} so far), map re-rendered "
                f"from the optimised poses; the frame moves by x {t[0]:.3f} y {t[1]:.3f} m, "
                f"yaw {np.degrees(t[2]):.2f} deg"
            )
        g = self.stage.grid
        if g.scans_beyond_bound and not self._warned_bound:
            self._warned_bound = True
            self.get_logger().warn(
                f"scan {index} reaches beyond what grid.max_cells ({g.cfg.max_cells}) lets the "
                f"map grow to ({g.height} x {g.width} cells): those cells are not mapped (counted: "
                "faults map_beyond_bound)"
            )
        self.pub_grid.publish(
            convert.grid_to_msg(patch.occupancy, patch.resolution, patch.origin, stamp, self.map_frame)
        )

    def _publish_sensor_tf(self, frame: str, stamp: int) -> None:
        """base_frame -> the scan's frame (latched, once): the laser mounting the SLAM uses."""
        self.pub_tf_static, pub = None, self.pub_tf_static
        if not frame or frame == self.base_frame:
            return
        tf = convert.transform(self.base_frame, frame, self.stage.filter_cfg.sensor_offset, stamp)
        ext = self.stage.laser_cfg.extrinsic
        if any(ext):  # a tilted laser: its full 3D mounting
            t = tf.transform
            t.translation.x, t.translation.y, t.translation.z = ext[9:]
            q = matrix_to_quat(np.asarray(ext[:9]).reshape(3, 3))
            t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w = q
        pub.publish(TFMessage(transforms=[tf]))

    def _maybe_finish(self) -> None:
        if self._open is not None:  # the last scans wait for a loop match
            return
        if self.total is not None and self.last_index == self.total - 1:
            if not self.localize and self.stage.finish():
                self.get_logger().info("end of the run: map re-rendered from the final loop-closure solution")
            if self.stage.loops is not None:
                self.path.set(*self._path_corrected())
            self.publish_map()
            self.publish_status()
            self.final_map_sent, self.scans_total, self.total = True, self.total, None  # the final map once
        if self.stage.loops is not None and self.final_map_sent and not self.final_trajectory_sent:
            if self.poses_seen >= self.scans_total:  # every scan's pose is here
                self.final_trajectory_sent = True
                stamps, poses = self.corrected_trajectory()
                self.pub_trajectory.publish(cdr.path_bytes(stamps, poses, self.last_stamp, self.map_frame))

    def _path_corrected(self) -> tuple[np.ndarray, np.ndarray]:
        """/path's poses (the corrected scans') in the final frame."""
        stamps, poses = self.path.arrays()
        return stamps, self.stage.corrected(stamps / 1e9, poses)

    def publish_map(self) -> None:
        if self.localize:  # the loaded map, unchanged (without map_file: another node's /map)
            if self.fixed_map is None:
                return
            msg = self.fixed_map
            msg.header.stamp = msg.info.map_load_time = convert.ns_to_stamp(self.last_stamp)
        elif not self.stage.ready:
            return
        else:
            occ, res, origin = self.stage.map_occupancy()
            msg = convert.grid_to_msg(trinary(occ, *self.thresholds), res, origin, self.last_stamp, self.map_frame)
        self.pub_map.publish(msg)
        self.pub_meta.publish(msg.info)
        self.pub_path.publish(cdr.path_bytes(*self.path.arrays(), self.last_stamp, self.map_frame))


def main(args: list[str] | None = None) -> int:
    return run_node(Mapper, args)


if __name__ == "__main__":
    import sys

    sys.exit(main())
