"""Loop closure (core/posegraph.py, core/loops.py): the pose graph's solution, the loop match
(exact, refused when ambiguous or contradicted), the back end on a drifting loop, and the
stages' frame change (the map re-rendered, the filter's set moved with it)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pf_slam_nodes.core import loops
from pf_slam_nodes.core.config import (
    CorrelationConfig,
    FilterConfig,
    GridConfig,
    LaserConfig,
    LoopClosureConfig,
    ResampleConfig,
)
from pf_slam_nodes.core.geometry import compose, relative_pose, wrap_angle
from pf_slam_nodes.core.loops import LoopCloser, match_submaps, min_inliers, scan_polygon
from pf_slam_nodes.core.posegraph import edge_errors, optimize
from pf_slam_nodes.core.stages import CorrectionStage, MapPatch, MappingStage

# --------------------------------------------------------------------------- pose graph


def test_edge_jacobians_match_finite_differences():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(4, 3))
    i, j = np.array([0, 1, 2, 0]), np.array([1, 2, 3, 3])
    z = rng.normal(size=(4, 3))
    e, a, b = edge_errors(x, i, j, z)
    eps = 1e-7
    for k in range(4):
        for c in range(3):
            for node, jac in ((i[k], a), (j[k], b)):
                xp = x.copy()
                xp[node, c] += eps
                num = (edge_errors(xp, i, j, z)[0][k] - e[k]) / eps
                num[2] = wrap_angle(num[2] * eps) / eps
                np.testing.assert_allclose(num, jac[k][:, c], atol=1e-5)


def _square(n_side: int = 10, step: float = 1.0) -> np.ndarray:
    """Poses around a square, counter-clockwise, ``n_side`` steps a side."""
    poses, p = [], np.zeros(3)
    for _ in range(4):
        for _ in range(n_side):
            poses.append(p)
            p = compose(p, np.array([step, 0.0, 0.0]))
        p = compose(p, np.array([0.0, 0.0, math.pi / 2]))
    return np.array(poses)


def test_pose_graph_spreads_a_loop_error_and_downweights_a_wrong_loop_edge():
    truth = _square()
    n = len(truth)
    z_seq = relative_pose(truth[:-1], truth[1:])
    drifted = z_seq.copy()
    drifted[:, 2] += 0.015  # a heading bias: the chain alone ends 0.6 rad and metres off
    x0 = np.vstack([truth[:1], compose(truth[0], drifted[0])[None]])
    for k in range(1, n - 1):
        x0 = np.vstack([x0, compose(x0[-1], drifted[k])[None]])
    loop = relative_pose(truth[0], truth[-1])
    wrong = relative_pose(truth[5], truth[25]) + np.array([3.0, -2.0, 0.5])
    i = np.concatenate([np.arange(n - 1), [0, 5]])
    j = np.concatenate([np.arange(1, n), [n - 1, 25]])
    z = np.vstack([drifted, loop, wrong])
    info = np.repeat(np.diag([100.0, 100.0, 400.0])[None], len(i), axis=0)
    info[-2:] = np.diag([400.0, 400.0, 2500.0])
    robust = np.arange(len(i)) >= n - 1
    x, chi2 = optimize(x0, i, j, z, info, robust, cauchy=1.0)
    err0 = np.hypot(*(x0[:, :2] - truth[:, :2]).T).max()
    err = np.hypot(*(x[:, :2] - truth[:, :2]).T).max()
    assert err0 > 3.0
    assert err < 0.35 * err0
    assert chi2[-1] > 100 * chi2[-2]  # the wrong edge is the one left disagreeing


# --------------------------------------------------------------------------- loop match


def _room_points(rng: np.random.Generator) -> np.ndarray:
    """Walls of a 12 m x 8 m room with a pillar and two boxes, sampled every 2 cm."""
    segs = [((0, 0), (12, 0)), ((12, 0), (12, 8)), ((12, 8), (0, 8)), ((0, 8), (0, 0))]
    for cx, cy, hx, hy in ((4.0, 3.0, 0.3, 0.3), (8.5, 5.5, 0.8, 0.4), (2.0, 6.5, 0.5, 0.9)):
        c = [(cx - hx, cy - hy), (cx + hx, cy - hy), (cx + hx, cy + hy), (cx - hx, cy + hy)]
        segs += [(c[k], c[(k + 1) % 4]) for k in range(4)]
    pts = []
    for (x0, y0), (x1, y1) in segs:
        n = max(2, int(math.hypot(x1 - x0, y1 - y0) / 0.02))
        t = np.linspace(0, 1, n)
        pts.append(np.stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)], 1))
    p = np.concatenate(pts)
    return p + rng.normal(scale=0.005, size=p.shape)


ROOM_POLY = [np.array([[0.05, 0.05], [11.95, 0.05], [11.95, 7.95], [0.05, 7.95]])]


def test_match_recovers_an_offset_pose_within_centimetres():
    rng = np.random.default_rng(1)
    cfg = LoopClosureConfig(enabled=True)
    ref = _room_points(rng)
    true = np.array([0.7, -0.4, 0.06])  # the query's frame in the reference's
    query = transform_inverse(_room_points(rng), true)
    m = match_submaps(query, ref, ROOM_POLY, np.zeros(3), 1.5, cfg)
    assert m is not None
    pose, score, inliers, contradictions, rival, _ = m
    assert np.hypot(*(pose[:2] - true[:2])) < 0.02
    assert abs(wrap_angle(pose[2] - true[2])) < math.radians(0.3)
    assert inliers > 0.9 and contradictions < 0.02
    assert score - rival > cfg.min_margin


def transform_inverse(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """World points into the frame of ``pose``."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = points - pose[:2]
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1)


def test_match_in_a_featureless_corridor_is_ambiguous():
    """Two long parallel walls: every shift along them fits as well, so the best candidate has
    rivals metres away that score the same and a loop closer must not keep it."""
    x = np.arange(-20, 20, 0.02)
    ref = np.concatenate([np.stack([x, np.full_like(x, -1.2)], 1), np.stack([x, np.full_like(x, 1.2)], 1)])
    query = np.concatenate(
        [np.stack([x[::3] / 2, np.full(x[::3].size, -1.2)], 1), np.stack([x[::3] / 2, np.full(x[::3].size, 1.2)], 1)]
    )
    cfg = LoopClosureConfig(enabled=True)
    poly = [np.array([[-20.0, -1.15], [20.0, -1.15], [20.0, 1.15], [-20.0, 1.15]])]
    pose, score, inliers, _, rival, _ = match_submaps(query, ref, poly, np.zeros(3), 3.0, cfg)
    assert inliers > 0.9
    assert score - rival < cfg.min_margin


def _street(rng: np.random.Generator, half_m: float) -> np.ndarray:
    """Two facades 4 m either side of a street along x (``half_m`` either way), and a pillar on
    the curb."""
    x = np.arange(-half_m, half_m, 0.05)
    pts = [np.stack([x, np.full_like(x, -4.0)], 1), np.stack([x, np.full_like(x, 4.0)], 1)]
    a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    pts.append(np.stack([2.0 + 0.3 * np.cos(a), -2.5 + 0.3 * np.sin(a)], 1))
    p = np.concatenate(pts)
    return p + rng.normal(scale=0.005, size=p.shape)


def test_a_match_that_slides_along_a_street_holds_loosely_along_it_only():
    """A street whose facades fit at every shift along it, and one pillar: from a search narrower
    than ``ambiguity_m`` no rival shows, so the match is kept; but its score falls little along
    the street (the pillar's share), so the loop edge holds along the street loosely and across
    it and in yaw as tightly as any. A room's match falls steeply every way: no loosening."""
    rng = np.random.default_rng(4)
    cfg = LoopClosureConfig(enabled=True, ambiguity_m=2.0)
    poly = [np.array([[-30.0, -3.95], [30.0, -3.95], [30.0, 3.95], [-30.0, 3.95]])]
    true = np.array([0.3, 0.1, 0.02])
    query = transform_inverse(_street(rng, 15.0)[::2], true)
    pose, score, inliers, _, rival, (u, fall) = match_submaps(query, _street(rng, 30.0), poly, np.zeros(3), 1.0, cfg)
    assert abs(pose[1] - true[1]) < 0.02 and abs(pose[0] - true[0]) < 0.2 and inliers > 0.9
    assert score - rival >= cfg.min_margin  # kept: nothing 2 m away was searched
    assert abs(u[0]) > 0.99  # the weakest direction is along the street
    assert 0.0 <= fall < cfg.min_margin / 3
    info = loops.loop_information(cfg, pose, (u, fall))
    along, across = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    assert along @ info @ along < 0.15 * cfg.loop_sigma_xy_m**-2
    assert across @ info @ across == pytest.approx(cfg.loop_sigma_xy_m**-2, rel=1e-3)
    assert info[2, 2] == cfg.loop_sigma_rad**-2
    # the room: the score falls by more than min_margin half ambiguity_m away in every direction
    room = _room_points(rng)
    m = match_submaps(transform_inverse(_room_points(rng), true), room, ROOM_POLY, np.zeros(3), 1.0, cfg)
    assert m[5][1] >= cfg.min_margin
    assert np.allclose(
        loops.loop_information(cfg, m[0], m[5]), np.diag([cfg.loop_sigma_xy_m**-2] * 2 + [cfg.loop_sigma_rad**-2])
    )


def test_loop_information_is_in_the_edge_frame():
    """The weak direction is found in the reference's frame; the edge's error is in ``z``'s
    frame (core/posegraph.py): a match turned by 90 degrees is loose along its own y axis."""
    cfg = LoopClosureConfig(enabled=True)
    info = loops.loop_information(cfg, np.array([0.0, 0.0, math.pi / 2]), (np.array([1.0, 0.0]), 0.0))
    assert info[1, 1] == pytest.approx((cfg.loop_sigma_xy_m * loops.MAX_SLIDE_FACTOR) ** -2)
    assert info[0, 0] == pytest.approx(cfg.loop_sigma_xy_m**-2)
    assert abs(info[0, 1]) < 1e-6 * info[0, 0]


def test_query_points_far_beyond_the_reference_are_neutral():
    """Points of the query that land far outside the reference's grid (another building wing)
    neither index outside the search table nor change the match."""
    rng = np.random.default_rng(3)
    cfg = LoopClosureConfig(enabled=True, max_range_m=5.0)
    ref = _room_points(rng)
    far = np.stack([np.linspace(60.0, 80.0, 300), np.full(300, 60.0)], 1)
    query = np.concatenate([_room_points(rng), far])
    pose, _, inliers, contradictions, _, _ = match_submaps(query, ref, ROOM_POLY, np.zeros(3), 2.0, cfg)
    assert np.hypot(*pose[:2]) < 0.02 and abs(pose[2]) < math.radians(0.3)
    assert contradictions < 0.02 and inliers > 0.7


def test_a_wall_where_the_reference_saw_free_space_contradicts_the_match():
    rng = np.random.default_rng(2)
    cfg = LoopClosureConfig(enabled=True)
    ref = _room_points(rng)
    extra = np.stack([np.full(200, 6.0), np.linspace(1.0, 7.0, 200)], 1)  # a wall across the room
    query = np.concatenate([_room_points(rng), extra])
    _, _, _, contradictions, _, _ = match_submaps(query, ref, ROOM_POLY, np.zeros(3), 1.0, cfg)
    assert contradictions > cfg.max_contradictions


# --------------------------------------------------------------------------- the back end


def _ray_room(pose: np.ndarray, n_beams: int = 181, max_range: float = 20.0):
    """Ranges of a 360-degree laser at ``pose`` in the room of :func:`_room_points` (exact)."""
    from pf_slam_tools.sim.indoor import ray_cast

    segs = []
    for (x0, y0), (x1, y1) in [((0, 0), (12, 0)), ((12, 0), (12, 8)), ((12, 8), (0, 8)), ((0, 8), (0, 0))]:
        segs.append((x0, y0, x1, y1))
    for cx, cy, hx, hy in ((4.0, 3.0, 0.3, 0.3), (8.5, 5.5, 0.8, 0.4), (2.0, 6.5, 0.5, 0.9)):
        c = [(cx - hx, cy - hy), (cx + hx, cy - hy), (cx + hx, cy + hy), (cx - hx, cy + hy)]
        segs += [(*c[k], *c[(k + 1) % 4]) for k in range(4)]
    angles = np.linspace(-math.pi, math.pi, n_beams, endpoint=False)
    r = ray_cast(pose[None], angles, np.asarray(segs, float), max_range).reshape(-1)
    return r, angles


def _loop_drive() -> np.ndarray:
    """Twice around a 6 m x 3 m rectangle inside the room, 0.25 m steps (true poses)."""
    pts = []
    for _ in range(2):
        for (x0, y0), (x1, y1) in (((3, 2), (9, 2)), ((9, 2), (9, 5)), ((9, 5), (3, 5)), ((3, 5), (3, 2))):
            n = int(math.hypot(x1 - x0, y1 - y0) / 0.25)
            th = math.atan2(y1 - y0, x1 - x0)
            for t in np.arange(n) / n:
                pts.append((x0 + t * (x1 - x0), y0 + t * (y1 - y0), th))
    return np.array(pts)


def test_loop_closer_pulls_a_drifting_trajectory_back():
    """The "filter" drifts 0.4 deg and 1 % per metre; once the drive comes round, the corrected
    keyframes are far closer to the truth than the drifted ones."""
    pytest.importorskip("pf_slam_tools")
    truth = _loop_drive()
    inc = relative_pose(truth[:-1], truth[1:])
    inc[:, 0] *= 1.01
    inc[:, 2] += math.radians(0.4) * np.hypot(inc[:, 0], inc[:, 1])
    drifted = [truth[0]]
    for d in inc:
        drifted.append(compose(drifted[-1], d))
    drifted = np.array(drifted)
    cfg = LoopClosureConfig(enabled=True, min_loop_travel_m=10.0, submap_m=5.0)
    lc = LoopCloser(cfg)
    for k, (t, p) in enumerate(zip(truth, drifted)):
        r, a = _ray_room(t)
        ends = np.stack([np.minimum(r, 20.0) * np.cos(a), np.minimum(r, 20.0) * np.sin(a)], 1)
        pts = ends[np.isfinite(r)]
        lc.add(float(k), p, pts, scan_polygon(np.zeros(2), ends))
    assert len(lc.loops) >= 3
    out = compose(lc.corrections(np.arange(len(truth), dtype=float)), drifted)
    before = np.hypot(*(drifted[:, :2] - truth[:, :2]).T)
    after = np.hypot(*(out[:, :2] - truth[:, :2]).T)
    assert before[-20:].mean() > 0.5
    assert after[-20:].mean() < 0.3 * before[-20:].mean()


def test_loop_matches_in_a_worker_process_give_the_same_corrections():
    """Keyframes started and finished apart (the mapper node's worker: process) with the matches in
    a worker process: the same loops and corrections, bit for bit, as add() in this process."""
    pytest.importorskip("pf_slam_tools")
    from pf_slam_nodes.nodes.worker import ProcessBackend

    truth = _loop_drive()[:160]
    inc = relative_pose(truth[:-1], truth[1:])
    inc[:, 0] *= 1.01
    drifted = [truth[0]]
    for d in inc:
        drifted.append(compose(drifted[-1], d))
    cfg = LoopClosureConfig(enabled=True, min_loop_travel_m=10.0, submap_m=5.0)
    here = LoopCloser(cfg)
    apart = LoopCloser(cfg, lambda cls, args: ProcessBackend(cls, args, name="loop matches"))
    waited = 0
    try:
        for k, (t, p) in enumerate(zip(truth, drifted)):
            r, a = _ray_room(t)
            ends = np.stack([np.minimum(r, 20.0) * np.cos(a), np.minimum(r, 20.0) * np.sin(a)], 1)
            pts, poly = ends[np.isfinite(r)], scan_polygon(np.zeros(2), ends)
            here.add(float(k), p, pts, poly)
            if apart.observe(p):
                apart.start_keyframe(float(k), p, pts, poly)
                waited += apart.waiting
                apart.finish_keyframe()
    finally:
        apart.close()
    assert waited == apart.attempts == here.attempts > 0 and len(here.loops) >= 1
    assert [(e.ref, e.cur) for e in apart.loops] == [(e.ref, e.cur) for e in here.loops]
    keys = np.arange(len(truth), dtype=float)
    assert np.array_equal(apart.corrections(keys), here.corrections(keys))


def test_a_wider_search_needs_more_inliers():
    """Look-elsewhere: the best of many wrong poses fits better, so the inlier share a match
    needs grows with the search volume; up to the reference volume it is ``min_inliers``."""
    cfg = LoopClosureConfig(enabled=True)
    assert min_inliers(cfg, 1.0) == cfg.min_inliers
    need = [min_inliers(cfg, w) for w in (2.0, 4.0, 6.0, 10.0)]
    assert need == sorted(need) and need[-1] > 0.55  # the campus's wrong 10 m loops had 0.50-0.52
    assert min_inliers(LoopClosureConfig(window_rad=0.25), 4.0) > cfg.min_inliers  # a wider rotation search
    assert min_inliers(LoopClosureConfig(window_min_m=0.0, window_per_m=0.0), 0.0) == cfg.min_inliers
    assert min_inliers(LoopClosureConfig(window_rad=0.03), 6.0) == cfg.min_inliers  # the car's window
    off = LoopClosureConfig(look_elsewhere=0.0)
    assert min_inliers(off, 10.0) == off.min_inliers


@pytest.mark.parametrize(("window", "kept"), [(2.0, True), (10.0, False)])
def test_a_loop_closer_refuses_a_weak_match_from_a_wide_search(monkeypatch, window, kept):
    """The same match (54 % inliers, no rival) closes the loop from a 2 m search and is refused
    from a 10 m one."""
    calls = []

    def match(query, ref, polys, guess, window_m, cfg):
        calls.append(window_m)
        return np.asarray(guess, dtype=float), 0.54, 0.54, 0.0, -1.0, (np.array([1.0, 0.0]), 1.0)

    monkeypatch.setattr(loops, "match_submaps", match)
    cfg = LoopClosureConfig(
        enabled=True, min_loop_travel_m=10.0, submap_m=4.0, window_min_m=window, window_max_m=window
    )
    lc = LoopCloser(cfg)
    square = [(x, 0.0) for x in range(6)] + [(5.0, y) for y in range(1, 6)]
    square += [(x, 5.0) for x in range(4, -1, -1)] + [(0.0, y) for y in range(4, -2, -1)]
    pts = np.array([[1.0, 1.0], [2.0, -1.0], [3.0, 0.5]])
    for k, (x, y) in enumerate(square):
        lc.add(float(k), np.array([x, y, 0.0]), pts, scan_polygon(np.zeros(2), pts))
    assert calls and calls[0] == window
    assert (len(lc.loops) > 0) is kept and (lc.rejected == 0) is kept


# --------------------------------------------------------------------------- stages


def test_a_frame_change_patch_moves_the_next_set_and_replaces_the_field():
    stage = CorrectionStage(
        FilterConfig(num_particles=3), GridConfig(size_x_m=10, size_y_m=10), CorrelationConfig(), ResampleConfig()
    )
    occ = np.full((40, 60), -1, np.int8)
    occ[10, 5:55] = 100
    move = np.array([1.0, -2.0, 0.3])
    stage.apply_patch(MapPatch(occ, 0.05, np.array([3.0, 4.0]), move))
    assert stage.field.width == 60 and stage.field.height == 40  # exactly the re-rendered grid
    np.testing.assert_allclose(stage.field.origin, [3.0, 4.0])
    parts = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.1], [0.0, 1.0, -0.2]])
    c = stage.correct(parts, np.full(3, -math.log(3)), np.array([]), np.array([]))
    np.testing.assert_allclose(
        c.particles[np.argsort(c.particles[:, 0])], compose(move, parts)[np.argsort(compose(move, parts)[:, 0])]
    )


def test_mapping_stage_maps_poses_across_its_frame_changes():
    stage = MappingStage(FilterConfig(), GridConfig(size_x_m=10, size_y_m=10), None, LoopClosureConfig(enabled=True))
    stage.loops.add(0.0, np.zeros(3), np.zeros((0, 2)), np.zeros((1, 2)))
    stage.loops.opt[0] = [0.5, 0.0, 0.0]  # as if a solution moved the first keyframe
    # the filter's frame changed at key 5: poses from then on are in a frame 1 m further on
    stage.frames.append((5.0, np.array([-1.0, 0.0, 0.0])))
    out = stage.corrected(np.array([1.0, 6.0]), np.array([[2.0, 0.0, 0.0], [3.0, 0.0, 0.0]]))
    np.testing.assert_allclose(out, [[2.5, 0.0, 0.0], [2.5, 0.0, 0.0]], atol=1e-12)


def _street_drive(n: int, odom_scale: float, early: int, applied: float, followed: float):
    """A drive along a bent street, 2 m steps of odometry (the wheels' travel is true travel /
    ``odom_scale``). The filter's poses: its first ``early`` steps at ``followed`` x the odometry's
    travel (1: it followed the unscaled odometry), the rest at the true travel, with the scale
    ``applied`` from keyframe ``early`` on. Returns (truth, filter poses, odometry poses, scales)."""
    yaw = np.concatenate([np.zeros(n // 2), np.full(n - n // 2, math.radians(30.0))])
    steps = np.stack([np.full(n, 2.0), np.zeros(n), np.diff(yaw, prepend=0.0)], axis=1)
    truth, filt, odom = [np.zeros(3)], [np.zeros(3)], [np.zeros(3)]
    for k in range(1, n):
        s = steps[k].copy()
        truth.append(compose(truth[-1], s))
        o = s.copy()
        o[:2] /= odom_scale
        odom.append(compose(odom[-1], o))
        f = o.copy()
        f[:2] *= followed if k < early else odom_scale
        filt.append(compose(filt[-1], f))
    scales = np.where(np.arange(n) < early, 1.0, applied)
    return np.array(truth), np.array(filt), np.array(odom), scales


def _closer(scale_early: bool, filt, odom, scales) -> LoopCloser:
    cfg = LoopClosureConfig(enabled=True, keyframe_m=1.0, min_loop_travel_m=1e4, scale_early_travel=scale_early)
    lc = LoopCloser(cfg)
    pts = np.array([[5.0, 3.0], [5.0, -3.0], [10.0, 3.0]] * 12)
    for k, (p, o, s) in enumerate(zip(filt, odom, scales)):
        lc.add(float(k), p, pts, scan_polygon(np.zeros(2), pts), odom=o, scale=float(s))
    return lc


def test_the_travel_before_the_scale_applied_is_rescaled_to_it():
    """loops.scale_early_travel: the filter followed the wheels' scale (0.993 of the truth) for its
    first 30 steps, then the estimate (0.993) applied; the graph rescales those first steps to the
    estimate times the odometry's travel, so the corrected poses lie on the truth's. Off, or with
    the filter's early travel already at the true scale, or with every scale 1 (the estimate off),
    nothing moves."""
    truth, filt, odom, scales = _street_drive(80, 0.993, 30, 0.993, 1.0)
    keys = np.arange(len(truth), dtype=float)
    off = _closer(False, filt, odom, scales)
    assert np.abs(off.corrections(keys)).max() < 1e-9  # the filter's own chain
    before = np.hypot(*(filt[:, :2] - truth[:, :2]).T)
    assert before[-1] > 0.35  # 30 steps x 2 m x 0.7 %
    on = _closer(True, filt, odom, scales)
    assert on._early_edges() == 29  # the edges into keyframes 1-29
    after = np.hypot(*(compose(on.corrections(keys), filt)[:, :2] - truth[:, :2]).T)
    assert after.max() < 0.03 < 0.1 * before[-1]
    # the filter's matches had already found the true travel: nothing left to rescale
    truth, filt, odom, scales = _street_drive(80, 0.993, 30, 0.993, 0.993)
    done = _closer(True, filt, odom, scales)
    assert np.abs(done.corrections(keys)[:, :2]).max() < 0.01
    # the estimate off (every scale 1): exactly what the graph gives without the option
    truth, filt, odom, _ = _street_drive(80, 0.993, 30, 0.993, 1.0)
    ones = np.ones(len(truth))
    assert np.array_equal(_closer(True, filt, odom, ones).corrections(keys), off.corrections(keys))


def _corridor_scan(rng: np.random.Generator, pose_x: float, posts: np.ndarray) -> np.ndarray:
    """What a 181-beam, 180-degree laser at ``(pose_x, 0, 0)`` sees of a corridor along x with
    walls 2 m either side (the beams' angles offset at random by up to half a beam, so their ends
    fall anywhere along the walls) and ``posts`` (centres ``(P, 2)``, 0.15 m radius, as points):
    what lies ahead within 20 m, in its frame, 1 cm of noise."""
    th = np.radians(np.linspace(-90.0, 90.0, 181) + rng.uniform(-0.5, 0.5))
    th = th[np.abs(np.tan(th)) > 0.1]
    wall = np.stack([2.0 / np.abs(np.tan(th)), np.sign(th) * 2.0], 1)
    a = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    pts = [wall] + [np.stack([px - pose_x + 0.15 * np.cos(a), py + 0.15 * np.sin(a)], 1) for px, py in posts]
    local = np.concatenate(pts)
    local = local[(local[:, 0] > 0.0) & (np.hypot(local[:, 0], local[:, 1]) < 20.0)]
    return local + rng.normal(scale=0.01, size=local.shape)


def _pairs_closer(
    stretch: float, posts: bool, baseline: float, noise: float = math.nan, min_noise: float = 0.0
) -> tuple[LoopCloser, np.ndarray, np.ndarray]:
    """100 m along the corridor in 0.5 m steps, with (``posts``) a post every 2.5-4.5 m on
    alternate sides; the filter's poses stretched along it by ``stretch`` (its matches ran
    ahead), each keyframe's points as seen from the true pose, its laser's noise ``noise``.
    Returns (closer, truth, filter poses)."""
    rng = np.random.default_rng(3)
    px = np.cumsum(rng.uniform(2.5, 4.5, 40)) if posts else np.zeros(0)
    centres = np.stack([px, np.where(np.arange(px.size) % 2 == 0, 1.6, -1.6)], 1)
    truth = np.stack([np.arange(0.0, 100.0, 0.5), np.zeros(200), np.zeros(200)], 1)
    filt = truth * np.array([stretch, 1.0, 1.0])
    cfg = LoopClosureConfig(enabled=True, min_loop_travel_m=1e4, pair_baseline_m=baseline, pair_min_noise_m=min_noise)
    lc = LoopCloser(cfg)
    for k, (t, f) in enumerate(zip(truth, filt)):
        local = _corridor_scan(rng, t[0], centres)
        lc.add(float(k), f, local, scan_polygon(np.zeros(2), local), noise=noise)
    return lc, truth, filt


def test_scan_pairs_take_the_stretch_out_of_the_final_trajectory():
    """loops.pair_baseline_m: the filter ran 1 % ahead along a corridor with posts (nothing a
    loop could see). The scan pairs measure the keyframes' true travel, and the final solve
    brings the stretch down to a fraction of a percent; without pairs (or before the end) the
    chain is the filter's."""
    keys = np.arange(200, dtype=float)
    lc, truth, filt = _pairs_closer(1.01, True, 4.0)
    assert np.abs(lc.corrections(keys)).max() < 1e-9  # during the run: the filter's chain
    n = lc.add_pair_edges()
    assert n > 0.8 * (len(lc) - 5)  # nearly every keyframe 4 m on measures its travel
    assert lc.add_pair_edges() == n  # once per run
    final = compose(lc.corrections(keys), filt)
    before = filt[-1, 0] - truth[-1, 0]
    after = final[-1, 0] - truth[-1, 0]
    assert before > 0.98 and abs(after) < 0.3 * before
    assert np.abs(final[:, 1]).max() < 0.01 and np.abs(final[:, 2]).max() < 1e-3  # nothing across or in yaw
    # off: no pair, the filter's chain
    off, _, _ = _pairs_closer(1.01, True, 0.0)
    assert off.add_pair_edges() == 0 and np.abs(off.corrections(keys)).max() < 1e-9


def test_scan_pairs_measure_nothing_in_a_featureless_corridor():
    """Walls alone fit at every shift along the corridor: no pair is kept, the chain is the filter's."""
    lc, _, _ = _pairs_closer(1.01, False, 4.0)
    assert lc.add_pair_edges() == 0
    assert np.abs(lc.corrections(np.arange(200, dtype=float))).max() < 1e-9


def test_scan_pairs_only_where_the_laser_is_noisy():
    """loops.pair_min_noise_m: keyframes whose laser noise is below it (or not known) are not
    paired; at or above it, the same pairs as without the gate."""
    n_all = _pairs_closer(1.01, True, 4.0)[0].add_pair_edges()
    assert _pairs_closer(1.01, True, 4.0, noise=0.03, min_noise=0.015)[0].add_pair_edges() == n_all > 0
    assert _pairs_closer(1.01, True, 4.0, noise=0.006, min_noise=0.015)[0].add_pair_edges() == 0
    assert _pairs_closer(1.01, True, 4.0, noise=math.nan, min_noise=0.015)[0].add_pair_edges() == 0


@pytest.mark.parametrize("smooth", [2, 0])
def test_the_mapping_stage_keeps_each_keyframes_laser_noise_and_pairs_at_the_end(smooth):
    """loops.pair_min_noise_m: the mapper keeps each keyframe's laser noise as measured before any
    smoothing (the smoothing's own estimate, or the scan's when it does not smooth); its finish()
    adds the scan-pair edges before the last solve."""
    pytest.importorskip("pf_slam_tools")
    rng = np.random.default_rng(5)
    loop_cfg = LoopClosureConfig(enabled=True, min_loop_travel_m=1e4, pair_baseline_m=2.0, pair_min_noise_m=0.015)
    stage = MappingStage(
        FilterConfig(), GridConfig(size_x_m=20, size_y_m=20), LaserConfig(smooth_beams=smooth), loop_cfg
    )
    for k, x in enumerate(np.arange(3.0, 9.0, 0.25)):
        pose = np.array([x, 4.0, 0.0])
        r, a = _ray_room(pose, n_beams=361)
        stage.integrate(pose, r + rng.normal(scale=0.03, size=r.shape), a, 0.0, 20.0, key=float(k))
    noise = np.asarray(stage.loops.noise)
    assert len(noise) >= 5 and np.all((noise > 0.02) & (noise < 0.04))  # the 3 cm laser, not the smoothed scan
    stage.finish()
    assert len(stage.loops.pairs) > 0
