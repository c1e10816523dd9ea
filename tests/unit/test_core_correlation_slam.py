"""Likelihood field, scan-to-map correlation and the reference SLAM loop (synthetic worlds)."""

import dataclasses
import math

import numpy as np
import pytest

from pf_slam_nodes.core.config import CorrelationConfig, FilterConfig, GridConfig, OdometryMotionConfig, ResampleConfig
from pf_slam_nodes.core.correlation import (
    GridLikelihoodField,
    build_likelihood_field,
    build_likelihood_field_from_map,
    correlate,
    weighing_points,
)
from pf_slam_nodes.core.grid import LogOddsGrid, from_occupancy
from pf_slam_nodes.core.motion import compose, relative_pose
from pf_slam_nodes.core.scan import beam_angles, scan_to_points
from pf_slam_nodes.core.slam import ParticleFilterSlam

RES = 0.05


def world():
    """int8 occupancy (H, W) of a 12 m x 10 m room with inner boxes; origin (0, 0)."""
    occ = np.zeros((200, 240), dtype=np.int8)
    occ[:2, :] = occ[-2:, :] = 100
    occ[:, :2] = occ[:, -2:] = 100
    occ[40:60, 50:90] = 100
    occ[120:130, 150:200] = 100
    occ[150:190, 60:64] = 100
    occ[70:74, 170:236] = 100
    return occ


def raycast(occ, pose, angles, max_range=20.0, step=0.01):
    """Ranges from ``pose`` to the first occupied cell (test helper, vectorised over beams)."""
    t = np.arange(0.0, max_range, step)
    x = pose[0] + np.cos(pose[2] + angles)[:, None] * t
    y = pose[1] + np.sin(pose[2] + angles)[:, None] * t
    c = np.clip((x / RES).astype(int), 0, occ.shape[1] - 1)
    r = np.clip((y / RES).astype(int), 0, occ.shape[0] - 1)
    hit = occ[r, c] >= 50
    first = np.where(hit.any(axis=1), hit.argmax(axis=1), t.size - 1)
    return t[first]


def test_likelihood_field_values():
    occ = np.full((20, 20), -1, dtype=np.int8)
    occ[10, 10] = 100
    occ[10, 12] = 40  # below threshold: not an obstacle
    f = build_likelihood_field(occ, 0.1, sigma_m=0.1, occupied_threshold=65, origin=(0.0, 0.0), max_distance_m=0.5)
    ll = f.log_likelihood
    assert ll.dtype == np.float32 and ll.shape == (20, 20)
    assert ll[10, 10] == 0.0
    assert ll[10, 13] == pytest.approx(-0.5 * 9)  # d = 0.3 m
    assert ll[0, 0] == pytest.approx(-0.5 * 25)  # clamped at 0.5 m
    assert f.lookup(np.array([[1.05, 1.05], [-5.0, 0.0]])).tolist() == pytest.approx([0.0, -12.5])


def test_incremental_field_equals_full_rebuild():
    occ = world()
    cfg = CorrelationConfig()
    m = from_occupancy(occ, RES, (0.0, 0.0))
    full = build_likelihood_field_from_map(m, cfg)
    inc = GridLikelihoodField(occ.shape[0], occ.shape[1], RES, (0.0, 0.0), cfg)
    inc.update_from_occupancy(occ)
    np.testing.assert_allclose(inc.distance_m, full.distance_m, atol=1e-6)
    occ2 = occ.copy()
    occ2[40:60, 50:90] = 0
    occ2[100, 100] = 100
    inc.update_from_occupancy(occ2)
    full2 = build_likelihood_field(occ2, RES, cfg.sigma_m, cfg.occupied_threshold, (0.0, 0.0), cfg.max_distance_m)
    np.testing.assert_allclose(inc.distance_m, full2.distance_m, atol=1e-6)
    np.testing.assert_allclose(inc.log_likelihood, full2.log_likelihood, atol=1e-5)


@pytest.mark.parametrize("offset", [(0.08, -0.06, 0.03), (-0.15, 0.1, -0.12), (0.0, 0.17, 0.18)])
def test_correlation_recovers_known_offset(offset):
    occ = world()
    true_pose = np.array([6.1, 5.2, 0.4])
    ang = beam_angles(-math.pi / 2, math.pi / 180, 181)
    ranges = raycast(occ, true_pose, ang)
    pts = scan_to_points(ranges, ang, 0.1, 19.0)
    # the map is built from the synthetic scan itself (as the mapper would)
    grid = LogOddsGrid(GridConfig(size_x_m=12.0, size_y_m=10.0, origin_x_m=0.0, origin_y_m=0.0))
    grid.integrate_scan(true_pose, ranges, ang)
    cfg = CorrelationConfig(search_x_m=0.2, search_y_m=0.2, search_yaw_rad=0.2)
    field = build_likelihood_field_from_map(grid.to_occupancy_map(), cfg)
    start = compose(true_pose, np.array(offset))
    rng = np.random.default_rng(0)
    starts = np.vstack([start, start + rng.normal(0, [0.02, 0.02, 0.01], (4, 3))])
    best, scores = correlate(starts, pts, field, cfg)
    assert best.shape == (5, 3) and scores.shape == (5,)
    err = relative_pose(true_pose, best[np.argmax(scores)])
    assert math.hypot(err[0], err[1]) < 0.02 and abs(err[2]) < 0.005
    # a particle far off scores worse than the true pose
    far, far_score = correlate(
        compose(true_pose, np.array([1.0, 1.0, 1.0]))[None],
        pts,
        field,
        CorrelationConfig(search_x_m=0, search_y_m=0, search_yaw_rad=0, refine_iterations=0),
    )
    assert far_score[0] < scores.max()


def _simulate(n_steps=40):
    occ = world()
    ang = beam_angles(-math.pi / 2, math.pi / 180, 181)
    rng = np.random.default_rng(7)
    true = [np.array([3.0, 3.0, 0.3])]
    for k in range(n_steps):
        true.append(compose(true[-1], np.array([0.15, 0.0, 0.04 if k < 20 else -0.03])))
    true = np.array(true)
    d = relative_pose(true[:-1], true[1:])
    odom = [true[0].copy()]
    for k in range(n_steps):  # odometry with a systematic drift and scale errors + noise
        dk = d[k] * np.array([1.05, 1.0, 1.1]) + np.array([0.0, 0.0, 0.01]) + rng.normal(0, [0.01, 0.005, 0.005])
        odom.append(compose(odom[-1], dk))
    scans = [raycast(occ, p, ang) for p in true]
    return true, np.array(odom), scans, ang


def test_slam_loop_beats_odometry_and_is_deterministic():
    true, odom, scans, ang = _simulate()
    cfgs = (
        FilterConfig(num_particles=20, seed=3),
        OdometryMotionConfig(),
        GridConfig(size_x_m=30.0, size_y_m=30.0),
        CorrelationConfig(),
        ResampleConfig(),
    )
    runs = []
    for _ in range(2):
        slam = ParticleFilterSlam(*cfgs)
        est = np.array(
            [slam.process_odometry_scan(0.1 * k, odom[k], scans[k], ang, 0.1, 19.5) for k in range(len(true))]
        )
        runs.append(est)
    np.testing.assert_array_equal(runs[0], runs[1])
    est = runs[0]
    err_est = relative_pose(true[-1], est[-1])
    err_odo = relative_pose(true[-1], odom[-1])
    assert math.hypot(err_est[0], err_est[1]) < 0.1 and abs(err_est[2]) < 0.02
    assert abs(err_odo[2]) > 0.1
    assert slam.particles.shape == (20, 3) and slam.log_weights.shape == (20,)
    occ = slam.grid.occupancy()
    assert occ.dtype == np.int8 and (occ >= 65).sum() > 100


def test_slam_skipped_scans_get_odometry_pose():
    true, odom, scans, ang = _simulate(3)
    slam = ParticleFilterSlam(
        FilterConfig(num_particles=5, min_travel_m=10.0, min_rotation_rad=10.0),
        OdometryMotionConfig(),
        GridConfig(size_x_m=30.0, size_y_m=30.0),
        CorrelationConfig(),
        ResampleConfig(),
    )
    p0 = slam.process_odometry_scan(0.0, odom[0], scans[0], ang)
    p2 = slam.process_odometry_scan(0.2, odom[2], scans[2], ang)
    np.testing.assert_allclose(p0, odom[0])
    np.testing.assert_allclose(p2, compose(odom[0], relative_pose(odom[0], odom[2])), atol=1e-12)
    assert slam.num_updates == 0


@pytest.mark.parametrize("residual", ["likelihood", "distance"])
def test_refine_converges_and_never_increases_cost(residual):
    from pf_slam_nodes.core.correlation import _cost, refine

    occ = world()
    true_pose = np.array([6.1, 5.2, 0.4])
    ang = beam_angles(-math.pi / 2, math.pi / 180, 181)
    pts = scan_to_points(raycast(occ, true_pose, ang), ang, 0.1, 19.0)
    cfg = CorrelationConfig()
    field = build_likelihood_field(occ, RES, cfg.sigma_m, cfg.occupied_threshold, (0.0, 0.0), cfg.max_distance_m)
    starts = np.array(
        [
            compose(true_pose, np.array(o))
            for o in [(0.03, -0.02, 0.01), (-0.04, 0.03, -0.02), (0.0, 0.0, 0.0), (0.02, 0.02, 0.03)]
        ]
    )
    d0 = _cost(starts, pts, field, residual)[0]
    best, cost = refine(starts, pts, field, 30, residual)
    assert np.all(cost <= (d0 * d0).sum(axis=1) + 1e-12)
    d1 = _cost(best, pts, field, residual)[0]
    np.testing.assert_allclose(cost, (d1.astype(np.float64) ** 2).sum(axis=1), rtol=1e-6)  # float32 residuals
    # the starts converge to the optimum reached from the true pose (the raycast world's own bias)
    opt, _ = refine(true_pose[None], pts, field, 30, residual)
    e1 = np.hypot(*relative_pose(opt[0], best)[:, :2].T)
    assert np.median(e1) < 0.01
    # zero iterations: poses unchanged (angle-wrapped)
    same, _ = refine(starts, pts, field, 0, residual)
    np.testing.assert_allclose(same, starts, atol=1e-12)


def test_remap_and_numpy_paths_agree(monkeypatch):
    """OpenCV remap (fields < 32000 cells a side) and the numpy fallback find the same poses."""
    import pf_slam_nodes.core.correlation as corr

    occ = world()
    true_pose = np.array([6.1, 5.2, 0.4])
    ang = beam_angles(-math.pi / 2, math.pi / 180, 181)
    pts = scan_to_points(raycast(occ, true_pose, ang), ang, 0.1, 19.0)
    cfg = CorrelationConfig(search_x_m=0.2, search_y_m=0.2, search_yaw_rad=0.1)
    field = build_likelihood_field(occ, RES, cfg.sigma_m, cfg.occupied_threshold, (0.0, 0.0), cfg.max_distance_m)
    rng = np.random.default_rng(3)
    starts = compose(true_pose, np.array([0.07, -0.05, 0.04])) + rng.normal(0, [0.03, 0.03, 0.02], (20, 3))
    assert corr._use_remap(field)
    w_remap, s_remap = corr.window_search(starts, pts[::2], field, cfg)
    best_remap, score_remap = correlate(starts, pts, field, cfg)
    monkeypatch.setattr(corr, "_REMAP_MAX_CELLS", 0)
    assert not corr._use_remap(field)
    w_np, s_np = corr.window_search(starts, pts[::2], field, cfg)
    best_np, score_np = correlate(starts, pts, field, cfg)
    # window search: the same cells up to float32 rounding at cell edges
    assert np.mean(np.all(np.abs(w_remap - w_np) < 1e-9, axis=1)) >= 0.9
    np.testing.assert_allclose(s_remap, s_np, atol=0.05 * np.abs(s_np).max())
    # refinement: remap's bilinear weights are quantised to 1/32 cell (1.6 mm here)
    e = np.hypot(*(best_remap[:, :2] - best_np[:, :2]).T)
    assert np.median(e) < 0.005 and e.max() < 0.03
    np.testing.assert_allclose(score_remap, score_np, rtol=0.05, atol=1.0)


def test_one_particle_wide_search_gathers_in_numpy_and_finds_the_remap_pose(monkeypatch):
    """Few candidates x points per shift (one particle's +-0.7 m search, recovery.py) go through
    one numpy gather instead of one remap call per shift (225 here): the same pose and score as
    the remap path; many particles stay on remap."""
    import pf_slam_nodes.core.correlation as corr

    occ = world()
    true_pose = np.array([6.1, 5.2, 0.4])
    ang = beam_angles(-math.pi / 2, math.pi / 180, 181)
    pts = scan_to_points(raycast(occ, true_pose, ang), ang, 0.1, 19.0)[::2]
    cfg = CorrelationConfig(search_x_m=0.7, search_y_m=0.7)
    field = build_likelihood_field(occ, RES, cfg.sigma_m, cfg.occupied_threshold, (0.0, 0.0), cfg.max_distance_m)
    start = compose(true_pose, np.array([0.42, -0.31, 0.1]))[None]
    calls = []
    orig = corr._window_scores_remap
    monkeypatch.setattr(corr, "_window_scores_remap", lambda *a: calls.append(1) or orig(*a))
    w_np, s_np = corr.window_search(start, pts, field, cfg)
    assert calls == []
    np.testing.assert_allclose(w_np[0], true_pose, atol=0.051)
    monkeypatch.setattr(corr, "_REMAP_MIN_LOOKUPS", 0)
    w_remap, s_remap = corr.window_search(start, pts, field, cfg)
    assert len(calls) == 1  # one chunk: its 225 shifts are 225 remap calls
    np.testing.assert_allclose(w_np, w_remap, atol=1e-9)
    np.testing.assert_allclose(s_np, s_remap, atol=0.05 * abs(s_np[0]) + 1e-6)
    monkeypatch.setattr(corr, "_REMAP_MIN_LOOKUPS", 2048)
    calls.clear()
    corr.window_search(np.repeat(start, 10, axis=0), pts, field, cfg)
    assert len(calls) == 1  # one chunk: its 225 shifts are 225 remap calls


def test_window_search_any_particle_count_chunks_the_remap():
    """cv2.remap takes fewer than SHRT_MAX (32767) rows: 4000 particles x 9 yaws = 36000 candidate
    rows crashed it. Chunked over particles: 20 000 particles work, and every particle's result
    is the one it gets alone or in a small set (bit for bit), as for the counts that fit one call."""
    import pf_slam_nodes.core.correlation as corr

    occ = world()
    true_pose = np.array([6.1, 5.2, 0.4])
    ang = beam_angles(-math.pi / 2, math.pi / 180, 181)
    pts = scan_to_points(raycast(occ, true_pose, ang), ang, 0.1, 19.0)[::4]
    cfg = CorrelationConfig()  # 9 yaws x 25 shifts
    field = build_likelihood_field(occ, RES, cfg.sigma_m, cfg.occupied_threshold, (0.0, 0.0), cfg.max_distance_m)
    assert corr._use_remap(field) and pts.shape[0] < 32000
    n_yaw = corr._offsets(cfg.search_yaw_rad, cfg.step_yaw_rad).size
    assert 4000 * n_yaw > 32767
    rng = np.random.default_rng(5)
    starts = true_pose + rng.normal(0, [0.1, 0.1, 0.05], (20000, 3))
    best, score = corr.window_search(starts, pts, field, cfg)
    assert best.shape == (20000, 3) and np.isfinite(score).all()
    for i0 in (0, 3555, 19900):  # pieces of 100 particles: one remap call each, as before
        b, s = corr.window_search(starts[i0 : i0 + 100], pts, field, cfg)
        np.testing.assert_array_equal(best[i0 : i0 + 100], b)
        np.testing.assert_array_equal(score[i0 : i0 + 100], s)
    # the search moves the particles towards the true pose
    assert np.median(np.hypot(*(best[:, :2] - true_pose[:2]).T)) < np.median(
        np.hypot(*(starts[:, :2] - true_pose[:2]).T)
    )
    # more points than remap's columns: the numpy path (no crash)
    many = np.repeat(pts, 33000 // pts.shape[0] + 1, axis=0)
    b, s = corr.window_search(starts[:2], many, field, cfg)
    np.testing.assert_allclose(
        s, corr.window_search(starts[:2], pts, field, cfg)[1] * many.shape[0] / pts.shape[0], rtol=0.02
    )


def test_field_block_update_is_exact_across_tiles():
    """Changes scattered over many tiles (as a long-range scan makes them) update the field
    exactly like a rebuild; cells far from every change are not touched."""
    occ = world()
    cfg = CorrelationConfig()
    f = GridLikelihoodField(occ.shape[0], occ.shape[1], RES, (0.0, 0.0), cfg)
    assert f.set_obstacle_block(0, 0, occ >= cfg.occupied_threshold) > 0
    occ2 = occ.copy()
    occ2[5, 5] = occ2[190, 230] = occ2[100, 3] = 100  # far apart: separate tiles
    occ2[40:60, 50:90] = 0
    block = (occ2 >= cfg.occupied_threshold)[3:195, 2:235]
    before = f.distance_m.copy()
    assert f.set_obstacle_block(3, 2, block) == int(np.count_nonzero(block != (occ >= 65)[3:195, 2:235]))
    full = build_likelihood_field(occ2, RES, cfg.sigma_m, cfg.occupied_threshold, (0.0, 0.0), cfg.max_distance_m)
    np.testing.assert_allclose(f.distance_m, full.distance_m, atol=1e-6)
    np.testing.assert_allclose(f.log_likelihood, full.log_likelihood, atol=1e-5)
    assert f.set_obstacle_block(3, 2, block) == 0  # nothing changed: nothing to do
    np.testing.assert_array_equal(f.distance_m[150:160, 120:130], before[150:160, 120:130])


def test_float32_precision_matches_float64_and_is_checked():
    occ = world()
    true_pose = np.array([6.1, 5.2, 0.4])
    ang = beam_angles(-math.pi / 2, math.pi / 180, 181)
    pts = scan_to_points(raycast(occ, true_pose, ang), ang, 0.1, 19.0)
    field = build_likelihood_field(occ, RES, 0.05, 65, (0.0, 0.0), 0.3)
    start = compose(true_pose, np.array([0.05, -0.04, 0.03]))[None]
    b64, s64 = correlate(start, pts, field, CorrelationConfig())
    b32, s32 = correlate(start, pts, field, CorrelationConfig(precision="float32"))
    assert np.hypot(*(b64[0, :2] - b32[0, :2])) < 0.005 and abs(b64[0, 2] - b32[0, 2]) < 0.002
    assert s32[0] == pytest.approx(s64[0], rel=0.05)
    with pytest.raises(ValueError, match="precision"):
        CorrelationConfig(precision="float16")


def corridor_ending_ahead():
    """A 2.4 m wide corridor, the robot at (10, 3) heading along it, its map ending 6 m ahead:
    ``(pose, scan points, field, beam angles)``."""
    occ_true = np.zeros((120, 800), dtype=np.int8)  # 40 m x 6 m, walls at y = 1.8 and 4.2 m
    occ_true[36, :] = occ_true[84, :] = 100
    occ_map = occ_true.copy()
    occ_map[:, 320:] = -1  # mapped up to x = 16 m
    pose = np.array([10.0, 3.0, 0.0])
    ang = beam_angles(-math.pi / 2, math.pi / 180, 181)
    pts = scan_to_points(raycast(occ_true, pose, ang), ang, 0.1, 19.0)
    field = build_likelihood_field(occ_map, RES, 0.05, 65, (0.0, 0.0), 0.3)
    return pose, pts, field, ang


def test_a_bare_corridor_moves_no_match_along_it_with_degenerate_ratio():
    """A corridor whose mapped walls end 6 m ahead (where the robot's map stops): the points
    beyond pull the match back along it. With ``degenerate_ratio`` the match keeps the predicted
    position along the corridor and still corrects across it; in a room nothing changes."""
    pose, pts, field, ang = corridor_ending_ahead()
    start = (pose + np.array([0.0, 0.07, 0.0]))[None]  # 7 cm off across the corridor
    plain, _ = correlate(start, pts, field, CorrelationConfig())
    kept, _ = correlate(start, pts, field, CorrelationConfig(degenerate_ratio=0.02))
    assert plain[0, 0] < pose[0] - 0.05  # pulled back along the corridor
    assert abs(kept[0, 0] - pose[0]) < 1e-9  # along it: as predicted
    assert abs(kept[0, 1] - pose[1]) < 0.02  # across it: corrected
    occ = world()  # a room: every direction is constrained, the same match either way
    p = np.array([6.1, 5.2, 0.4])
    r = raycast(occ, p, ang)
    room = build_likelihood_field(occ, RES, 0.05, 65, (0.0, 0.0), 0.3)
    s = compose(p, np.array([0.08, -0.06, 0.03]))[None]
    a, _ = correlate(s, scan_to_points(r, ang, 0.1, 19.0), room, CorrelationConfig())
    b, _ = correlate(s, scan_to_points(r, ang, 0.1, 19.0), room, CorrelationConfig(degenerate_ratio=0.02))
    assert np.array_equal(a, b)


@pytest.mark.parametrize("shape", ["isotropic", "weak"])
def test_a_refinement_prior_holds_a_bare_corridor_match_along_it_and_not_across(shape):
    """The corridor above, its map ending 6 m ahead: with ``refine_prior_xy_m`` the refined pose
    stays near the prediction along the corridor (where the scan's curvature is weak and the end
    of the mapped wall pulls it back) and is still corrected across it; in a room, where every
    direction is constrained, the prior moves the match by about a centimetre at most. The same
    with ``refine_prior_shape='weak'``, which holds only the direction the points do not
    constrain."""
    pose, pts, field, ang = corridor_ending_ahead()
    start = (pose + np.array([0.0, 0.07, 0.0]))[None]
    cfg = CorrelationConfig(refine_prior_xy_m=0.1, refine_prior_shape=shape)
    plain, s_plain = correlate(start, pts, field, CorrelationConfig())
    held, s_held = correlate(start, pts, field, cfg)
    assert plain[0, 0] < pose[0] - 0.05
    assert abs(held[0, 0] - pose[0]) < 0.02  # along: the prediction
    assert abs(held[0, 1] - pose[1]) < 0.02  # across: corrected
    assert s_held[0] <= s_plain[0]  # the weight is the scan's score at the held pose
    occ = world()
    p = np.array([6.1, 5.2, 0.4])
    room_pts = scan_to_points(raycast(occ, p, ang), ang, 0.1, 19.0)
    room = build_likelihood_field(occ, RES, 0.05, 65, (0.0, 0.0), 0.3)
    s = compose(p, np.array([0.08, -0.06, 0.03]))[None]
    a, _ = correlate(s, room_pts, room, CorrelationConfig())
    b, _ = correlate(s, room_pts, room, cfg)
    assert np.hypot(*(a[0, :2] - b[0, :2])) < 0.015 and abs(a[0, 2] - b[0, 2]) < 0.003
    with pytest.raises(ValueError, match="refine_prior_xy_m"):
        CorrelationConfig(refine_prior_xy_m=-0.1)
    with pytest.raises(ValueError, match="refine_prior_shape"):
        CorrelationConfig(refine_prior_shape="round")


def set_spread_along_corridor():
    """Seven particles spread 0.3 m along :func:`corridor_ending_ahead` (and 3 cm across, by
    turns), the weak-shaped refinement prior, and their plain correlation: ``(set, scan points,
    field, config, refined poses, scores)``."""
    pose, pts, field, _ = corridor_ending_ahead()
    spread = pose + np.array([[dx, 0.03 * (-1) ** i, 0.0] for i, dx in enumerate(np.linspace(-0.15, 0.15, 7))])
    cfg = CorrelationConfig(refine_prior_xy_m=0.15, refine_prior_shape="weak")
    return (spread, pts, field, cfg, *correlate(spread, pts, field, cfg))


def test_weak_score_weighs_a_set_spread_along_a_bare_corridor_alike():
    """The corridor whose map ends 6 m ahead, a set spread 0.3 m along it: the plain weights
    favour the particles furthest back (their points beyond the end of the mapped wall land on
    it): their scores fall by about 17 over the 0.3 m. With ``weak_score`` the particles are
    weighed at the set's mean along the corridor and score within a fraction of that; the
    refined poses are the same either way."""
    spread, pts, field, cfg, plain, s_plain = set_spread_along_corridor()
    held, s_held = correlate(spread, pts, field, dataclasses.replace(cfg, weak_score=True))
    np.testing.assert_array_equal(plain, held)
    assert np.all(np.diff(s_plain) < 0) and s_plain[0] - s_plain[-1] > 5.0  # behind scores better
    assert np.ptp(s_held) < 0.1 * np.ptp(s_plain)
    with pytest.raises(ValueError, match="weak_score"):
        CorrelationConfig(refine_prior_xy_m=0.15, weak_score=True)  # the isotropic shape


def test_the_sparse_grazing_returns_weigh_no_particle_along_a_bare_corridor():
    """The corridor whose map ends 6 m ahead, the set spread 0.3 m along it: the far returns
    from the side walls (more than 1 m apart, at grazing angles) are what weighs the particles
    furthest back up; with ``weigh_graze_span_m`` they weigh no particle, the scores lie within
    a fraction of a unit and the refined poses are the same. ``weigh_range_margin_m`` leaves out
    the returns near the end of the correlation range."""
    spread, pts, field, cfg, plain, s_plain = set_spread_along_corridor()
    kept, s_kept = correlate(spread, pts, field, dataclasses.replace(cfg, weigh_graze_span_m=1.0))
    np.testing.assert_array_equal(plain, kept)
    assert s_plain[0] - s_plain[-1] > 5.0  # behind scores better
    assert np.ptp(s_kept) < 0.01 * np.ptp(s_plain)
    near = weighing_points(pts, CorrelationConfig(range_max_m=8.0, weigh_range_margin_m=2.0))
    r = np.hypot(pts[:, 0], pts[:, 1])
    np.testing.assert_array_equal(near, pts[r <= 6.0])
    with pytest.raises(ValueError, match="weigh_range_margin_m"):
        CorrelationConfig(weigh_range_margin_m=-1.0)
