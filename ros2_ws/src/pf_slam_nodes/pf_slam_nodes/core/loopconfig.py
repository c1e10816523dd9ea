"""The loop closure's configuration (the mapper's ``loops.*``; core/loops.py), re-exported by
:mod:`.config` with the other stages' configs."""

from __future__ import annotations

import dataclasses

from .configbase import _check_finite, _check_int, _check_nonneg, _check_pos, _check_unit, _ConfigBase


@dataclasses.dataclass(frozen=True)
class LoopClosureConfig(_ConfigBase):
    """Loop closure on top of the filter (mapper; core/loops.py): keyframes, loop matches of a
    keyframe's recent surroundings against an earlier place's, an SE(2) pose graph; a closed
    loop that moves the map re-renders it from the optimised poses, and the filter goes on in
    that frame.

    Attributes
    ----------
    enabled : bool
        Run the back end (off: the filter alone, as before).
    keyframe_m, keyframe_rad : float
        A corrected scan becomes a keyframe after this much travel (m) or turning (rad) since the last one.
    submap_m : float
        The scans of the keyframes within this much travel (m) of a keyframe form its local map:
        the query (the last ``submap_m`` before it) and the reference (``submap_m`` each side of
        the earlier place).
    min_loop_travel_m : float
        A loop is with a keyframe at least this much travel (m) back.
    loop_every_m : float
        At most one loop match per this much travel (m), when an earlier keyframe is near.
    window_min_m, window_per_m, window_max_m : float
        Half-width (m) of the loop match's translation search: ``window_min_m + window_per_m *``
        the travel since the last closed loop, at most ``window_max_m``.
    window_rad : float
        Half-width (rad) of its rotation search.
    resolution_m, coarse_m : float
        Cells (m) of the match's fine field (refinement, scores) and coarse field (exhaustive search).
    sigma_m : float
        Match tolerance (m): a query point within ``2 sigma_m`` of a reference point is an inlier.
    max_range_m : float
        Scan points farther than this (m) are not used.
    max_points : int
        Query points used in the coarse search (evenly strided).
    candidates : int
        Coarse peaks refined.
    min_inliers : float
        A match is kept when at least this share of the query's points are inliers ...
    max_contradictions : float
        ... at most this share lies in the free space the reference's scans saw ...
    min_margin : float
        ... and its score beats every candidate ``ambiguity_m`` or more away by this; a kept match
        whose score falls less than this ``ambiguity_m / 2`` along some direction holds loosely there.
    ambiguity_m : float
        Distance (m) beyond which a candidate is a rival match.
    look_elsewhere, look_elsewhere_m, look_elsewhere_rad : float
        A wide search needs more inliers: ``min_inliers`` + ``look_elsewhere`` per e-fold of the search
        volume beyond ``look_elsewhere_m`` (m) x ``look_elsewhere_rad`` (rad) half-widths.
    seq_sigma_xy_m, seq_sigma_xy_per_m : float
        Std (m, m per m) of the translation between consecutive keyframes as the filter has it,
        along the direction of travel ...
    seq_sigma_lateral_per_m : float
        ... and across it (m per m): a filter whose error is mostly the odometry's scale (the car
        on a street) is far better across than along.
    seq_sigma_rad, seq_sigma_rad_per_m : float
        Std (rad, rad per m) of its rotation.
    loop_sigma_xy_m, loop_sigma_rad : float
        Std (m, rad) of a loop match.
    cauchy : float
        Scale of the Cauchy kernel on the loop edges' chi-square.
    max_chi2 : float
        A loop edge whose chi-square stays above this at the solution is dropped.
    rebuild_m : float
        Re-render the map from the optimised poses when a solution moves a keyframe more than this (m) from its map pose.
    scale_early_travel : bool
        The travel before ``correlation.odom_scale`` first applied is rescaled in the graph to the
        latest scale x the odometry's travel there (core/loops.py); nothing while that scale is 1.
    pair_baseline_m : float
        At the end of the run, each keyframe's scan is matched against the keyframe this much
        travel (m) back by the symmetric scan-pair cost (core/scanpair.py) and the travel it
        measures joins the graph as an edge along the direction of travel, for the final solve
        (the final trajectory and map); 0: off.
    pair_sigma_m : float
        Std (m) of such an edge.
    pair_reach_margin_m : float
        A pair uses the points of each scan within ``max_range_m`` less this (m) of the other's pose.
    pair_min_noise_m : float
        Only keyframes whose laser noise (the scan's own estimate, core/scan.py ``range_noise``) is
        at least this (m) are paired: a noisy laser's walls pull the filter's matches ahead, a
        precise one's chain is better than a pair (0: every keyframe).
    """

    enabled: bool = False
    keyframe_m: float = 1.0
    keyframe_rad: float = 0.5
    submap_m: float = 8.0
    min_loop_travel_m: float = 15.0
    loop_every_m: float = 2.0
    window_min_m: float = 0.6
    window_per_m: float = 0.03
    window_max_m: float = 10.0
    window_rad: float = 0.12
    resolution_m: float = 0.05
    coarse_m: float = 0.2
    sigma_m: float = 0.05
    max_range_m: float = 20.0
    max_points: int = 400
    candidates: int = 8
    min_inliers: float = 0.5
    max_contradictions: float = 0.05
    min_margin: float = 0.15
    ambiguity_m: float = 1.0
    look_elsewhere: float = 0.03
    look_elsewhere_m: float = 4.0
    look_elsewhere_rad: float = 0.12
    seq_sigma_xy_m: float = 0.01
    seq_sigma_xy_per_m: float = 0.01
    seq_sigma_lateral_per_m: float = 0.01
    seq_sigma_rad: float = 0.002
    seq_sigma_rad_per_m: float = 0.002
    loop_sigma_xy_m: float = 0.05
    loop_sigma_rad: float = 0.01
    cauchy: float = 3.0
    max_chi2: float = 30.0
    rebuild_m: float = 0.3
    scale_early_travel: bool = True
    pair_baseline_m: float = 0.0
    pair_sigma_m: float = 0.03
    pair_reach_margin_m: float = 3.0
    pair_min_noise_m: float = 0.0

    def __post_init__(self) -> None:
        for name in ("enabled", "scale_early_travel"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be a bool, got {getattr(self, name)!r}")
        for name in (
            *("keyframe_m", "keyframe_rad", "submap_m", "loop_every_m", "window_max_m", "window_rad"),
            *("resolution_m", "coarse_m", "sigma_m", "max_range_m", "ambiguity_m", "cauchy", "max_chi2"),
            *("seq_sigma_xy_m", "seq_sigma_rad", "loop_sigma_xy_m", "loop_sigma_rad"),
            *("look_elsewhere_m", "look_elsewhere_rad", "pair_sigma_m"),
        ):
            _check_pos(name, getattr(self, name))
        for name in (
            *("min_loop_travel_m", "window_min_m", "window_per_m", "min_margin", "rebuild_m", "look_elsewhere"),
            *("seq_sigma_xy_per_m", "seq_sigma_lateral_per_m", "seq_sigma_rad_per_m"),
            *("pair_baseline_m", "pair_reach_margin_m", "pair_min_noise_m"),
        ):
            _check_nonneg(name, getattr(self, name))
        for name, least in (("max_points", 30), ("candidates", 1)):
            _check_int(name, getattr(self, name), least)
        for name in ("min_inliers", "max_contradictions"):
            _check_finite(name, getattr(self, name))
            _check_unit(name, getattr(self, name))
        if self.window_min_m > self.window_max_m:
            raise ValueError(f"window_min_m ({self.window_min_m!r}) must be <= window_max_m ({self.window_max_m!r})")
