"""Localization on a fixed map, ROS-free (core/localization.py, CorrectionStage.set_map): where
the particles start, that a scan finds the true pose from no guess and from a wrong one, the
convergence rule, and the map files it reads."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from pf_slam_nodes.core import config as cfg
from pf_slam_nodes.core.correlation import build_likelihood_field
from pf_slam_nodes.core.geometry import wrap_angle
from pf_slam_nodes.core.localization import (
    Localizer,
    coarse_scores,
    free_mask,
    sample_free_poses,
    sample_gaussian_poses,
    spread,
)
from pf_slam_nodes.core.stages import CorrectionStage, PredictionStage
from pf_slam_nodes.io.mapfile import read_map

ROOT = Path(__file__).resolve().parents[2]
GT_MAP = ROOT / "bags" / "ground_truth_map.yaml"  # the simulated office, in its start frame


def _stage(**loc) -> CorrectionStage:
    return CorrectionStage(
        cfg.FilterConfig(num_particles=30),
        cfg.GridConfig(),
        cfg.CorrelationConfig(),
        cfg.ResampleConfig(),
        None,
        cfg.LocalizationConfig(**loc),
    )


def _office_scan(pose: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's laser (181 beams, 1 cm noise) at a true pose of the office."""
    indoor = pytest.importorskip("pf_slam_tools.sim.indoor")
    angles = indoor.beam_angles()
    r = indoor.ray_cast(np.asarray(pose, float)[None], angles, indoor.office_world().segments, indoor.RANGE_MAX_M)[0]
    r = r + np.random.default_rng(seed).normal(0.0, 0.01, r.shape)
    return np.where(np.isfinite(r), r, np.inf), angles


def test_free_poses_lie_on_free_cells_and_are_seeded():
    occ = np.full((20, 30), -1, np.int8)
    occ[5:10, 3:8] = 0
    occ[7, 5] = 100
    a = sample_free_poses(free_mask(occ), 0.1, (1.0, -2.0), 500, np.random.default_rng(3))
    b = sample_free_poses(free_mask(occ), 0.1, (1.0, -2.0), 500, np.random.default_rng(3))
    assert np.array_equal(a, b)
    cols = np.floor((a[:, 0] - 1.0) / 0.1).astype(int)
    rows = np.floor((a[:, 1] + 2.0) / 0.1).astype(int)
    assert (occ[rows, cols] == 0).all()
    assert (np.abs(a[:, 2]) <= math.pi).all() and a[:, 2].std() > 1.5  # headings all round
    with pytest.raises(ValueError, match="no free cell"):
        sample_free_poses(np.zeros((3, 3), bool), 0.1, (0, 0), 5, np.random.default_rng(0))


def test_gaussian_poses_follow_the_covariance():
    cov = np.array([[0.25, 0.1, 0.0], [0.1, 0.16, 0.0], [0.0, 0.0, 0.04]])
    p = sample_gaussian_poses([1.0, 2.0, 3.1], cov, 40000, np.random.default_rng(0))
    assert np.allclose(p[:, :2].mean(axis=0), [1.0, 2.0], atol=0.01)
    assert np.allclose(np.cov(p[:, :2].T), cov[:2, :2], atol=0.01)
    d = wrap_angle(p[:, 2] - 3.1)  # wrapped across +-pi, spread kept
    assert (np.abs(p[:, 2]) <= math.pi).all() and abs(d.std() - 0.2) < 0.005
    flat = sample_gaussian_poses([0, 0, 0], np.diag([1.0, 0.0, -1e-12]), 10, np.random.default_rng(0))
    assert np.allclose(flat[:, 1:], 0.0)  # a semi-definite covariance (rviz2 sends zeros) is fine


def test_coarse_scores_are_sums_of_nearest_cell_lookups(monkeypatch):
    occ, res, origin = read_map(GT_MAP)
    field = build_likelihood_field(occ, res, 0.15, 65, origin[:2], 0.45)
    rng = np.random.default_rng(1)
    poses = np.column_stack([rng.uniform(-5, 15, 3000), rng.uniform(-8, 8, 3000), rng.uniform(-4, 4, 3000)])
    pts = rng.uniform(-6, 6, (40, 2))
    got = coarse_scores(poses, pts, field)
    c, s = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3])
    world = np.stack(
        [poses[:, 0:1] + c * pts[:, 0] - s * pts[:, 1], poses[:, 1:2] + s * pts[:, 0] + c * pts[:, 1]], axis=-1
    )
    ref = field.lookup(world).sum(axis=1, dtype=np.float64)
    close = np.isclose(got, ref, rtol=1e-5, atol=1e-3)
    assert close.mean() > 0.97  # the same cells but for float32 rounding at a cell's edge
    assert np.array_equal(coarse_scores(poses[:7], pts, field), got[:7])  # chunking does not matter
    import pf_slam_nodes.core.localization as loc

    monkeypatch.setattr(loc, "_use_remap", lambda *a: False)  # a map too large for remap: numpy lookups
    assert np.array_equal(coarse_scores(poses, pts, field), ref)


@pytest.mark.parametrize("truth", [(0.0, 0.0, 0.0), (5.7, -4.6, 2.2), (-1.2, 4.1, -1.0)])
def test_global_initialisation_finds_the_pose_from_one_scan(truth):
    occ, res, origin = read_map(GT_MAP)
    st = _stage()
    st.set_map(occ, res, origin[:2])
    assert st.pending_init == (None, None)  # no initial pose in the parameters: global
    ranges, angles = _office_scan(truth)
    c = st.correct(np.zeros((30, 3)), np.full(30, -math.log(30)), ranges, angles, 0.1, 20.0)
    assert st.last_init == "global" and st.pending_init is None
    assert math.hypot(*(c.pose[:2] - truth[:2])) < 0.05 and abs(wrap_angle(c.pose[2] - truth[2])) < 0.02
    assert c.particles.shape[0] in (30, st.loc_cfg.init_particles)


def test_wrong_guess_is_corrected_and_the_set_shrinks_once_converged():
    occ, res, origin = read_map(GT_MAP)
    st = _stage()
    st.set_map(occ, res, origin[:2])
    truth = np.array([5.7, -4.6, 2.2])
    st.request_init(truth + [0.6, 0.8, math.radians(30)], np.diag([0.25, 0.25, 0.0685]))
    pred = PredictionStage(cfg.FilterConfig(num_particles=30), cfg.OdometryMotionConfig())
    ranges, angles = _office_scan(truth)
    c = st.correct(pred.particles, pred.log_weights, ranges, angles, 0.1, 20.0)
    assert st.last_init == "initial pose"
    assert math.hypot(*(c.pose[:2] - truth[:2])) < 0.05
    assert c.particles.shape[0] == 30 and st.converged_at == 0  # one scan decided it here
    status = st.localization_status(30)
    assert status["initialisations"] == 1 and status["converged_at_correction"] == 0


def test_spread_and_reduce():
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.normal(0, 0.1, 1000), rng.normal(0, 0.1, 1000), rng.normal(0, 0.02, 1000)])
    lw = np.full(1000, -math.log(1000))
    sxy, syaw = spread(p, lw)
    assert abs(sxy - 0.1 * math.sqrt(2)) < 0.01 and abs(syaw - 0.02) < 0.002
    # two far hypotheses: not converged; one of them weighted out: converged
    two = np.vstack([p[:500], p[500:] + [5.0, 0.0, 0.0]])
    loc = Localizer(
        np.zeros((10, 10), np.int8),
        0.1,
        (0, 0),
        cfg.CorrelationConfig(),
        cfg.LocalizationConfig(converged_xy_m=0.2, converged_yaw_rad=0.05),
    )
    assert not loc.converged(two, lw)
    lw2 = np.where(np.arange(1000) < 500, 0.0, -1e9)
    assert loc.converged(two, lw2)
    small, w = loc.reduce(two, lw2, 30, rng)
    assert small.shape == (30, 3) and np.allclose(w, -math.log(30)) and (small[:, 0] < 1.0).all()


def test_localization_config_checks_its_values():
    assert cfg.LocalizationConfig().init_particles == 2000
    for bad, match in (
        ({"init_particles": 0}, "init_particles"),
        ({"coarse_sigma_m": 0.0}, "coarse_sigma_m"),
        ({"use_initial_pose": 1}, "use_initial_pose"),
        ({"initial_pose_x_m": math.nan}, "initial_pose_x_m"),
    ):
        with pytest.raises(ValueError, match=match):
            cfg.LocalizationConfig(**bad)


def _write(tmp_path: Path, img: np.ndarray, yaml: str, name: str = "m.png") -> Path:
    cv2.imwrite(str(tmp_path / name), img)
    y = tmp_path / "m.yaml"
    y.write_text(f"image: {name}\nresolution: 0.1\norigin: [1.0, 2.0, 0.0]\n" + yaml)
    return y


def test_read_map_modes_as_map_server(tmp_path):
    img = np.array([[0, 254, 205, 100]], np.uint8)  # black, white, grey, dark grey
    occ, _, origin = read_map(
        _write(tmp_path, img, "mode: trinary\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    )
    assert occ.tolist() == [[100, 0, -1, -1]] and origin.tolist() == [1.0, 2.0, 0.0]
    occ, _, _ = read_map(_write(tmp_path, img, "mode: trinary\nnegate: 1\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"))
    assert occ.tolist() == [[0, 100, 100, -1]]  # negate: white is occupied
    occ, _, _ = read_map(_write(tmp_path, img, "mode: scale\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"))
    assert occ.tolist() == [[100, 0, 0, 91]]  # rint(100 (0.608 - 0.196) / (0.65 - 0.196))
    raw = np.array([[0, 50, 100, 255]], np.uint8)
    occ, _, _ = read_map(_write(tmp_path, raw, "mode: raw\n"))
    assert occ.tolist() == [[0, 50, 100, -1]]
    rgba = np.dstack([np.full((1, 2), 0, np.uint8)] * 3 + [np.array([[255, 0]], np.uint8)])
    occ, _, _ = read_map(_write(tmp_path, rgba, "mode: scale\n", "a.png"))
    assert occ.tolist() == [[100, -1]]  # transparent: unknown


def test_read_map_errors_name_the_file(tmp_path):
    with pytest.raises(ValueError, match=r"nope\.yaml: cannot read"):
        read_map(tmp_path / "nope.yaml")
    y = _write(tmp_path, np.zeros((2, 2), np.uint8), "mode: fancy\n")
    with pytest.raises(ValueError, match=r"m\.yaml: bad map yaml \(mode must be"):
        read_map(y)
    y.write_text("image: m.png\norigin: [0, 0, 0]\n")
    with pytest.raises(ValueError, match=r"missing key 'resolution'"):
        read_map(y)
    y.write_text("image: gone.png\nresolution: 0.1\norigin: [0, 0, 0]\n")
    with pytest.raises(ValueError, match=r"gone\.png: missing or not an image"):
        read_map(y)


def test_localize_flags_become_parameters_and_bad_ones_one_line_errors(tmp_path):
    from pf_slam_nodes.graph import RunError, _localize_overrides

    assert _localize_overrides(None, None) == {}
    o = _localize_overrides(str(GT_MAP), "1,-2,0.5")
    assert o["mapper"] == {"mode": "localization", "map_file": str(GT_MAP.resolve())}
    assert o["correlator"] == {
        "mode": "localization",
        "localization.use_initial_pose": True,
        "localization.initial_pose_x_m": 1.0,
        "localization.initial_pose_y_m": -2.0,
        "localization.initial_pose_yaw_rad": 0.5,
    }
    assert "localization.use_initial_pose" not in _localize_overrides(str(GT_MAP), None)["correlator"]
    for args, match in (
        ((None, "1,2,3"), "--initial-pose needs --localize"),
        ((str(tmp_path / "no.yaml"), None), r"--localize: .*no\.yaml: cannot read"),
        ((str(GT_MAP), "1,2"), "expected X,Y,YAW"),
    ):
        with pytest.raises(RunError, match=match) as e:
            _localize_overrides(*args)
        assert "\n" not in str(e.value)


def _room_with_pillar():
    """A 10 m square room (symmetric under quarter turns) with one pillar near its north-west
    corner: segments, and its map at 0.05 m (origin (-6, -6))."""
    room = [(-5, -5, 5, -5), (5, -5, 5, 5), (5, 5, -5, 5), (-5, 5, -5, -5)]
    cx, cy, h = -3.5, 3.5, 0.3
    pillar = [
        (cx - h, cy - h, cx + h, cy - h),
        (cx + h, cy - h, cx + h, cy + h),
        (cx + h, cy + h, cx - h, cy + h),
        (cx - h, cy + h, cx - h, cy - h),
    ]
    segs = np.array(room + pillar, dtype=np.float64)
    res, origin = 0.05, np.array([-6.0, -6.0])
    occ = np.full((240, 240), -1, np.int8)
    occ[20:220, 20:220] = 0  # inside the room
    occ[int((cy - h + 6) / res) : int((cy + h + 6) / res), int((cx - h + 6) / res) : int((cx + h + 6) / res)] = -1
    img = np.zeros(occ.shape, np.uint8)
    for x0, y0, x1, y1 in segs:
        p0 = tuple(int(v) for v in np.floor((np.array([x0, y0]) - origin) / res))
        p1 = tuple(int(v) for v in np.floor((np.array([x1, y1]) - origin) / res))
        cv2.line(img, p0, p1, 255, 1)
    occ[img > 0] = 100
    return segs, occ, res, origin


def test_ambiguous_start_keeps_its_hypotheses_until_a_scan_decides():
    """From the room's centre, facing east, the pillar is behind the 180 deg laser: four headings
    fit the first scan equally, so the set stays large (not converged). Turning round brings the
    pillar into view: the next correction keeps only the true heading and cuts the set."""
    indoor = pytest.importorskip("pf_slam_tools.sim.indoor")
    segs, occ, res, origin = _room_with_pillar()
    angles = indoor.beam_angles()
    fc = cfg.FilterConfig(num_particles=30)
    st = CorrectionStage(
        fc, cfg.GridConfig(), cfg.CorrelationConfig(), cfg.ResampleConfig(), None, cfg.LocalizationConfig()
    )
    st.set_map(occ, res, origin)
    pred = PredictionStage(fc, cfg.OdometryMotionConfig())
    headings = []
    for yaw in (0.0, math.pi):
        truth = np.array([0.2, -0.1, yaw])
        pred.predict(np.array([0.0, 0.0, yaw]))  # odometry: a turn on the spot
        r = indoor.ray_cast(truth[None], angles, segs, indoor.RANGE_MAX_M)[0]
        c = st.correct(pred.particles, pred.log_weights, np.where(np.isfinite(r), r, np.inf), angles, 0.1, 20.0)
        pred.set_corrected(c.particles, c.log_weights)
        w = np.exp(c.log_weights)
        # weight near each of the room's four symmetric images of the true pose (quarter turns about its centre)
        weights = []
        for q in range(4):
            a = q * math.pi / 2
            image = np.array(
                [
                    math.cos(a) * truth[0] - math.sin(a) * truth[1],
                    math.sin(a) * truth[0] + math.cos(a) * truth[1],
                    yaw + a,
                ]
            )
            near = (np.hypot(*(c.particles[:, :2] - image[:2]).T) < 0.1) & (
                np.abs(wrap_angle(c.particles[:, 2] - image[2])) < 0.1
            )
            weights.append(float(w[near].sum()))
        headings.append(weights)
        if yaw == 0.0:
            assert c.particles.shape[0] == st.loc_cfg.init_particles and st.converged_at is None
            assert sum(h > 0.1 for h in headings[0]) >= 3 and sum(headings[0]) > 0.9, headings  # kept
    assert c.particles.shape[0] == 30 and st.converged_at == 1, headings
    assert headings[1][0] > 0.99 and abs(wrap_angle(c.pose[2] - math.pi)) < 0.02
    assert math.hypot(c.pose[0] - 0.2, c.pose[1] + 0.1) < 0.05
