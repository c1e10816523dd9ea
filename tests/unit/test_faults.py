"""Run-time input checks (core/faults.py), the encoder counter-jump clamp, and the removal of
stale Fast DDS shared-memory segments after a killed node."""

from __future__ import annotations

import fcntl
import math
import os
import time

import numpy as np
import pytest

from pf_slam_nodes.core.faults import ScanChecks
from pf_slam_nodes.core.odometry import WheelOdometryIntegrator
from pf_slam_nodes.graph import remove_stale_shm

INC = math.radians(1.0)
A_MIN, A_MAX = -math.pi / 2, math.pi / 2  # 181 beams, angle_max = the last beam


def _scan(checks: ScanChecks, stamp_s: float, ranges=None, a_max: float = A_MAX):
    r = np.full(181, 5.0, dtype=np.float32) if ranges is None else np.asarray(ranges, dtype=np.float32)
    return checks.check(int(stamp_s * 1e9), r, A_MIN, a_max, INC)


def test_clean_scans_raise_nothing_and_inf_is_no_return():
    c = ScanChecks()
    r = np.full(181, 5.0, dtype=np.float32)
    r[:10] = np.inf  # REP 117: no return
    r[10:20] = 0.0  # below range_min: the sensor's "no reading"
    for k in range(5):
        assert _scan(c, 0.1 * k, r) == (True, [])
    # the other convention: angle_max one increment past the last beam
    assert _scan(c, 1.0, a_max=A_MAX + INC) == (True, [])
    assert set(c.counts.values()) == {0}


def test_nan_negative_and_minus_inf_ranges_counted_scan_still_used():
    c = ScanChecks()
    r = np.full(181, 5.0, dtype=np.float32)
    r[[3, 4]] = np.nan
    r[7] = -1.0
    r[9] = -np.inf
    usable, faults = _scan(c, 0.0, r)
    assert usable and [k for k, _ in faults] == ["scan_bad_ranges"]
    assert "4 of 181" in faults[0][1]
    _scan(c, 0.1, r)
    assert c.counts["scan_bad_ranges"] == 2


def test_beam_count_disagreeing_with_the_angles_is_not_corrected_with():
    c = ScanChecks()
    usable, faults = _scan(c, 0.0, np.full(90, 5.0))
    assert not usable and faults[0][0] == "scan_count_mismatch" and "90 ranges" in faults[0][1]
    usable, faults = c.check(100_000_000, np.full(181, 5.0, np.float32), A_MIN, A_MAX, 0.0)  # no increment
    assert not usable and faults[0][0] == "scan_count_mismatch"
    assert c.counts["scan_count_mismatch"] == 2


def test_time_backwards_and_gap_counted_once_per_step():
    c = ScanChecks(time_gap_s=60.0)
    _scan(c, 10.0)
    _, f = _scan(c, 9.2)  # 0.8 s back (the Intel log does this)
    assert [k for k, _ in f] == ["time_backwards"] and "0.800 s" in f[0][1]
    assert _scan(c, 9.3)[1] == []  # time goes on from there: no second fault
    _, f = _scan(c, 200.0)  # minutes later
    assert [k for k, _ in f] == ["time_gap"] and "190.7 s" in f[0][1]
    assert _scan(c, 200.1)[1] == []
    assert c.counts["time_backwards"] == 1 and c.counts["time_gap"] == 1
    with pytest.raises(ValueError, match="time_gap_s"):
        ScanChecks(time_gap_s=0.0)


def test_unreadable_scan_counted():
    c = ScanChecks()
    faults = c.unreadable(ValueError("truncated CDR"))
    assert faults[0][0] == "scan_unreadable" and "truncated CDR" in faults[0][1]
    assert c.counts["scan_unreadable"] == 1


def test_encoder_counter_jump_discarded_motion_goes_on():
    w = WheelOdometryIntegrator(0.6, 0.6, 1.5, max_speed_mps=50.0)
    ref = WheelOdometryIntegrator(0.6, 0.6, 1.5)
    rad_per_step = 10.0 * 0.01 / 0.3  # 10 m/s at 100 Hz on a 0.3 m radius
    offset = 0.0
    for k in range(100):
        if k == 50:
            offset = 2.0**20  # the counter jumps (reset / wrap / glitch)
        a = k * rad_per_step
        pose = w.step(a + offset, a + offset, 0.01)
        expected = ref.step(a, a, 0.01)
        if k != 50:  # the jump's step is the one step lost
            assert w.jumps == (1 if k > 50 else 0)
    assert w.jumps == 1
    np.testing.assert_allclose(pose[0], expected[0] - rad_per_step * 0.3, atol=1e-9)
    assert abs(pose[1]) < 1e-9
    # without dt no check (as before), and the gyro's yaw still applies on a discarded step
    g = WheelOdometryIntegrator(0.6, 0.6, 1.5, max_speed_mps=50.0)
    g.step(0.0, 0.0, None)
    g.add_gyro(0.1)
    assert g.step(1e6, 1e6, 0.01)[2] == pytest.approx(0.1) and g.jumps == 1
    with pytest.raises(ValueError, match="max_speed_mps"):
        WheelOdometryIntegrator(0.6, 0.6, 1.5, max_speed_mps=0.0)


def test_remove_stale_shm_only_unlocked_participant_segments(tmp_path):
    def segment(name: str) -> None:
        (tmp_path / name).write_bytes(b"\0" * 64)
        (tmp_path / f"{name}_el").touch()

    segment("fastrtps_00000000000000aa")  # owner gone: lock free
    segment("fastrtps_00000000000000bb")  # owner alive: flock held
    segment("fastrtps_port7411")  # shared port segment: never touched
    old = time.time() - 10
    for f in tmp_path.iterdir():
        os.utime(f, (old, old))
    segment("fastrtps_00000000000000cc")  # just created: too young to judge
    fd = os.open(tmp_path / "fastrtps_00000000000000bb_el", os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        removed = remove_stale_shm(tmp_path)
    finally:
        os.close(fd)
    assert sorted(removed) == ["fastrtps_00000000000000aa", "fastrtps_00000000000000aa_el"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "fastrtps_00000000000000bb",
        "fastrtps_00000000000000bb_el",
        "fastrtps_00000000000000cc",
        "fastrtps_00000000000000cc_el",
        "fastrtps_port7411",
        "fastrtps_port7411_el",
    ]
