"""ROS-free reference loop: the graph's stages chained in one call per scan.

:class:`ParticleFilterSlam` runs exactly what the predictor, correlator and mapper nodes run
(the same :mod:`~pf_slam_nodes.core.stages` objects, the same map patches between mapping and
correlation, the same random streams), so for the same seed it produces the same trajectory as
the node graph, bit for bit. Used by tests, tuning and the stage profile of the benchmarks.

Two ways to feed it: :meth:`ParticleFilterSlam.process_odometry_scan` (one scan with the
odometry pose at its time, already paired), or the input streams as the predictor node gets them
(:meth:`~ParticleFilterSlam.open_stream`, then ``add_scan`` / ``add_odometry`` / ``add_encoders``
/ ``add_gyro`` / ``add_imu`` in arrival order and ``end_of_stream``): these go through the
predictor node's own scheduling (:class:`~pf_slam_nodes.core.scheduler.PredictorScheduler`:
odometry pairing, wheel encoders integrated once the gyro covers them, the fault counts), with
each correction run at once.
"""

from __future__ import annotations

import math

import numpy as np

from .config import (
    CorrelationConfig,
    FilterConfig,
    GridConfig,
    LaserConfig,
    LoopClosureConfig,
    OdometryMotionConfig,
    ResampleConfig,
    WheelsConfig,
)
from .geometry import compose
from .grid import LogOddsGrid
from .likelihood import GridLikelihoodField
from .scheduler import PredictorScheduler, PublishPose, SendCorrection
from .stages import STAGE_STEPS, CorrectionStage, MappingStage, PredictionStage, stage_seconds

STAGES = STAGE_STEPS


class ParticleFilterSlam:
    """Particle filter with scan-to-map correlation and one shared log-odds map.

    Per scan: if the odometry moved less than ``min_travel_m`` / ``min_rotation_rad`` since the
    last correction, return ``last_corrected_pose (+) odometry_since``. Otherwise predict
    (odometry motion model) -> correlate every particle in its search window (moves it to its
    best match) -> update log-weights (softmax with temperature) -> resample when
    ``N_eff < neff_threshold * N`` -> integrate the scan at the best particle -> update the
    likelihood field where the map's obstacles changed. The first scan initialises the
    particles at the odometry pose (the map frame = the odometry frame at the first scan).

    Attributes
    ----------
    timings : dict[str, float]
        Accumulated wall time (s) per stage (``STAGES``, from the stages' own clocks, as in the
        nodes); ``counts`` the number of calls.
    """

    def __init__(
        self,
        filter_cfg: FilterConfig,
        motion_cfg: OdometryMotionConfig,
        grid_cfg: GridConfig,
        corr_cfg: CorrelationConfig,
        resample_cfg: ResampleConfig,
        laser_cfg: LaserConfig | None = None,
        loop_cfg: LoopClosureConfig | None = None,
    ) -> None:
        self.predictor = PredictionStage(filter_cfg, motion_cfg)
        self.corrector = CorrectionStage(filter_cfg, grid_cfg, corr_cfg, resample_cfg, laser_cfg)
        self.mapper = MappingStage(filter_cfg, grid_cfg, laser_cfg, loop_cfg)
        self.num_updates = 0  # corrections after the first scan
        self.scans_processed = 0  # process_odometry_scan: the scan's index is its key
        self._pose: np.ndarray | None = None
        self.scheduler: PredictorScheduler | None = None  # open_stream()
        self.stream_poses: list[tuple[int, np.ndarray]] = []  # (stamp ns, pose) per scan, in scan order
        self._counts = {"scans": 0, "odometry": 0, "gyro": 0}

    @property
    def timings(self) -> dict[str, float]:
        return stage_seconds(self.predictor, self.corrector, self.mapper)[0]

    @property
    def counts(self) -> dict[str, int]:
        return stage_seconds(self.predictor, self.corrector, self.mapper)[1]

    @property
    def particles(self) -> np.ndarray:
        """``(N, 3)`` particle poses (copy)."""
        return self.predictor.particles.copy()

    @property
    def log_weights(self) -> np.ndarray:
        """``(N,)`` normalised log-weights (copy)."""
        return self.predictor.log_weights.copy()

    @property
    def grid(self) -> LogOddsGrid | None:
        """The map (None before the first scan)."""
        return self.mapper.grid

    @property
    def field(self) -> GridLikelihoodField | None:
        """The correlation stage's likelihood field of the map (None before the first scan)."""
        return self.corrector.field

    @property
    def pose(self) -> np.ndarray | None:
        """Last corrected pose ``(3,)`` (None before the first scan)."""
        return None if self._pose is None else self._pose.copy()

    @property
    def num_resamples(self) -> int:
        return self.corrector.num_resamples

    def process_odometry_scan(
        self,
        stamp: float,
        odom_pose: np.ndarray,
        ranges: np.ndarray,
        angles: np.ndarray,
        range_min: float = 0.0,
        range_max: float = math.inf,
    ) -> np.ndarray:
        """Process one scan with the odometry pose at its time.

        Parameters
        ----------
        stamp : float
            Scan time (s); informational (the loop is driven by odometry displacement).
        odom_pose : numpy.ndarray
            ``(3,)`` odometry pose of the robot at the scan time (odometry frame).
        ranges, angles : numpy.ndarray
            ``(B,)`` ranges (m; inf/NaN allowed) and beam angles in the sensor frame (rad).
        range_min, range_max : float
            Sensor limits (m); beams above ``range_max`` are "no return".

        Returns
        -------
        numpy.ndarray
            ``(3,)`` pose of the robot in the map frame: the best particle on corrected scans,
            last corrected pose (+) odometry since then otherwise.
        """
        first = self._pose is None
        key = float(self.scans_processed)
        self.scans_processed += 1
        update, delta = self.predictor.predict(odom_pose)
        if not update:
            return compose(self._pose, delta)
        c = self.corrector.correct(
            self.predictor.particles,
            self.predictor.log_weights,
            ranges,
            angles,
            range_min,
            range_max,
            odom_pose=odom_pose,
        )
        self.predictor.set_corrected(c.particles, c.log_weights)
        patch = self.mapper.integrate(
            c.pose, ranges, angles, range_min, range_max, key=key, odom=odom_pose, odom_scale=c.odom_scale
        )
        self.corrector.apply_patch(patch)
        self._pose = c.pose.copy()
        self.num_updates += 0 if first else 1
        return c.pose.copy()

    def trajectory(self, keys: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """The run's poses (``poses`` ``(N, 3)`` as returned, at ``keys``: the scan indices of
        :meth:`process_odometry_scan`, or the stamps in seconds of the stream) in the final frame
        of the loop closure (the map re-rendered if needed); as they are without it."""
        self.mapper.finish()
        return self.mapper.corrected(keys, poses)

    # ------------------------------------------------------------------ input streams
    def open_stream(
        self,
        odometry_source: str = "odom",
        odom_sync: str = "interpolate",
        wheels_cfg: WheelsConfig | None = None,
        gyro: bool = False,
        time_gap_s: float = 60.0,
    ) -> PredictorScheduler:
        """Take the inputs as streams, as the predictor node does (same parameters: the
        node's ``odometry_source``, ``odom_sync``, ``wheels.*``, a gyro (``fog_format`` not
        'none') and ``time_gap_s``). All input is here (no live waiting: ``odom_wait_scans``
        and the clock check are off, as under `pf-slam run`). The poses collect in
        :attr:`stream_poses`; the fault counts are ``scheduler.faults()``."""
        self.scheduler = PredictorScheduler(
            self.predictor.filter_cfg,
            self.predictor.motion_cfg,
            odometry_source,
            odom_sync,
            wheels_cfg,
            gyro=gyro,
            odom_wait_scans=0,
            stamp_offset_s=0.0,
            time_gap_s=time_gap_s,
            stage=self.predictor,
            laser_cfg=self.mapper.laser_cfg,
        )
        self.stream_poses = []
        self._counts = {"scans": 0, "odometry": 0, "gyro": 0, "mount": 0}
        return self.scheduler

    def _run(self, actions: list) -> None:
        """Carry out the scheduler's actions; a correction is run at once and answered."""
        work = list(actions)
        while work:
            a = work.pop(0)
            if isinstance(a, PublishPose):
                self.stream_poses.append((int(a.stamp), np.asarray(a.pose, dtype=np.float64).copy()))
            elif isinstance(a, SendCorrection):
                ranges, angles, range_min, range_max = a.payload
                first = self._pose is None
                c = self.corrector.correct(
                    a.particles,
                    a.log_weights,
                    ranges,
                    angles,
                    range_min,
                    range_max,
                    extrinsic=a.mount,
                    odom_pose=a.odom,
                )
                patch = self.mapper.integrate(
                    c.pose,
                    ranges,
                    angles,
                    range_min,
                    range_max,
                    extrinsic=a.mount,
                    key=a.stamp / 1e9,
                    odom=a.odom,
                    odom_scale=c.odom_scale,
                )
                self.corrector.apply_patch(patch)
                self._pose = c.pose.copy()
                self.num_updates += 0 if first else 1
                work[:0] = self.scheduler.corrected(a.index, c.particles, c.log_weights, c.pose, a.stamp)

    def add_scan(
        self,
        stamp_ns: int,
        ranges: np.ndarray,
        angle_min: float,
        angle_max: float,
        angle_increment: float,
        range_min: float = 0.0,
        range_max: float = math.inf,
    ) -> None:
        """A scan as a LaserScan carries it (ranges (B,), the angles and the range limits):
        checked (:class:`~pf_slam_nodes.core.faults.ScanChecks`), then posed in its turn."""
        s = self.scheduler
        ranges = np.asarray(ranges, dtype=np.float64)
        usable, faults = s.checks.check(stamp_ns, ranges, angle_min, angle_max, angle_increment, range_min, range_max)
        angles = angle_min + angle_increment * np.arange(ranges.size, dtype=np.float64)
        self._counts["scans"] += 1
        geometry = (ranges, angles, float(range_min), float(range_max))
        self._run(s.add_scan(int(stamp_ns), usable, geometry, faults, geometry=geometry))

    def add_mount(self, stamp_ns: int, quat_xyzw, translation) -> None:
        """A sample of the moving mount (``base -> laser.dynamic_frame``, e.g. THOR's base_link ->
        head on /tf); None: a /tf message without it."""
        self._counts["mount"] += 1
        self._run(self.scheduler.add_mount(int(stamp_ns), quat_xyzw, translation))

    def add_odometry(self, stamp_ns: int, pose: np.ndarray) -> None:
        """An odometry pose ``(x, y, yaw)`` (odometry_source 'odom')."""
        self._counts["odometry"] += 1
        self._run(self.scheduler.add_odometry(int(stamp_ns), np.asarray(pose, dtype=np.float64)))

    def add_encoders(self, stamp_ns: int, wheels_rad: np.ndarray | None) -> None:
        """Cumulative (left, right) wheel angles (rad), e.g. a JointState's first two positions
        (odometry_source 'encoders'); None: an unreadable message (counted)."""
        self._counts["odometry"] += 1
        self._run(
            self.scheduler.add_encoders(
                int(stamp_ns), None if wheels_rad is None else np.asarray(wheels_rad, dtype=np.float64)
            )
        )

    def add_gyro(self, stamps_ns: np.ndarray | None, dyaw_rad: np.ndarray | None) -> None:
        """One gyro message: yaw increments (rad) at their stamps, e.g. a FogBatch."""
        self._counts["gyro"] += 1
        self._run(self.scheduler.add_gyro(stamps_ns, dyaw_rad))

    def add_imu(self, stamp_ns: int, yaw_rate: float) -> None:
        """A yaw rate (rad/s, an Imu's angular_velocity.z)."""
        self._counts["gyro"] += 1
        self._run(self.scheduler.add_imu(int(stamp_ns), float(yaw_rate)))

    def end_of_stream(self) -> list[tuple[int, np.ndarray]]:
        """No more input: the scans still waiting are posed. Returns :attr:`stream_poses`."""
        c = self._counts
        self._run(self.scheduler.end_of_stream(c["scans"], c["odometry"], c["gyro"], c["mount"]))
        return self.stream_poses
