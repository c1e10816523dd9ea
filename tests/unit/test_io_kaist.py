"""KAIST Urban layout: calibration parsing on the real files, the Bayer pattern of the real stereo
pair, and round trips of small data sets written here in the exact layout."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import DATA

from pf_slam_nodes.core import geometry
from pf_slam_nodes.core.geometry import quat_to_matrix
from pf_slam_nodes.io import calib
from pf_slam_nodes.io.bag import TYPESTORE, BagError, bag_info, deserialize, read_bag, stamp_ns_of
from pf_slam_nodes.io.kaist import (
    BAYER_ENCODING,
    FOG_BATCH_TYPE,
    convert_kaist,
    kaist_static_transforms,
    read_kaist_layout,
    register_fog_batch,
)

KAIST = DATA / "kaist_sample"
PARAM = KAIST / "param"
needs_data = pytest.mark.skipif(not KAIST.is_dir(), reason=f"{KAIST} not available")

T0 = 1544582648735466220  # a real-looking ns stamp: above 2**53, so float64 would round it


# --------------------------------------------------------------------------------------------
# calibration


@needs_data
def test_parse_real_extrinsics():
    rot, t, rpy = calib.parse_extrinsic(PARAM / "Vehicle2Lidar.txt")
    np.testing.assert_array_equal(rpy, [142.759, 0.0584636, 89.9254])
    np.testing.assert_array_equal(t, [0.8349, -0.0126869, 1.76416])
    assert rot[0, 1] == 0.796097 and rot[1, 0] == 0.999999 and rot[2, 2] == -0.796097  # row-major
    rot_f, t_f, rpy_f = calib.parse_extrinsic(PARAM / "Vehicle2FOG.txt")
    np.testing.assert_array_equal(rot_f, np.eye(3))
    np.testing.assert_array_equal(t_f, [-0.335, -0.035, 0.78])
    np.testing.assert_array_equal(rpy_f, [0, 0, 0])
    rot_s, t_s, rpy_s = calib.parse_extrinsic(PARAM / "Vehicle2Stereo.txt")
    np.testing.assert_array_equal(rpy_s, [-90.878, 0.0132, -90.3899])
    np.testing.assert_array_equal(t_s, [1.64239, 0.247401, 1.58411])
    assert rot_s[0, 2] == 0.99985 and rot_s[2, 1] == -0.999883
    # "XYZ extrinsic" RPY = Rz(yaw) Ry(pitch) Rx(roll) reproduces R to the file's rounding
    for r, a in ((rot, rpy), (rot_s, rpy_s)):
        assert np.abs(geometry.rpy_to_matrix(a) - r).max() < 2e-5
        assert np.abs(geometry.rpy_to_matrix(a) - r.T).max() > 0.5  # the transpose does not
    # R maps camera vectors into the vehicle frame (x forward, y left, z up): the optical axis
    # (camera z) looks forward, image x (right) is the vehicle's -y, image y (down) is -z
    np.testing.assert_allclose(rot_s @ [0, 0, 1], [1, 0, 0], atol=0.02)
    np.testing.assert_allclose(rot_s @ [1, 0, 0], [0, -1, 0], atol=0.02)
    np.testing.assert_allclose(rot_s @ [0, 1, 0], [0, 0, -1], atol=0.02)
    # the lidar's scan plane (its x-y plane) is tilted: its normal points forward and down
    np.testing.assert_allclose(rot @ [0, 0, 1], [0.605167, -0.00160026, -0.796097])


@needs_data
def test_parse_real_params():
    assert calib.parse_encoder_params(PARAM / "EncoderParameter.txt") == {
        "resolution": 4096,
        "left_wheel_diameter_m": 0.623479,
        "right_wheel_diameter_m": 0.622806,
        "wheel_base_m": 1.52439,
    }
    assert calib.parse_lidar_params(PARAM / "lidar_param.txt") == {
        "fov_deg": 190.0,
        "start_deg": -5.0,
        "end_deg": 185.0,
        "resolution_deg": 0.666,
        "max_range_m": 80.0,
    }
    assert calib.parse_stereo_baseline(PARAM / "stereo_param.txt") == pytest.approx(0.475143600050775, abs=1e-15)


@needs_data
def test_read_real_camera_yamls():
    left = calib.read_camera_yaml(PARAM / "left_camera.yaml")
    right = calib.read_camera_yaml(PARAM / "right_camera.yaml")
    assert (left["width"], left["height"]) == (1280, 560)
    assert left["distortion_model"] == "plumb_bob" and left["camera_name"] == "/stereo/left"
    np.testing.assert_array_equal(
        left["K"],
        [
            [8.1690378992770002e02, 5.0510166700000003e-01, 6.0850726281690004e02],
            [0.0, 8.1156803828490001e02, 2.6347599764440002e02],
            [0.0, 0.0, 1.0],
        ],
    )
    np.testing.assert_array_equal(
        left["D"],
        [
            -5.6143027800000002e-02,
            1.3952563200000001e-01,
            -1.2155906999999999e-03,
            -9.7281389999999998e-04,
            -8.0878168799999997e-02,
        ],
    )
    assert left["R"][0, 0] == 9.9996942080938533e-01 and left["R"][2, 1] == -2.2975031148170580e-03
    assert left["P"].shape == (3, 4) and left["P"][0, 0] == 7.7537235550066748e02
    assert right["P"][0, 3] == -3.6841758740842312e02
    # the right projection's Tx = -fx * baseline agrees with stereo_param.txt
    baseline = calib.parse_stereo_baseline(PARAM / "stereo_param.txt")
    assert -right["P"][0, 3] / right["P"][0, 0] == pytest.approx(baseline, rel=1e-4)


def test_calib_errors(tmp_path):
    with pytest.raises(ValueError, match="missing"):
        calib.parse_extrinsic(tmp_path / "nope.txt")
    f = tmp_path / "Vehicle2X.txt"
    f.write_text("RPY: 0 0 0\nR: 1 0 0 0 1 0 0 0\nT: 0 0 0\n")
    with pytest.raises(ValueError, match=r'Vehicle2X.txt: "r:" needs 9 numbers'):
        calib.parse_extrinsic(f)
    f.write_text("RPY: 0 0 0\nR: 2 0 0 0 1 0 0 0 1\nT: 0 0 0\n")
    with pytest.raises(ValueError, match="not a rotation"):
        calib.parse_extrinsic(f)
    f.write_text("Encoder resolution: abc\n")
    with pytest.raises(ValueError, match="encoder resolution"):
        calib.parse_encoder_params(f)
    y = tmp_path / "cam.yaml"
    y.write_text("%YAML:1.0\n---\nimage_width: [1, 2\n")
    with pytest.raises(ValueError, match="cam.yaml"):
        calib.read_camera_yaml(y)


def test_matrix_to_quat_robust():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[:4] = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]  # 180 deg turns, identity
    q[4] = [1e-9, 0.6, 0.8, 0.0]
    for qi in q:
        got = geometry.matrix_to_quat(quat_to_matrix(*qi))
        sign = 1.0 if np.dot(got, qi) >= 0 else -1.0
        np.testing.assert_allclose(got, sign * qi, atol=1e-9)
        assert got[3] >= 0.0
    with pytest.raises(ValueError):
        geometry.matrix_to_quat(np.full((3, 3), np.nan))


@needs_data
def test_static_transforms_from_real_files():
    warnings: list = []
    tfs = {child: (xyz, q) for parent, child, xyz, q in kaist_static_transforms(PARAM, warnings)}
    assert warnings == []
    assert set(tfs) == {"lidar", "fog", "stereo_left", "stereo_right"}
    for child, fname in (
        ("lidar", "Vehicle2Lidar.txt"),
        ("stereo_left", "Vehicle2Stereo.txt"),
        ("fog", "Vehicle2FOG.txt"),
    ):
        rot, t, rpy = calib.parse_extrinsic(PARAM / fname)
        xyz, q = tfs[child]
        np.testing.assert_array_equal(xyz, t)
        # the file's R is rounded to 6 digits: the quaternion is that of the nearest rotation
        np.testing.assert_allclose(quat_to_matrix(*q), rot, atol=2e-5)
        # and the same rotation as the RPY line's (both with w >= 0)
        q_rpy = geometry.matrix_to_quat(geometry.rpy_to_matrix(rpy))
        np.testing.assert_allclose(q, q_rpy, atol=2e-5)
    np.testing.assert_allclose(tfs["lidar"][1], (0.670414, 0.669772, 0.225289, 0.226267), atol=1e-6)
    assert tfs["fog"][1] == (0.0, 0.0, 0.0, 1.0)
    # right camera: 0.4751 m along the left camera's x axis (the vehicle's -y), same rotation
    rot_s, t_s, _ = calib.parse_extrinsic(PARAM / "Vehicle2Stereo.txt")
    d = np.array(tfs["stereo_right"][0]) - t_s
    assert np.linalg.norm(d) == pytest.approx(0.475143600050775, abs=1e-12)
    np.testing.assert_allclose(d, 0.475143600050775 * geometry.nearest_rotation(rot_s)[:, 0], atol=1e-12)
    np.testing.assert_allclose(d, 0.475143600050775 * rot_s[:, 0], atol=1e-5)
    assert d[1] < -0.47
    assert tfs["stereo_right"][1] == tfs["stereo_left"][1]


# --------------------------------------------------------------------------------------------
# Bayer pattern


def test_bayer_bg2bgr_is_rggb():
    """OpenCV's COLOR_BAYER_BG2BGR decodes a mosaic whose top-left cell is R G / G B, which is
    ROS ``bayer_rggb8`` (cv_bridge maps bayer_rggb8 -> COLOR_BayerBG2BGR for the same reason)."""
    bgr = np.zeros((8, 8, 3), np.uint8)
    bgr[:] = (30, 60, 200)
    mosaic = np.empty((8, 8), np.uint8)
    mosaic[0::2, 0::2] = bgr[0::2, 0::2, 2]  # R
    mosaic[0::2, 1::2] = bgr[0::2, 1::2, 1]  # G
    mosaic[1::2, 0::2] = bgr[1::2, 0::2, 1]  # G
    mosaic[1::2, 1::2] = bgr[1::2, 1::2, 0]  # B
    assert BAYER_ENCODING == "bayer_rggb8"
    np.testing.assert_array_equal(cv2.cvtColor(mosaic, cv2.COLOR_BAYER_BG2BGR)[4, 4], (30, 60, 200))
    np.testing.assert_array_equal(cv2.cvtColor(mosaic, cv2.COLOR_BAYER_RG2BGR)[4, 4], (200, 60, 30))


def _hue_fractions(bgr: np.ndarray) -> tuple[float, float]:
    """Of the clearly coloured pixels: fraction with a red-to-green hue (0..170 deg), fraction
    blue-to-purple (190..330 deg)."""
    chroma = bgr.max(-1).astype(int) - bgr.min(-1) > 30
    hue = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)[..., 0][chroma].astype(int) * 2
    return float(np.mean(hue < 170)), float(np.mean((hue >= 190) & (hue < 330)))


@needs_data
@pytest.mark.parametrize("side", ["left", "right"])
def test_real_stereo_pair_is_rggb(side):
    """Evidence on the real pair (measured, left / right):

    * green phase: GB2BGR / GR2BGR give a magenta cast (mean G - (R+B)/2 = -4.9 / -4.1), BG2BGR /
      RG2BGR give +4.8 / +4.0, so green sits at (0,1), (1,0): the pattern is RGGB or BGGR;
    * red / blue: with BG2BGR the sunlit road is a warm grey (B, G, R = 33, 47, 51) and 76 % of
      the coloured pixels have red-to-green hues (trees, orange cones, tail lights) against 17 %
      blue-purple (sky is overexposed white); with RG2BGR the road turns blue (51, 47, 33) and
      53 % of the coloured pixels are blue-purple. Viewed, BG2BGR shows green trees and orange
      traffic cones, RG2BGR blue ones.
    """
    raw = cv2.imread(str(KAIST / "stereo" / f"image_{side}.png"), cv2.IMREAD_UNCHANGED)
    assert raw.shape == (560, 1280) and raw.dtype == np.uint8
    dec = {c: cv2.cvtColor(raw, getattr(cv2, f"COLOR_BAYER_{c}2BGR")) for c in ("BG", "RG", "GB", "GR")}
    green_excess = {c: float(b[..., 1].mean() - (b[..., 0].mean() + b[..., 2].mean()) / 2) for c, b in dec.items()}
    assert green_excess["BG"] > 3 and green_excess["RG"] > 3
    assert green_excess["GB"] < -3 and green_excess["GR"] < -3
    road = dec["BG"][400:, 300:900].reshape(-1, 3).mean(0)
    assert road[2] > road[1] > road[0]  # asphalt in sunlight: warm grey, not blue
    warm, cool = _hue_fractions(dec["BG"])
    assert warm > 0.7 and cool < 0.25
    warm_rg, cool_rg = _hue_fractions(dec["RG"])
    assert cool_rg > 0.5 and warm_rg < 0.45


# --------------------------------------------------------------------------------------------
# round trip on a small data set in the exact layout


def _png(path: Path, seed: int, shape=(560, 1280)) -> np.ndarray:
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    img = ((xx // 16 + yy // 16 * 3 + seed * 7) % 256).astype(np.uint8)
    img[seed::97, :] = 255
    assert cv2.imwrite(str(path), img)
    return img


def _write_csv(path: Path, rows: list[str], bad: dict[int, str], header: str | None) -> dict:
    """Write ``rows``; ``bad`` = {index in rows before which to insert: bad line}.

    Returns {line number: bad line}."""
    lines, bad_lines = [], {}
    if header:
        lines.append(header)
    for i, row in enumerate(rows):
        if i in bad:
            lines.append(bad[i])
            bad_lines[len(lines)] = bad[i]
        lines.append(row)
    path.write_text("\n".join(lines) + "\n")
    return bad_lines


def make_dataset(root: Path, n_enc=60, n_fog=503, n_scan=50, bad=True) -> dict:
    """A small data set in the KAIST layout: real param files, synthetic CSVs and PNGs."""
    rng = np.random.default_rng(1)
    shutil.copytree(PARAM, root / "param")
    sd = root / "sensor_data"
    sd.mkdir(parents=True)
    exp: dict = {"bad_lines": {}}

    enc_t = T0 + np.arange(n_enc, dtype=np.int64) * 10_000_000 + rng.integers(0, 1000, n_enc)
    enc_c = np.cumsum(rng.integers(0, 40, (n_enc, 2)), axis=0)
    rows = [f"{t},{a},{b}" for t, a, b in zip(enc_t, enc_c[:, 0], enc_c[:, 1])]
    bad_enc = (
        {
            10: f"{enc_t[9] + 5},1",
            20: f"{enc_t[19] + 5},12x,3",
            30: f"{enc_t[29] + 5},nan,3",
            40: f"{enc_t[39]},1,2",
            50: f"{enc_t[40]},1,2",
        }
        if bad
        else {}
    )
    exp["bad_lines"]["encoder.csv"] = _write_csv(sd / "encoder.csv", rows, bad_enc, None)
    exp["enc"] = (enc_t, enc_c)

    fog_t = T0 - 3_000_000 + np.arange(n_fog, dtype=np.int64) * 1_000_000 + 17
    fog_d = rng.normal(0.0, 1e-4, (n_fog, 3))
    rows = [f"{t},{a!r},{b!r},{c!r}" for t, (a, b, c) in zip(fog_t, fog_d.tolist())]
    bad_fog = {5: f"{fog_t[4] + 1},0.1,0.2", 100: f"{fog_t[99] + 1},0.1,inf,0.2", 200: "T0,0,0,0"} if bad else {}
    exp["bad_lines"]["fog.csv"] = _write_csv(
        sd / "fog.csv", rows, bad_fog, "timestamp,delta_roll,delta_pitch,delta_yaw"
    )
    exp["fog"] = (fog_t, fog_d)

    scan_t = T0 + 5_000_000 + np.arange(n_scan, dtype=np.int64) * 10_000_000
    ranges = np.round(rng.uniform(1.0, 79.0, (n_scan, 286)), 3)
    ranges[rng.random((n_scan, 286)) < 0.1] = 0.0
    rows = [f"{t}," + ",".join(f"{r:g}" for r in rr) for t, rr in zip(scan_t, ranges)]
    bad_scan = (
        {3: f"{scan_t[2] + 1}," + ",".join(["1"] * 285), 7: f"{scan_t[5]}," + ",".join(["1"] * 286)} if bad else {}
    )
    exp["bad_lines"]["lidar.csv"] = _write_csv(sd / "lidar.csv", rows, bad_scan, None)
    exp["scan"] = (scan_t, ranges)

    img_t = [int(T0 + 100_000_000 + k * 100_000_000) for k in range(3)]
    imgs = {}
    for cam in ("left", "right"):
        d = root / "stereo_images" / f"stereo_{cam}"
        d.mkdir(parents=True)
        for k, t in enumerate(img_t):
            imgs[cam, t] = _png(d / f"{t}.png", k + (cam == "right"))
    exp["img_t"], exp["imgs"] = img_t, imgs
    return exp


def _msgs(bag, topic):
    return [(t, deserialize(raw, mt)) for _, mt, t, raw in read_bag(bag, topics=[topic])]


@needs_data
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_round_trip(tmp_path, storage):
    root = tmp_path / "kaist"
    exp = make_dataset(root)
    # a truncated PNG replaces the last left image
    bad_png = root / "stereo_images" / "stereo_left" / f"{exp['img_t'][2]}.png"
    bad_png.write_bytes(bad_png.read_bytes()[:200])
    out = tmp_path / "bag"
    rep = convert_kaist(root, out, storage=storage)

    enc_t, enc_c = exp["enc"]
    fog_t, fog_d = exp["fog"]
    scan_t, ranges = exp["scan"]
    assert rep.counts == {
        "/tf_static": 1,
        "/encoders": len(enc_t),
        "/fog": math.ceil(len(fog_t) / 10),
        "/scan": len(scan_t),
        "/stereo/left/image_raw": 2,
        "/stereo/left/camera_info": 2,
        "/stereo/right/image_raw": 3,
        "/stereo/right/camera_info": 3,
    }
    assert rep.skipped == {
        "encoder.csv: expected 3 columns, got 2": 1,
        "encoder.csv: non-numeric value": 1,
        "encoder.csv: NaN or inf value": 1,
        "encoder.csv: timestamp repeats": 1,
        "encoder.csv: timestamp steps back": 1,
        "fog.csv: expected 4 columns, got 3": 1,
        "fog.csv: NaN or inf value": 1,
        "fog.csv: non-numeric timestamp": 1,
        "lidar.csv: expected 287 columns, got 286": 1,
        "lidar.csv: timestamp steps back": 1,
        "stereo_left: bad image": 1,
    }
    for fname, bad_lines in exp["bad_lines"].items():
        for line_no in bad_lines:
            assert sum(f"{fname}:{line_no}: " in w for w in rep.warnings) == 1, (fname, line_no)
    assert any(str(bad_png) in w and "image skipped" in w for w in rep.warnings)
    assert len(rep.warnings) == 11

    info = bag_info(out)
    assert info["storage"] == storage
    assert info["custom_data"]["pf_slam.encoder_resolution"] == "4096"
    assert float(info["custom_data"]["pf_slam.left_wheel_diameter_m"]) == 0.623479
    assert float(info["custom_data"]["pf_slam.right_wheel_diameter_m"]) == 0.622806
    assert float(info["custom_data"]["pf_slam.wheel_base_m"]) == 1.52439
    assert info["topics"]["/fog"][0] == FOG_BATCH_TYPE
    # a FogBatch is stamped (and recorded) at its last sample
    t_first = min(enc_t[0], fog_t[9], scan_t[0], exp["img_t"][0])
    assert rep.start_ns == t_first
    assert rep.end_ns == max(enc_t[-1], fog_t[-1], scan_t[-1], exp["img_t"][2])

    # record times: merged in time order, each = its header stamp; tf_static first
    allmsgs = list(read_bag(out))
    assert allmsgs[0][0] == "/tf_static" and allmsgs[0][2] == t_first
    rec = np.array([t for _, _, t, _ in allmsgs], dtype=np.int64)
    assert np.all(np.diff(rec) >= 0)
    for topic, mt, t, raw in allmsgs:
        msg = deserialize(raw, mt)
        if topic != "/tf_static":
            assert stamp_ns_of(msg) == t, topic

    enc = _msgs(out, "/encoders")
    assert [t for t, _ in enc] == enc_t.tolist()
    pos = np.array([m.position for _, m in enc])
    np.testing.assert_array_equal(pos, enc_c * (2 * np.pi / 4096))
    assert list(enc[0][1].name) == ["left_wheel", "right_wheel"]
    assert enc[0][1].header.frame_id == "base_link"

    fog = _msgs(out, "/fog")
    stamps = np.concatenate([m.stamps_ns for _, m in fog])
    np.testing.assert_array_equal(stamps, fog_t)  # every sample once, in order
    d = np.stack(
        [np.concatenate([getattr(m, f) for _, m in fog]) for f in ("delta_roll", "delta_pitch", "delta_yaw")], axis=1
    )
    np.testing.assert_array_equal(d, fog_d)
    assert all(len(m.stamps_ns) == 10 for _, m in fog[:-1]) and len(fog[-1][1].stamps_ns) == 3
    assert all(t == m.stamps_ns[-1] and m.header.frame_id == "fog" for t, m in fog)

    scans = _msgs(out, "/scan")
    assert [t for t, _ in scans] == scan_t.tolist()
    want = ranges.astype(np.float32)
    want[ranges == 0] = np.inf
    np.testing.assert_array_equal(np.array([m.ranges for _, m in scans]), want)
    s = scans[0][1]
    assert s.header.frame_id == "lidar" and s.range_min == 0.0 and s.range_max == 80.0
    assert s.angle_min == pytest.approx(math.radians(-5.0))
    assert s.angle_max == pytest.approx(math.radians(185.0))
    assert s.angle_increment == pytest.approx(math.radians(190.0 / 285))

    for cam, n in (("left", 2), ("right", 3)):
        ims = _msgs(out, f"/stereo/{cam}/image_raw")
        infos = _msgs(out, f"/stereo/{cam}/camera_info")
        assert [t for t, _ in ims] == exp["img_t"][:n] == [t for t, _ in infos]
        yaml = calib.read_camera_yaml(PARAM / f"{cam}_camera.yaml")
        for (t, im), (_, ci) in zip(ims, infos):
            assert (im.height, im.width, im.step, im.encoding) == (560, 1280, 1280, "bayer_rggb8")
            assert im.header.frame_id == ci.header.frame_id == f"stereo_{cam}"
            np.testing.assert_array_equal(im.data.reshape(560, 1280), exp["imgs"][cam, t])
            assert (ci.width, ci.height, ci.distortion_model) == (1280, 560, "plumb_bob")
            np.testing.assert_array_equal(ci.k, yaml["K"].ravel())
            np.testing.assert_array_equal(ci.d, yaml["D"])
            np.testing.assert_array_equal(ci.r, yaml["R"].ravel())
            np.testing.assert_array_equal(ci.p, yaml["P"].ravel())

    tf = _msgs(out, "/tf_static")[0][1]
    assert stamp_ns_of(tf.transforms[0]) == t_first
    got = {tr.child_frame_id: tr for tr in tf.transforms}
    assert set(got) == {"lidar", "fog", "stereo_left", "stereo_right"}
    assert all(tr.header.frame_id == "base_link" for tr in tf.transforms)
    lid = got["lidar"].transform
    assert (lid.translation.x, lid.translation.y, lid.translation.z) == (0.8349, -0.0126869, 1.76416)
    rot, _, _ = calib.parse_extrinsic(PARAM / "Vehicle2Lidar.txt")
    q = (lid.rotation.x, lid.rotation.y, lid.rotation.z, lid.rotation.w)
    np.testing.assert_allclose(quat_to_matrix(*q), rot, atol=2e-6)

    with pytest.raises(BagError, match="refusing to overwrite"):
        convert_kaist(root, out, storage=storage)


@needs_data
def test_fog_options(tmp_path):
    root = tmp_path / "kaist"
    exp = make_dataset(root, n_enc=5, n_fog=40, n_scan=5, bad=False)
    fog_t, fog_d = exp["fog"]
    rep = convert_kaist(root, tmp_path / "vec", fog_format="vector3", images=False)
    assert rep.counts == {"/tf_static": 1, "/encoders": 5, "/fog": 40, "/scan": 5}
    assert rep.warnings == [] and rep.skipped == {}
    assert bag_info(tmp_path / "vec")["topics"]["/fog"][0] == "geometry_msgs/msg/Vector3Stamped"
    fog = _msgs(tmp_path / "vec", "/fog")
    assert [t for t, _ in fog] == fog_t.tolist()
    got = np.array([(m.vector.x, m.vector.y, m.vector.z) for _, m in fog])
    np.testing.assert_array_equal(got, fog_d)
    assert fog[0][1].header.frame_id == "fog"

    rep = convert_kaist(root, tmp_path / "b1", fog_batch=1, images=False)
    assert rep.counts["/fog"] == 40
    fog = _msgs(tmp_path / "b1", "/fog")
    assert [list(m.stamps_ns) for _, m in fog] == [[t] for t in fog_t.tolist()]

    with pytest.raises(ValueError, match="fog_batch"):
        convert_kaist(root, tmp_path / "x", fog_batch=0)
    with pytest.raises(ValueError, match="fog_format"):
        convert_kaist(root, tmp_path / "x", fog_format="imu")
    assert not (tmp_path / "x").exists()


@needs_data
def test_layout_and_missing_files(tmp_path):
    root = tmp_path / "kaist"
    make_dataset(root, n_enc=3, n_fog=3, n_scan=3, bad=False)
    lay = read_kaist_layout(root)
    assert lay.missing == [] and lay.images == {"left": 3, "right": 3}
    assert "sensor_data/lidar.csv" in lay.present and "param/left_camera.yaml" in lay.present
    assert "stereo_left: 3 PNG" in lay.summary()
    (root / "param" / "Vehicle2Lidar.txt").unlink()
    with pytest.raises(ValueError, match=r"param/Vehicle2Lidar.txt: missing") as ei:
        convert_kaist(root, tmp_path / "out")
    assert "\n" not in str(ei.value)
    shutil.copy(PARAM / "Vehicle2Lidar.txt", root / "param")
    (root / "sensor_data" / "fog.csv").unlink()
    with pytest.raises(ValueError, match=r"sensor_data/fog.csv: missing"):
        convert_kaist(root, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    with pytest.raises(ValueError, match="not a directory"):
        read_kaist_layout(tmp_path / "nope")


@needs_data
def test_no_usable_rows(tmp_path):
    root = tmp_path / "kaist"
    make_dataset(root, n_enc=2, n_fog=2, n_scan=2, bad=False)
    shutil.rmtree(root / "stereo_images")
    for f in ("encoder.csv", "fog.csv", "lidar.csv"):
        (root / "sensor_data" / f).write_text("timestamp,a\n1,2,3,4,5\n")
    with pytest.raises(ValueError, match="no usable row"):
        convert_kaist(root, tmp_path / "out")


def test_fog_batch_type_matches_msg_file():
    name = register_fog_batch()
    fields = [f[0] for f in TYPESTORE.get_msgdef(name).fields]
    assert fields == ["header", "stamps_ns", "delta_roll", "delta_pitch", "delta_yaw"]
    assert register_fog_batch() == name  # idempotent


@needs_data
def test_csv_edge_cases(tmp_path, monkeypatch):
    """Header optional, float-formatted ns stamps kept exact, 'nan' first row is data (bad),
    blank lines ignored, warnings capped per file with a summary line."""
    from pf_slam_nodes.io import skips

    monkeypatch.setattr(skips, "MAX_LINE_WARNINGS", 2)
    root = tmp_path / "kaist"
    make_dataset(root, n_enc=3, n_fog=3, n_scan=3, bad=False)
    shutil.rmtree(root / "stereo_images")
    (root / "sensor_data" / "encoder.csv").write_text(
        "nan,1,2\n\n"  # line 1: data row with a NaN stamp -> bad
        f"{T0}.0,0,0\n"  # line 3: '.0' stamp, exact
        f"{T0 + 10_000_000} , 1 , 2\r\n"  # line 4: spaces, CRLF
        f"{T0 + 5},3,3\n{T0 + 6},3,3\n{T0 + 7},3,3\n"  # lines 5-7: step back x3
        f"{T0 + 20_000_000}.5,4,4\n"
    )  # line 8: fractional ns -> bad
    rep = convert_kaist(root, tmp_path / "bag", images=False)
    assert rep.counts["/encoders"] == 2
    assert rep.skipped["encoder.csv: NaN or inf timestamp"] == 1
    assert rep.skipped["encoder.csv: timestamp steps back"] == 3
    assert rep.skipped["encoder.csv: timestamp not an integer number of ns"] == 1
    enc_w = [w for w in rep.warnings if "encoder.csv" in w]
    assert enc_w[0].endswith("encoder.csv:1: NaN or inf timestamp; row skipped")
    assert enc_w[1].endswith("encoder.csv:5: timestamp steps back; row skipped")
    assert enc_w[2].endswith("encoder.csv: 3 more skipped not listed") and len(enc_w) == 3
    enc = _msgs(tmp_path / "bag", "/encoders")
    assert [t for t, _ in enc] == [T0, T0 + 10_000_000]
    np.testing.assert_array_equal(enc[1][1].position, [2 * np.pi / 4096, 4 * np.pi / 4096])


def _read_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(stamps int64, values float64) of a header-less sensor CSV, parsed independently."""
    rows = [line.split(",") for line in path.read_text().splitlines() if line]
    return (np.array([int(r[0]) for r in rows], dtype=np.int64), np.array([r[1:] for r in rows], dtype=np.float64))


@needs_data
def test_round_trip_simulated_drive(tmp_path):
    """A 5 s drive of the car simulator (sim/car.py), converted: every row one message."""
    car = pytest.importorskip("pf_slam_tools.sim.car")
    sim = car.simulate_car(tmp_path / "sim", seed=3, duration_s=5.0, stereo_rate_hz=0.4)
    rep = convert_kaist(tmp_path / "sim", tmp_path / "bag")
    assert rep.skipped == {} and rep.warnings == []
    assert rep.counts == {
        "/tf_static": 1,
        "/encoders": sim.n_encoder,
        "/fog": math.ceil(sim.n_fog / 10),
        "/scan": sim.n_lidar,
        "/stereo/left/image_raw": sim.n_stereo,
        "/stereo/left/camera_info": sim.n_stereo,
        "/stereo/right/image_raw": sim.n_stereo,
        "/stereo/right/camera_info": sim.n_stereo,
    }
    assert sim.n_encoder == 500 and sim.n_fog == 5000 and sim.n_stereo == 2
    sd = tmp_path / "sim" / "sensor_data"

    enc_t, enc_c = _read_csv(sd / "encoder.csv")
    enc = _msgs(tmp_path / "bag", "/encoders")
    assert [t for t, _ in enc] == [stamp_ns_of(m) for _, m in enc] == enc_t.tolist()
    np.testing.assert_array_equal([m.position for _, m in enc], enc_c * (2 * np.pi / 4096))

    fog_t, fog_d = _read_csv(sd / "fog.csv")
    fog = _msgs(tmp_path / "bag", "/fog")
    np.testing.assert_array_equal(np.concatenate([m.stamps_ns for _, m in fog]), fog_t)
    np.testing.assert_array_equal(np.concatenate([m.delta_yaw for _, m in fog]), fog_d[:, 2])
    assert [t for t, _ in fog] == [int(m.stamps_ns[-1]) for _, m in fog]

    scan_t, ranges = _read_csv(sd / "lidar.csv")
    scans = _msgs(tmp_path / "bag", "/scan")
    assert [t for t, _ in scans] == scan_t.tolist()
    want = ranges.astype(np.float32)
    want[ranges == 0] = np.inf
    np.testing.assert_array_equal([m.ranges for _, m in scans], want)

    for cam in ("left", "right"):
        pngs = sorted((tmp_path / "sim" / "stereo_images" / f"stereo_{cam}").glob("*.png"))
        ims = _msgs(tmp_path / "bag", f"/stereo/{cam}/image_raw")
        assert [t for t, _ in ims] == [int(p.stem) for p in pngs]
        for (_, im), p in zip(ims, pngs):
            raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            np.testing.assert_array_equal(im.data.reshape(im.height, im.width), raw)
    rec = [t for _, _, t, _ in read_bag(tmp_path / "bag")]
    assert rec == sorted(rec)
