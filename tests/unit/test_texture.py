"""Texture map core: stereo geometry, ground plane, accumulator, rendering; the real KAIST pair
(road plane height, disparity density) and a simulated drive (colour error vs the true floor)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from pf_slam_nodes.core.geometry import nearest_rotation, rpy_to_matrix  # noqa: E402
from pf_slam_nodes.core.texture import (  # noqa: E402
    IncrementalRender,
    StereoRig,
    StereoTexturer,
    TextureConfig,
    TextureMap,
    colour_error,
    debayer,
    fit_ground_plane,
    interpolate_poses,
    measure_stereo_pair,
    north_up_bgr,
    overlay_occupancy,
    road_region_mask,
)
from pf_slam_nodes.io.calib import read_stereo_rig  # noqa: E402
from pf_slam_nodes.io.texture_files import read_floor_texture  # noqa: E402

# A KAIST-like rectified rig (numbers of the real calibration, rounded)
F, CX, CY, B = 775.37, 619.47, 257.18, 0.47515
W, H = 1280, 560
R_VS = nearest_rotation(rpy_to_matrix([-90.878, 0.0132, -90.3899]))
T_VS = np.array([1.64239, 0.247401, 1.58411])


def synthetic_rig() -> StereoRig:
    p_left = np.array([[F, 0, CX, 0], [0, F, CY, 0], [0, 0, 1, 0]], dtype=float)
    p_right = p_left.copy()
    p_right[0, 3] = -F * B
    cam = lambda p: {"K": p[:, :3], "D": np.zeros(5), "R": np.eye(3), "P": p}  # noqa: E731
    return StereoRig(W, H, cam(p_left), cam(p_right), R_VS, T_VS)


def _rz(th: float) -> np.ndarray:
    c, s = math.cos(th), math.sin(th)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


# a textured flat world: 0.02 m texels over x in [-5, 45], y in [-20, 20]
TEX_RES, TEX_ORIGIN = 0.02, np.array([-5.0, -20.0])


def floor_texture() -> np.ndarray:
    """RGB (row 0 = lowest y): multi-scale noise, a white 0.2 m stripe along y = -1.8 (a lane
    edge) and a dashed one along y = 1.7."""
    rng = np.random.default_rng(3)
    h, w = int(40 / TEX_RES), int(50 / TEX_RES)
    tex = np.full((h, w, 3), (90.0, 92.0, 95.0), np.float32)
    for cells, amp in ((250, 25.0), (50, 15.0), (10, 10.0)):
        n = rng.normal(size=(h // cells + 2, w // cells + 2, 3)).astype(np.float32)
        tex += amp * cv2.resize(n, (w + cells, h + cells), interpolation=cv2.INTER_CUBIC)[:h, :w]
    ys = TEX_ORIGIN[1] + (np.arange(h) + 0.5) * TEX_RES
    xs = TEX_ORIGIN[0] + (np.arange(w) + 0.5) * TEX_RES
    tex[np.abs(ys + 1.8) < 0.1] = (235, 235, 230)
    dash = (np.abs(ys - 1.7) < 0.1)[:, None] & (np.mod(xs, 6.0) < 3.0)[None, :]
    tex[dash] = (235, 235, 230)
    return np.clip(tex, 0, 255).astype(np.uint8)


def render(pose: np.ndarray, tex: np.ndarray, right: bool = False) -> np.ndarray:
    """Rectified RGB image of the flat textured world from the rig at vehicle ``pose``."""
    rot = _rz(pose[2])
    r_wc = rot @ R_VS
    c = np.array([pose[0], pose[1], 0.0]) + rot @ T_VS + (r_wc[:, 0] * B if right else 0.0)
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    d = np.stack([(u - CX) / F, (v - CY) / F, np.ones_like(u)], axis=-1) @ r_wc.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d[..., 2] < -1e-9, -c[2] / d[..., 2], np.nan)
    mx = ((c[0] + t * d[..., 0] - TEX_ORIGIN[0]) / TEX_RES - 0.5).astype(np.float32)
    my = ((c[1] + t * d[..., 1] - TEX_ORIGIN[1]) / TEX_RES - 0.5).astype(np.float32)
    img = cv2.remap(
        tex,
        np.nan_to_num(mx, nan=-10),
        np.nan_to_num(my, nan=-10),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=(60, 70, 60),
    )
    img[np.isnan(t)] = (200, 210, 230)  # sky
    return img


# -------------------------------------------------------------------------------- config
def test_config_validates():
    TextureConfig()
    with pytest.raises(ValueError, match="num_disparities"):
        TextureConfig(num_disparities=100)
    with pytest.raises(ValueError, match="block_size"):
        TextureConfig(block_size=6)
    with pytest.raises(ValueError, match="rectify"):
        TextureConfig(rectify="maybe")
    with pytest.raises(ValueError, match="unknown"):
        TextureConfig.from_dict({"cell_size": 0.1})


# -------------------------------------------------------------------------------- geometry
def test_point_grid_round_trip_on_exact_disparity():
    """Disparities of the ground computed from the model come back as points on z = 0 at the
    ray-plane intersections (sub-millimetre)."""
    rig = synthetic_rig()
    tx = StereoTexturer(rig, TextureConfig(rectify="no"))
    k = tx.cfg.downscale
    h, w = (H - tx.first_row) // k, W // k
    v = tx.first_row + k * np.arange(h) + 0.5 * (k - 1)
    u = k * np.arange(w) + 0.5 * (k - 1)
    uu, vv = np.meshgrid(u, v)
    ray_v = rig.pixel_rays(uu.ravel(), vv.ravel()) @ R_VS.T  # vehicle-frame directions
    s = -T_VS[2] / ray_v[:, 2]  # to z = 0
    ground = T_VS + ray_v * s[:, None]
    z_cam = s  # camera depth = ray scale (ray z = 1)
    disp = np.where(s > 0, F * B / z_cam, np.nan).reshape(h, w).astype(np.float32)
    g = tx.point_grid(disp, rectified_here=False).reshape(-1, 3)
    ok = np.isfinite(g[:, 2]) & (s < 60)
    assert ok.sum() > 0.8 * ok.size
    assert np.abs(g[ok] - ground[ok]).max() < 1e-3  # float32 arithmetic, depths up to 60 m
    assert np.abs(g[ok, 2]).max() < 1e-3


def test_fit_ground_plane_with_outliers():
    rng = np.random.default_rng(0)
    n = np.array([0.02, -0.01, 1.0])
    n /= np.linalg.norm(n)
    xy = rng.uniform([3, -8], [20, 8], size=(3000, 2))
    z = -(n[0] * xy[:, 0] + n[1] * xy[:, 1] - 0.05) / n[2] + rng.normal(0, 0.01, 3000)
    pts = np.column_stack([xy, z])
    pts[:600, 2] += rng.uniform(0.3, 2.0, 600)  # 20 % obstacles
    plane, inl = fit_ground_plane(pts, tol_m=0.04, rng=np.random.default_rng(1))
    assert plane is not None
    assert np.degrees(np.arccos(plane.normal @ n)) < 0.2
    assert abs(plane.c - (-0.05)) < 0.005
    assert inl[600:].mean() > 0.95 and inl[:600].mean() < 0.05
    assert fit_ground_plane(pts[:2])[0] is None


def test_interpolate_poses_wraps_the_angle():
    t = np.array([0, 10, 20], dtype=np.int64)
    p = np.array([[0, 0, 3.1], [1, 2, -3.1], [2, 4, -3.0]])
    q = interpolate_poses(t, p, np.array([5, 15, 25, -1]))
    np.testing.assert_allclose(q[0, :2], [0.5, 1.0])
    assert abs(abs(q[0, 2]) - math.pi) < 1e-9  # through +-pi, not through 0
    np.testing.assert_allclose(q[1], [1.5, 3.0, -3.05])
    assert np.isnan(q[2:]).all()


def test_debayer_patterns_and_encodings():
    rgb = np.zeros((4, 4, 3), np.uint8)
    rgb[..., 0] = 200  # pure red
    mosaic = rgb[..., 1].copy()
    mosaic[0::2, 0::2] = rgb[0::2, 0::2, 0]  # R G / G B: bayer_rggb8
    out = debayer(mosaic, "bayer_rggb8", "bilinear")
    assert out[1:3, 1:3, 0].min() > 150 and out[1:3, 1:3, 1:].max() < 50
    np.testing.assert_array_equal(debayer(rgb[..., ::-1].copy(), "bgr8"), rgb)
    with pytest.raises(ValueError, match="encoding"):
        debayer(rgb, "yuv422")


# -------------------------------------------------------------------------------- accumulator
def test_texture_map_running_mean_and_tiles():
    tm = TextureMap(cell_m=0.1, tile_cells=16, max_tiles=4)
    xy = np.array([[0.05, 0.05], [0.06, 0.04], [1.55, 0.05]])
    assert tm.add(xy, [[10, 20, 30], [20, 40, 60], [255, 255, 255]]) == 3
    assert tm.add([[0.01, 0.09]], [[60, 60, 60]]) == 1
    mean, count = tm.tiles[(0, 0)]
    np.testing.assert_allclose(mean[0, 0], [30, 40, 50])  # (10+20+60)/3, ...
    assert count[0, 0] == 3 and tm.cell_count() == 2
    # a scattered batch (many tiles): grouped; beyond max_tiles: dropped and counted
    far = np.array([[100.0 * k, -50.0 * k] for k in range(1, 11)])
    added = tm.add(far, np.full((10, 3), 7))
    assert added == 3 and tm.samples_dropped == 7 and len(tm.tiles) == 4  # (0, 0) + 3 new
    assert tm.memory_bytes == 4 * 16 * 16 * 16


def test_render_geometry_fine_coarse_and_layout():
    tm = TextureMap(cell_m=0.1, tile_cells=8, anchor_xy=(-1.0, -1.0))
    # one red sample at (0.25, 0.72), one blue one at (0.35, 0.78): different 0.1 cells, same 0.2
    tm.add([[0.25, 0.72], [0.35, 0.78]], [[250, 0, 0], [0, 0, 250]])
    rgb, cov = tm.render((-1.0, -1.0), 0.1, 30, 20)  # aligned, same resolution
    assert cov.sum() == 2
    np.testing.assert_array_equal(rgb[17, 12], [250, 1, 1])  # row = (0.72+1)/0.1, col = (0.25+1)/0.1
    np.testing.assert_array_equal(rgb[17, 13], [1, 1, 250])
    assert not rgb[~cov].any()
    rgb2, cov2 = tm.render((-1.0, -1.0), 0.2, 15, 10)  # coarse: sample-weighted mean
    assert cov2.sum() == 1 and cov2[8, 6]
    np.testing.assert_array_equal(rgb2[8, 6], [125, 1, 125])
    rgb3, cov3 = tm.render((0.2, 0.7), 0.05, 4, 2)  # fine: 2 x 2 output per cell
    assert cov3.all() and (rgb3[:, :2, 0] == 250).all() and (rgb3[:, 2:, 2] == 250).all()
    # OccupancyGrid layout -> north-up BGR for a PNG; overlay marks occupied cells red
    bgr = north_up_bgr(rgb)
    np.testing.assert_array_equal(bgr[20 - 1 - 17, 12], [1, 1, 250])
    occ = np.zeros((20, 30), np.int8)
    occ[0, 0] = 100
    over = overlay_occupancy(rgb, cov, occ)
    np.testing.assert_array_equal(over[0, 0], [255, 0, 0])
    np.testing.assert_array_equal(over[17, 12], rgb[17, 12])
    assert over[5, 5].tolist() == [200, 200, 200]


# -------------------------------------------------------------------------------- pipeline
@pytest.mark.parametrize("res", [0.2, 0.1, 0.05])
def test_incremental_render_equals_a_full_render(res):
    """The texture node's periodic image drawn again only where tiles changed (and where the map
    grew) is the full render, pixel for pixel: as the car drives on, as /map grows by whole cells
    on either side, after an origin moved by a fraction of a cell, on a new map object (the
    texture placed again) and at another resolution; and it did skip the unchanged blocks."""
    rng = np.random.default_rng(3)
    tm = TextureMap(cell_m=0.1, tile_cells=32, max_tiles=10_000, anchor_xy=(0.0, 0.0))
    inc = IncrementalRender()
    origin, w, h = np.array([-10.0, -10.0]), int(round(120 / res)), int(round(40 / res))
    calls = []
    orig_render = TextureMap.render

    def counting_render(self, *a, **k):
        calls.append(k.get("only"))
        return orig_render(self, *a, **k)

    TextureMap.render = counting_render
    try:
        for step in range(12):
            x0 = 8.0 * step  # a 10 m x 6 m patch a step, as a car's pairs
            tm.add(rng.uniform([x0, 2.0], [x0 + 10.0, 8.0], size=(20_000, 2)), rng.integers(0, 256, (20_000, 3)))
            if step == 4:  # /map grew west and north by whole cells
                origin, w, h = origin - [res * 37, 0.0], w + 37, h + 19
            if step == 7:  # grew east only
                w += 50
            if step == 9:  # an origin off by a fraction of a cell: drawn whole
                origin = origin + [0.3 * res, 0.0]
            if step == 10:  # the texture placed again: another map object
                tm = tm.copy()
            got = inc.render(tm, origin, res, w, h)
            want = orig_render(tm, origin, res, w, h)
            np.testing.assert_array_equal(got[0], want[0], err_msg=f"step {step}")
            np.testing.assert_array_equal(got[1], want[1], err_msg=f"step {step}")
        got = inc.render(tm, origin, 2 * res, w // 2, h // 2)  # another resolution
        want = orig_render(tm, origin, 2 * res, w // 2, h // 2)
        np.testing.assert_array_equal(got[0], want[0])
    finally:
        TextureMap.render = orig_render
    incremental = [c for c in calls if c is not None]
    assert len(incremental) >= 8  # all but the first, the fractional shift, the new map, the resolution
    assert all(len(changed) < len(tm.tiles) / 2 for changed, _ in incremental)


def test_synthetic_flat_world_texture_and_plane():
    """Rendered stereo pairs of a textured plane: the plane comes back, the texture matches the
    floor (cell means), the lane edge is straight."""
    rig = synthetic_rig()
    tex = floor_texture()
    cfg = TextureConfig(rectify="no")
    tx = StereoTexturer(rig, cfg)
    tm = TextureMap.from_config(cfg, anchor_xy=TEX_ORIGIN)
    for pose in (np.array([0.0, 0.0, 0.02]), np.array([6.0, 0.1, 0.0])):
        res = tx.integrate(tm, render(pose, tex), render(pose, tex, right=True), pose, "rgb8")
        assert res.plane_fitted
        assert abs(abs(res.plane.normal @ T_VS + res.plane.c) - T_VS[2]) < 0.01
        assert res.plane.tilt_deg < 0.2
        assert res.valid_fraction > 0.8
    # ground truth at 0.1 m: the 0.02 m texture averaged 5 x 5
    gt = cv2.resize(tex, (tex.shape[1] // 5, tex.shape[0] // 5), interpolation=cv2.INTER_AREA)
    rgb, cov = tm.render(TEX_ORIGIN, 0.1, gt.shape[1], gt.shape[0])
    score = colour_error(rgb, cov, gt)
    assert score["cells_coloured"] > 20000
    assert score["mean_abs_rgb_error"] < 4.0, score
    # the solid lane edge (y = -1.8) is straight and continuous from 5 to 20 m ahead
    rows = np.arange(gt.shape[0])
    y = TEX_ORIGIN[1] + (rows + 0.5) * 0.1
    band = (y > -2.6) & (y < -1.0)
    cols = np.flatnonzero(
        (TEX_ORIGIN[0] + (np.arange(gt.shape[1]) + 0.5) * 0.1 > 7.0)
        & (TEX_ORIGIN[0] + (np.arange(gt.shape[1]) + 0.5) * 0.1 < 21.0)
    )
    lum = rgb[band][:, cols].astype(float).mean(axis=2)
    assert cov[band][:, cols].any(axis=0).all()  # continuous
    peak_y = y[band][np.argmax(lum, axis=0)]
    assert np.abs(peak_y - (-1.8)).max() <= 0.1  # straight, in place (one cell)


# -------------------------------------------------------------------------------- real pair
@pytest.fixture(scope="module")
def kaist(data_dir: Path) -> Path:
    d = data_dir / "kaist_sample"
    if not (d / "stereo" / "image_left.png").is_file():
        pytest.skip(f"{d}/stereo: real stereo pair not available")
    return d


def test_real_pair_road_plane_and_density(kaist):
    """Measured on the real pair (docs/texture.md): 92 % valid disparity on the ego-lane road
    region, plane 1.607 m below the camera, tilt 0.05 deg. Bounds: density > 0.85; height within
    0.05 m of the calibrated 1.584 m (Vehicle2Stereo T_z: the car's load and pitch, the road's
    camber / crown over the lane (2 % over 1.75 m = 3.5 cm) and the matching (a 0.1 px
    disparity bias moves the plane ~1 cm) each move it by centimetres); tilt < 1 deg."""
    rig = read_stereo_rig(kaist / "param")
    left = cv2.imread(str(kaist / "stereo" / "image_left.png"), cv2.IMREAD_UNCHANGED)
    right = cv2.imread(str(kaist / "stereo" / "image_right.png"), cv2.IMREAD_UNCHANGED)
    m = measure_stereo_pair(left, right, rig)
    assert m.rectified_here  # the real images are not rectified: 'auto' must see it
    assert m.road_mask.sum() > 40000
    assert m.road_density > 0.85, m.as_dict()
    assert m.plane_fitted and abs(m.camera_height_m - 1.584) < 0.05, m.as_dict()
    assert m.tilt_deg < 1.0
    assert m.normal_camera[1] < -0.99  # up = the camera's -y


def test_road_region_is_below_the_horizon_in_the_lane():
    rig = synthetic_rig()
    m = road_region_mask(rig, rectified_here=False)
    rows, cols = np.nonzero(m)

    # 5..15 m ahead of the camera on the ground: the rows those points project to (the camera
    # looks 0.88 deg down: ~12 px above the level-camera rows cy + f h / z)
    def row(ahead: float) -> float:
        q = R_VS.T @ (np.array([T_VS[0] + ahead, T_VS[1], 0.0]) - T_VS)
        return CY + F * q[1] / q[2]

    assert abs(rows.min() - row(15.0)) < 2 and abs(rows.max() - row(5.0)) < 2
    assert abs(row(15.0) - (CY + F * T_VS[2] / 15.0) + 12) < 1
    assert abs(np.median(cols) - CX) < 30


# -------------------------------------------------------------------------------- simulated drive
def test_simulated_drive_colour_error(tmp_path):
    """A 3 s simulated drive (stereo 1 Hz: 3 pairs, the car pulls away: 3.6 m; ~12 s to
    simulate), ground-truth poses. Measured: mean abs RGB error 5.0, coverage 0.94
    (docs/texture.md has the 60 s drive: 5.7 and 0.89). Bounds with margin for other seeds /
    OpenCV builds: < 8, > 0.8."""
    from pf_slam_tools.bench.texture import texture_from_dataset
    from pf_slam_tools.sim.car import simulate_car

    ds = tmp_path / "sim"
    simulate_car(ds, seed=0, duration_s=3.0, stereo_rate_hz=1.0)
    out = texture_from_dataset(ds, tmp_path / "out", log=lambda s: None)
    assert out["pairs_textured"] == 3 and out["rectified_here"] is False
    assert out["mean_abs_rgb_error"] < 8.0, out
    assert out["coverage"] > 0.8, out
    for name in ("texture.png", "texture_overlay.png", "texture_sim.json"):
        assert (tmp_path / "out" / name).is_file()
    # the floor's white markings (lane lines, ~225 grey) come out white, not smeared into the
    # asphalt (78): measured 205 (truth 224) over 761 cells
    assert out["marking_cells"] > 400
    assert out["marking_luminance"] > 180, out
    gt, res, origin = read_floor_texture(ds / "ground_truth" / "floor_texture.png")
    assert res == pytest.approx(0.1) and gt.shape[2] == 3
    png = cv2.imread(str(tmp_path / "out" / "texture.png"))
    assert png is not None and png.ndim == 3


# -------------------------------------------------------------------------------- speed paths
def test_texture_map_add_equals_per_cell_mean_over_tiles():
    """The accumulator (one bincount over the batch's box, then the touched cells tile by tile)
    gives every cell the mean of all samples that fell in it, over several batches, across tile
    borders and with a negative anchor offset; counts are exact."""
    rng = np.random.default_rng(7)
    tm = TextureMap(cell_m=0.1, tile_cells=16, max_tiles=1000, anchor_xy=(-0.33, 0.21))
    xs, cs = [], []
    for k in range(4):
        xy = rng.normal(size=(5000, 2)) * [2.0, 1.5] + [k * 1.0, -k * 0.5]
        col = rng.integers(0, 256, size=(5000, 3)).astype(np.uint8)
        assert tm.add(xy, col) == 5000
        xs.append(xy)
        cs.append(col)
    xy, col = np.concatenate(xs), np.concatenate(cs).astype(np.float64)
    cells = np.floor((xy - tm.anchor) / 0.1).astype(np.int64)
    keys, inv = np.unique(cells, axis=0, return_inverse=True)
    inv = inv.ravel()
    cnt = np.bincount(inv)
    mean = np.stack([np.bincount(inv, weights=col[:, c]) for c in range(3)], axis=-1) / cnt[:, None]
    t = tm.tile_cells
    for (i, j), n, m in zip(keys, cnt, mean):
        tmean, tcount = tm.tiles[(i // t, j // t)]
        assert tcount[j % t, i % t] == n
        np.testing.assert_allclose(tmean[j % t, i % t], m, atol=1e-3)
    assert tm.cell_count() == len(keys) and tm.samples_added == 20000


def test_real_pair_samples_deterministic_and_on_the_ground(kaist):
    """The real pair through two texturers of the same seed, twice each (the second time from the
    cached sample set and rays): the same samples bit for bit; every sample inside the range box; colours from the ground pixels
    (dark asphalt: mean grey well below the sky's)."""
    rig = read_stereo_rig(kaist / "param")
    left = cv2.imread(str(kaist / "stereo" / "image_left.png"), cv2.IMREAD_UNCHANGED)
    right = cv2.imread(str(kaist / "stereo" / "image_right.png"), cv2.IMREAD_UNCHANGED)
    cfg = TextureConfig()
    pose = np.array([3.0, -2.0, 0.4])
    runs = []
    for _ in range(2):  # two texturers (same seed), two pairs each: the second from the caches
        tx = StereoTexturer(rig, cfg)
        runs.append([tx.process(left, right, pose, cells=(np.zeros(2), 0.1)) for _ in range(2)])
    for r1, r2 in zip(*runs):
        np.testing.assert_array_equal(r1.xy_world, r2.xy_world)
        np.testing.assert_array_equal(r1.rgb, r2.rgb)
    a = runs[0][1]
    assert len(a.xy_vehicle) > 50000 and a.plane_fitted
    ahead = a.xy_vehicle[:, 0] - rig.t_vehicle_cam[0]
    assert ahead.min() >= cfg.min_range_m - 1e-6 and ahead.max() <= cfg.max_range_m + 1e-6
    assert np.abs(a.xy_vehicle[:, 1] - rig.t_vehicle_cam[1]).max() <= cfg.max_lateral_m + 1e-6
    assert a.rgb[: len(a.xy_vehicle)].astype(float).mean() < 120


def test_weighted_samples_are_repeated_samples():
    rng = np.random.default_rng(3)
    xy = rng.uniform(-2.0, 2.0, (500, 2))
    rgb = rng.integers(0, 256, (500, 3))
    n = rng.integers(1, 5, 500)
    a, b = TextureMap(), TextureMap()
    a.add(np.repeat(xy, n, axis=0), np.repeat(rgb, n, axis=0))
    b.add(xy, rgb, n)
    ra, ca = a.render((-2.0, -2.0), 0.1, 40, 40)
    rb, cb = b.render((-2.0, -2.0), 0.1, 40, 40)
    np.testing.assert_array_equal(ca, cb)
    assert np.abs(ra.astype(int) - rb.astype(int)).max() <= 1


def _road(rng: np.random.Generator, pose: np.ndarray, n: int = 80000) -> tuple[np.ndarray, np.ndarray]:
    """Samples 3-20 m ahead of `pose`, coloured by a pattern fixed to the ground in the vehicle frame."""
    v = np.column_stack([rng.uniform(3.0, 20.0, n), rng.uniform(-6.0, 6.0, n)])
    rgb = np.column_stack([(v[:, 0] * 40) % 256, (v[:, 1] * 40) % 256, np.full(n, 128.0)])
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.column_stack([pose[0] + c * v[:, 0] - s * v[:, 1], pose[1] + s * v[:, 0] + c * v[:, 1]]), rgb


def test_kept_pairs_are_placed_again_at_the_corrected_poses():
    """Pairs textured at the filter's poses, rebuilt at the corrected ones: the same cells, to the
    bins' resolution, as texturing at the corrected poses in the first place."""
    from pf_slam_nodes.core.texture import PairPatches

    online = np.array([[0.0, 0.0, 0.0], [10.0, 0.3, 0.02], [20.0, 0.8, 0.05]])
    corrected = online + np.array([[0.0, 0.0, 0.0], [0.4, -0.2, 0.01], [0.9, -0.5, 0.02]])
    stamps = np.array([1.0, 2.0, 3.0])
    direct, placed, keep = TextureMap(), TextureMap(), PairPatches(0.05)
    for t, p, q in zip(stamps, online, corrected):
        r = np.random.default_rng(int(t))
        xy, rgb = _road(r, p)
        placed.add(xy, rgb)
        keep.keep(t, p, xy, rgb, placed)
        direct.add(*_road(np.random.default_rng(int(t)), q))
    rebuilt, info = keep.replace(stamps, corrected, placed)
    assert info["pairs_moved"] == 3 and info["pairs_frozen"] == 0
    assert abs(info["shift_max_m"] - np.hypot(0.9, 0.5)) < 1e-3
    geo = ((-5.0, -10.0), 0.1, 400, 200)
    rd, cd = direct.render(*geo)
    rr, cr = rebuilt.render(*geo)
    ro, co = placed.render(*geo)
    both = cd & cr
    assert both.sum() > 0.97 * cd.sum() and abs(int(cr.sum()) - int(cd.sum())) < 0.03 * cd.sum()
    err_rebuilt = np.abs(rr[both].astype(int) - rd[both].astype(int)).mean()
    both_o = cd & co
    err_online = np.abs(ro[both_o].astype(int) - rd[both_o].astype(int)).mean()
    assert err_rebuilt < 3.0 and err_online > 4 * err_rebuilt, (err_rebuilt, err_online)
    # a second trajectory replaces the first: placing is from the kept samples, not cumulative
    again, _ = keep.replace(stamps, corrected, placed)
    np.testing.assert_array_equal(again.render(*geo)[0], rr)


def test_kept_pairs_beyond_the_budget_stay_where_they_were_placed():
    from pf_slam_nodes.core.texture import PairPatches

    rng = np.random.default_rng(1)
    poses = np.array([[0.0, 0.0, 0.0], [30.0, 0.0, 0.0], [60.0, 0.0, 0.0]])
    tm = TextureMap()
    one = PairPatches(0.05)
    one.keep(0.0, poses[0], *_road(rng, poses[0]), tm)
    keep = PairPatches(0.05, budget_bytes=int(1.5 * one.nbytes))  # room for one pair
    for t, p in enumerate(poses):
        keep.keep(float(t), p, *_road(np.random.default_rng(t), p), tm)
    assert len(keep.patches) == 1 and keep.pairs_frozen == 2 and keep.nbytes <= keep.budget_bytes
    moved = poses + [0.0, 1.0, 0.0]
    out, info = keep.replace(np.arange(3.0), moved, tm)
    assert info["pairs_moved"] == 1 and info["pairs_frozen"] == 2
    _, cov = out.render((-5.0, -10.0), 0.1, 900, 200)
    ys = np.nonzero(cov)[0] * 0.1 - 10.0
    xs = np.nonzero(cov)[1] * 0.1 - 5.0
    # the frozen pairs (x < 55 m) stay at |y| <= 6 m; the kept one moved 1 m to the left
    assert ys[xs < 55].max() < 6.1 and ys[xs > 62].max() > 6.8 and ys[xs > 62].min() > -5.1
    with pytest.raises(ValueError):
        PairPatches(0.0)
