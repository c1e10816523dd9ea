"""Configuration dataclasses of the pf_slam algorithm core.

One frozen dataclass per stage. Every config validates itself in ``__post_init__`` and raises
``ValueError`` naming the parameter and the bad value. ``from_dict`` builds a config from a plain
mapping (e.g. ROS parameters) and rejects unknown keys.

Defaults are tuned for the CARMEN indoor logs (Intel Research Lab, MIT CSAIL): 0.05 m grid,
180/361-beam SICK scanners, odometry increments between scans.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .configbase import _check_finite, _check_int, _check_nonneg, _check_pos, _check_unit, _ConfigBase
from .loopconfig import LoopClosureConfig

__all__ = [
    "CorrelationConfig",
    "DiffDriveConfig",
    "FilterConfig",
    "GridConfig",
    "LaserConfig",
    "LocalizationConfig",
    "LoopClosureConfig",
    "OdometryMotionConfig",
    "ResampleConfig",
    "WheelsConfig",
]


@dataclasses.dataclass(frozen=True)
class OdometryMotionConfig(_ConfigBase):
    """Gaussian noise on an odometry increment ``delta = (dx, dy, dtheta)`` (robot frame).

    The increment is perturbed component-wise in the frame of the previous pose, then composed:
    ``dx' = dx + N(0, s_xy)``, ``dy' = dy + N(0, s_xy)``, ``dtheta' = dtheta + N(0, s_th)`` with
    standard deviations (GMapping srr/srt/str/stt style, linear in the motion)

    ``s_xy = sigma_xy_per_m * |t| + sigma_xy_per_rad * |dtheta| + sigma_xy_min_m``

    ``s_th = sigma_theta_per_m * |t| + sigma_theta_per_rad * |dtheta| + sigma_theta_min_rad``

    where ``t = hypot(dx, dy)``. All zeros gives the exact composition.

    Attributes
    ----------
    sigma_xy_per_m : float
        Translation noise std per metre travelled (m/m).
    sigma_xy_per_rad : float
        Translation noise std per radian turned (m/rad).
    sigma_theta_per_m : float
        Rotation noise std per metre travelled (rad/m).
    sigma_theta_per_rad : float
        Rotation noise std per radian turned (rad/rad).
    sigma_xy_min_m : float
        Constant translation noise std added to every prediction (m).
    sigma_theta_min_rad : float
        Constant rotation noise std added to every prediction (rad).
    gyro_noise_scale : float
        Wheel encoders with a gyro calibrated at rest (``wheels.gyro_rest_bias``) only: once a
        standstill has calibrated the gyro, ``sigma_theta_per_m * |t| + sigma_theta_min_rad`` is
        replaced by this factor times the gyro's own heading uncertainty over the prediction's
        interval ``dt``, ``sqrt(q dt + (s_b dt)^2)``, both measured at rest: ``q`` the gyro's noise
        density (rad^2/s, the spread of its increments at rest) and ``s_b`` the bias estimate's std
        (``sqrt(q / rest time)``). Before any standstill the terms above apply (they must then
        follow the whole bias). 0 (default): off.
    """

    sigma_xy_per_m: float = 0.05
    sigma_xy_per_rad: float = 0.02
    sigma_theta_per_m: float = 0.02
    sigma_theta_per_rad: float = 0.05
    sigma_xy_min_m: float = 0.005
    sigma_theta_min_rad: float = 0.002
    gyro_noise_scale: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            _check_nonneg(f.name, getattr(self, f.name))


@dataclasses.dataclass(frozen=True)
class DiffDriveConfig(_ConfigBase):
    """Gaussian noise of the differential-drive (wheel encoder [+ gyro]) motion model.

    Per step, ``distance' = distance + N(0, sigma_v * |distance| + sigma_v_min_m)`` and
    ``dyaw' = dyaw + N(0, sigma_omega * |dyaw| + sigma_omega_per_m * |distance| + sigma_omega_min_rad)``.

    Attributes
    ----------
    sigma_v : float
        Distance noise std per metre travelled (m/m, dimensionless).
    sigma_omega : float
        Yaw noise std per radian turned (rad/rad).
    sigma_omega_per_m : float
        Yaw noise std per metre travelled (rad/m).
    sigma_v_min_m : float
        Constant distance noise std per step (m).
    sigma_omega_min_rad : float
        Constant yaw noise std per step (rad).
    """

    sigma_v: float = 0.05
    sigma_omega: float = 0.05
    sigma_omega_per_m: float = 0.02
    sigma_v_min_m: float = 0.0
    sigma_omega_min_rad: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            _check_nonneg(f.name, getattr(self, f.name))


@dataclasses.dataclass(frozen=True)
class WheelsConfig(_ConfigBase):
    """Wheel encoders (+ gyro) as odometry (predictor, ``odometry_source: encoders``).

    Cumulative wheel angles (rad) become a differential-drive pose
    (:class:`~pf_slam_nodes.core.odometry.WheelOdometryIntegrator`); with a gyro its yaw
    increments replace the wheels' yaw difference.

    Attributes
    ----------
    left_diameter_m : float
        Left wheel diameter, odometry_source encoders (m).
    right_diameter_m : float
        Right wheel diameter, odometry_source encoders (m).
    base_m : float
        Distance between the wheels, odometry_source encoders (m).
    max_speed_mps : float
        A wheel step faster than this is an encoder counter jump: its motion is discarded and
        counted (m/s; .inf: no check).
    gyro_rest_bias : bool
        With a gyro: steps where neither wheel counter moved have zero yaw, and rests of
        wheels.rest_min_s or longer calibrate the gyro's yaw bias (standstill calibration).
    rest_min_s : float
        wheels.gyro_rest_bias: shortest rest (no counter moving) that calibrates the gyro bias (s).
    """

    left_diameter_m: float = 0.154
    right_diameter_m: float = 0.154
    base_m: float = 0.33
    max_speed_mps: float = 50.0
    gyro_rest_bias: bool = True
    rest_min_s: float = 0.5

    def __post_init__(self) -> None:
        _check_pos("left_diameter_m", self.left_diameter_m)
        _check_pos("right_diameter_m", self.right_diameter_m)
        _check_pos("base_m", self.base_m)
        v = self.max_speed_mps
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:  # inf: no check
            raise ValueError(f"max_speed_mps must be > 0, got {v!r}")
        if not isinstance(self.gyro_rest_bias, bool):
            raise ValueError(f"gyro_rest_bias must be a bool, got {self.gyro_rest_bias!r}")
        _check_pos("rest_min_s", self.rest_min_s)


@dataclasses.dataclass(frozen=True)
class GridConfig(_ConfigBase):
    """Log-odds occupancy grid.

    Attributes
    ----------
    resolution_m : float
        Cell edge length (m).
    size_x_m, size_y_m : float
        Initial map extent along x (columns) and y (rows) (m). The grid grows by whole tiles
        (``grid.TILE_CELLS``) wherever a scan reaches beyond it, up to ``max_cells``.
    origin_x_m, origin_y_m : float or None
        World position of the corner of cell (0, 0) (ROS ``map.info.origin``). ``None`` (both)
        centres the grid on the first pose.
    log_odds_hit : float
        Increment for the endpoint cell of a beam.
    log_odds_miss : float
        Increment (negative) for cells a beam passes through. -0.2 against a hit of 0.85: a cell
        stays an obstacle while it returns about one beam in five of those that reach it (as
        GMapping's hit counts and Cartographer's 0.55 / 0.49 odds do): walls and pillars grazed
        by later beams stay (docs/architecture.md, "Walls that stay").
    clip_min, clip_max : float
        Log-odds clamp.
    range_max_usable_m : float
        Beams longer than this mark free space up to this range, no hit. A beam without return
        (``+inf``) marks free space up to this range or the scan's ``range_max``, the shorter:
        the sensor saw nothing within its reach and says nothing beyond it.
    min_return_fraction : float
        A scan with fewer than this fraction of its beams returning within
        ``range_max_usable_m`` (the map) or ``correlation.range_max_m`` (the match) has that
        range raised, up to the sensor's ``range_max``, until this fraction returns within it
        (:func:`~.scan.sparse_scan_range`): open outdoor spaces, where most returns are far.
        The indoor profile's 0.25 changes no scan of the CARMEN logs. 0 (default): fixed ranges.
    graze_margin_m : float
        A beam grazing a surface (incidence ``a`` from the normal) leaves the last
        ``floor(1/sin(a)) - 1`` cells before its end unchanged, at most this length (m). 0: off.
    surface_fill_m : float
        The segment between two neighbouring beams' ends is marked as hit cells too when it is
        at most this long (m) and both ends lie on one smooth surface (each end collinear with
        its other neighbour within 5 degrees: no range jump at an edge, no clutter): walls
        mapped as lines, not as the dots the beams hit, which pulled the next scan's points back
        to the last scan's dots (the matches lagged along corridors). 0 (default): hits at the
        beams' ends only. The indoor profile's 1.0: docs/architecture.md, "Walls as lines".
    peak_ratio : float
        The correlator matches only the occupied cells holding at least this fraction of the beam
        ends of their 4-neighbour with the most (``/map`` unchanged). 0 (default): every occupied
        cell (docs/architecture.md, "Walls at their peak": measured, off).
    free_stop_cells : int
        The free trace of a beam that ends in a hit stops this many cells before the cell in
        front of its end. 0 (default): it clears up to that cell, so noisy ends leave a wall's
        far side occupied and its near side cleared, and matches run ahead. The indoor
        profile's 1: docs/architecture.md, "Walls on both sides of the noise".
    max_cells : int
        Bound on the grown grid (cells, rows x columns; the mapper's grid and the correlator's
        likelihood field take ~19 bytes per cell together). A scan reaching beyond what this
        allows is integrated only where it fits (counted: ``map_beyond_bound``). A value at or
        below the initial size keeps the grid fixed.
    """

    resolution_m: float = 0.05
    size_x_m: float = 100.0
    size_y_m: float = 100.0
    origin_x_m: float | None = None
    origin_y_m: float | None = None
    log_odds_hit: float = 0.85
    log_odds_miss: float = -0.2
    clip_min: float = -5.0
    clip_max: float = 5.0
    range_max_usable_m: float = 20.0
    min_return_fraction: float = 0.0
    max_cells: int = 100_000_000
    graze_margin_m: float = 0.0
    surface_fill_m: float = 0.0
    peak_ratio: float = 0.0
    free_stop_cells: int = 0

    def __post_init__(self) -> None:
        _check_pos("resolution_m", self.resolution_m)
        _check_int("max_cells", self.max_cells, 0)
        _check_pos("size_x_m", self.size_x_m)
        _check_pos("size_y_m", self.size_y_m)
        if (self.origin_x_m is None) != (self.origin_y_m is None):
            raise ValueError(
                f"origin_x_m and origin_y_m must both be set or both None, got "
                f"origin_x_m={self.origin_x_m!r}, origin_y_m={self.origin_y_m!r}"
            )
        if self.origin_x_m is not None:
            _check_finite("origin_x_m", self.origin_x_m)
            _check_finite("origin_y_m", self.origin_y_m)
        for name, sign in (("log_odds_hit", 1), ("log_odds_miss", -1), ("clip_min", -1), ("clip_max", 1)):
            value = getattr(self, name)
            _check_finite(name, value)
            if value * sign <= 0:
                raise ValueError(f"{name} must be {'>' if sign > 0 else '<'} 0, got {value!r}")
        _check_pos("range_max_usable_m", self.range_max_usable_m)
        _check_unit("min_return_fraction", self.min_return_fraction)
        _check_nonneg("graze_margin_m", self.graze_margin_m)
        _check_nonneg("surface_fill_m", self.surface_fill_m)
        _check_unit("peak_ratio", self.peak_ratio)
        _check_int("free_stop_cells", self.free_stop_cells, 0)
        if self.size_x_m / self.resolution_m > 50000 or self.size_y_m / self.resolution_m > 50000:
            raise ValueError(
                f"size_x_m/size_y_m too large for resolution_m={self.resolution_m!r}: "
                f"size_x_m={self.size_x_m!r}, size_y_m={self.size_y_m!r} (max 50000 cells per axis)"
            )


@dataclasses.dataclass(frozen=True)
class CorrelationConfig(_ConfigBase):
    """Scan-to-map correlation (per-particle window search + Gauss-Newton refinement).

    The search evaluates every particle at ``(2*round(search_x_m/step_xy_m)+1) *
    (2*round(search_y_m/step_xy_m)+1) * (2*round(search_yaw_rad/step_yaw_rad)+1)`` candidate poses
    with nearest-cell lookups in the likelihood field, keeps the best, then refines it with
    ``refine_iterations`` Gauss-Newton steps on the bilinearly interpolated distance field.

    Attributes
    ----------
    search_x_m, search_y_m : float
        Half-widths of the translation window (m). 0 disables the search along that axis.
    search_yaw_rad : float
        Half-width of the rotation window (rad). 0 disables it.
    step_xy_m : float
        Translation step (m); rounded to a whole number of grid cells (at least 1) at search time.
    step_yaw_rad : float
        Rotation step (rad). 0.05 (the refinement's largest rotation step) measured as accurate
        as 0.025 on intel_910 over seeds 0-4 at half the search cost.
    beam_stride : int
        Use every ``beam_stride``-th beam for the window search. 2 (vs 4) picks the right
        candidate more often: intel_910 relations error 0.030 m mean / 0.038 m worst over seeds
        0-4 (0.044 / 0.070 with 4) and intel_2726 0.022 m / 0.024 m over seeds 0-2 (0.25 m:
        two loop-closure relations failed with 4).
    refine_beam_stride : int
        Use every ``refine_beam_stride``-th beam for the refinement and the final score.
    range_max_m : float
        Beams longer than this are not used for correlation (m).
    sigma_m : float
        Std of the likelihood field: ``log p = -d^2 / (2 sigma^2)``, ``d`` = distance to the
        nearest occupied cell (m).
    max_distance_m : float
        Distances are clamped at this value (robustness to unmatched beams) (m).
    occupied_threshold : int
        Occupancy value (0..100) at or above which a cell counts as an obstacle.
    temperature : float
        Softmax temperature: ``log_w += log_score / temperature``.
    refine_iterations : int
        Gauss-Newton iterations after the window search (0 disables the refinement).
    refine_residual : str
        ``'likelihood'``: residual ``1 - exp(-d^2 / (2 sigma^2))`` (smooth, default);
        ``'distance'``: residual ``d``.
    refine_prior_xy_m, refine_prior_yaw_rad : float
        Motion prior inside the refinement: its least-squares cost gains ``(dx^2 + dy^2) /
        refine_prior_xy_m^2 + dyaw^2 / refine_prior_yaw_rad^2`` (the offset from the particle's
        predicted pose), so each direction moves as far as the scan's own curvature along it
        outweighs the prior: across a corridor the walls decide, along a bare one the odometry
        does, and between the two the balance is smooth. Only the refined pose changes; the
        particle's weight update is its scan score as without the prior. 0 disables that axis;
        both 0 (default): off (docs/architecture.md, "A corridor that says nothing along it").
    refine_prior_shape : str
        ``'isotropic'`` (default): the x, y prior above holds every direction alike. ``'weak'``:
        it holds only the direction the match's points do not constrain, as much as they do not
        -- per particle, from ``S = sum a g g^T`` over its points' obstacle-distance gradients
        ``g`` at the window's best pose (``a = exp(-d^2 / 2 sigma^2)``: points on the map count),
        the prior's weight along ``S``'s weak eigenvector is ``(1 - weak / strong)`` times
        ``min(1, strong / (MATCHED_SHARE * points))`` and 0 along the strong one. Along a bare
        corridor that is nearly the full prior; in a room, or in open space where the scan lies on
        little of the map, nearly none, so the scan corrects the pose as without a prior.
    weak_score : bool
        With ``refine_prior_shape='weak'``: each particle's weight update is its scan score at its
        refined pose moved along its weak direction, by the prior's fraction ``(1 - weak /
        strong) * min(1, strong / (MATCHED_SHARE * points))`` of the way, to the set's mean
        there. Along a bare corridor the particles then weigh the same whatever their offset
        along it, so the weights cannot favour the particles the end of the mapped wall pulls
        back. Default False: measured, not the profile's (docs/architecture.md, "A corridor that
        says nothing along it").
    precision : str
        ``'float64'`` (default) or ``'float32'``: the arithmetic of the refinement's and the
        score's bilinear lookups. float32 is ~25 % faster; on the car's 0.2 m grid it is as
        accurate, on the indoor 0.05 m logs it is not (intel_910 segment test), so only
        ``kaist.yaml`` sets it.
    degenerate_ratio : float
        A match whose weak direction (in x, y) is constrained by less than this fraction of
        its points -- the smaller eigenvalue of ``sum g g^T`` over the points' obstacle-distance
        gradients ``g`` at the matched pose, divided by their number -- while its strong one
        holds at least a quarter of them (``correlation.MATCHED_SHARE``) moves the particle only
        along the strong direction: along a bare corridor the walls say
        nothing about the position along it, and what little the scan seems to say (the end of
        the wall mapped so far, which moves with the estimate) pulled the matches back until the
        robot stood still in the map. 0 (default): off (docs/architecture.md, "A corridor that
        says nothing along it").
    weigh_graze_span_m : float
        The returns that sample a straight surface more than this far apart at a grazing angle
        (> 70 deg from its normal; :func:`~.scan.grazing_samples`) weigh no particle; they
        still move the poses. Along a bare corridor these are the far returns from the side
        walls: the map keeps them only as dots that later rays graze away, so where its walls end
        moves with the estimate, and the particles behind the estimate put those returns on the
        walls and were weighed up, scan after scan. 0 (default): off.
    weigh_range_margin_m : float
        The returns within this distance of the correlation range's end (``range_max_m``, or a
        sparse scan's own cut) weigh no particle; they still move the poses. They land beyond
        where the earlier scans, which reached as far from a little way back, mapped the walls.
        0 (default): off.
    skip_unknown : bool
        Drop the scan points that fall on never-observed map cells (occupancy -1) at the
        highest-weighted predicted particle before matching. Such points carry no information,
        but they score better once shifted onto the known end of a wall, which makes the matches
        slide back along corridors and streets while the sensor keeps seeing new wall ahead
        (the car's tilted lidar). Default False (the CARMEN settings).
    prior_sigma_xy_m, prior_sigma_yaw_rad : float
        Motion prior of the match: a candidate shifted by ``(dx, dy, dyaw)`` from the particle's
        predicted pose scores ``log_score - (dx^2 + dy^2) / (2 prior_sigma_xy_m^2) - dyaw^2 /
        (2 prior_sigma_yaw_rad^2)`` in the window search, and after the refinement the particle
        keeps the better (by that penalised score) of its refined and its predicted pose; the
        penalised score is its weight update. So a shift must buy its cost in scan likelihood,
        and weakly observable shifts (along a street) stay at the odometry. 0 disables the term
        of that axis; both 0 (default): no prior, the CARMEN behaviour.
    gain_xy, gain_yaw : float
        Fraction in ``[0, 1]`` of its match's shift that a particle takes: ``pose = predicted +
        gain * (matched - predicted)`` per axis (translation, yaw), a fixed-gain fusion of the
        odometry and the match; the particle's weight update is its score at that pose. 1
        (default) moves it onto the match (the CARMEN behaviour). Below 1 for odometry that is
        better between corrections than a match against the map built moments ago (the car's
        calibrated wheels and FOG): the match then bounds the drift without adding its noise.
    odom_scale : bool
        Estimate the odometry's translation scale (a wheel-diameter calibration error) online
        and apply it to the predicted sets (:class:`~.odometry.OdomScaleEstimator`): each
        correction's scan is matched against the scan ``odom_scale_baseline_m`` of odometry back
        (core/scanpair.py; not against the map, which follows the odometry's scale); the estimate
        is the ratio of measured to odometry travel over the last ``odom_scale_window_m``. Needs
        the odometry pose with each predicted set. Default False.
    odom_scale_window_m : float
        correlation.odom_scale: travel over which the measurements are averaged (exponential
        forgetting, m).
    odom_scale_ramp_m : float
        correlation.odom_scale: the estimate's departure from 1 is phased in over this much travel
        measured by the scan pairs (m): applied in proportion to it, in full from here on; 0: at once.
    odom_scale_max : float
        correlation.odom_scale: the estimate is clamped to ``1 +- odom_scale_max``.
    odom_scale_baseline_m : float
        correlation.odom_scale: odometry travel between the two scans of a pair (m).
    odom_scale_min_curvature : float
        correlation.odom_scale: a pair counts only where its cost along the street has a clear
        minimum: second difference above this (sum of squared match residuals per m^2).
    shadow_jump_m : float
        A beam with a neighbour (within ``shadow_beams`` beams) closer by more than this (m) moves
        no pose (search, refinement) but is scored and mapped: it lies where the background comes
        out from behind an occluding edge, a boundary that moves with the viewpoint (and on a real
        laser, mixed returns). 0 disables the rule.
    shadow_beams : int
        correlation.shadow_jump_m: beams on each side of a beam that are its neighbours.
    shadow_angle_rad : float
        correlation.shadow_jump_m: the neighbours are also every beam within this angle (rad) on
        each side, ``floor(shadow_angle_rad / beam spacing)`` beams if that is more than
        ``shadow_beams``: an occluding edge shadows the same angle on a dense scanner (0.25 deg:
        3 beams at 0.0131) as one beam does on a 0.5 or 1 deg one. 0 (default): ``shadow_beams``.
    recover_search_m : float
        A filter that slid off the map (along a corridor, past the reach of the window) finds
        its way back (:class:`~.recovery.Recovery`): after each correction whose best fit is
        worse than ``-recover_min_gain``, the best particle is searched again in a window of
        +-``recover_search_m`` (capped by the likelihood field's padding: 0.75 m on a 0.05 m
        grid) and +-``recover_search_yaw_rad``; when that finds a fit better by at least
        ``recover_min_gain`` and by half (score >= half the local one) on
        ``recover_corrections`` consecutive corrections, with shifts that agree within 0.1 (m,
        m, rad), the predicted set is shifted by it and corrected again. One correction alone
        never moves the set: while the robot explores, a scan often fits the map better a
        little way back (its new wall is not mapped yet), but not the same way scan after scan.
        0 (default): off; the indoor profile sets 0.7.
    recover_search_yaw_rad : float
        correlation.recover_search_m: the wide search's yaw half-width (rad).
    recover_corrections : int
        correlation.recover_search_m: consecutive corrections whose wide searches must agree.
    recover_min_gain : float
        correlation.recover_search_m: a correction is searched wide when its best fit (summed
        log-likelihood) is below minus this, and a shift must improve that fit by at least this.
    """

    search_x_m: float = 0.2
    search_y_m: float = 0.2
    search_yaw_rad: float = 0.2
    step_xy_m: float = 0.1
    step_yaw_rad: float = 0.05
    beam_stride: int = 2
    refine_beam_stride: int = 1
    range_max_m: float = 20.0
    sigma_m: float = 0.05
    max_distance_m: float = 0.3
    occupied_threshold: int = 65
    temperature: float = 20.0
    refine_iterations: int = 30
    refine_residual: str = "likelihood"
    refine_prior_xy_m: float = 0.0
    refine_prior_yaw_rad: float = 0.0
    refine_prior_shape: str = "isotropic"
    weak_score: bool = False
    precision: str = "float64"
    skip_unknown: bool = False
    prior_sigma_xy_m: float = 0.0
    prior_sigma_yaw_rad: float = 0.0
    gain_xy: float = 1.0
    gain_yaw: float = 1.0
    odom_scale: bool = False
    odom_scale_window_m: float = 1000.0
    odom_scale_ramp_m: float = 0.0
    odom_scale_max: float = 0.03
    odom_scale_baseline_m: float = 10.0
    odom_scale_min_curvature: float = 1000.0
    shadow_jump_m: float = 0.0
    shadow_beams: int = 1
    shadow_angle_rad: float = 0.0
    recover_search_m: float = 0.0
    recover_search_yaw_rad: float = 0.2
    recover_corrections: int = 3
    recover_min_gain: float = 15.0
    degenerate_ratio: float = 0.0
    weigh_graze_span_m: float = 0.0
    weigh_range_margin_m: float = 0.0

    def __post_init__(self) -> None:
        _check_int("shadow_beams", self.shadow_beams, 1)
        _check_unit("degenerate_ratio", self.degenerate_ratio)
        _check_nonneg("refine_prior_xy_m", self.refine_prior_xy_m)
        _check_nonneg("refine_prior_yaw_rad", self.refine_prior_yaw_rad)
        _check_nonneg("weigh_graze_span_m", self.weigh_graze_span_m)
        _check_nonneg("weigh_range_margin_m", self.weigh_range_margin_m)
        _check_int("recover_corrections", self.recover_corrections, 1)
        _check_pos("recover_min_gain", self.recover_min_gain)
        if not isinstance(self.odom_scale, bool):
            raise ValueError(f"odom_scale must be a bool, got {self.odom_scale!r}")
        _check_pos("odom_scale_window_m", self.odom_scale_window_m)
        _check_nonneg("odom_scale_ramp_m", self.odom_scale_ramp_m)
        _check_nonneg("odom_scale_max", self.odom_scale_max)
        _check_pos("odom_scale_baseline_m", self.odom_scale_baseline_m)
        _check_nonneg("odom_scale_min_curvature", self.odom_scale_min_curvature)
        for name in ("gain_xy", "gain_yaw"):
            _check_unit(name, getattr(self, name))
        if not isinstance(self.skip_unknown, bool):
            raise ValueError(f"skip_unknown must be a bool, got {self.skip_unknown!r}")
        for name in (
            "prior_sigma_xy_m",
            "prior_sigma_yaw_rad",
            "shadow_jump_m",
            "shadow_angle_rad",
            "search_x_m",
            "search_y_m",
            "recover_search_m",
            "recover_search_yaw_rad",
        ):
            _check_nonneg(name, getattr(self, name))
        _check_nonneg("search_yaw_rad", self.search_yaw_rad)
        _check_pos("step_xy_m", self.step_xy_m)
        _check_pos("step_yaw_rad", self.step_yaw_rad)
        _check_int("beam_stride", self.beam_stride, 1)
        _check_int("refine_beam_stride", self.refine_beam_stride, 1)
        _check_pos("range_max_m", self.range_max_m)
        _check_pos("sigma_m", self.sigma_m)
        _check_pos("max_distance_m", self.max_distance_m)
        _check_int("occupied_threshold", self.occupied_threshold, 1)
        if self.occupied_threshold > 100:
            raise ValueError(f"occupied_threshold must be <= 100, got {self.occupied_threshold!r}")
        _check_pos("temperature", self.temperature)
        _check_int("refine_iterations", self.refine_iterations, 0)
        if self.refine_prior_shape not in ("isotropic", "weak"):
            raise ValueError(f"refine_prior_shape must be 'isotropic' or 'weak', got {self.refine_prior_shape!r}")
        if not isinstance(self.weak_score, bool):
            raise ValueError(f"weak_score must be a bool, got {self.weak_score!r}")
        if self.weak_score and (self.refine_prior_shape != "weak" or self.refine_prior_xy_m <= 0):
            raise ValueError("weak_score needs refine_prior_shape 'weak' and a refine_prior_xy_m above 0")
        if self.refine_residual not in ("likelihood", "distance"):
            raise ValueError(f"refine_residual must be 'likelihood' or 'distance', got {self.refine_residual!r}")
        if self.precision not in ("float64", "float32"):
            raise ValueError(f"precision must be 'float64' or 'float32', got {self.precision!r}")
        for name, value, step in (
            ("search_x_m", self.search_x_m, self.step_xy_m),
            ("search_y_m", self.search_y_m, self.step_xy_m),
            ("search_yaw_rad", self.search_yaw_rad, self.step_yaw_rad),
        ):
            if value / step > 200:
                raise ValueError(f"{name}={value!r} is more than 200 steps of {step!r}")


@dataclasses.dataclass(frozen=True)
class ResampleConfig(_ConfigBase):
    """Resampling policy.

    Attributes
    ----------
    neff_threshold : float
        Resample when ``N_eff < neff_threshold * N``; in (0, 1]. 1 resamples at every update.
    method : str
        ``'stratified'`` or ``'systematic'``.
    """

    neff_threshold: float = 0.5
    method: str = "stratified"

    def __post_init__(self) -> None:
        _check_finite("neff_threshold", self.neff_threshold)
        if not 0.0 < self.neff_threshold <= 1.0:
            raise ValueError(f"neff_threshold must be in (0, 1], got {self.neff_threshold!r}")
        if self.method not in ("stratified", "systematic"):
            raise ValueError(f"method must be 'stratified' or 'systematic', got {self.method!r}")


@dataclasses.dataclass(frozen=True)
class FilterConfig(_ConfigBase):
    """Particle filter loop.

    Attributes
    ----------
    num_particles : int
        Number of particles N.
    seed : int
        Seed of the filter's ``np.random.Generator`` (determinism).
    min_travel_m : float
        Run a correction only after the odometry moved at least this far since the last one (m)...
    min_rotation_rad : float
        ... or turned at least this much (rad).
    sensor_offset_x_m, sensor_offset_y_m, sensor_offset_yaw_rad : float
        Pose of the laser in the robot (base) frame (a planar, upright mount; `pf-slam run` sets
        them from the bag's /tf_static).
    pose_estimate : str
        The pose reported for a corrected scan and used by the mapper: ``'best'`` (the
        highest-weight particle, the classic choice) or ``'mean'`` (the weighted mean of the
        particles, yaw on the circle: it averages out the per-particle motion noise that the
        best particle carries into the map; better on the car, see config/kaist.yaml).
    """

    num_particles: int = 30
    seed: int = 0
    min_travel_m: float = 0.1
    min_rotation_rad: float = 0.05
    sensor_offset_x_m: float = 0.0
    sensor_offset_y_m: float = 0.0
    sensor_offset_yaw_rad: float = 0.0
    pose_estimate: str = "best"

    def __post_init__(self) -> None:
        if self.pose_estimate not in ("best", "mean"):
            raise ValueError(f"pose_estimate must be 'best' or 'mean', got {self.pose_estimate!r}")
        _check_int("num_particles", self.num_particles, 1)
        _check_int("seed", self.seed, 0)
        _check_nonneg("min_travel_m", self.min_travel_m)
        _check_nonneg("min_rotation_rad", self.min_rotation_rad)
        _check_finite("sensor_offset_x_m", self.sensor_offset_x_m)
        _check_finite("sensor_offset_y_m", self.sensor_offset_y_m)
        _check_finite("sensor_offset_yaw_rad", self.sensor_offset_yaw_rad)

    @property
    def sensor_offset(self) -> np.ndarray:
        """Laser pose in the base frame, ``(3,)`` float64 ``[x, y, yaw]``."""
        return np.array([self.sensor_offset_x_m, self.sensor_offset_y_m, self.sensor_offset_yaw_rad])


@dataclasses.dataclass(frozen=True)
class LaserConfig(_ConfigBase):
    """How the laser's returns become planar points for a 2D map.

    A planar laser (the CARMEN robots) needs nothing here: its 2D mounting is
    ``filter.sensor_offset_*``. An upside-down laser (roll 180 deg) is given here too: its scan
    plane is horizontal, so it is used as an exact mirrored planar scan (no projection). A tilted laser (the car's LMS511, roll ~143 deg) is projected
    in 3D: each return ``r`` at beam angle ``a`` is ``R @ [r cos a, r sin a, 0] + T`` in the
    vehicle frame; returns outside ``[min_range_m, max_range_m]`` or whose height is outside
    ``[min_height_m, max_height_m]`` (the ground, the sky) are dropped, and the rest are used by
    their ``(x, y)`` as if measured by a planar sensor at ``(T_x, T_y)``.

    Attributes
    ----------
    extrinsic : tuple of 12 float
        ``R`` row-major (9, laser frame -> vehicle frame) then ``T`` (3, m). All zeros: planar.
    min_range_m, max_range_m : float
        Range gate (m).
    min_height_m, max_height_m : float
        Height gate in the vehicle frame (m). With the vehicle frame on the ground (base_link),
        ``min_height_m`` is the floor margin: returns lower than it are the floor, dropped.
    dynamic_frame : str
        A moving mount (a lidar on a robot's head): the frame between the base and the laser
        whose ``base_frame -> dynamic_frame`` transform comes on /tf at its own stamps; then
        ``extrinsic`` is the static ``dynamic_frame -> laser`` part, and each scan is projected
        with the mount interpolated at its stamp (core/mount.py). Empty: a static mount.
    min_kept_fraction : float
        With a moving mount: a scan of which less than this fraction of the returns survives
        the height gate is *mostly floor*: posed from odometry, neither corrected nor mapped
        with, counted in ``faults.scan_mostly_floor``. 0: off.
    smooth_beams : int
        A noisy laser's returns are moved onto the line through them and this many neighbours
        on each side, where those lie on one surface within the scan's noise
        (:func:`~pf_slam_nodes.core.scan.smooth_scan`); the correlator and the mapper see the
        same smoothed scan. Only scans whose noise, estimated from the scan itself, is at least
        ``smooth_min_noise_m`` and whose ranges are not rounded to 2 cm or coarser. 0
        (default): off. The indoor profile's 2: docs/architecture.md, "A noisy laser".
    smooth_min_noise_m : float
        laser.smooth_beams: the range noise (std, m) from which a scan is smoothed.
    """

    extrinsic: tuple = (0.0,) * 12
    min_range_m: float = 0.0
    max_range_m: float = 1000.0
    min_height_m: float = -1000.0
    max_height_m: float = 1000.0
    dynamic_frame: str = ""
    min_kept_fraction: float = 0.0
    smooth_beams: int = 0
    smooth_min_noise_m: float = 0.015

    def __post_init__(self) -> None:
        _check_int("smooth_beams", self.smooth_beams, 0)
        _check_nonneg("smooth_min_noise_m", self.smooth_min_noise_m)
        ext = tuple(self.extrinsic)
        if len(ext) != 12:
            raise ValueError(f"extrinsic must have 12 numbers (R row-major, T), got {len(ext)}")
        for v in ext:
            _check_finite("extrinsic", v)
        object.__setattr__(self, "extrinsic", tuple(float(v) for v in ext))
        if any(ext):
            r = np.asarray(ext[:9], dtype=np.float64).reshape(3, 3)
            if not np.allclose(r @ r.T, np.eye(3), atol=1e-3):
                raise ValueError(f"extrinsic rotation is not orthonormal: {ext[:9]!r}")
        _check_nonneg("min_range_m", self.min_range_m)
        _check_pos("max_range_m", self.max_range_m)
        _check_finite("min_height_m", self.min_height_m)
        _check_finite("max_height_m", self.max_height_m)
        if self.max_range_m <= self.min_range_m:
            raise ValueError(f"max_range_m must be > min_range_m, got {self.max_range_m!r}")
        if self.max_height_m <= self.min_height_m:
            raise ValueError(f"max_height_m must be > min_height_m, got {self.max_height_m!r}")
        if not isinstance(self.dynamic_frame, str):
            raise ValueError(f"dynamic_frame must be a frame name (string), got {self.dynamic_frame!r}")
        _check_finite("min_kept_fraction", self.min_kept_fraction)
        _check_unit("min_kept_fraction", self.min_kept_fraction)

    @property
    def is_3d(self) -> bool:
        return any(self.extrinsic)


@dataclasses.dataclass(frozen=True)
class LocalizationConfig(_ConfigBase):
    """Localization on a fixed map (correlator, ``mode: localization``; see core/localization.py).

    Attributes
    ----------
    init_particles : int
        Particles after an initialisation (global, or around an initial pose); the set is
        resampled to filter.num_particles once it has converged.
    global_candidates_per_m2 : float
        Global initialisation: candidate poses drawn per m^2 of the map's free space (uniform
        position and heading), scored against the coarse field; the init_particles best are kept.
    max_candidates : int
        Upper bound on the candidates of a global initialisation.
    pose_candidates : int
        Candidates drawn from an initial pose's Gaussian (those on free cells are scored).
    coarse_sigma_m : float
        Std of the coarse likelihood field that ranks the candidates (m); clamped at 3 sigma.
    coarse_beams : int
        Scan points used to rank the candidates (evenly strided).
    converged_xy_m : float
        The set has converged when its weighted position std is at most this (m) ...
    converged_yaw_rad : float
        ... and its circular heading std at most this (rad).
    use_initial_pose : bool
        Start from initial_pose_* (a Gaussian with initial_sigma_*) instead of a global
        initialisation; an /initialpose message replaces either at the next correction.
    initial_pose_x_m, initial_pose_y_m, initial_pose_yaw_rad : float
        Initial pose in the map frame (m, m, rad), with use_initial_pose.
    initial_sigma_xy_m : float
        Std of the initial pose's position (m), per axis (rviz2's default: 0.5).
    initial_sigma_yaw_rad : float
        Std of the initial pose's heading (rad) (rviz2's default: 0.2618, 15 deg).
    """

    init_particles: int = 2000
    global_candidates_per_m2: float = 1000.0
    max_candidates: int = 500_000
    pose_candidates: int = 20_000
    coarse_sigma_m: float = 0.15
    coarse_beams: int = 60
    converged_xy_m: float = 0.15
    converged_yaw_rad: float = 0.05
    use_initial_pose: bool = False
    initial_pose_x_m: float = 0.0
    initial_pose_y_m: float = 0.0
    initial_pose_yaw_rad: float = 0.0
    initial_sigma_xy_m: float = 0.5
    initial_sigma_yaw_rad: float = 0.2618

    def __post_init__(self) -> None:
        for name in ("init_particles", "max_candidates", "pose_candidates", "coarse_beams"):
            _check_int(name, getattr(self, name), 1)
        for name in ("global_candidates_per_m2", "coarse_sigma_m", "converged_xy_m", "converged_yaw_rad"):
            _check_pos(name, getattr(self, name))
        if not isinstance(self.use_initial_pose, bool):
            raise ValueError(f"use_initial_pose must be a bool, got {self.use_initial_pose!r}")
        for name in ("initial_pose_x_m", "initial_pose_y_m", "initial_pose_yaw_rad"):
            _check_finite(name, getattr(self, name))
        _check_nonneg("initial_sigma_xy_m", self.initial_sigma_xy_m)
        _check_nonneg("initial_sigma_yaw_rad", self.initial_sigma_yaw_rad)
