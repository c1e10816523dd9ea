"""A lidar on a moving mount (THOR's head): interpolation, projection, floor removal, the
mostly-floor skip in the scheduler."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pf_slam_nodes.core import scheduler as sch
from pf_slam_nodes.core.config import FilterConfig, LaserConfig, OdometryMotionConfig
from pf_slam_nodes.core.geometry import matrix_to_quat
from pf_slam_nodes.core.mount import MountBuffer, base_points, compose_extrinsic, kept_fraction, mounted_scan

HEAD_Z = 0.93 + 0.33
LIDAR_ON_HEAD = (1, 0, 0, 0, 1, 0, 0, 0, 1, 0.0, 0.0, 0.15)


def rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def head(neck, pitch):
    """base_link -> head as the THOR contract publishes it: (quat xyzw, translation)."""
    return matrix_to_quat(rz(neck) @ ry(pitch)), (0.0, 0.0, HEAD_Z)


def test_interpolation_at_the_scan_stamp():
    buf = MountBuffer()
    buf.add(0, *head(0.0, 0.0))
    buf.add(100, *head(0.4, 0.2))
    rot, t = buf.at(50)
    # slerp: half the rotation from the first sample to the second, about the same axis
    r1 = rz(0.4) @ ry(0.2)
    angle = lambda r: math.acos((np.trace(r) - 1) / 2)  # noqa: E731
    assert angle(rot) == pytest.approx(angle(r1) / 2, abs=1e-9)
    assert angle(rot.T @ r1) == pytest.approx(angle(r1) / 2, abs=1e-9)
    assert np.allclose(rot, rz(0.2) @ ry(0.1), atol=2e-2)  # close to the joint angles' half way
    assert np.allclose(t, [0, 0, HEAD_Z])
    assert np.allclose(buf.at(-5)[0], np.eye(3)) and np.allclose(buf.at(500)[0], rz(0.4) @ ry(0.2))
    assert buf.covers(100) and not buf.covers(101)
    buf.add(90, *head(0.0, 0.0))  # older than the newest: dropped, counted
    assert buf.out_of_order == 1 and len(buf) == 2


def test_known_joint_angles_give_known_endpoints():
    neck, pitch = math.radians(30), math.radians(20)
    q, t = head(neck, pitch)
    buf = MountBuffer()
    buf.add(0, q, t)
    ext = compose_extrinsic(*buf.at(0), LIDAR_ON_HEAD)
    # the beam straight ahead, 2 m: the lidar at the head + R (0, 0, 0.15), the point 2 m along R x
    p = base_points(np.array([2.0]), np.array([0.0]), ext)[:, 0]
    r = rz(neck) @ ry(pitch)
    lidar = np.array([0, 0, HEAD_Z]) + r @ [0, 0, 0.15]
    assert np.allclose(p, lidar + 2.0 * r[:, 0])
    # by hand: nose down 20 deg, turned 30 deg left
    assert p[2] == pytest.approx(HEAD_Z + 0.15 * math.cos(pitch) - 2.0 * math.sin(pitch))
    assert math.degrees(math.atan2(p[1], p[0])) == pytest.approx(30.0, abs=1e-9)


def test_floor_returns_removed_by_their_height():
    laser = LaserConfig(min_height_m=0.25, max_height_m=2.5, min_kept_fraction=0.3)
    pitch = math.radians(30)
    ext = compose_extrinsic(ry(pitch), [0, 0, HEAD_Z], LIDAR_ON_HEAD)
    angles = np.radians(np.linspace(-135, 135, 1081))
    h = HEAD_Z + 0.15 * math.cos(pitch)
    # the ground in front: along each beam the floor at range h / (sin(pitch) cos(a)); a wall at 4 m
    # in the other half of the beams
    floor_r = h / (math.sin(pitch) * np.cos(angles))
    wall = np.abs(angles) > math.radians(60)
    ranges = np.where(wall, 4.0, floor_r)
    ranges = np.where(wall | (floor_r > 0), ranges, np.inf)
    r2, a2, off = mounted_scan(ranges, angles, laser, ext, 0.1, 30.0)
    floor_beams = (~wall) & np.isfinite(ranges)
    assert floor_beams.sum() > 300
    assert np.isnan(r2[floor_beams]).all()  # every floor return dropped, never a hit
    pts = base_points(ranges, angles, ext)
    kept_wall = wall & (pts[2] >= 0.25) & (pts[2] <= 2.5)
    assert np.isfinite(r2[kept_wall]).all() and kept_wall.sum() > 100
    frac = kept_fraction(ranges, angles, laser, ext, 0.1, 30.0)
    assert frac == pytest.approx(kept_wall.sum() / np.isfinite(ranges).sum())
    # looking straight down the corridor (pitch 0): a planar scan, everything kept
    ext0 = compose_extrinsic(np.eye(3), [0, 0, HEAD_Z], LIDAR_ON_HEAD)
    assert kept_fraction(np.full(1081, 4.0), angles, laser, ext0) == 1.0


def _scheduler(laser):
    return sch.PredictorScheduler(
        FilterConfig(num_particles=5, min_travel_m=0.1),
        OdometryMotionConfig(),
        "odom",
        "exact",
        odom_wait_scans=0,
        stamp_offset_s=0.0,
        laser_cfg=laser,
    )


def test_mostly_floor_scan_is_posed_from_odometry_and_counted():
    laser = LaserConfig(
        extrinsic=LIDAR_ON_HEAD, min_height_m=0.25, max_height_m=2.5, min_kept_fraction=0.3, dynamic_frame="head"
    )
    s = _scheduler(laser)
    angles = np.radians(np.linspace(-135, 135, 1081))
    walls = np.full(1081, 3.0)
    pitch = math.radians(45)
    h = HEAD_Z + 0.15 * math.cos(pitch)
    floor = np.where(np.cos(angles) > 0.2, h / (math.sin(pitch) * np.clip(np.cos(angles), 0.2, 1)), np.inf)
    geo = lambda r: (r, angles, 0.1, 30.0)  # noqa: E731
    out = []
    # joints: level until 1.5 s, then nose down 45 deg; a scan every 0.5 s, the robot moves 0.3 m each
    for k in range(6):
        t = int(k * 0.5e9)
        ranges = walls if k < 3 else floor
        out += s.add_scan(t, True, f"scan{k}", geometry=geo(ranges))
        out += s.add_odometry(t, np.array([0.3 * k, 0.0, 0.0]))
        out += s.add_mount(t, *head(0.0, 0.0 if k < 3 else pitch))
        for a in list(out):
            if isinstance(a, sch.SendCorrection):
                out += s.corrected(a.index, a.particles, a.log_weights, a.odom, a.stamp)
    sends = [a for a in out if isinstance(a, sch.SendCorrection)]
    assert [a.payload for a in sends] == ["scan0", "scan1", "scan2"]
    assert all(a.mount is not None and a.mount[11] == pytest.approx(HEAD_Z + 0.15) for a in sends)
    poses = [a for a in out if isinstance(a, sch.PublishPose)]
    assert len(poses) == 6  # every scan still gets its pose
    assert s.faults()["scan_mostly_floor"] == 3
    floor_faults = [a for a in out if isinstance(a, sch.Fault) and a.kind == "scan_mostly_floor"]
    assert len(floor_faults) == 3


def test_scan_waits_for_the_mount_sample_at_its_stamp():
    laser = LaserConfig(extrinsic=LIDAR_ON_HEAD, dynamic_frame="head")
    s = _scheduler(laser)
    angles = np.radians(np.linspace(-135, 135, 1081))
    out = s.add_mount(0, *head(0.0, 0.0))
    out += s.add_scan(int(1e9), True, "a", geometry=(np.full(1081, 3.0), angles, 0.1, 30.0))
    out += s.add_odometry(int(1e9), np.zeros(3))
    assert not any(isinstance(a, sch.SendCorrection) for a in out)  # the head at 1 s is not known yet
    out = s.add_mount(int(2e9), *head(0.5, 0.0))
    send = [a for a in out if isinstance(a, sch.SendCorrection)]
    assert len(send) == 1
    rot = np.asarray(send[0].mount[:9]).reshape(3, 3)
    assert math.atan2(rot[1, 0], rot[0, 0]) == pytest.approx(0.25, abs=1e-9)  # interpolated at 1 s


def test_tf_cdr_reader_reads_what_the_bag_writer_wrote():
    """The predictor reads /tf from the bytes (100 Hz): the same values as the message."""
    from pf_slam_nodes.io.bag import TYPESTORE, tf_static
    from pf_slam_nodes.ros.cdr import tf_transforms

    q = matrix_to_quat(rz(0.3) @ ry(0.2))
    msg = tf_static(
        1_700_000_000_123_456_789,
        [("base_link", "head", (0.1, -0.2, HEAD_Z), q), ("/odom", "base_link", (1.0, 2.0, 0.0), (0, 0, 0, 1))],
    )
    raw = bytes(TYPESTORE.serialize_cdr(msg, "tf2_msgs/msg/TFMessage"))
    out = tf_transforms(raw)
    assert [(s, p, c) for s, p, c, _, _ in out] == [
        (1_700_000_000_123_456_789, "base_link", "head"),
        (1_700_000_000_123_456_789, "/odom", "base_link"),
    ]
    assert out[0][3] == (0.1, -0.2, HEAD_Z) and np.allclose(out[0][4], q)
    with pytest.raises(ValueError, match="truncated"):
        tf_transforms(raw[:-8])


def test_live_scan_waits_at_most_odom_wait_scans_for_its_head_sample():
    """Live (no replay to say the /tf stream ended): a scan whose head sample does not come is
    decided with the newest sample once odom_wait_scans scans wait behind it."""
    laser = LaserConfig(extrinsic=LIDAR_ON_HEAD, dynamic_frame="head")
    s = sch.PredictorScheduler(
        FilterConfig(num_particles=5, min_travel_m=0.1),
        OdometryMotionConfig(),
        "odom",
        "exact",
        odom_wait_scans=3,
        stamp_offset_s=0.0,
        laser_cfg=laser,
    )
    angles = np.radians(np.linspace(-135, 135, 1081))
    out = s.add_mount(0, *head(0.3, 0.0))
    for k in range(4):
        t = int((k + 1) * 1e9)
        out += s.add_scan(t, True, f"s{k}", geometry=(np.full(1081, 3.0), angles, 0.1, 30.0))
        out += s.add_odometry(t, np.array([0.3 * k, 0.0, 0.0]))
    sends = [a for a in out if isinstance(a, sch.SendCorrection)]
    assert [a.payload for a in sends] == ["s0"]  # decided once 3 scans waited behind it
    rot = np.asarray(sends[0].mount[:9]).reshape(3, 3)
    assert math.atan2(rot[1, 0], rot[0, 0]) == pytest.approx(0.3)  # the newest sample, held
