"""Pairing odometry with scans (core/odometry.py), including the Intel log's bad timestamps."""

import numpy as np
import pytest

from pf_slam_nodes.core.odometry import OdometryBuffer, WheelOdometryIntegrator


def test_exact_pairs_repeated_and_backward_stamps_in_order():
    buf = OdometryBuffer("exact")
    stamps = [100, 200, 200, 150, 300]  # a repeat and a step back, as in intel_2726
    for k, t in enumerate(stamps):
        buf.add(t, np.array([k, 0.0, 0.0]))
    got = [buf.lookup(t)[0] for t in stamps]
    assert got == [0, 1, 2, 3, 4]
    assert buf.backward_steps == 1


def test_exact_waits_then_falls_back_when_final():
    buf = OdometryBuffer("exact")
    buf.add(100, np.array([1.0, 0, 0]))
    assert buf.lookup(150) is None
    np.testing.assert_array_equal(buf.lookup(150, final=True), [1.0, 0, 0])
    assert buf.missing == 1


def test_interpolate_between_bracketing_poses_and_wraps_yaw():
    buf = OdometryBuffer("interpolate")
    buf.add(0, np.array([0.0, 0.0, np.pi - 0.1]))
    assert buf.lookup(5) is None  # the bracket's upper end has not arrived
    buf.add(10, np.array([1.0, 2.0, -np.pi + 0.1]))
    p = buf.lookup(5)
    np.testing.assert_allclose(p[:2], [0.5, 1.0])
    assert abs(abs(p[2]) - np.pi) < 1e-9  # through +-pi, not through 0


def test_bad_sync_name():
    with pytest.raises(ValueError, match="odom_sync"):
        OdometryBuffer("nearest")


def test_wheel_integrator_straight_and_turn():
    w = WheelOdometryIntegrator(0.2, 0.2, 0.5)
    w.step(0.0, 0.0)
    p = w.step(10.0, 10.0)  # 10 rad * 0.1 m radius = 1 m straight
    np.testing.assert_allclose(p, [1.0, 0.0, 0.0], atol=1e-12)
    p = w.step(10.0, 10.0 + 2.5)  # right wheel 0.25 m more: dyaw = 0.25 / 0.5
    assert p[2] == pytest.approx(0.5)
    w.add_gyro(0.1)
    p2 = w.step(10.0, 12.5)  # gyro yaw replaces the wheels' yaw
    assert p2[2] == pytest.approx(0.6)
    with pytest.raises(ValueError, match="wheel_base_m"):
        WheelOdometryIntegrator(0.2, 0.2, 0.0)


def _drive_with_biased_gyro(rest_bias: bool, rest_steps: int, bias_rad_s: float = 5e-4, rest_min_s: float = 0.5):
    """100 Hz steps: `rest_steps` at rest, then 10 s straight at 1 m/s; the gyro adds a constant bias."""
    w = WheelOdometryIntegrator(0.5, 0.5, 1.5, gyro_rest_bias=rest_bias, rest_min_s=rest_min_s)
    dt, angle = 0.01, 0.0
    w.step(0.0, 0.0, None)
    for k in range(rest_steps + 1000):
        if k >= rest_steps:
            angle += 1.0 * dt / 0.25  # wheel radius 0.25 m: 1 m/s
        w.add_gyro(bias_rad_s * dt)
        pose = w.step(angle, angle, dt)
    return w, pose


def test_gyro_rest_bias_calibrates_at_standstill():
    raw, p_raw = _drive_with_biased_gyro(False, 100)
    assert p_raw[2] == pytest.approx(5e-4 * 11.0, rel=1e-6)  # the bias turns the heading, at rest too
    cal, p_cal = _drive_with_biased_gyro(True, 100)
    assert cal.gyro_bias_rad_s == pytest.approx(5e-4, rel=1e-6) and cal.rest_s == pytest.approx(1.0)
    assert abs(p_cal[2]) < 1e-9 and abs(p_cal[1]) < 1e-9 and p_cal[0] == pytest.approx(10.0)


def test_gyro_rest_bias_ignores_short_rests_but_zeroes_their_yaw():
    w, p = _drive_with_biased_gyro(True, 30)  # 0.3 s: a wheel that did not tick, not a calibration
    assert w.gyro_bias_rad_s == 0.0 and w.rest_s == 0.0
    assert p[2] == pytest.approx(5e-4 * 10.0, rel=1e-6)  # the rest steps' yaw was zeroed, moving ones kept
    with pytest.raises(ValueError, match="rest_min_s"):
        WheelOdometryIntegrator(0.5, 0.5, 1.5, gyro_rest_bias=True, rest_min_s=0.0)


# ------------------------------------------------------------------ bad and missing odometry
def _line(buf, stamps, bad=()):
    for t in stamps:
        buf.add(t, None if t in bad else np.array([t / 10.0, 0.0, 0.0]))


@pytest.mark.parametrize("sync", ["exact", "interpolate"])
@pytest.mark.parametrize("run", [2, 5, 50])
def test_bad_messages_in_a_row_are_bridged_once_a_good_one_comes(sync, run):
    """`run` NaN messages in a row: their scans wait for the next good message (not for ever:
    nothing in the buffer blocks on a count), then get the interpolation across, each counted."""
    buf = OdometryBuffer(sync)
    stamps = list(range(0, 10 * (run + 20), 10))
    bad = set(stamps[10 : 10 + run])
    _line(buf, stamps[: 10 + run], bad)
    for t in stamps[:10]:
        assert buf.lookup(t)[0] == t / 10.0
    assert buf.lookup(stamps[10]) is None  # the next good message has not arrived
    _line(buf, stamps[10 + run :])
    got = [buf.lookup(t) for t in stamps[10:]]
    np.testing.assert_allclose([p[0] for p in got], [t / 10.0 for t in stamps[10:]])  # a straight line
    assert buf.missing == run


def test_exact_missing_partners_resolved_when_a_later_scan_pairs():
    buf = OdometryBuffer("exact")
    _line(buf, [0, 10, 20])
    for t in (0, 10, 20):
        buf.lookup(t)
    queue = [30, 40, 50, 60]  # the odometry of 30..50 never comes; 60's does
    assert not buf.later_paired(queue)
    _line(buf, [60])
    assert buf.later_paired(queue) and buf.later_paired([30, None, 60])  # None: an unreadable scan
    p = [buf.lookup(t, final=True) for t in (30, 40, 50)]
    np.testing.assert_allclose([q[0] for q in p], [3.0, 4.0, 5.0])  # between 20 and 60
    assert buf.missing == 3 and buf.last_missing
    assert buf.lookup(60)[0] == 6.0 and not buf.last_missing


def test_interpolate_across_a_gap_counts_missing():
    buf = OdometryBuffer("interpolate")
    _line(buf, [0, 10, 20, 30, 2000, 2010])
    buf.GAP_MIN_NS = 100
    assert buf.lookup(25) is not None and not buf.last_missing
    assert buf.lookup(120) is not None and not buf.last_missing  # 90 from the odometry at 30
    assert buf.lookup(1000)[0] == pytest.approx(100.0) and buf.last_missing
    assert buf.lookup(1950) is not None and not buf.last_missing
    assert buf.lookup(2000)[0] == 200.0 and not buf.last_missing  # its own message


def test_final_without_any_good_odometry_is_the_origin():
    buf = OdometryBuffer("interpolate")
    assert buf.lookup(5) is None
    np.testing.assert_array_equal(buf.lookup(5, final=True), [0, 0, 0])
    buf.add_bad(10)
    assert buf.lookup(10) is None  # nothing good yet: wait
    assert buf.missing == 1


def test_no_partner_tells_separate_odometry_from_a_gap():
    """Exact pairing on odometry recorded at other times (CARMEN ODOM lines): detected once 5
    scans the odometry has passed have no partner while odometry between them arrived; a
    stretch with no odometry at all is not that."""
    buf = OdometryBuffer("exact")
    _line(buf, [5, 15, 25, 35, 45, 55])  # between the scans at 0, 10, .., 50
    assert buf.lookup(0) is None
    assert buf.no_partner([0, 10, 20, 30]) is None  # 4 scans: not yet
    assert buf.no_partner([0, 10, 20, 30, 40, 50]) == (6, 5)
    buf.fall_back(scan=0)
    assert buf.sync == "interpolate" and buf.fallback == {"scan": 0}
    assert buf.lookup(10)[0] == pytest.approx(1.0)
    gap = OdometryBuffer("exact")
    _line(gap, [0, 100])
    gap.lookup(0)
    assert gap.no_partner([10, 20, 30, 40, 50, 60]) is None  # nothing arrived between them


def test_run_says_what_the_standstills_calibrated_or_warns_that_none_did():
    from pf_slam_nodes.runner.outputs import gyro_line

    cal = _drive_with_biased_gyro(True, 100)[0]
    line = gyro_line({"bias_rad_s": cal.gyro_bias_rad_s, "rest_s": cal.rest_s})
    assert line.startswith("gyro yaw bias: +500.0 µrad/s (+103.13 deg/h), calibrated over 1.0 s of standstill")
    never = _drive_with_biased_gyro(True, 10)[0]  # 0.1 s at rest: shorter than rest_min_s
    assert never.rest_s == 0.0
    warn = gyro_line({"bias_rad_s": never.gyro_bias_rad_s, "rest_s": never.rest_s})
    assert warn.startswith("warning: the gyro's yaw bias was never calibrated") and "wheels.rest_min_s" in warn
