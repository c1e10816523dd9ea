"""The THOR simulator -> `pf-slam convert thor` round trip: the .mat layout as the published loader
reads it, the bag's messages, and the geometry end to end (lidar endpoints on the true walls,
depth pixels carried into the RGB image through the contract's transforms land on the true floor
colour)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import scipy.io

from pf_slam_nodes import cli
from pf_slam_nodes.core.geometry import quat_to_matrix
from pf_slam_nodes.io import thor as th
from pf_slam_nodes.io.bag import bag_info, deserialize, read_bag, stamp_ns_of
from pf_slam_nodes.io.mapfile import read_map
from pf_slam_nodes.io.texture_files import read_floor_texture
from pf_slam_nodes.io.trajectory import read_trajectory
from pf_slam_tools.sim import thor as sim

DURATION_S, KINECT_HZ = 6.0, 1.0


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict:
    out = tmp_path_factory.mktemp("thor") / "sim"
    assert (
        cli.main(
            [
                "simulate",
                "thor",
                "--out",
                str(out),
                "--seed",
                "3",
                "--duration",
                str(DURATION_S),
                "--kinect-rate",
                str(KINECT_HZ),
            ]
        )
        == 0
    )
    bag = out.parent / "bag"
    assert (
        cli.main(
            [
                "convert",
                "thor",
                "--lidar",
                str(out / "lidar.mat"),
                "--joint",
                str(out / "joint.mat"),
                "--rgb",
                str(out / "rgb.mat"),
                "--depth",
                str(out / "depth.mat"),
                str(bag),
            ]
        )
        == 0
    )
    msgs: dict[str, list] = {}
    stamps = []
    for topic, mt, st, raw in read_bag(bag):
        msgs.setdefault(topic, []).append(deserialize(raw, mt))
        stamps.append(st)
    return {"out": out, "bag": bag, "msgs": msgs, "stamps": stamps}


def test_mat_layout_as_the_published_loader_reads_it(run):
    out = run["out"]
    d = scipy.io.loadmat(out / "lidar.mat")
    assert d["lidar"].shape == (1, DURATION_S * 40)
    for m in d["lidar"][0][:3]:  # a 1xN cell of 1x1 structs
        n = len(m[0][0])
        assert n == 6 and m[0][0].dtype.names == ("t", "delta_pose", "pose", "res", "rpy", "scan")
        assert 1.7e9 < m[0][0][0][0][0] < 1.7e9 + 10
        assert m[0][0][n - 4].shape == (1, 3) and m[0][0][n - 3][0][0] == 0.0044
        assert m[0][0][n - 1].shape == (1, 1081)
    j = scipy.io.loadmat(out / "joint.mat")
    assert {"ts", "head_angles", "acc", "rpy", "gyro", "pos", "ft_l", "ft_r"} <= set(j)
    assert j["ts"].shape == (1, DURATION_S * 100) and j["head_angles"].shape == (2, DURATION_S * 100)
    for name, var, fld, shape in (("rgb", "RGB", "image", (1080, 1920, 3)), ("depth", "DEPTH", "depth", (424, 512))):
        k = scipy.io.loadmat(out / f"{name}.mat")[var]
        assert k.shape == (1, DURATION_S * KINECT_HZ)
        rec = k[0][0][0][0]
        assert rec.dtype.names == th.KINECT_FIELDS + (fld,)
        assert rec[15].shape == shape and rec[15].dtype == (np.uint8 if name == "rgb" else np.uint16)
    for f in (
        "ground_truth.tum",
        "ground_truth_map.yaml",
        "ground_truth_map.pgm",
        "floor_colour.png",
        "floor_colour.yaml",
        "sim_info.yaml",
    ):
        assert (out / f).is_file(), f


def test_bag_counts_order_and_head_tf(run):
    info = bag_info(run["bag"])
    assert info["custom_data"]["pf_slam.format"] == "thor"
    n = {t: c for t, (_, c) in info["topics"].items()}
    assert n["/scan"] == n["/odom"] == 240 and n["/joint_states"] == n["/tf"] == 600
    assert n["/kinect/rgb/image_raw"] == n["/kinect/depth/image_raw"] == n["/kinect/rgb/camera_info"] == 6
    assert run["stamps"] == sorted(run["stamps"])
    m = run["msgs"]
    for topic in ("/scan", "/odom", "/joint_states", "/kinect/rgb/image_raw", "/kinect/depth/image_raw"):
        s = [stamp_ns_of(x) for x in m[topic]]
        assert all(b > a for a, b in zip(s, s[1:])), topic
    assert [stamp_ns_of(a) for a in m["/scan"]] == [stamp_ns_of(a) for a in m["/odom"]]
    for js, tf in zip(m["/joint_states"][::37], m["/tf"][::37]):
        q = tf.transforms[0].transform.rotation
        np.testing.assert_allclose(quat_to_matrix(q.x, q.y, q.z, q.w), th.head_rotation(*js.position), atol=1e-12)
    # the head scans: both angles span a real range in 6 s
    pos = np.array([js.position for js in m["/joint_states"]])
    assert np.ptp(pos[:, 0]) > 0.3 and np.ptp(pos[:, 1]) > 0.1
    # the odometry is the robot's own (drifts, sways) and the ground truth is on the scans' stamps
    t_gt, gt = read_trajectory(run["out"] / "ground_truth.tum")
    np.testing.assert_allclose(t_gt, [stamp_ns_of(a) / 1e9 for a in m["/scan"]], atol=2e-6)
    od = np.array([[o.pose.pose.position.x, o.pose.pose.position.y] for o in m["/odom"]])
    err = np.hypot(*(od - gt[:, :2]).T)
    assert err[0] < 1e-4 and 0.002 < err[-1] < 0.5


def _pose(
    t: float, t_gt: np.ndarray, gt: np.ndarray, t_j: np.ndarray, ang: np.ndarray, above_head: float
) -> tuple[np.ndarray, np.ndarray]:
    """World (R, p) of a frame `above_head` over the head joint at time t (interpolated)."""
    x, y = np.interp(t, t_gt, gt[:, 0]), np.interp(t, t_gt, gt[:, 1])
    yaw = np.interp(t, t_gt, np.unwrap(gt[:, 2]))
    neck, pitch = np.interp(t, t_j, ang[:, 0]), np.interp(t, t_j, ang[:, 1])
    rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    r = rz @ th.head_rotation(neck, pitch)
    return r, np.array([x, y, th.HEAD_HEIGHT_M]) + r @ [0, 0, above_head]


def test_lidar_endpoints_on_true_walls_and_floor(run):
    m, out = run["msgs"], run["out"]
    t_gt, gt = read_trajectory(out / "ground_truth.tum")
    t_j = np.array([stamp_ns_of(js) / 1e9 for js in m["/joint_states"]])
    ang = np.array([js.position for js in m["/joint_states"]])
    occ, res, origin = read_map(out / "ground_truth_map.yaml")
    free = np.where(occ == 100, 0, 255).astype(np.uint8)
    dist = cv2.distanceTransform(free, cv2.DIST_L2, 5) * res
    walls = floor = 0
    far = []
    for sc in m["/scan"][::10]:
        t = stamp_ns_of(sc) / 1e9
        r, p = _pose(t, t_gt, gt, t_j, ang, 0.15)
        rr = np.asarray(sc.ranges, dtype=np.float64)
        a = sc.angle_min + sc.angle_increment * np.arange(len(rr))
        ok = (rr > sc.range_min) & (rr < sc.range_max)
        pts = p[None] + (rr[ok, None] * np.stack([np.cos(a[ok]), np.sin(a[ok]), 0 * a[ok]], 1)) @ r.T
        on_floor = np.abs(pts[:, 2]) < 0.05
        wall = (pts[:, 2] > 0.1) & (pts[:, 2] < sim.CEILING_M - 0.1)
        floor += int(on_floor.sum())
        walls += int(wall.sum())
        c = np.floor((pts[wall, :2] - origin[:2]) / res).astype(int)
        far.append(dist[np.clip(c[:, 1], 0, occ.shape[0] - 1), np.clip(c[:, 0], 0, occ.shape[1] - 1)])
    far = np.concatenate(far)
    assert walls > 2000 and floor > 20
    assert np.mean(far <= 0.1) > 0.97, np.percentile(far, [50, 90, 99])


def test_depth_pixels_into_rgb_land_on_the_true_floor_colour(run):
    m, out = run["msgs"], run["out"]
    t_gt, gt = read_trajectory(out / "ground_truth.tum")
    t_j = np.array([stamp_ns_of(js) / 1e9 for js in m["/joint_states"]])
    ang = np.array([js.position for js in m["/joint_states"]])
    tex, tres, torg = read_floor_texture(out / "floor_colour.png", out / "floor_colour.yaml")
    st = {tr.child_frame_id: tr.transform for tr in m["/tf_static"][0].transforms}

    def mat(tf) -> np.ndarray:
        a = np.eye(4)
        q = tf.rotation
        a[:3, :3] = quat_to_matrix(q.x, q.y, q.z, q.w)
        a[:3, 3] = tf.translation.x, tf.translation.y, tf.translation.z
        return a

    kin_rgb = mat(st["kinect_rgb_optical"])
    rgb_depth = mat(st["kinect_depth_optical"])
    checked, good = 0, 0
    for dm, di, rm, ri in zip(
        m["/kinect/depth/image_raw"],
        m["/kinect/depth/camera_info"],
        m["/kinect/rgb/image_raw"],
        m["/kinect/rgb/camera_info"],
    ):
        assert stamp_ns_of(rm) - stamp_ns_of(dm) == pytest.approx(15e6, abs=2e3)  # paired by time
        depth = np.frombuffer(dm.data, "<u2").reshape(dm.height, dm.width).astype(np.float64) / 1000.0
        rgb = np.frombuffer(rm.data, np.uint8).reshape(rm.height, rm.width, 3)
        kd, kr = np.reshape(di.k, (3, 3)), np.reshape(ri.k, (3, 3))
        v, u = np.nonzero(depth > 0)
        z = depth[v, u]
        pd = np.stack([(u - kd[0, 2]) / kd[0, 0] * z, (v - kd[1, 2]) / kd[1, 1] * z, z, np.ones_like(z)])
        world = []
        for stamp, chain in ((stamp_ns_of(dm), kin_rgb @ rgb_depth), (stamp_ns_of(rm), kin_rgb)):
            r, p = _pose(stamp / 1e9, t_gt, gt, t_j, ang, 0.07)
            w = np.eye(4)
            w[:3, :3], w[:3, 3] = r, p
            world.append(w @ chain)
        pw = world[0] @ pd  # depth pixels in the world
        floor = np.abs(pw[2]) < 0.02
        pc = np.linalg.inv(world[1]) @ pw[:, floor]  # into the RGB camera at its stamp
        uv = (kr @ pc[:3]) / pc[2]
        ui, vi = np.rint(uv[0]).astype(int), np.rint(uv[1]).astype(int)
        inside = (ui >= 0) & (ui < rm.width) & (vi >= 0) & (vi < rm.height)
        col = np.floor((pw[0, floor][inside] - torg[0]) / tres).astype(int)
        row = np.floor((pw[1, floor][inside] - torg[1]) / tres).astype(int)
        diff = np.abs(rgb[vi[inside], ui[inside]].astype(int) - tex[row, col].astype(int)).max(axis=1)
        checked += diff.size
        good += int((diff <= 12).sum())
    assert checked > 50_000
    assert good / checked > 0.9, good / checked


def test_layouts_differ_by_seed():
    layouts = [sim.office_layout(np.random.default_rng(s)) for s in range(4)]
    sigs = {(len(lay.world.segments), tuple(np.round(lay.world.bounds, 2)), lay.styles) for lay in layouts}
    assert len(sigs) == 4
    for lay in layouts:
        occ, _ = sim.rasterise_world(lay.world, sim.RES_M)
        assert occ.shape[:2] == lay.floor_rgb.shape[:2]
        # the walk stays clear of walls and boxes
        from pf_slam_tools.sim.indoor import distance_to_segments

        route = lay.route
        pts = np.concatenate([a + np.linspace(0, 1, 50)[:, None] * (b - a) for a, b in zip(route[:-1], route[1:])])
        assert distance_to_segments(pts, lay.world.segments).min() > 0.45


def test_simulate_refuses_to_overwrite(run, capsys):
    rc = cli.main(["simulate", "thor", "--out", str(run["out"]), "--duration", "2"])
    assert rc == 2 and "already holds a THOR simulation" in capsys.readouterr().err


def test_same_seed_same_data(tmp_path):
    runs = []
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        sim.simulate_thor(tmp_path / name, seed=seed, duration_s=1.5, kinect_rate_hz=0.0)
        runs.append(
            (
                th.read_lidar(tmp_path / name / "lidar.mat"),
                th.read_joint(tmp_path / name / "joint.mat"),
                (tmp_path / name / "floor_colour.png").read_bytes(),
            )
        )
    (la, ja, fa), (lb, jb, fb), (lc, _, fc) = runs
    for f in ("t", "pose", "scan"):
        np.testing.assert_array_equal(getattr(la, f), getattr(lb, f))
    np.testing.assert_array_equal(ja.neck, jb.neck)
    assert fa == fb and fa != fc and not np.array_equal(la.scan, lc.scan)
