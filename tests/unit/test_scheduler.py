"""core/scheduler.py PredictorScheduler without ROS: the poses depend only on the data, not on
how the streams interleave on arrival nor on how late the corrections come back (what makes
one process and many, and the graph and the ROS-free loop, agree)."""

from __future__ import annotations

import numpy as np
import pytest

from pf_slam_nodes.core import config as cfg
from pf_slam_nodes.core import scheduler as sch

S = 1_000_000_000


def _drive(n_scans: int = 60):
    """A car at 2 m/s turning slowly: scans at 10 Hz, encoders at 100 Hz, a 1 kHz gyro in
    batches of 10 (each batch stamped at its last sample)."""
    d, yaw_rate, v = 0.5, 0.2, 2.0
    t_enc = np.arange(0, n_scans * 10 + 5) * (S // 100) + 3_000_000  # offset from the scans
    wheel = v * t_enc / S / (d / 2)
    encoders = [(int(t), np.array([w, w + 0.001 * k])) for k, (t, w) in enumerate(zip(t_enc, wheel))]
    t_gyro = np.arange(1, len(t_enc) * 10 + 10) * (S // 1000)
    gyro = [(t_gyro[i : i + 10], np.full(len(t_gyro[i : i + 10]), yaw_rate / 1000)) for i in range(0, len(t_gyro), 10)]
    scans = [int(t) for t in (np.arange(n_scans) * (S // 10) + S // 20)]
    return scans, encoders, gyro


def _events(order: str, scans, encoders, gyro):
    """The three streams merged by stamp ("stamp"), the gyro a second late ("gyro_late") or
    each stream's messages in bursts ("bursts")."""
    ev = [(t, 0, "scan", t) for t in scans] + [(t, 1, "enc", (t, w)) for t, w in encoders]
    lag = S if order == "gyro_late" else 0
    ev += [(int(st[-1]) + lag, 2, "gyro", (st, dy)) for st, dy in gyro]
    if order == "bursts":
        ev = [(t // (S // 2), k, kind, x) for t, k, kind, x in ev]  # half-second bursts per stream
    return [(kind, x) for _, _, kind, x in sorted(ev, key=lambda e: (e[0], e[1]))]


def _run(events, delay: int = 0, wheels=None, bad=(), motion=None):
    """Feed the events; each correction is answered after `delay` more events. Returns the
    poses (stamp, pose) in publication order and the scheduler."""
    s = sch.PredictorScheduler(
        cfg.FilterConfig(num_particles=5, min_travel_m=0.5),
        motion or cfg.OdometryMotionConfig(),
        "encoders",
        "interpolate",
        wheels or cfg.WheelsConfig(left_diameter_m=0.5, right_diameter_m=0.5, base_m=0.6),
        gyro=True,
        odom_wait_scans=0,
        stamp_offset_s=0.0,
    )
    poses, pending, counts = [], [], {"scan": 0, "enc": 0, "gyro": 0}
    s.most_deferred = 0  # pass-throughs queued behind a correction in flight, at most

    def act(actions):
        for a in actions:
            if isinstance(a, sch.PublishPose):
                poses.append((a.stamp, a.pose.copy()))
            elif isinstance(a, sch.SendCorrection):
                shifted = a.particles + np.array([0.01, -0.02, 0.001])  # a "correction"
                pending.append([delay, a.index, shifted, a.log_weights.copy(), a.stamp])

    def answer(force=False):
        while pending and (force or pending[0][0] <= 0):
            _, index, p, lw, stamp = pending.pop(0)
            s.most_deferred = max(s.most_deferred, len(s.deferred))
            act(s.corrected(index, p, lw, p[int(np.argmax(lw))], stamp))

    for i, (kind, x) in enumerate(events):
        counts[kind] += 1
        if kind == "scan":
            act(s.add_scan(x, True, x))
        elif kind == "enc":
            t, w = x
            act(s.add_encoders(t, np.full(2, np.nan) if i in bad else w))
        else:
            act(s.add_gyro(*x))
        for p in pending:
            p[0] -= 1
        answer()
    act(s.end_of_stream(counts["scan"], counts["enc"], counts["gyro"]))
    while pending:
        answer(force=True)
    return poses, s


@pytest.fixture(scope="module")
def drive():
    return _drive()


@pytest.fixture(scope="module")
def reference(drive):
    return _run(_events("stamp", *drive))


def test_every_scan_one_pose_in_order_with_corrections(drive, reference):
    scans = drive[0]
    poses, s = reference
    assert [t for t, _ in poses] == scans  # exactly one per scan, in scan order
    assert s.stage.clock.calls["predict"] >= 5  # corrections happened (2 m/s, one every 0.5 m)
    assert poses[-1][1][0] > 8.0 and poses[-1][1][2] > 0.9  # 12 m on a 10 m radius arc, turned ~1.2 rad
    assert s.end_sent or s.last_pass_through is None or s.last_pass_through[0] != len(scans) - 1
    assert not any(s.faults().values()) and s.most_deferred == 0


@pytest.mark.parametrize("order", ["gyro_late", "bursts"])
def test_arrival_order_of_the_streams_does_not_change_the_poses(drive, reference, order):
    poses, _ = _run(_events(order, *drive))
    assert [t for t, _ in poses] == [t for t, _ in reference[0]]
    assert np.array_equal(np.array([p for _, p in poses]), np.array([p for _, p in reference[0]]))


@pytest.mark.parametrize("delay", [3, 40, 300])
def test_late_corrections_do_not_change_the_poses(drive, reference, delay):
    """A correction in flight for many messages (another process, a slow correlator): the
    pass-throughs behind it are deferred, the next scan that needs one is blocked, and the poses
    come out the same, in the same order."""
    poses, s = _run(_events("stamp", *drive), delay=delay)
    assert [t for t, _ in poses] == [t for t, _ in reference[0]]
    assert np.array_equal(np.array([p for _, p in poses]), np.array([p for _, p in reference[0]]))
    assert not s.deferred and not s.scans
    assert s.most_deferred >= {3: 0, 40: 1, 300: 2}[delay]  # a correction every 2.5 scans: then blocked
    assert s.blocked >= 0 or delay < 300  # a scan needed the next correction while one was in flight


def test_bad_encoder_message_is_counted_and_keeps_its_place(drive):
    events = _events("stamp", *drive)
    bad = next(i for i, (k, _) in enumerate(events) if k == "enc" and i > 100)
    poses, s = _run(events, bad={bad})
    assert len(poses) == len(drive[0])
    f = s.faults()
    assert f["odometry_nonfinite"] == 1 and f["encoder_jump"] == 0
    assert all(np.isfinite(p).all() for _, p in poses)


def test_wheels_config_validates_and_names_the_field():
    assert cfg.WheelsConfig().to_dict() == {
        "left_diameter_m": 0.154,
        "right_diameter_m": 0.154,
        "base_m": 0.33,
        "max_speed_mps": 50.0,
        "gyro_rest_bias": True,
        "rest_min_s": 0.5,
    }
    assert cfg.WheelsConfig(max_speed_mps=float("inf")).max_speed_mps == float("inf")  # no jump check
    for bad, name in [
        ({"base_m": 0.0}, "base_m"),
        ({"left_diameter_m": -1.0}, "left_diameter_m"),
        ({"max_speed_mps": float("nan")}, "max_speed_mps"),
        ({"rest_min_s": 0}, "rest_min_s"),
        ({"gyro_rest_bias": 1}, "gyro_rest_bias"),
        ({"right_diameter_m": "x"}, "right_diameter_m"),
    ]:
        with pytest.raises(ValueError, match=name):
            cfg.WheelsConfig(**bad)
    with pytest.raises(ValueError, match="unknown"):
        cfg.WheelsConfig.from_dict({"wheel_base": 1.0})


def _drive_with_rest(n_scans: int = 60, rest_s: float = 1.5, noise: float = 2e-6, bias: float = 3e-7):
    """As _drive, but standing still for ``rest_s`` first, with a gyro that has a bias and white
    noise (``noise`` rad per 1 kHz sample)."""
    scans, encoders, _ = _drive(n_scans)
    d, yaw_rate, v = 0.5, 0.2, 2.0
    moving = [max(t / S - rest_s, 0.0) for t, _ in encoders]  # seconds of driving so far
    encoders = [(t, np.array([v * m / (d / 2), v * m / (d / 2) + 0.1 * m])) for (t, _), m in zip(encoders, moving)]
    t_gyro = np.arange(1, len(encoders) * 10 + 10) * (S // 1000)
    rng = np.random.default_rng(7)
    dy = np.where(t_gyro / S > rest_s, yaw_rate / 1000, 0.0) + bias + noise * rng.standard_normal(len(t_gyro))
    gyro = [(t_gyro[i : i + 10], dy[i : i + 10]) for i in range(0, len(t_gyro), 10)]
    return scans, encoders, gyro


def test_heading_noise_from_the_gyros_rest_calibration():
    """motion.gyro_noise_scale: the rest measures the gyro's noise (q = 2e-6^2 * 1000 rad^2/s);
    the heading noise of the predictions after it follows from that, from the stamps only (the
    streams' arrival order does not change a pose), and differs from the profile's."""
    drive = _drive_with_rest()
    motion = cfg.OdometryMotionConfig(gyro_noise_scale=2.0)
    poses, s = _run(_events("stamp", *drive), motion=motion)
    assert len(s._gyro_noise) == 1
    t_cal, q, bias_std = s._gyro_noise[0]
    assert 1.5 * S <= t_cal <= 1.52 * S  # the first moving wheel step ends the rest
    assert q == pytest.approx(2e-6**2 * 1000, rel=0.2) and bias_std == pytest.approx(np.sqrt(q / 1.5), rel=0.05)
    assert s.wheels.gyro_bias_rad_s == pytest.approx(3e-4, abs=3 * bias_std)
    for order in ("gyro_late", "bursts"):
        other, _ = _run(_events(order, *drive), motion=motion)
        assert np.array_equal(np.array([p for _, p in other]), np.array([p for _, p in poses]))
    off, s_off = _run(_events("stamp", *drive))
    assert [t for t, _ in off] == [t for t, _ in poses]
    assert not np.array_equal(np.array([p for _, p in off]), np.array([p for _, p in poses]))
    assert s_off._heading_sigma(drive[0][-1]) is None  # off by default
    # before the rest has ended no calibration applies; after it, scale * sqrt(q dt + (s_b dt)^2)
    assert s._heading_sigma(int(1.4 * S)) is None
    dt = (drive[0][-1] - s._t_update) / S
    assert s._heading_sigma(drive[0][-1]) == pytest.approx(2.0 * np.sqrt(q * dt + (bias_std * dt) ** 2))


def test_sample_odometry_motion_takes_a_given_heading_noise():
    from pf_slam_nodes.core.motion import sample_odometry_motion

    rng = np.random.default_rng(3)
    c = cfg.OdometryMotionConfig(sigma_theta_per_m=0.1, sigma_theta_per_rad=0.5, sigma_theta_min_rad=0.05)
    out = sample_odometry_motion(np.zeros((20000, 3)), np.array([2.0, 0.0, 0.1]), c, rng, sigma_theta_rad=0.001)
    assert out[:, 2].std() == pytest.approx(0.5 * 0.1 + 0.001, rel=0.05)  # the turning term stays
