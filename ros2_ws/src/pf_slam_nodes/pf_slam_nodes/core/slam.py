"""ROS-free reference loop: the graph's stages chained in one call per scan.

:class:`ParticleFilterSlam` runs exactly what the predictor, correlator and mapper nodes run
(the same :mod:`~pf_slam_nodes.core.stages` objects, the same map patches between mapping and
correlation, the same random streams), so for the same seed it produces the same trajectory as
the node graph, bit for bit. Used by tests, tuning and the stage profile of the benchmarks.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from .config import (CorrelationConfig, FilterConfig, GridConfig, LaserConfig, OdometryMotionConfig,
                     ResampleConfig)
from .correlation import GridLikelihoodField
from .grid import LogOddsGrid
from .geometry import compose
from .stages import CorrectionStage, MappingStage, PredictionStage, STAGE_STEPS, stage_seconds

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

    def __init__(self, filter_cfg: FilterConfig, motion_cfg: OdometryMotionConfig, grid_cfg: GridConfig,
                 corr_cfg: CorrelationConfig, resample_cfg: ResampleConfig,
                 laser_cfg: Optional[LaserConfig] = None) -> None:
        self.predictor = PredictionStage(filter_cfg, motion_cfg)
        self.corrector = CorrectionStage(filter_cfg, grid_cfg, corr_cfg, resample_cfg, laser_cfg)
        self.mapper = MappingStage(filter_cfg, grid_cfg, laser_cfg)
        self.num_updates = 0  # corrections after the first scan
        self._pose: Optional[np.ndarray] = None

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
    def grid(self) -> Optional[LogOddsGrid]:
        """The map (None before the first scan)."""
        return self.mapper.grid

    @property
    def field(self) -> Optional[GridLikelihoodField]:
        """The correlation stage's likelihood field of the map (None before the first scan)."""
        return self.corrector.field

    @property
    def pose(self) -> Optional[np.ndarray]:
        """Last corrected pose ``(3,)`` (None before the first scan)."""
        return None if self._pose is None else self._pose.copy()

    @property
    def num_resamples(self) -> int:
        return self.corrector.num_resamples

    def process_odometry_scan(self, stamp: float, odom_pose: np.ndarray, ranges: np.ndarray,
                              angles: np.ndarray, range_min: float = 0.0,
                              range_max: float = math.inf) -> np.ndarray:
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
        update, delta = self.predictor.predict(odom_pose)
        if not update:
            return compose(self._pose, delta)
        c = self.corrector.correct(self.predictor.particles, self.predictor.log_weights, ranges, angles,
                                   range_min, range_max)
        self.predictor.set_corrected(c.particles, c.log_weights)
        patch = self.mapper.integrate(c.pose, ranges, angles, range_min, range_max)
        self.corrector.apply_patch(patch)
        self._pose = c.pose.copy()
        self.num_updates += 0 if first else 1
        return c.pose.copy()
