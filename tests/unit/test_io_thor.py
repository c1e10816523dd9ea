"""THOR .mat reader and converter on small hand-made files (5- and 6-field lidar records, struct
and cell arrays, every loadmat variant, bad input), the contract's transforms and the URDF."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from pf_slam_nodes import cli
from pf_slam_nodes.core.geometry import quat_to_matrix, rpy_to_quat
from pf_slam_nodes.io import thor as th
from pf_slam_nodes.io.bag import bag_info, deserialize, read_bag, stamp_ns_of

URDF = Path(__file__).resolve().parents[2] / "ros2_ws" / "src" / "pf_slam_nodes" / "urdf" / "thor_head.urdf"
T0 = 1_450_000_000.25


def _scan(k: int) -> np.ndarray:
    return (1.0 + 0.001 * np.arange(th.N_BEAMS) + k).astype(np.float32)[None]


def _lidar_records(n: int, six: bool) -> list[dict]:
    recs = []
    for k in range(n):
        r = {"t": np.array([[T0 + 0.025 * k]])}
        if six:
            r["delta_pose"] = np.array([[0.01, 0.0, 0.0]])
        r.update(
            pose=np.array([[0.01 * k, -0.02 * k, 0.1 * k]]),
            res=np.array([[0.0044]]),
            rpy=np.array([[0.0, 0.01, 0.1 * k]]),
            scan=_scan(k),
        )
        recs.append(r)
    return recs


def _cell(recs: list) -> np.ndarray:
    c = np.empty((1, len(recs)), dtype=object)
    for i, r in enumerate(recs):
        c[0, i] = r
    return c


def _write_lidar(path: Path, n: int = 4, six: bool = False, struct_array: bool = False) -> Path:
    recs = _lidar_records(n, six)
    if struct_array:  # a 1xN struct array (all records alike)
        arr = np.empty((1, n), dtype=[(k, object) for k in recs[0]])
        for i, r in enumerate(recs):
            for k, v in r.items():
                arr[0, i][k] = v
        scipy.io.savemat(path, {"lidar": arr})
    else:
        scipy.io.savemat(path, {"lidar": _cell(recs)})
    return path


def _write_joint(path: Path, m: int = 12, **override) -> Path:
    ts = T0 - 0.005 + 0.01 * np.arange(m)
    data = {
        "ts": ts[None],
        "head_angles": np.stack([0.05 * np.arange(m), 0.3 - 0.02 * np.arange(m)]),
        "acc": np.zeros((3, m)),
        "rpy": np.zeros((3, m)),
        "gyro": np.zeros((3, m)),
        "pos": np.zeros((35, m)),
        "ft_l": np.zeros((6, m)),
        "ft_r": np.zeros((6, m)),
    }
    data.update(override)
    scipy.io.savemat(path, data)
    return path


def _kinect_record(t: float, kind: str, img: np.ndarray) -> dict:
    r = {f: np.array([[0.0]]) for f in th.KINECT_FIELDS}
    r["t"] = np.array([[t]])
    r["name"] = kind
    r["image" if kind == "rgb" else "depth"] = img
    return r


# --------------------------------------------------------------------------------------------
# reader


@pytest.mark.parametrize("six", [False, True])
@pytest.mark.parametrize("struct_array", [False, True])
def test_lidar_5_and_6_fields_cell_and_struct_array(tmp_path, six, struct_array):
    p = _write_lidar(tmp_path / "lidar.mat", n=4, six=six, struct_array=struct_array)
    lid = th.read_lidar(p)
    assert lid.n_fields == (6 if six else 5)
    np.testing.assert_allclose(lid.t, T0 + 0.025 * np.arange(4))
    np.testing.assert_allclose(lid.pose[3], [0.03, -0.06, 0.3])
    np.testing.assert_allclose(lid.rpy[2], [0.0, 0.01, 0.2])
    assert lid.scan.shape == (4, th.N_BEAMS) and lid.scan.dtype == np.float32
    np.testing.assert_allclose(lid.scan[2], _scan(2)[0])


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"squeeze_me": True},
        {"struct_as_record": False},
        {"squeeze_me": True, "struct_as_record": False},
        {"simplify_cells": True},
    ],
)
@pytest.mark.parametrize("six", [False, True])
def test_lidar_every_loadmat_variant(tmp_path, kwargs, six):
    p = _write_lidar(tmp_path / "lidar.mat", n=3, six=six)
    ref = th.read_lidar(p)
    got = th.lidar_from_mat(scipy.io.loadmat(p, **kwargs), "x.mat")
    for f in ("t", "pose", "res", "rpy", "scan"):
        np.testing.assert_array_equal(getattr(got, f), getattr(ref, f), err_msg=f"{f} {kwargs}")


def test_lidar_fields_by_position_when_names_differ(tmp_path):
    recs = [
        {
            "T": np.array([[T0]]),
            "odo": np.zeros((1, 3)),
            "xyth": np.array([[1.0, 2.0, 0.5]]),
            "r": np.array([[0.0044]]),
            "imu": np.zeros((1, 3)),
            "ranges": _scan(0),
        }
    ]
    scipy.io.savemat(tmp_path / "l.mat", {"lidar": _cell(recs)})
    lid = th.read_lidar(tmp_path / "l.mat")
    np.testing.assert_array_equal(lid.pose[0], [1.0, 2.0, 0.5])
    assert lid.t[0] == T0


@pytest.mark.parametrize("kwargs", [{}, {"squeeze_me": True}, {"struct_as_record": False}, {"simplify_cells": True}])
def test_joint_variants(tmp_path, kwargs):
    p = _write_joint(tmp_path / "joint.mat", m=5)
    j = th.joint_from_mat(scipy.io.loadmat(p, **kwargs), "joint.mat")
    np.testing.assert_allclose(j.ts, T0 - 0.005 + 0.01 * np.arange(5))
    np.testing.assert_allclose(j.neck, 0.05 * np.arange(5))
    np.testing.assert_allclose(j.head, 0.3 - 0.02 * np.arange(5))


def test_bad_lidar_input_names_file_variable_record_field(tmp_path):
    p = tmp_path / "lidar.mat"
    scipy.io.savemat(p, {"scans": np.zeros(3)})
    with pytest.raises(ValueError, match=r"lidar\.mat: no variable 'lidar' \(variables: scans\)"):
        th.read_lidar(p)
    recs = _lidar_records(3, six=False)
    del recs[1]["scan"]
    scipy.io.savemat(p, {"lidar": _cell(recs)})
    with pytest.raises(
        ValueError,
        match=r"lidar\.mat: lidar record 1: 4 fields \(t, pose, res, rpy\).*"
        r"missing field 'scan'",
    ):
        th.read_lidar(p)
    recs = _lidar_records(3, six=True)
    recs[2]["pose"] = np.array([[1.0, 2.0]])
    scipy.io.savemat(p, {"lidar": _cell(recs)})
    with pytest.raises(ValueError, match=r"lidar record 2 field pose: expected 3 values, got shape \(1, 2\)"):
        th.read_lidar(p)
    recs = _lidar_records(2, six=False)
    recs[0]["scan"] = np.ones((1, 1080))
    scipy.io.savemat(p, {"lidar": _cell(recs)})
    with pytest.raises(ValueError, match=r"lidar record 0 field scan .*expected 1081 values, got shape \(1, 1080\)"):
        th.read_lidar(p)
    recs = _lidar_records(2, six=False)
    recs[1]["t"] = "soon"
    scipy.io.savemat(p, {"lidar": _cell(recs)})
    with pytest.raises(ValueError, match=r"lidar record 1 field t: expected numbers"):
        th.read_lidar(p)
    (tmp_path / "junk.mat").write_bytes(b"not a mat file at all")
    with pytest.raises(ValueError, match=r"junk\.mat: cannot read as a MATLAB \.mat file"):
        th.read_lidar(tmp_path / "junk.mat")
    with pytest.raises(ValueError, match=r"nope\.mat: no such file"):
        th.read_lidar(tmp_path / "nope.mat")


def test_bad_joint_and_kinect_input(tmp_path):
    p = _write_joint(tmp_path / "joint.mat", m=6, head_angles=np.zeros((3, 6)))
    with pytest.raises(ValueError, match=r"joint\.mat: head_angles: expected 2x6 .*got shape \(3, 6\)"):
        th.read_joint(p)
    scipy.io.savemat(p, {"ts": np.zeros((1, 4))})
    with pytest.raises(ValueError, match=r"joint\.mat: no variable 'head_angles'"):
        th.read_joint(p)
    rec = _kinect_record(T0, "depth", np.zeros((424, 500), dtype=np.uint16))
    scipy.io.savemat(tmp_path / "depth.mat", {"DEPTH": _cell([rec])})
    with pytest.raises(
        ValueError,
        match=r"depth\.mat: DEPTH record 0 field depth: expected 424x512 numbers, "
        r"got uint16 424x500",
    ):
        th.read_kinect(tmp_path / "depth.mat", "depth")
    rec = _kinect_record(T0, "depth", np.zeros((424, 512), dtype=np.uint16))
    del rec["depth"]
    scipy.io.savemat(tmp_path / "depth.mat", {"DEPTH": _cell([rec])})
    with pytest.raises(ValueError, match=r"DEPTH record 0: no field 'depth' \(15 fields"):
        th.read_kinect(tmp_path / "depth.mat", "depth")


def test_cli_error_is_one_line(tmp_path, capsys):
    rc = cli.main(
        [
            "convert",
            "thor",
            "--lidar",
            str(tmp_path / "none.mat"),
            "--joint",
            str(tmp_path / "j.mat"),
            str(tmp_path / "bag"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert rc == 1 and err.count("\n") == 0 and "none.mat: no such file" in err


# --------------------------------------------------------------------------------------------
# transforms


def test_static_transforms_follow_the_contract():
    st = {(p, c): (np.array(xyz), quat_to_matrix(*q)) for p, c, xyz, q in th.static_transforms()}
    np.testing.assert_allclose(st[("head", "lidar")][0], [0, 0, 0.15])
    np.testing.assert_allclose(st[("head", "kinect")][0], [0, 0, 0.07])
    opt = st[("kinect", "kinect_rgb_optical")][1]
    np.testing.assert_allclose(opt @ [0, 0, 1], [1, 0, 0], atol=1e-12)  # optical z = forward
    np.testing.assert_allclose(opt @ [1, 0, 0], [0, -1, 0], atol=1e-12)  # optical x = right
    np.testing.assert_allclose(opt @ [0, 1, 0], [0, 0, -1], atol=1e-12)  # optical y = down
    t, r = st[("kinect_rgb_optical", "kinect_depth_optical")]
    np.testing.assert_allclose(t, [0.05227, 0.00152, -0.00061])
    np.testing.assert_allclose(r[0], [0.99997, 0.00590, 0.00530], atol=1e-5)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    # head: positive pitch looks down, positive neck yaw looks left
    np.testing.assert_allclose(th.head_rotation(0.0, 0.3) @ [1, 0, 0], [math.cos(0.3), 0, -math.sin(0.3)])
    np.testing.assert_allclose(th.head_rotation(0.4, 0.0) @ [1, 0, 0], [math.cos(0.4), math.sin(0.4), 0])
    for neck, pitch in ((0.4, 0.3), (-1.1, 0.7)):  # the converter's quaternion: roll 0, pitch, yaw
        np.testing.assert_allclose(
            quat_to_matrix(*rpy_to_quat((0.0, pitch, neck))), th.head_rotation(neck, pitch), atol=1e-12
        )


def _urdf_chain(root: ET.Element, child: str, joints: dict[str, float]) -> np.ndarray:
    """4x4 pose of link `child` in base_link from the URDF's joints."""
    by_child = {j.find("child").get("link"): j for j in root.findall("joint")}
    m = np.eye(4)
    chain = []
    while child != "base_link":
        j = by_child[child]
        chain.append(j)
        child = j.find("parent").get("link")
    for j in reversed(chain):
        o = j.find("origin")
        xyz = [float(v) for v in o.get("xyz").split()]
        r, p, y = [float(v) for v in o.get("rpy").split()]
        rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
        ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
        rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
        a = np.eye(4)
        a[:3, :3], a[:3, 3] = rz @ ry @ rx, xyz
        if j.get("type") == "revolute":
            ax = np.array([float(v) for v in j.find("axis").get("xyz").split()])
            ang = joints[j.get("name")]
            k = np.array([[0, -ax[2], ax[1]], [ax[2], 0, -ax[0]], [-ax[1], ax[0], 0]])
            rot = np.eye(4)
            rot[:3, :3] = np.eye(3) + math.sin(ang) * k + (1 - math.cos(ang)) * k @ k
            a = a @ rot
        m = m @ a
    return m


def test_urdf_head_chain_matches_the_contract():
    root = ET.parse(URDF).getroot()
    names = {j.get("name"): j.get("type") for j in root.findall("joint")}
    assert names["neck"] == "revolute" and names["head"] == "revolute"
    st = {c: (p, np.array(xyz), quat_to_matrix(*q)) for p, c, xyz, q in th.static_transforms()}
    for neck, pitch in ((0.0, 0.0), (0.5, 0.3), (-0.9, -0.2)):
        j = {"neck": neck, "head": pitch}
        head = _urdf_chain(root, "head", j)
        np.testing.assert_allclose(head[:3, 3], [0, 0, th.HEAD_HEIGHT_M], atol=1e-12)
        np.testing.assert_allclose(head[:3, :3], th.head_rotation(neck, pitch), atol=1e-12)
        for frame in ("lidar", "kinect", "kinect_rgb_optical", "kinect_depth_optical"):
            want, f = np.eye(4), frame
            while f != "head":
                p, xyz, r = st[f]
                a = np.eye(4)
                a[:3, :3], a[:3, 3] = r, xyz
                want, f = a @ want, p
            np.testing.assert_allclose(_urdf_chain(root, frame, j), head @ want, atol=2e-9, err_msg=frame)


# --------------------------------------------------------------------------------------------
# converter


def test_convert_hand_made_files(tmp_path):
    lidar = _write_lidar(tmp_path / "lidar.mat", n=4, six=True)
    joint = _write_joint(tmp_path / "joint.mat", m=12)
    rgb_img = np.zeros((1080, 1920, 3), dtype=np.uint8)
    rgb_img[10, 0] = (255, 0, 0)  # stored mirrored: the marker is at the right edge
    dep = np.full((424, 512), 1000, dtype=np.uint16)
    dep[5, 0], dep[6, 1], dep[7, 2] = 2000, 300, 4600  # mirrored; 300 and 4600 are invalid
    scipy.io.savemat(tmp_path / "rgb.mat", {"RGB": _cell([_kinect_record(T0 + 0.03, "rgb", rgb_img)])})
    scipy.io.savemat(tmp_path / "depth.mat", {"DEPTH": _cell([_kinect_record(T0 + 0.02, "depth", dep)])})
    out = tmp_path / "bag"
    rc = cli.main(
        [
            "convert",
            "thor",
            "--lidar",
            str(lidar),
            "--joint",
            str(joint),
            "--rgb",
            str(tmp_path / "rgb.mat"),
            "--depth",
            str(tmp_path / "depth.mat"),
            str(out),
        ]
    )
    assert rc == 0
    info = bag_info(out)
    assert info["custom_data"]["pf_slam.format"] == "thor"
    assert {t: n for t, (_, n) in info["topics"].items()} == {
        "/tf_static": 1,
        "/tf": 12,
        "/joint_states": 12,
        "/odom": 4,
        "/scan": 4,
        "/kinect/rgb/image_raw": 1,
        "/kinect/rgb/camera_info": 1,
        "/kinect/depth/image_raw": 1,
        "/kinect/depth/camera_info": 1,
    }
    msgs = [(t, s, deserialize(r, m)) for t, m, s, r in read_bag(out)]
    stamps = [s for _, s, _ in msgs]
    assert stamps == sorted(stamps)
    assert msgs[0][0] == "/tf_static"
    by = {}
    for t, _, m in msgs:
        by.setdefault(t, []).append(m)
    scan = by["/scan"][2]
    assert scan.header.frame_id == "lidar" and len(scan.ranges) == 1081
    assert scan.angle_min == pytest.approx(-2.35619449) and scan.angle_increment == pytest.approx(0.00436332313)
    assert scan.angle_max == pytest.approx(2.35619449)
    assert (scan.range_min, scan.range_max) == pytest.approx((0.1, 30.0))
    assert stamp_ns_of(scan) == round((T0 + 0.05) * 1e6) * 1000
    np.testing.assert_allclose(scan.ranges, _scan(2)[0])
    od = by["/odom"][3]
    assert (od.header.frame_id, od.child_frame_id) == ("odom", "base_link")
    assert od.pose.pose.position.x == pytest.approx(0.03) and od.pose.pose.position.y == pytest.approx(-0.06)
    for js, tf in zip(by["/joint_states"], by["/tf"]):
        (tr,) = tf.transforms
        assert (tr.header.frame_id, tr.child_frame_id) == ("base_link", "head")
        assert stamp_ns_of(tr) == stamp_ns_of(js) and list(js.name) == ["neck", "head"]
        assert tr.transform.translation.z == pytest.approx(1.26)
        q = tr.transform.rotation
        np.testing.assert_allclose(quat_to_matrix(q.x, q.y, q.z, q.w), th.head_rotation(*js.position), atol=1e-12)
    img = by["/kinect/rgb/image_raw"][0]
    assert (img.encoding, img.width, img.height, img.header.frame_id) == ("rgb8", 1920, 1080, "kinect_rgb_optical")
    px = np.frombuffer(img.data, np.uint8).reshape(1080, 1920, 3)
    assert tuple(px[10, 1919]) == (255, 0, 0) and px.sum() == 255
    info_rgb = by["/kinect/rgb/camera_info"][0]
    np.testing.assert_allclose(np.reshape(info_rgb.k, (3, 3)), [[1049.33, 0, 956.91], [0, 1051.32, 533.45], [0, 0, 1]])
    d = by["/kinect/depth/image_raw"][0]
    assert (d.encoding, d.width, d.height, d.step, d.header.frame_id) == (
        "16UC1",
        512,
        424,
        1024,
        "kinect_depth_optical",
    )
    dd = np.frombuffer(d.data, "<u2").reshape(424, 512)
    assert (dd[5, 511], dd[6, 510], dd[7, 509], dd[0, 0]) == (2000, 0, 0, 1000)
    np.testing.assert_allclose(
        np.reshape(by["/kinect/depth/camera_info"][0].k, (3, 3))[[0, 1, 0, 1], [0, 1, 2, 2]],
        [364.457, 364.543, 258.422, 202.487],
    )
    (static,) = by["/tf_static"]
    assert {(t.header.frame_id, t.child_frame_id) for t in static.transforms} == {
        ("head", "lidar"),
        ("head", "kinect"),
        ("kinect", "kinect_rgb_optical"),
        ("kinect_rgb_optical", "kinect_depth_optical"),
    }


def test_convert_rgb_scale_and_pairs(tmp_path):
    lidar = _write_lidar(tmp_path / "lidar.mat", n=2)
    joint = _write_joint(tmp_path / "joint.mat", m=4)
    with pytest.raises(ValueError, match="both --rgb and --depth"):
        th.convert_thor(lidar, joint, tmp_path / "b0", rgb_path=lidar)
    img = np.zeros((1080, 1920, 3), dtype=np.uint8)
    img[:, :960] = 200  # stored mirrored: the left half is the right half of the real image
    scipy.io.savemat(tmp_path / "rgb.mat", {"RGB": _cell([_kinect_record(T0, "rgb", img)])})
    scipy.io.savemat(tmp_path / "depth.mat", {"DEPTH": _cell([_kinect_record(T0, "depth", np.zeros((424, 512)))])})
    rep = th.convert_thor(lidar, joint, tmp_path / "b1", tmp_path / "rgb.mat", tmp_path / "depth.mat", rgb_scale=0.5)
    assert "RGB images scaled by 0.5 to 960x540" in rep.summary()
    (im,) = [deserialize(r, m) for _, m, _, r in read_bag(tmp_path / "b1", ["/kinect/rgb/image_raw"])]
    (ci,) = [deserialize(r, m) for _, m, _, r in read_bag(tmp_path / "b1", ["/kinect/rgb/camera_info"])]
    assert (im.width, im.height, ci.width, ci.height) == (960, 540, 960, 540)
    px = np.frombuffer(im.data, np.uint8).reshape(540, 960, 3)
    assert px[:, :480].max() == 0 and px[:, 480:].min() == 200
    assert ci.k[0] == pytest.approx(1049.33 / 2) and ci.k[2] == pytest.approx((956.91 + 0.5) / 2 - 0.5)


def test_convert_skips_records_whose_time_does_not_increase(tmp_path):
    recs = _lidar_records(5, six=False)
    recs[3]["t"] = recs[1]["t"]
    scipy.io.savemat(tmp_path / "lidar.mat", {"lidar": _cell(recs)})
    joint = _write_joint(tmp_path / "joint.mat", m=6)
    rep = th.convert_thor(tmp_path / "lidar.mat", joint, tmp_path / "bag")
    assert rep.counts["/scan"] == 4 and rep.skipped == {"lidar.mat: lidar": 1}
    assert "first: record 3" in rep.summary()
