"""CARMEN reader on the real Intel / MIT logs and on small hand-written logs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import DATA as SHARED_DATA

from pf_slam_nodes.io.carmen import flaser_angles, read_carmen, stamp_str_to_ns

DATA = SHARED_DATA / "carmen"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"{DATA} not available")


@needs_data
def test_intel_910_flaser():
    log = read_carmen(DATA / "intel_910.clf")
    assert len(log.scans) == 910
    assert log.odoms == [] and log.skipped == {} and log.warnings == []
    s = log.scans[0]
    assert s.ranges.dtype == np.float32 and s.ranges.shape == (180,)
    assert s.angle_min == pytest.approx(-math.pi / 2)
    assert s.angle_increment == pytest.approx(math.radians(1.0))
    assert s.stamp_s == pytest.approx(976052890.244111)
    assert s.stamp_ns == 976052890244111000
    np.testing.assert_allclose(s.odom_pose, [0.698, -0.015, -0.463373])
    np.testing.assert_allclose(s.laser_pose, s.odom_pose)
    assert s.ranges[0] == pytest.approx(1.09) and s.line_no == 4
    # 81.83 in the file = no return = +inf; nothing else is infinite
    n_8183 = 0
    with open(DATA / "intel_910.clf") as fh:
        for line in fh:
            if line.startswith("FLASER"):
                n_8183 += line.split()[2:182].count("81.83")
    all_r = np.concatenate([x.ranges for x in log.scans])
    assert np.isposinf(all_r).sum() == n_8183 > 0
    assert np.all(all_r[np.isfinite(all_r)] < 80.0)
    assert log.stamp_repeats == 0 and log.stamp_steps_back == 0


@needs_data
def test_mit_csail_361_beams():
    log = read_carmen(DATA / "mit-csail.clf")
    assert len(log.scans) == 1988
    s = log.scans[0]
    assert s.ranges.shape == (361,)
    assert s.angle_increment == pytest.approx(math.radians(0.5))
    assert s.angle_min + 360 * s.angle_increment == pytest.approx(math.pi / 2)
    assert np.isposinf(s.ranges[24])  # 81.91 in the file
    assert s.ranges[0] == pytest.approx(1.40)
    assert s.stamp_s == pytest.approx(1134864629.895182)


@needs_data
def test_intel_2726_non_monotonic_stamps_kept_in_order():
    log = read_carmen(DATA / "intel_2726.clf")
    assert len(log.scans) == 2726
    assert log.stamp_repeats == 55 and log.stamp_steps_back == 26
    assert any("step back" in w for w in log.warnings)
    assert [s.line_no for s in log.scans] == sorted(s.line_no for s in log.scans)


def test_flaser_angle_rule():
    assert flaser_angles(180) == (-math.pi / 2, math.pi / 180)
    assert flaser_angles(181)[1] == pytest.approx(math.pi / 180)
    assert flaser_angles(361)[1] == pytest.approx(math.pi / 360)
    with pytest.raises(ValueError):
        flaser_angles(1)


def test_stamp_exact():
    assert stamp_str_to_ns("1134864629.895182") == 1134864629895182000
    assert stamp_str_to_ns("12") == 12_000_000_000
    with pytest.raises(ValueError):
        stamp_str_to_ns("abc")


def _flaser(n, ranges, pose=(1.0, 2.0, 0.5), odom=(1.0, 2.0, 0.5), t="100.5"):
    vals = " ".join(str(r) for r in ranges)
    return f"FLASER {n} {vals} {' '.join(map(str, pose))} {' '.join(map(str, odom))} {t} host {t}\n"


def test_odom_robotlaser1_and_other_types(tmp_path):
    ranges = [1.0, 2.0, 50.0, 3.5]
    rl = (
        "ROBOTLASER1 0 -1.5 3.0 0.75 50.0 0.01 0 4 "
        + " ".join(map(str, ranges))
        + " 2 0.1 0.2 0.3 0.4 0.5 0.0 0.1 0.2 0.5 0.25 0.1 0.1 1.0 200.25 host 1.0\n"
    )
    text = (
        "# comment\n"
        "PARAM robot_use_laser on nohost 0\n"
        "SYNC 1 2 3\n"
        "ODOM 1.0 2.0 0.3 0.5 0.1 0.0 199.5 host 0.5\n" + rl + "ODOM 1.1 2.0 0.3 0.5 0.1 0.0 200.5 host 0.5\n\n"
    )
    p = tmp_path / "small.clf"
    p.write_text(text)
    log = read_carmen(p)
    assert log.skipped == {"PARAM": 1, "SYNC": 1}
    assert len(log.odoms) == 2 and len(log.scans) == 1
    o = log.odoms[0]
    np.testing.assert_allclose(o.pose, [1.0, 2.0, 0.3])
    assert (o.tv, o.rv, o.stamp_s, o.line_no) == (0.5, 0.1, 199.5, 4)
    s = log.scans[0]
    assert s.kind == "ROBOTLASER1" and s.line_no == 5
    assert s.angle_min == -1.5 and s.angle_increment == 0.75 and s.range_max == 50.0
    np.testing.assert_allclose(s.ranges, [1.0, 2.0, np.inf, 3.5])
    np.testing.assert_allclose(s.laser_pose, [0.3, 0.4, 0.5])
    np.testing.assert_allclose(s.odom_pose, [0.0, 0.1, 0.2])
    assert (s.tv, s.rv, s.stamp_s) == (0.5, 0.25, 200.25)


def test_bad_lines_counted_with_file_and_line(tmp_path):
    good = _flaser(4, [1, 2, 3, 81.83])
    lines = [
        good,
        _flaser(5, [1, 2, 3, 4]),  # wrong beam count
        _flaser(4, [1, "x", 3, 4]),  # non-numeric
        _flaser(4, [1, "nan", 3, 4]),  # NaN
        _flaser(4, [1, 2, 3, 4], t="abc"),  # bad timestamp
        "FLASER\n",  # truncated
        "ODOM 1 2 3\n",  # short ODOM
        good,
    ]
    p = tmp_path / "bad.clf"
    p.write_text("".join(lines))
    log = read_carmen(p)
    assert len(log.scans) == 2
    assert [s.line_no for s in log.scans] == [1, 8]
    assert np.isposinf(log.scans[0].ranges[3])
    assert log.skipped == {"malformed FLASER": 5, "malformed ODOM": 1}
    joined = "\n".join(log.warnings)
    for ln in (2, 3, 4, 5, 6, 7):
        assert f"bad.clf:{ln}:" in joined
    assert "expected 16 fields for 5 beams" in joined
    assert "NaN" in joined and "'x'" in joined
    # the repeat of line 1's stamp at line 8 is reported
    assert log.stamp_repeats == 1


def test_both_flaser_and_robotlaser1_keeps_robotlaser1(tmp_path):
    rl = "ROBOTLASER1 0 -1.5 3.0 1.0 50.0 0.01 0 4 1 2 3 4 0 0 0 0 0 0 0 0 0 0.5 0.25 0.1 100.5 host 1.0\n"
    p = tmp_path / "both.clf"
    p.write_text(_flaser(4, [1, 2, 3, 4]) + rl)
    log = read_carmen(p)
    assert [s.kind for s in log.scans] == ["ROBOTLASER1"]
    assert log.skipped == {"FLASER (ROBOTLASER1 present)": 1}


def test_missing_file_raises_oserror(tmp_path):
    with pytest.raises(OSError):
        read_carmen(tmp_path / "nope.clf")
