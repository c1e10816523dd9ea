"""The car simulator: KAIST layout and formats, determinism, and every sensor against geometry."""

from __future__ import annotations

import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import DATA as SHARED_DATA

from pf_slam_nodes.io.mapfile import read_map
from pf_slam_tools.sim import car
from pf_slam_tools.sim import car_sensors as cs
from pf_slam_tools.sim.car_params import PARAM_FILES, extrinsic, yaml_matrix

REAL_PARAM = SHARED_DATA / "kaist_sample" / "param"
DURATION_S = 30.0


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> car.CarSimResult:
    """30 s, 3 stereo pairs, no wheel slip (exact encoder geometry); written once."""
    return car.simulate_car(
        tmp_path_factory.mktemp("car") / "ds", seed=0, duration_s=DURATION_S, stereo_rate_hz=0.1, encoder_slip=0.0
    )


def _rows(path: Path) -> list[list[str]]:
    return [ln.split(",") for ln in path.read_text().splitlines()]


def _bilinear(tex: np.ndarray, origin: np.ndarray, res: float, xy: np.ndarray) -> np.ndarray:
    """Independent bilinear lookup of texel centres (row 0 = lowest y)."""
    fx = (xy[:, 0] - origin[0]) / res - 0.5
    fy = (xy[:, 1] - origin[1]) / res - 0.5
    x0, y0 = np.floor(fx).astype(int), np.floor(fy).astype(int)
    ax, ay = (fx - x0)[:, None], (fy - y0)[:, None]
    t = tex.astype(np.float64)
    return (t[y0, x0] * (1 - ax) + t[y0, x0 + 1] * ax) * (1 - ay) + (
        t[y0 + 1, x0] * (1 - ax) + t[y0 + 1, x0 + 1] * ax
    ) * ay


# ---- layout and formats ---------------------------------------------------------------------


def test_layout_and_csv_formats(sim: car.CarSimResult) -> None:
    d = sim.out_dir
    enc = _rows(d / "sensor_data" / "encoder.csv")
    fog = _rows(d / "sensor_data" / "fog.csv")
    lid = _rows(d / "sensor_data" / "lidar.csv")
    assert {len(r) for r in enc} == {3} and {len(r) for r in fog} == {4}
    assert {len(r) for r in lid} == {287}
    assert len(enc) == sim.n_encoder and len(fog) == sim.n_fog and len(lid) == sim.n_lidar
    assert abs(len(enc) - 100 * DURATION_S) <= 1 and abs(len(lid) - 100 * DURATION_S) <= 1
    assert abs(len(fog) - 1000 * DURATION_S) <= 1
    for rows in (enc, fog, lid):  # no header; int64 ns, increasing
        assert all(re.fullmatch(r"\d{19}", r[0]) for r in rows)
        t = np.array([int(r[0]) for r in rows], dtype=np.int64)
        assert np.all(np.diff(t) > 0) and t[0] >= car.EPOCH_NS
        assert t[-1] < car.EPOCH_NS + int(DURATION_S * 1e9)
    assert all(re.fullmatch(r"-?\d+", v) for r in enc[:50] for v in r[1:])
    assert all(re.fullmatch(r"\d+\.\d{3}", v) for r in lid[:50] for v in r[1:])
    # streams have their own clocks
    firsts = {int(rows[0][0]) % 10_000_000 for rows in (enc, lid)}
    assert len(firsts) == 2
    r = np.array([[float(v) for v in row[1:]] for row in lid])
    assert r.max() <= 80.0 and r.min() >= 0.0
    assert 0.003 < (r == 0).mean() < 0.6


def test_param_files_are_the_real_calibration(sim: car.CarSimResult) -> None:
    for name, text in PARAM_FILES.items():
        data = (sim.out_dir / "param" / name).read_bytes()
        assert data == text.encode()
        if REAL_PARAM.is_dir():
            assert data == (REAL_PARAM / name).read_bytes(), name
    assert sorted(p.name for p in (sim.out_dir / "param").iterdir()) == sorted(PARAM_FILES)
    r, t = extrinsic("Lidar")
    assert r[0, 1] == 0.796097 and t.tolist() == [0.8349, -0.0126869, 1.76416]
    r, t = extrinsic("Stereo")
    assert r[2, 2] == -0.0153234 and t.tolist() == [1.64239, 0.247401, 1.58411]
    fs = cv2.FileStorage(str(sim.out_dir / "param" / "right_camera.yaml"), cv2.FILE_STORAGE_READ)
    p_right = fs.getNode("projection_matrix").mat()
    assert np.array_equal(p_right, yaml_matrix("right_camera.yaml", "projection_matrix"))
    assert -p_right[0, 3] / p_right[0, 0] == pytest.approx(cs.STEREO_BASELINE_M, abs=1e-12)
    assert cs.STEREO_BASELINE_M == pytest.approx(0.475143600050775, abs=1e-5)
    assert (cs.ENCODER_TICKS, cs.WHEEL_D_LEFT_M, cs.WHEEL_D_RIGHT_M, cs.WHEEL_BASE_M) == (
        4096,
        0.623479,
        0.622806,
        1.52439,
    )


def test_stereo_images_are_bayer_pngs(sim: car.CarSimResult) -> None:
    left = sorted((sim.out_dir / "stereo_images" / "stereo_left").glob("*.png"))
    right = sorted((sim.out_dir / "stereo_images" / "stereo_right").glob("*.png"))
    assert len(left) == sim.n_stereo == 3 and [p.name for p in left] == [p.name for p in right]
    for p in left[:1] + right[:1]:
        assert re.fullmatch(r"\d{19}\.png", p.name)
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        assert img.shape == (560, 1280) and img.dtype == np.uint8
        bgr = cv2.cvtColor(img, cv2.COLOR_BAYER_BG2BGR)
        assert bgr[:150].mean(axis=(0, 1))[0] > bgr[:150].mean(axis=(0, 1))[2]  # blue sky


def test_bayer_mosaic_round_trip(sim: car.CarSimResult) -> None:
    rgb = cs.render_rgb(sim.drive.poses_at(np.array([12.0]))[0], sim.world)
    bgr = cv2.cvtColor(cs.rgb_to_bayer(rgb), cv2.COLOR_BAYER_BG2BGR)
    err = np.abs(bgr[..., ::-1].astype(float) - rgb)[2:-2, 2:-2]
    assert err.mean() < 4.0
    assert np.median(err) <= 2.0


def test_ground_truth_files(sim: car.CarSimResult) -> None:
    gt = sim.out_dir / "ground_truth"
    lines = (gt / "poses.csv").read_text().splitlines()
    assert lines[0] == "timestamp,x,y,theta" and len(lines) == 1 + int(100 * DURATION_S)
    stamps = np.array([int(ln.split(",")[0]) for ln in lines[1:]], dtype=np.int64)
    poses = np.array([[0.0] + [float(v) for v in ln.split(",")[1:]] for ln in lines[1:]])
    assert np.all(poses[0, 1:] == 0.0)
    assert stamps[0] == car.EPOCH_NS and np.all(np.diff(stamps) == 10_000_000)
    assert np.all(np.abs(poses[:, 3]) <= math.pi + 1e-6)
    speed = np.hypot(*np.diff(poses[:, 1:3], axis=0).T) / 0.01
    assert speed.max() < 12.5 and speed.max() > 7.0
    assert len(sim.stop_times_s) >= 2  # the initial stand-still and a stop
    occ, res, origin = read_map(gt / "occupancy.yaml")
    assert res == 0.2 and (occ == 100).mean() > 0.1 and (occ == 0).mean() > 0.3
    ij = ((poses[:, 1:3] - origin[:2]) / res).astype(int)
    assert np.all(occ[ij[:, 1], ij[:, 0]] == 0)  # the drive stays in free space
    tex = cv2.imread(str(gt / "floor_texture.png"), cv2.IMREAD_COLOR)
    assert np.array_equal(tex[::-1, :, ::-1], sim.world.texture)
    meta = (gt / "floor_texture.yaml").read_text()
    assert "resolution: 0.1\n" in meta
    assert f"origin: [{sim.world.texture_origin[0]:.6f}" in meta


# ---- determinism ----------------------------------------------------------------------------


def test_deterministic_per_seed(tmp_path: Path) -> None:
    args = ["--seed", "3", "--duration", "3", "--stereo-rate", "0.5"]
    assert car.main(["--out", str(tmp_path / "a")] + args) == 0
    assert car.main(["--out", str(tmp_path / "a")] + args) == 2  # exists, no --force
    car.simulate_car(tmp_path / "b", seed=3, duration_s=3.0, stereo_rate_hz=0.5)
    car.simulate_car(tmp_path / "c", seed=4, duration_s=3.0, stereo_rate_hz=0.5)
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert len(files) == len(PARAM_FILES) + 3 + 6 + 4
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    assert (tmp_path / "a" / "sensor_data" / "lidar.csv").read_bytes() != (
        tmp_path / "c" / "sensor_data" / "lidar.csv"
    ).read_bytes()


# ---- lidar ----------------------------------------------------------------------------------


def test_lidar_against_a_wall_and_the_ground() -> None:
    """Vehicle at the origin facing +x, a 40 m high wall at x = 20 m."""
    wall = np.array([[20.0, -100.0, 0.0, 21.0, 100.0, 40.0]])
    r = cs.lidar_ranges(np.zeros((1, 3)), wall)[0]
    a = np.rad2deg(cs.LIDAR_ANGLES_RAD)
    k90 = int(np.argmin(np.abs(a - 90.0)))
    d = cs.R_LIDAR @ [math.cos(cs.LIDAR_ANGLES_RAD[k90]), math.sin(cs.LIDAR_ANGLES_RAD[k90]), 0]
    assert d[2] > 0.5  # the 90 deg beam looks forward and UP
    assert r[k90] == pytest.approx((20.0 - 0.8349) / d[0], abs=1e-6)
    assert r[k90] == pytest.approx(19.1651 / 0.796097, abs=0.01)
    # the first beam (-5 deg) points down and hits the ground (no wall in its way)
    d0 = cs.R_LIDAR @ [math.cos(math.radians(-5.0)), math.sin(math.radians(-5.0)), 0.0]
    assert d0[2] < 0 and r[0] == pytest.approx(1.76416 / -d0[2], abs=1e-6)
    assert 30.0 < r[0] < 35.0
    # beams 0 .. 180 deg without the wall and the ground in reach: no return
    assert np.isinf(cs.lidar_ranges(np.zeros((1, 3)), wall[:0])[0][(a > 0.5) & (a < 179.5)]).all()
    # a wall on the left (y = 5 m) is hit by the horizontal 0 deg beam at (5 m - T_y) / d_y
    side = np.array([[-50.0, 5.0, 0.0, 50.0, 6.0, 10.0]])
    k0 = int(np.argmin(np.abs(a)))
    r = cs.lidar_ranges(np.zeros((1, 3)), side)[0]
    d = cs.R_LIDAR @ [math.cos(cs.LIDAR_ANGLES_RAD[k0]), math.sin(cs.LIDAR_ANGLES_RAD[k0]), 0]
    assert r[k0] == pytest.approx((5.0 + 0.0126869) / d[1], abs=1e-6)
    # the same scene shifted with the vehicle gives the same ranges
    shifted = side + np.array([3.0, -2.0, 0.0, 3.0, -2.0, 0.0])
    r2 = cs.lidar_ranges(np.array([[3.0, -2.0, 0.0]]), shifted)[0]
    assert np.allclose(r2, r, equal_nan=True)


def test_lidar_csv_matches_ray_casting(sim: car.CarSimResult) -> None:
    lid = _rows(sim.out_dir / "sensor_data" / "lidar.csv")
    rows = lid[::97]
    t = np.array([int(r[0]) for r in rows], dtype=np.int64)
    meas = np.array([[float(v) for v in r[1:]] for r in rows])
    poses = sim.drive.poses_at((t - car.EPOCH_NS) * 1e-9)
    true = cs.lidar_ranges(poses, sim.world.boxes)
    both = (meas > 0) & np.isfinite(true)
    err = meas[both] - true[both]
    assert both.sum() > 1000
    assert abs(err.mean()) < 0.005 and 0.02 < err.std() < 0.03
    miss = (meas == 0) & np.isfinite(true)
    assert 0.003 < miss.sum() / np.isfinite(true).sum() < 0.02  # ~1 % dropouts
    assert np.all(meas[~np.isfinite(true)] == 0.0)


def test_lidar_horizontal_hits_are_on_the_occupancy_map(sim: car.CarSimResult) -> None:
    occ, res, origin = read_map(sim.out_dir / "ground_truth" / "occupancy.yaml")
    lid = _rows(sim.out_dir / "sensor_data" / "lidar.csv")[::50]
    t = np.array([int(r[0]) for r in lid], dtype=np.int64)
    ranges = np.array([[float(v) for v in r[1:]] for r in lid])
    poses = sim.drive.poses_at((t - car.EPOCH_NS) * 1e-9)
    a = np.rad2deg(cs.LIDAR_ANGLES_RAD)
    beams = (np.abs(a) < 2.0) | (np.abs(a - 180.0) < 2.0)  # ~1.7 m above the ground
    dirs = cs.lidar_directions()[beams]
    pts = []
    for pose, rr in zip(poses, ranges[:, beams]):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        rot = np.array([[c, -s], [s, c]])
        ok = rr > 0
        v = cs.T_LIDAR[:2] + rr[ok, None] * dirs[ok, :2]
        pts.append(v @ rot.T + pose[:2])
    p = np.concatenate(pts)
    assert len(p) > 100
    ij = np.floor((p - origin[:2]) / res).astype(int)
    hit = np.zeros(len(p), bool)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            hit |= occ[ij[:, 1] + dj, ij[:, 0] + di] == 100
    assert hit.mean() > 0.95


# ---- encoders and FOG -----------------------------------------------------------------------


def test_encoder_counts_on_a_straight(sim: car.CarSimResult) -> None:
    enc = np.array([[int(v) for v in r] for r in _rows(sim.out_dir / "sensor_data" / "encoder.csv")], dtype=np.int64)
    t = (enc[:, 0] - car.EPOCH_NS) * 1e-9
    theta = sim.drive.poses_at(t)[:, 2]
    s = sim.drive.s_at(t)
    straight = np.flatnonzero(np.abs(theta) < 1e-12)
    i0, i1 = straight[0], straight[-1]
    assert s[i1] - s[i0] > 10.0
    for k, d_true in enumerate(sim.wheel_d_true_m):
        expect = (s[i1] - s[i0]) / (math.pi * d_true) * cs.ENCODER_TICKS
        assert abs((enc[i1, 1 + k] - enc[i0, 1 + k]) - expect) <= 1.0
    # nominal diameters would get the distance wrong by 0.1-0.4 %
    d_nom = (cs.WHEEL_D_LEFT_M, cs.WHEEL_D_RIGHT_M)
    dist = (enc[-1, 1:] - enc[0, 1:]) * np.pi * np.array(d_nom) / cs.ENCODER_TICKS
    travel = (
        np.array(cs.wheel_travel(s[[0, -1]], theta[[0, -1]]))[:, 1]
        - np.array(cs.wheel_travel(s[[0, -1]], theta[[0, -1]]))[:, 0]
    )
    rel = dist / travel - 1.0
    assert np.all(np.abs(rel) > 5e-4) and np.all(np.abs(rel) < 5e-3)
    assert np.all(np.diff(enc[:, 1:], axis=0) >= 0)


def test_encoder_slip_is_a_random_walk() -> None:
    s = np.linspace(0.0, 100.0, 10001)
    th = np.zeros_like(s)
    rng = np.random.default_rng(0)
    ends = np.array([cs.encoder_counts(s, th, (0.62, 0.62), (0, 0), 0.003, rng)[-1, 0] for _ in range(40)])
    ideal = math.floor(100.0 / 0.31 * cs.ENCODER_TICKS / (2 * math.pi))
    sigma_ticks = 0.003 * math.sqrt(100.0 / 0.31) * cs.ENCODER_TICKS / (2 * math.pi)
    assert abs(ends.mean() - ideal) < 4 * sigma_ticks / math.sqrt(40)
    assert 0.5 * sigma_ticks < ends.std() < 1.6 * sigma_ticks


def test_fog_yaw_sum_over_the_turns(sim: car.CarSimResult) -> None:
    fog = np.array([[float(v) for v in r[1:]] for r in _rows(sim.out_dir / "sensor_data" / "fog.csv")])
    t = np.array([int(r[0]) for r in _rows(sim.out_dir / "sensor_data" / "fog.csv")], dtype=np.int64)
    ts = (t - car.EPOCH_NS) * 1e-9
    th = sim.drive.poses_at(np.concatenate([[ts[0] - 1e-3], ts]))[:, 2]
    assert abs(th[-1] - th[0]) > 1.0  # the drive turns within 30 s
    n = len(fog)
    expect = th[-1] - th[0] + sim.fog_bias_rad * n
    assert fog[:, 2].sum() == pytest.approx(expect, abs=5 * car.FOG_SIGMA_RAD * math.sqrt(n))
    # on the initial stand-still the sum is the bias
    still = ts < 0.9
    assert fog[still, 2].sum() == pytest.approx(
        sim.fog_bias_rad * still.sum(), abs=5 * car.FOG_SIGMA_RAD * math.sqrt(n)
    )
    assert np.abs(fog[:, :2]).max() < 1e-5


# ---- stereo ---------------------------------------------------------------------------------


def _ground_rays(pose: np.ndarray, right: bool = False):
    r_wc, c = cs.camera_pose(pose, right)
    f, cx, cy = cs.P_LEFT[0, 0], cs.P_LEFT[0, 2], cs.P_LEFT[1, 2]
    v, u = np.mgrid[0 : cs.IMAGE_H, 0 : cs.IMAGE_W]
    d = np.stack([(u - cx) / f, (v - cy) / f, np.ones(u.shape)], -1) @ r_wc.T
    with np.errstate(divide="ignore"):
        t = np.where(d[..., 2] < 0, -c[2] / d[..., 2], np.inf)
    return c, d, t


def test_camera_convention() -> None:
    r_wc, c = cs.camera_pose(np.zeros(3))
    assert r_wc[:, 2] @ [1, 0, 0] > 0.999  # optical axis = vehicle forward
    assert r_wc[:, 1] @ [0, 0, -1] > 0.999  # image rows go down
    assert r_wc[:, 0] @ [0, -1, 0] > 0.999  # image columns go right
    assert c[2] == pytest.approx(1.58411)
    _, c_r = cs.camera_pose(np.zeros(3), right=True)
    assert np.linalg.norm(c_r - c) == pytest.approx(cs.STEREO_BASELINE_M, abs=1e-6)
    assert c_r[1] < c[1]  # the right camera is on the right


def test_ground_pixels_show_the_floor_texture(sim: car.CarSimResult) -> None:
    pose = sim.drive.poses_at(np.array([0.0]))[0]
    depth = np.empty((cs.IMAGE_H, cs.IMAGE_W))
    rgb = cs.render_rgb(pose, sim.world, grain=False, depth=depth)
    c, d, t = _ground_rays(pose)
    with np.errstate(invalid="ignore"):
        ground = np.isfinite(t) & (np.abs(depth - t) < 1e-3 * t) & (t < 60.0)
    assert ground[cs.IMAGE_H - 60 :, 500:700].all()  # the road right ahead
    vv, uu = np.nonzero(ground)
    pick = np.random.default_rng(0).choice(len(vv), 400, replace=False)
    vv, uu = vv[pick], uu[pick]
    xy = (c + t[vv, uu, None] * d[vv, uu])[:, :2]
    w = sim.world
    expect = _bilinear(w.texture, w.texture_origin, w.texture_res_m, xy)
    assert np.abs(rgb[vv, uu] - expect).max() <= 1.0 + 1e-9
    # 0.3 m off, the texture no longer matches
    wrong = _bilinear(w.texture, w.texture_origin, w.texture_res_m, xy + [0.3, 0.0])
    assert np.abs(rgb[vv, uu] - wrong).mean() > 4.0
    # with the procedural grain the colour stays close on average
    rgb_g = cs.render_rgb(pose, sim.world)
    assert np.abs(rgb_g[vv, uu] - expect).mean() < 8.0


def test_disparity_on_the_road(sim: car.CarSimResult) -> None:
    pose = sim.drive.poses_at(np.array([0.0]))[0]
    depth = np.empty((cs.IMAGE_H, cs.IMAGE_W))
    left = cs.render_rgb(pose, sim.world, depth=depth).astype(np.float64).mean(-1)
    right = cs.render_rgb(pose, sim.world, right=True).astype(np.float64).mean(-1)
    f = cs.P_LEFT[0, 0]
    for v, u in ((430, 600), (380, 640), (330, 560)):
        z = depth[v, u]
        expect = f * cs.STEREO_BASELINE_M / z
        patch = left[v - 5 : v + 6, u - 10 : u + 11]
        shifts = np.arange(0, 120)
        ssd = np.array([((right[v - 5 : v + 6, u - 10 - k : u + 11 - k] - patch) ** 2).sum() for k in shifts])
        k = int(np.argmin(ssd))
        den = ssd[k - 1] - 2 * ssd[k] + ssd[k + 1]
        sub = k + 0.5 * (ssd[k - 1] - ssd[k + 1]) / den
        assert sub == pytest.approx(expect, abs=0.5), (v, u, z)
