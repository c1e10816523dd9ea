"""The stages of the filter as the node graph runs them, ROS-free.

The predictor, correlator and mapper nodes each own one of these objects and only convert
messages around them; :class:`~pf_slam_nodes.core.slam.ParticleFilterSlam` chains the same
objects in one loop. The map reaches the correlation stage exactly as it does over ROS: after
each integration the mapper emits a *patch*, the int8 occupancy (nav_msgs/OccupancyGrid values)
of the bounding box of the cells that scan touched; the correlation stage keeps a likelihood
field of the whole grid and updates it where the patch changes the obstacles. So the graph and
the reference loop compute the same trajectory bit for bit, and no full grid crosses the
middleware per scan.

Random streams: one ``np.random.Generator`` per stage, seeded ``[seed, k]`` (k = 1 motion,
2 resampling, 3 a localization's initial candidates), so a stage's draws do not depend on which
process it runs in.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from .config import (
    CorrelationConfig,
    FilterConfig,
    GridConfig,
    LaserConfig,
    LocalizationConfig,
    LoopClosureConfig,
    OdometryMotionConfig,
    ResampleConfig,
)
from .correlation import correlate
from .deferred import Offload, inline
from .filter import n_eff, resample, update_log_weights
from .geometry import compose, relative_pose
from .grid import LogOddsGrid, grid_geometry, grow_array, growth_plan
from .likelihood import GridLikelihoodField
from .localization import Localizer, pending_from_config
from .loops import LoopCloser, scan_polygon
from .motion import sample_odometry_motion
from .mount import mounted_scan
from .odometry import OdomScaleEstimator
from .recovery import Recovery
from .scan import (
    NoiseTally,
    planar_scan,
    range_noise,
    scan_to_points,
    shadow_beams,
    shadow_neighbours,
    smooth_scan,
    sparse_scan_range,
    transform_points,
    valid_beams,
)
from .scanpair import ScalePairs

MOTION_STREAM = 1
RESAMPLE_STREAM = 2
INIT_STREAM = 3  # localization: the initialisation's candidates


@dataclasses.dataclass
class MapPatch:
    """The occupancy of a rectangle of the grid after an integration.

    ``occupancy``: int8 ``(h, w)`` (-1 unknown, 0..100), row = y; ``origin``: world ``(x, y)`` of
    its cell (0, 0) corner (m); ``resolution`` (m). ``transform``: a closed loop re-rendered the
    map: the patch is the whole new grid, and the filter's frame moves by this ``(x, y, yaw)``
    (the next correction's set is composed with it); None for an ordinary patch.
    """

    occupancy: np.ndarray
    resolution: float
    origin: np.ndarray
    transform: np.ndarray | None = None


class StageClock:
    """Wall time (s) and calls per named step of a stage: ``t0 = perf_counter(); ...;
    clock.add("name", t0)``. Read by the ROS-free loop and by `pf-slam run` (per-stage split)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}

    def add(self, name: str, t0: float) -> None:
        self.seconds[name] = self.seconds.get(name, 0.0) + (time.perf_counter() - t0)
        self.calls[name] = self.calls.get(name, 0) + 1


def stage_seconds(*stages) -> tuple[dict[str, float], dict[str, int]]:
    """The stages' clocks merged: (seconds, calls) per step, every step of ``STAGE_STEPS``."""
    seconds = {k: 0.0 for k in STAGE_STEPS}
    calls = {k: 0 for k in STAGE_STEPS}
    for st in stages:
        for k, v in st.clock.seconds.items():
            seconds[k] += v
            calls[k] += st.clock.calls[k]
    return seconds, calls


#: the steps the stages time, in pipeline order
STAGE_STEPS = ("predict", "correlate", "resample", "map", "field", "loops")


class PredictionStage:
    """Owns the particle set between corrections; gates updates on travelled distance."""

    def __init__(self, filter_cfg: FilterConfig, motion_cfg: OdometryMotionConfig) -> None:
        self.filter_cfg = filter_cfg
        self.motion_cfg = motion_cfg
        self.rng = np.random.default_rng([filter_cfg.seed, MOTION_STREAM])
        n = filter_cfg.num_particles
        self.particles = np.zeros((n, 3))
        self.log_weights = np.full(n, -math.log(n))
        self.odom_at_update: np.ndarray | None = None
        self.clock = StageClock()  # "predict": the motion model's sampling

    def predict(self, odom_pose: np.ndarray, sigma_theta_rad: float | None = None) -> tuple[bool, np.ndarray]:
        """Odometry pose at a scan -> (update?, increment since the last correction).

        The first scan always updates (it starts the map; particles are set to the odometry
        pose, so the map frame is the odometry frame at that moment). Otherwise the particles
        move only when the increment passes the motion gate. ``sigma_theta_rad``: the heading's
        own uncertainty over the increment (:func:`sample_odometry_motion`), if known.
        """
        odom = np.asarray(odom_pose, dtype=np.float64).reshape(3)
        if self.odom_at_update is None:
            self.particles[:] = odom
            self.odom_at_update = odom.copy()
            return True, np.zeros(3)
        update, delta = self.gate(odom)
        if not update:
            return False, delta
        t0 = time.perf_counter()
        self.particles = sample_odometry_motion(self.particles, delta, self.motion_cfg, self.rng, sigma_theta_rad)
        self.odom_at_update = odom.copy()
        self.clock.add("predict", t0)
        return True, delta

    def gate(self, odom_pose: np.ndarray) -> tuple[bool, np.ndarray]:
        """Would :meth:`predict` update at this odometry pose? -> (update?, increment since the
        last correction). No side effects: the predictor node asks this while a correction is
        still in flight, to pose the pass-through scans behind it without waiting."""
        if self.odom_at_update is None:
            return True, np.zeros(3)
        fc = self.filter_cfg
        delta = relative_pose(self.odom_at_update, np.asarray(odom_pose, dtype=np.float64).reshape(3))
        return bool(math.hypot(delta[0], delta[1]) >= fc.min_travel_m or abs(delta[2]) >= fc.min_rotation_rad), delta

    def set_corrected(self, particles: np.ndarray, log_weights: np.ndarray) -> None:
        self.particles = np.asarray(particles, dtype=np.float64).reshape(-1, 3).copy()
        self.log_weights = np.asarray(log_weights, dtype=np.float64).copy()


@dataclasses.dataclass
class Correction:
    particles: np.ndarray  # (N, 3) after correction (and resampling)
    log_weights: np.ndarray  # (N,) normalised
    pose: np.ndarray  # (3,) best particle before resampling
    resampled: bool
    matched: bool  # False when there was no map to match against
    odom_scale: float = 1.0  # the odometry scale applied to this set (correlation.odom_scale)


class CorrectionStage:
    """Scan-to-map correlation of every particle, weight update, resampling.

    SLAM: the likelihood field follows the mapping stage's patches (:meth:`apply_patch`).
    Localization: :meth:`set_map` fixes the map once; the next correction replaces the predicted
    set with an initial one (global, or around an initial pose: :meth:`request_init`), and a set
    of another size than ``filter.num_particles`` is resampled to it once it has converged
    (core/localization.py)."""

    def __init__(
        self,
        filter_cfg: FilterConfig,
        grid_cfg: GridConfig,
        corr_cfg: CorrelationConfig,
        resample_cfg: ResampleConfig,
        laser_cfg: LaserConfig | None = None,
        loc_cfg: LocalizationConfig | None = None,
        offload: Offload = inline,
    ) -> None:
        self.loc_cfg = loc_cfg or LocalizationConfig()
        self.localizer: Localizer | None = None  # set_map: localization on a fixed map
        self.pending_init: tuple | None = None  # (mean, cov): around a pose; (None, None): global
        self.init_rng = np.random.default_rng([filter_cfg.seed, INIT_STREAM])
        self.initialisations = 0
        self.converged_at: int | None = None  # correction at which the set was last reduced
        self.init_seconds = 0.0  # wall time of the last initialising correction (candidates + matching)
        self.last_init: str | None = None  # "global" or "initial pose"
        self.filter_cfg = filter_cfg
        self.laser_cfg = laser_cfg or LaserConfig()
        self.noise = NoiseTally() if self.laser_cfg.smooth_beams else None  # laser.smooth_beams: what it found
        self.grid_cfg = grid_cfg
        self.corr_cfg = corr_cfg
        self.resample_cfg = resample_cfg
        self.rng = np.random.default_rng([filter_cfg.seed, RESAMPLE_STREAM])
        self.field: GridLikelihoodField | None = None
        self.known: np.ndarray | None = None  # (H, W) bool observed cells (skip_unknown only)
        self.pose = np.zeros(3)
        self.num_corrections = 0
        self.num_resamples = 0
        # correlation.recover_search_m (mapping only): a set that slid off the map is shifted back
        self.recovery = Recovery() if corr_cfg.recover_search_m > 0 else None
        self.clock = StageClock()  # "correlate" (+ weights), "resample" (+ pose estimate), "field"
        c = corr_cfg
        self.odom_scale = (
            OdomScaleEstimator(c.odom_scale_window_m, c.odom_scale_ramp_m, c.odom_scale_max) if c.odom_scale else None
        )
        self._odom_prev: np.ndarray | None = None  # odometry pose of the last corrected set
        # odom_scale: the scan pairs measured beside the correction (offload: here or a worker
        # process); a scan's measurement is taken at the next correction, before its scale is read
        self.pairs = offload(ScalePairs, (float(grid_cfg.resolution_m), corr_cfg)) if c.odom_scale else None
        self._pair_pending = False
        self.scale_measurements = 0
        self._move: np.ndarray | None = None  # a closed loop's frame change, for the next set
        self._exact = False  # the next patch is a whole re-rendered grid: the field takes its geometry
        self.frame_changes = 0

    def set_map(self, occupancy: np.ndarray, resolution: float, origin) -> None:
        """Localization: the fixed map (int8 ``(H, W)``, -1 / 0..100, row 0 = lowest y) becomes
        the likelihood field, and the next correction initialises the set as the parameters say
        (``localization.use_initial_pose``, else global)."""
        t0 = time.perf_counter()
        occ = np.asarray(occupancy)
        if occ.ndim != 2 or occ.size == 0:
            raise ValueError(f"the fixed map must be a non-empty (H, W) grid, got shape {occ.shape}")
        h, w = occ.shape
        self.field = GridLikelihoodField(h, w, float(resolution), np.asarray(origin, float)[:2], self.corr_cfg)
        self.field.set_obstacle_block(0, 0, occ >= self.corr_cfg.occupied_threshold)
        self.known = (occ >= 0) if self.corr_cfg.skip_unknown else None
        self.localizer = Localizer(occ, resolution, origin, self.corr_cfg, self.loc_cfg)
        if self.pending_init is None and self.initialisations == 0:
            self.pending_init = pending_from_config(self.loc_cfg)
        self.clock.add("field", t0)

    def localization_status(self, particles: int) -> dict:
        """What a run reports of the localization (summary.json ``localization``)."""
        return {
            "initialisations": self.initialisations,
            "last_init": self.last_init,
            "converged_at_correction": self.converged_at,
            "init_seconds": round(self.init_seconds, 3),
            "particles": particles,
            "free_area_m2": round(self.localizer.free_area_m2, 1) if self.localizer else None,
        }

    def request_init(self, mean=None, cov=None) -> None:
        """Localization: the next correction starts a new set around ``mean`` (``(3,)``, map
        frame) with covariance ``cov`` (``(3, 3)``, x y yaw), or globally (``mean`` None)."""
        self.pending_init = (
            (None, None) if mean is None else (np.asarray(mean, float).reshape(3), np.asarray(cov, float).reshape(3, 3))
        )

    def frame_change(self, transform: np.ndarray) -> None:
        """A closed loop moved the map (the mapping stage's re-rendering, loops.*): the field is
        dropped, the next patch (the whole new grid) becomes it, and the next set to correct is
        composed with ``transform`` ``(x, y, yaw)`` into the new frame."""
        self.field = self.known = None
        self._move = np.asarray(transform, dtype=np.float64).reshape(3).copy()
        self._exact = True
        self.frame_changes += 1

    def apply_patch(self, patch: MapPatch) -> int:
        """Bring the likelihood field up to date with a map patch; returns the cells changed.

        The field starts as the grid the mapping stage builds around the first corrected pose
        and grows by whole tiles to take in a patch beyond it (:func:`~.grid.growth_plan`, up to
        ``grid.max_cells``); cells of a patch beyond that bound are ignored. A patch with a
        ``transform`` (a closed loop's re-rendered map) replaces the field (:meth:`frame_change`).
        """
        t0 = time.perf_counter()
        if patch.transform is not None:
            self.frame_change(patch.transform)
        changed = self._apply_patch(patch)
        self.clock.add("field", t0)
        return changed

    def _apply_patch(self, patch: MapPatch) -> int:
        if self.field is None:
            if self._exact:  # a re-rendered map: the field is exactly its grid
                (h, w), origin = np.asarray(patch.occupancy).shape, np.asarray(patch.origin, float)
                self._exact = False
            else:
                h, w, origin = grid_geometry(self.grid_cfg, self.pose[:2])
            self.field = GridLikelihoodField(h, w, float(self.grid_cfg.resolution_m), origin, self.corr_cfg)
            if self.corr_cfg.skip_unknown:
                self.known = np.zeros((h, w), dtype=bool)
        f = self.field
        occ = np.asarray(patch.occupancy)
        c0, r0 = np.rint((np.asarray(patch.origin, float) - f.origin) / f.resolution).astype(np.int64)
        if occ.size:
            add = growth_plan(
                f.height,
                f.width,
                (int(r0), int(r0) + occ.shape[0], int(c0), int(c0) + occ.shape[1]),
                int(self.grid_cfg.max_cells),
            )
            if add is not None and any(add):
                f.grow(add)
                if self.known is not None:
                    self.known = grow_array(self.known, add, False)
                r0, c0 = r0 + add[0], c0 + add[2]
        a0, a1 = max(int(r0), 0), min(int(r0) + occ.shape[0], f.height)  # the patch inside the grid
        b0, b1 = max(int(c0), 0), min(int(c0) + occ.shape[1], f.width)
        if a0 >= a1 or b0 >= b1:
            return 0
        sub = occ[a0 - r0 : a1 - r0, b0 - c0 : b1 - c0]
        if self.known is not None:
            self.known[a0:a1, b0:b1] = sub >= 0
        return f.set_obstacle_block(a0, b0, sub >= self.corr_cfg.occupied_threshold)

    def _observed(self, pts: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """``(M,)`` bool: robot-frame points that land on an observed map cell at ``pose``."""
        f = self.field
        cells = np.floor((transform_points(pts, pose) - f.origin) / f.resolution).astype(np.int64)
        ok = (cells[:, 0] >= 0) & (cells[:, 0] < f.width) & (cells[:, 1] >= 0) & (cells[:, 1] < f.height)
        keep = np.zeros(pts.shape[0], dtype=bool)
        keep[ok] = self.known[cells[ok, 1], cells[ok, 0]]
        return keep

    def correct(
        self,
        particles: np.ndarray,
        log_weights: np.ndarray,
        ranges: np.ndarray,
        angles: np.ndarray,
        range_min: float = 0.0,
        range_max: float = math.inf,
        extrinsic: np.ndarray | None = None,
        odom_pose: np.ndarray | None = None,
    ) -> Correction:
        """Correct a predicted set with a scan (ranges (B,), beam angles (B,) in the sensor frame;
        ``extrinsic``: this scan's mount (12,) on a moving mount, else the configured one;
        ``odom_pose``: the odometry pose (3,) the set was predicted to, for
        ``correlation.odom_scale``)."""
        t0 = t0_all = time.perf_counter()
        particles = np.asarray(particles, dtype=np.float64).reshape(-1, 3)
        if self._move is not None:  # a closed loop moved the map: the set follows it
            particles = compose(self._move, particles)
            self._move = None
        log_w = np.asarray(log_weights, dtype=np.float64)
        ranges, angles, offset = scan_in_base(
            ranges, angles, self.laser_cfg, self.filter_cfg.sensor_offset, range_min, range_max, extrinsic, self.noise
        )
        cut = sparse_scan_range(ranges, self.corr_cfg.range_max_m, range_max, self.grid_cfg.min_return_fraction)
        lo, hi = max(range_min, 1e-6), min(range_max, cut)
        pts = scan_to_points(ranges, angles, lo, hi)
        # beams behind an occluding edge weigh the particles but move no pose (correlation.shadow_jump_m)
        near = shadow_neighbours(angles, self.corr_cfg.shadow_beams, self.corr_cfg.shadow_angle_rad)
        shadow = shadow_beams(ranges, self.corr_cfg.shadow_jump_m, near)
        match = ~shadow[valid_beams(ranges, lo, hi)] if shadow.any() else None
        if np.any(offset):
            pts = transform_points(pts, offset)
        initialising = self.localizer is not None and self.pending_init is not None
        if initialising:
            particles = self.localizer.initial_set(pts, self.init_rng, *self.pending_init)
            log_w = np.full(particles.shape[0], -math.log(particles.shape[0]))
            self.last_init = "global" if self.pending_init[0] is None else "initial pose"
            self.pending_init = None
            self.initialisations += 1
            self.converged_at = None
        scale = 1.0
        if self.odom_scale is not None and odom_pose is not None and not initialising:
            odom = np.asarray(odom_pose, dtype=np.float64).reshape(3)
            self.collect_scale()
            if self._odom_prev is not None:
                scale = self.odom_scale.scale
                particles = scaled_increment(particles, relative_pose(self._odom_prev, odom), scale)
            self._odom_prev = odom
            self.pairs.submit("measure", odom, pts)  # all of the scan's points, in the vehicle frame
            self._pair_pending = True
        if self.known is not None and pts.shape[0] > 0:
            seen = self._observed(pts, particles[int(np.argmax(log_w))])
            pts = pts[seen]
            match = None if match is None else match[seen]
        matched = self.field is not None and pts.shape[0] > 0
        if matched:
            corr_cfg = self.corr_cfg  # a sparse scan (grid.min_return_fraction): its own, longer cut
            if cut != corr_cfg.range_max_m:
                corr_cfg = dataclasses.replace(corr_cfg, range_max_m=cut)
            predicted = particles
            particles, scores = correlate(particles, pts, self.field, corr_cfg, match)
            if self.recovery is not None and self.localizer is None:
                n = self.num_corrections
                particles, scores = self.recovery.correct(
                    n, predicted, particles, scores, pts, self.field, corr_cfg, match
                )
            log_w = update_log_weights(log_w, scores, self.corr_cfg.temperature)
        self.clock.add("correlate", t0)
        t0 = time.perf_counter()
        pose = pose_estimate(particles, log_w, self.filter_cfg)
        n = log_w.size
        resampled = bool(n_eff(log_w) < self.resample_cfg.neff_threshold * n)
        if resampled:
            idx = resample(log_w, self.resample_cfg.method, self.rng)
            particles = particles[idx]
            log_w = np.full(n, -math.log(n))
            self.num_resamples += 1
        target = self.filter_cfg.num_particles
        if self.localizer is not None and n != target and self.localizer.converged(particles, log_w):
            particles, log_w = self.localizer.reduce(particles, log_w, target, self.rng)
            self.converged_at = self.num_corrections
        if initialising:
            self.init_seconds = time.perf_counter() - t0_all
        self.pose = pose
        self.num_corrections += 1
        self.clock.add("resample", t0)
        return Correction(particles, log_w, pose, resampled, bool(matched), scale)

    def collect_scale(self) -> None:
        """correlation.odom_scale: the last scan's pair measurement into the estimate (the next
        correction does this before it reads the scale)."""
        if not self._pair_pending:
            return
        self._pair_pending = False
        got = self.pairs.collect()
        if got is not None:
            self.odom_scale.add(*got)
            self.scale_measurements += 1

    def scale_status(self) -> dict | None:
        """correlation.odom_scale: what the scan pairs measured of the odometry's translation
        scale (true / odometry travel; summary.json ``odom_scale``), None when off: ``scale``
        (applied now), ``measured`` (the ratio before shrinking and clamping), ``std_error``
        (None before two pairs), ``pairs`` and the odometry ``travel_m`` they cover."""
        est = self.odom_scale
        if est is None:
            return None
        se = est.std_error
        return {
            "scale": round(est.scale, 5),
            "measured": round(est.raw, 5),
            "std_error": round(se, 5) if math.isfinite(se) else None,
            "pairs": self.scale_measurements,
            "travel_m": round(est.travel_m, 1),
        }

    def close(self) -> None:
        """Stop the home of the work handed off (a worker process)."""
        if self.pairs is not None:
            self.pairs.close()


def scan_in_base(
    ranges,
    angles,
    laser: LaserConfig,
    planar_offset,
    range_min: float,
    range_max: float,
    extrinsic: np.ndarray | None = None,
    tally: NoiseTally | None = None,
):
    """:func:`planar_scan` with the configured mount, or with ``extrinsic`` (12,), this scan's
    mount on a moving mount (core/mount.py); smoothed where it is noisy (``laser.smooth_beams``,
    :func:`smooth_scan`; counted in ``tally``)."""
    if extrinsic is None:
        r, a, off = planar_scan(ranges, angles, laser, planar_offset, range_min, range_max)
    else:
        r, a, off = mounted_scan(ranges, angles, laser, extrinsic, range_min, range_max)
    if laser.smooth_beams:
        r, noise, verdict = smooth_scan(r, a, laser.smooth_beams, laser.smooth_min_noise_m)
        if tally is not None:
            tally.add(noise, verdict)
    return r, a, off


def scaled_increment(particles: np.ndarray, delta: np.ndarray, scale: float) -> np.ndarray:
    """Predicted particles whose odometry increment ``delta`` (the odometry frame's, (3,)) had its
    translation scaled by ``scale``: each particle moves by ``(scale - 1) * delta_xy`` in the frame
    of its heading before the increment."""
    out = particles.copy()
    if scale != 1.0:
        phi = particles[:, 2] - delta[2]
        c, s = np.cos(phi), np.sin(phi)
        k = scale - 1.0
        out[:, 0] += k * (c * delta[0] - s * delta[1])
        out[:, 1] += k * (s * delta[0] + c * delta[1])
    return out


def pose_estimate(particles: np.ndarray, log_w: np.ndarray, cfg: FilterConfig) -> np.ndarray:
    """The pose of a corrected set (``cfg.pose_estimate``): the best particle, or the weighted
    mean of all particles (yaw on the circle)."""
    best = int(np.argmax(log_w))
    if cfg.pose_estimate == "best":
        return particles[best].copy()
    w = np.exp(log_w - log_w[best])
    w /= w.sum()
    th = particles[:, 2]
    return np.array([w @ particles[:, 0], w @ particles[:, 1], math.atan2(w @ np.sin(th), w @ np.cos(th))])


class MappingStage:
    """The log-odds grid: integrates scans at corrected poses, exports occupancy.

    With ``loops.enabled`` it also runs the loop closure (core/loops.py) on the scans it
    integrates and keeps them: a closed loop that moves a keyframe by more than
    ``loops.rebuild_m`` from where the map has its scan re-renders the map from the optimised
    poses and returns it whole, with the frame change the filter's set must follow
    (:attr:`MapPatch.transform`). The poses of the scans after it are in the new frame; the
    frames are kept (:meth:`corrected`) so every pose of the run can be mapped into the final,
    optimised frame.
    """

    def __init__(
        self,
        filter_cfg: FilterConfig,
        grid_cfg: GridConfig,
        laser_cfg: LaserConfig | None = None,
        loop_cfg: LoopClosureConfig | None = None,
        offload: Offload = inline,
    ) -> None:
        self.filter_cfg = filter_cfg
        self.grid_cfg = grid_cfg
        self.laser_cfg = laser_cfg or LaserConfig()
        self.loop_cfg = loop_cfg or LoopClosureConfig()
        self.grid: LogOddsGrid | None = None
        self.pose: np.ndarray | None = None
        self._occ: np.ndarray | None = None  # int8 occupancy of the whole grid, kept current
        self.clock = StageClock()  # "map": ray tracing + log-odds + the patch; "loops": the back end
        self.loops = LoopCloser(self.loop_cfg, offload) if self.loop_cfg.enabled else None
        # the scan pairs' noise gate (loops.pair_baseline_m, pair_min_noise_m): each keyframe's laser
        # noise, from the smoothing's own estimate where it smooths
        lc = self.loop_cfg
        self._pair_gate = self.loops is not None and lc.pair_baseline_m > 0.0 and lc.pair_min_noise_m > 0.0
        self._noise = NoiseTally() if self._pair_gate and self.laser_cfg.smooth_beams else None
        self._open: MapPatch | None = None  # start_integrate's patch, while its loop match runs
        self._scans: list[tuple] = []  # loops: (key, raw pose, scan) of every integrated scan
        self.frame = np.zeros(3)  # loops: the filter's frame in the raw frame
        self.frames: list[tuple[float, np.ndarray]] = [(-math.inf, np.zeros(3))]  # (from key, frame)
        self._pending_frame: np.ndarray | None = None  # takes effect at the next integrated scan
        self.rebuilds = 0

    @property
    def ready(self) -> bool:
        return self.grid is not None

    def integrate(
        self,
        pose: np.ndarray,
        ranges: np.ndarray,
        angles: np.ndarray,
        range_min: float = 0.0,
        range_max: float = math.inf,
        extrinsic: np.ndarray | None = None,
        key: float = 0.0,
        odom: np.ndarray | None = None,
        odom_scale: float = 1.0,
    ) -> MapPatch:
        """Integrate a scan at a corrected pose; returns the patch of the cells it touched
        (``extrinsic``: this scan's mount (12,) on a moving mount, else the configured one;
        ``key``: the scan's time, increasing, for the loop closure's corrections; ``odom``,
        ``odom_scale``: its odometry pose and the odometry scale its set was predicted with,
        for ``loops.scale_early_travel``)."""
        self.start_integrate(pose, ranges, angles, range_min, range_max, extrinsic, key, odom, odom_scale)
        return self.finish_integrate()

    def answered(self) -> bool:
        """:meth:`finish_integrate` would not wait for the loop match."""
        return self.loops is None or self.loops.ready()

    def close(self) -> None:
        """Stop the home of the loop matches (a worker process)."""
        if self.loops is not None:
            self.loops.close()

    def start_integrate(
        self,
        pose: np.ndarray,
        ranges: np.ndarray,
        angles: np.ndarray,
        range_min: float = 0.0,
        range_max: float = math.inf,
        extrinsic: np.ndarray | None = None,
        key: float = 0.0,
        odom: np.ndarray | None = None,
        odom_scale: float = 1.0,
    ) -> None:
        """:meth:`integrate` up to the loop match it sends (if its keyframe is due one); then
        :meth:`finish_integrate` (before anything else of this stage) returns the patch. What
        runs between the two may not touch this stage: the result does not depend on when the
        match's answer came."""
        assert self._open is None, "finish_integrate() first"
        t0 = time.perf_counter()
        if self._pending_frame is not None:  # the set this pose came from followed the last re-rendering
            self.frame, self._pending_frame = self._pending_frame, None
            self.frames.append((float(key), self.frame.copy()))
        planar = scan_in_base(
            ranges, angles, self.laser_cfg, self.filter_cfg.sensor_offset, range_min, range_max, extrinsic, self._noise
        )
        self._open = self._integrate(pose, planar, range_min, range_max)
        self.clock.add("map", t0)
        if self.loops is not None:
            t0 = time.perf_counter()
            self._keyframe(float(key), pose, planar, range_min, range_max, odom, odom_scale)
            self.clock.add("loops", t0)

    def finish_integrate(self) -> MapPatch:
        """The patch of the scan :meth:`start_integrate` took (waits for its loop match): the
        cells it touched, or the whole re-rendered map when the loop it closed moved the map."""
        patch, self._open = self._open, None
        assert patch is not None, "start_integrate() first"
        if self.loops is None:
            return patch
        t0 = time.perf_counter()
        if self.loops.finish_keyframe() and self.loops.map_shift() > self.loop_cfg.rebuild_m:
            patch = self._rebuilt()
        self.clock.add("loops", t0)
        return patch

    def _keyframe(
        self, key: float, pose: np.ndarray, planar: tuple, rmin: float, rmax: float, odom=None, odom_scale: float = 1.0
    ) -> None:
        """Keep the scan (as the planar sensor saw it, for a re-rendering) and hand it to the
        loop closure if it is a keyframe (which may send a loop match)."""
        raw = compose(self.frame, np.asarray(pose, dtype=np.float64).reshape(3))
        r, a, offset = planar
        a32 = a.astype(np.float32)
        last = self._scans[-1][2][1] if self._scans else None
        kept_a = last if last is not None and np.array_equal(last, a32) else a32  # share a repeated beam layout
        self._scans.append((key, raw, (r.astype(np.float32), kept_a, offset, rmin, rmax)))
        if not self.loops.observe(raw):  # not a keyframe: nothing more to do
            return
        reach = min(self.loop_cfg.max_range_m, rmax)
        pts = transform_points(scan_to_points(r, a, max(rmin, 1e-6), reach), offset)
        ok = ~np.isnan(r)
        ends = np.where(np.isfinite(r[ok]) & (r[ok] <= reach), r[ok], reach)
        ends = transform_points(np.stack([ends * np.cos(a[ok]), ends * np.sin(a[ok])], axis=1), offset)
        poly = scan_polygon(offset[:2], ends, max(1, ends.shape[0] // 180))
        noise = math.nan  # the keyframe's laser noise, before any smoothing (the scan pairs' gate)
        if self._pair_gate:
            noise = self._noise.last if self._noise is not None else range_noise(r, a)
        self.loops.start_keyframe(key, raw, pts, poly, odom, odom_scale, noise)

    def _rebuilt(self) -> MapPatch:
        """A closed loop moved the keyframes: the map re-rendered from the optimised poses, whole,
        with the frame change the filter's set must follow."""
        corr = self._render()
        move = compose(corr, self.frame)  # the filter's frame -> the optimised one
        self._pending_frame = relative_pose(corr, np.zeros(3))  # optimised -> raw
        g = self.grid
        occ, _ = g.matching_patch(self._occ, (0, g.height, 0, g.width))
        return MapPatch(occ, g.resolution, g.origin.copy(), move)

    def _render(self) -> np.ndarray:
        """The map anew from every kept scan at its raw pose moved by its correction (the loop
        closure's current solution, marked as mapped); returns the correction of the scans mapped
        from now on (:meth:`LoopCloser.mark_mapped`)."""
        corr = self.loops.mark_mapped()
        poses = compose(
            self.loops.corrections(np.array([k for k, _, _ in self._scans])),
            np.array([raw for _, raw, _ in self._scans]),
        )
        self.grid = self._occ = None
        for pose, (_, _, (r, a, offset, rmin, rmax)) in zip(poses, self._scans):
            self._integrate(pose, (r, a, offset), rmin, rmax)
        self.pose = poses[-1].copy()
        self.rebuilds += 1
        return corr

    def finish(self) -> bool:
        """End of the run: the scan-pair edges added to the loop closure's graph
        (``loops.pair_baseline_m``), then the map re-rendered with the final corrections if any
        keyframe moved by more than half a cell since it was built. True if it was."""
        if self.loops is None or not self._scans:
            return False
        t0 = time.perf_counter()
        self.loops.add_pair_edges()
        if self.loops.map_shift() <= 0.5 * self.grid_cfg.resolution_m:
            self.clock.add("loops", t0)
            return False
        self._render()
        self.clock.add("loops", t0)
        return True

    def corrected(self, keys: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """Poses ``(N, 3)`` of the run at ``keys`` (the filter's, each in the frame it was in at
        its time) in the final optimised frame; unchanged without loop closure."""
        p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if self.loops is None or not len(self.loops):
            return p.copy()
        k = np.asarray(keys, dtype=np.float64).reshape(-1)
        starts = np.array([f for f, _ in self.frames])
        frames = np.array([g for _, g in self.frames])
        raw = compose(frames[np.searchsorted(starts, k, side="right") - 1], p)
        return compose(self.loops.corrections(k), raw)

    def _integrate(self, pose: np.ndarray, planar: tuple, range_min: float, range_max: float) -> MapPatch:
        """A scan as the planar sensor sees it (:func:`scan_in_base`: ranges, angles, offset) into
        the grid at ``pose``; the patch of the cells it touched."""
        pose = np.asarray(pose, dtype=np.float64).reshape(3)
        if self.grid is None:
            self.grid = LogOddsGrid(self.grid_cfg, center_xy=pose[:2])
            self._occ = np.full(self.grid.log_odds.shape, -1, dtype=np.int8)  # = occupancy() of an empty grid
        g = self.grid
        ranges, angles, offset = planar
        usable = sparse_scan_range(ranges, g.cfg.range_max_usable_m, range_max, g.cfg.min_return_fraction)
        g.integrate_scan(pose, ranges, angles, offset, range_min, range_max, usable)
        if g.last_growth is not None:  # the grid grew by whole tiles: so does its occupancy
            self._occ = grow_array(self._occ, g.last_growth, -1)
        self.pose = pose.copy()
        idx = g.last_touched_idx
        if idx.size == 0:
            return MapPatch(np.zeros((0, 0), np.int8), g.resolution, g.origin.copy())
        self._occ.reshape(-1)[idx] = g.occupancy_at(idx)  # only the touched cells changed
        occ, bounds = g.matching_patch(self._occ, g.last_touched_bounds)
        return MapPatch(occ, g.resolution, g.bounds_origin(bounds))

    def map_occupancy(self) -> tuple[np.ndarray, float, np.ndarray]:
        """int8 occupancy of the explored part of the grid (the whole grid before any scan)."""
        assert self.grid is not None and self._occ is not None
        bounds = self.grid.touched_bounds
        if bounds is None:
            return self._occ.copy(), self.grid.resolution, self.grid.bounds_origin(None)
        r0, r1, c0, c1 = bounds
        return self._occ[r0:r1, c0:c1].copy(), self.grid.resolution, self.grid.bounds_origin(bounds)
