"""The seeded indoor simulator: geometry, determinism, and sensor content against ground truth."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from pf_slam_nodes.core.geometry import quat_to_yaw
from pf_slam_nodes.io.bag import BagError, bag_info, deserialize, read_bag, stamp_ns_of
from pf_slam_nodes.io.mapfile import read_map
from pf_slam_nodes.io.trajectory import read_trajectory
from pf_slam_tools.sim import indoor
from pf_slam_tools.sim.indoor import (
    EPOCH_NS,
    N_BEAMS,
    RANGE_MAX_M,
    beam_angles,
    distance_to_segments,
    office_world,
    plan_drive,
    ray_cast,
    simulate_indoor,
)


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.arctan2(np.sin(a), np.cos(a))


@pytest.fixture(scope="module")
def sample(tmp_path_factory: pytest.TempPathFactory) -> indoor.SimResult:
    """The default sample (seed 0, 60 s), written once for the module."""
    return simulate_indoor(tmp_path_factory.mktemp("sim") / "out", seed=0)


@pytest.fixture(scope="module")
def decoded(sample: indoor.SimResult) -> dict:
    scans, odom, tf = [], [], []
    for topic, msgtype, stamp, raw in read_bag(sample.bag_path):
        msg = deserialize(raw, msgtype)
        head = msg.transforms[0] if topic == "/tf_static" else msg
        assert stamp_ns_of(head) == stamp, f"{topic}: header stamp differs from record time"
        {"/scan": scans, "/odom": odom, "/tf_static": tf}[topic].append(msg)
    return {"scans": scans, "odom": odom, "tf": tf}


def _odom_pose(msg) -> tuple[int, np.ndarray]:
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return stamp_ns_of(msg), np.array([p.x, p.y, float(quat_to_yaw(q.x, q.y, q.z, q.w))])


# ------------------------------------------------------------------------------------ geometry


def test_ray_cast_hand_computed_wall() -> None:
    # Wall x = 5 from y = -10 to 10; sensor at (1, 0) facing +x: straight beam hits at 4 m,
    # a beam at angle a at 4 / cos(a); a beam facing away (a = pi) hits nothing.
    wall = np.array([[5.0, -10.0, 5.0, 10.0]])
    angles = np.array([0.0, 0.5, -0.5, math.pi])
    r = ray_cast(np.array([1.0, 0.0, 0.0]), angles, wall, range_max_m=20.0)
    assert r[0] == 4.0
    np.testing.assert_allclose(r[1:3], 4.0 / math.cos(0.5), rtol=1e-12)
    assert r[3] == np.inf
    # Rotated sensor: at (5, 3) facing -y (theta = -pi/2), the wall y = 0 is 3 m ahead.
    floor = np.array([[0.0, 0.0, 10.0, 0.0]])
    assert ray_cast(np.array([5.0, 3.0, -0.5 * math.pi]), np.zeros(1), floor, 20.0)[0] == pytest.approx(3.0, abs=1e-12)
    # Beyond range_max -> no return; the nearest of two walls wins.
    assert ray_cast(np.array([1.0, 0.0, 0.0]), np.zeros(1), wall, 3.9)[0] == np.inf
    two = np.array([[5.0, -1.0, 5.0, 1.0], [2.5, -1.0, 2.5, 1.0]])
    assert ray_cast(np.array([1.0, 0.0, 0.0]), np.zeros(1), two, 20.0)[0] == 1.5


def test_ray_cast_in_the_office_world() -> None:
    # The start pose is (4.5, 7.5) on the floor plan, heading east along the corridor whose
    # far end (outer wall x = 20) is 15.5 m ahead; to the right (-pi/2) the corridor's south
    # wall (y = 6.5) is 1.0 m away; to the left the beam passes the door to room D (4.4 .. 5.6)
    # and hits the south face of the table there (y = 11.5), 4.0 m away.
    world = office_world()
    r = ray_cast(np.zeros(3), beam_angles(), world.segments, RANGE_MAX_M)
    assert r.shape == (N_BEAMS,)
    assert r[90] == pytest.approx(15.5, abs=1e-9)
    assert r[0] == pytest.approx(1.0, abs=1e-9)
    assert r[180] == pytest.approx(4.0, abs=1e-9)
    # Many poses at once equal one pose at a time (vectorised over poses and beams).
    poses = np.array([[0.0, 0.0, 0.0], [2.0, -3.0, 1.0], [-1.5, -4.0, -2.0]])
    batch = ray_cast(poses, beam_angles(), world.segments, RANGE_MAX_M, chunk=2)
    for k, p in enumerate(poses):
        np.testing.assert_array_equal(batch[k], ray_cast(p, beam_angles(), world.segments, RANGE_MAX_M))


def test_drive_keeps_clear_of_walls_and_closes_the_loop() -> None:
    world = office_world()
    for seed in range(4):
        t, poses = plan_drive(60.0, np.random.default_rng(seed))
        assert len(t) == 6000 and np.array_equal(poses[0], np.zeros(3))
        clearance = distance_to_segments(poses[:, :2], world.segments)
        assert clearance.min() > 0.4, f"seed {seed}: path within {clearance.min():.2f} m of a wall"
        step = np.hypot(*np.diff(poses[:, :2], axis=0).T) * 100.0  # m/s at 100 Hz
        assert 0.45 < np.percentile(step, 90) < 0.6
        assert (step < 1e-3).sum() >= 200, "expected a stop of >= 2 s"
        turn = np.abs(_wrap(np.diff(poses[:, 2]))) * 100.0
        assert turn.max() < 0.8, "turn rate above 0.8 rad/s"
        # Returns to the start region after the lap (loop closure).
        later = np.hypot(*poses[3000:, :2].T)
        assert later.min() < 0.2


def test_ground_truth_map_has_walls_where_the_segments_are(sample: indoor.SimResult) -> None:
    occ, res, origin = read_map(sample.map_yaml_path)
    assert res == pytest.approx(0.05)
    world = office_world()
    h, w = occ.shape
    assert (w, h) == (420, 320)
    cx = origin[0] + (np.arange(w) + 0.5) * res
    cy = origin[1] + (np.arange(h) + 0.5) * res
    gx, gy = np.meshgrid(cx, cy)
    occupied = occ == 100
    d = distance_to_segments(np.stack([gx[occupied], gy[occupied]], axis=1), world.segments)
    inside_box = np.zeros(d.shape, bool)
    for bx, by, lx, wy, yaw in world.boxes:
        lxy = np.stack([gx[occupied] - bx, gy[occupied] - by])
        u = math.cos(yaw) * lxy[0] + math.sin(yaw) * lxy[1]
        v = -math.sin(yaw) * lxy[0] + math.cos(yaw) * lxy[1]
        inside_box |= (np.abs(u) <= 0.5 * lx) & (np.abs(v) <= 0.5 * wy)
    assert np.all((d < 0.036) | inside_box)
    # The start cell (origin of the start frame) is free.
    i, j = int((0.0 - origin[1]) / res), int((0.0 - origin[0]) / res)
    assert occ[i, j] == 0


# ------------------------------------------------------------------------------- determinism


def _bag_bytes(bag: Path) -> dict[str, bytes]:
    return {f.name: f.read_bytes() for f in sorted(bag.iterdir())}


def test_same_seed_gives_identical_files_and_other_seed_differs(tmp_path: Path) -> None:
    a = simulate_indoor(tmp_path / "a", seed=3, duration_s=5.0)
    b = simulate_indoor(tmp_path / "b", seed=3, duration_s=5.0)
    c = simulate_indoor(tmp_path / "c", seed=4, duration_s=5.0)
    assert _bag_bytes(a.bag_path) == _bag_bytes(b.bag_path)
    assert a.ground_truth_path.read_bytes() == b.ground_truth_path.read_bytes()
    assert _bag_bytes(a.bag_path) != _bag_bytes(c.bag_path)
    assert a.ground_truth_path.read_bytes() != c.ground_truth_path.read_bytes()
    assert (a.n_scans, a.n_odom) == (50, 100)


def test_existing_bag_is_refused_unless_overwrite(tmp_path: Path) -> None:
    simulate_indoor(tmp_path, seed=0, duration_s=1.0)
    with pytest.raises(BagError, match="already exists"):
        simulate_indoor(tmp_path, seed=0, duration_s=1.0)
    res = simulate_indoor(tmp_path, seed=1, duration_s=2.0, overwrite=True)
    assert bag_info(res.bag_path)["topics"]["/scan"] == ("sensor_msgs/msg/LaserScan", 20)


@pytest.mark.parametrize("kwargs", [{"duration_s": 0.0}, {"odom_rate_hz": 30}])
def test_bad_arguments_fail_fast(tmp_path: Path, kwargs: dict) -> None:
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        simulate_indoor(tmp_path, **kwargs)
    assert not (tmp_path / "sample_indoor").exists()


def test_main_writes_the_sample(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert indoor.main(["--out", str(tmp_path), "--seed", "2", "--duration", "3"]) == 0
    assert "30 scans" in capsys.readouterr().out
    assert bag_info(tmp_path / "sample_indoor")["topics"]["/odom"][1] == 60
    assert indoor.main(["--out", str(tmp_path), "--duration", "3"]) == 2  # exists


# ------------------------------------------------------------------------ the default sample


def test_sample_counts_sizes_and_stamps(sample: indoor.SimResult, decoded: dict) -> None:
    info = bag_info(sample.bag_path)
    assert info["storage"] == "mcap"
    assert info["start_ns"] == EPOCH_NS
    assert info["topics"] == {
        "/scan": ("sensor_msgs/msg/LaserScan", 600),
        "/odom": ("nav_msgs/msg/Odometry", 1200),
        "/tf_static": ("tf2_msgs/msg/TFMessage", 1),
    }
    assert (sample.n_scans, sample.n_odom, sample.duration_s) == (600, 1200, 60.0)
    assert sum(f.stat().st_size for f in sample.bag_path.iterdir()) <= 2_000_000
    stamps, poses = read_trajectory(sample.ground_truth_path)
    assert len(stamps) == len(decoded["scans"]) == sample.n_scans
    scan_ns = np.array([stamp_ns_of(m) for m in decoded["scans"]])
    np.testing.assert_array_equal(scan_ns, EPOCH_NS + np.arange(600) * 100_000_000)
    np.testing.assert_allclose(stamps, scan_ns / 1e9, atol=1e-6)
    odom_ns = {stamp_ns_of(m) for m in decoded["odom"]}
    assert set(scan_ns.tolist()) <= odom_ns, "every scan stamp has an odometry message"
    tf = decoded["tf"][0].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("base_link", "laser")
    assert tf.transform.rotation.w == 1.0 and tf.transform.translation.x == 0.0
    scan = decoded["scans"][0]
    assert scan.header.frame_id == "laser" and len(scan.ranges) == N_BEAMS
    assert scan.angle_min == pytest.approx(-math.pi / 2)
    assert scan.angle_increment == pytest.approx(math.pi / 180)
    assert scan.angle_max == pytest.approx(math.pi / 2)
    assert scan.range_max == RANGE_MAX_M
    odom = decoded["odom"][0]
    assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "base_link")


def test_scan_noise_and_dropouts(decoded: dict) -> None:
    ranges = np.stack([np.asarray(m.ranges, dtype=np.float64) for m in decoded["scans"]])
    assert not np.isnan(ranges).any() and np.all(ranges[np.isfinite(ranges)] <= RANGE_MAX_M)
    missing = ~np.isfinite(ranges)
    assert np.all(ranges[missing] == np.inf)
    # Closed office: a missing return is (almost always) a dropout, rate ~1 %.
    assert 0.005 < missing.mean() < 0.02


def test_ground_truth_reprojects_scans_onto_the_walls(sample: indoor.SimResult, decoded: dict) -> None:
    _, gt = read_trajectory(sample.ground_truth_path)
    world = office_world()
    a = beam_angles()
    dists = []
    for pose, msg in zip(gt[::10], decoded["scans"][::10]):
        r = np.asarray(msg.ranges, dtype=np.float64)
        ok = np.isfinite(r)
        th = pose[2] + a[ok]
        pts = np.stack([pose[0] + r[ok] * np.cos(th), pose[1] + r[ok] * np.sin(th)], axis=1)
        dists.append(distance_to_segments(pts, world.segments))
    d = np.concatenate(dists)
    assert d.mean() < 0.03
    assert np.percentile(d, 99) < 0.05


def test_dead_reckoning_drifts_but_increments_stay_close(sample: indoor.SimResult, decoded: dict) -> None:
    _, gt = read_trajectory(sample.ground_truth_path)
    odom = dict(_odom_pose(m) for m in decoded["odom"])
    scan_ns = [stamp_ns_of(m) for m in decoded["scans"]]
    od = np.stack([odom[s] for s in scan_ns])
    np.testing.assert_allclose(od[0], gt[0], atol=1e-12)
    err = np.hypot(*(od[:, :2] - gt[:, :2]).T)
    assert err[-1] > 0.5, f"dead reckoning should drift visibly, ended {err[-1]:.2f} m off"
    assert err[-1] == pytest.approx(sample.odom_drift_m, abs=1e-5)
    assert err.max() < 3.0

    # Per-scan increments (in the previous pose's frame) stay close: correctable by SLAM.
    def increments(p: np.ndarray) -> np.ndarray:
        d = p[1:, :2] - p[:-1, :2]
        c, s = np.cos(p[:-1, 2]), np.sin(p[:-1, 2])
        return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], _wrap(p[1:, 2] - p[:-1, 2])], axis=1)

    diff = np.abs(increments(od) - increments(gt))
    assert diff[:, :2].max() < 0.01  # m per 0.1 s
    assert diff[:, 2].max() < 0.01  # rad per 0.1 s
    # The drive covers corridor and rooms: ~25-32 m, net turning over a full lap.
    assert 25.0 < sample.path_length_m < 32.0
    assert np.sum(_wrap(np.diff(gt[:, 2]))) < -2 * math.pi + 0.5
