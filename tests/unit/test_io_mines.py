"""Mines reader on the real exp1.dat and on damaged copies."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import DATA as SHARED_DATA

from pf_slam_nodes.io.mines import MINES_ANGLE_INCREMENT, MINES_ANGLE_MIN, read_mines

DATA = SHARED_DATA / "mines"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"{DATA} not available")


@needs_data
def test_exp1():
    log = read_mines(DATA / "exp1.dat")
    assert len(log.stamps_s) == 756
    assert log.ranges.shape == (756, 682) and log.ranges.dtype == np.float32
    assert log.skipped == {} and log.warnings == []
    assert log.stamps_us[0] == 212387282
    assert log.stamps_s[-1] - log.stamps_s[0] == pytest.approx(74.62, abs=0.01)
    assert np.all(np.diff(log.stamps_us) > 0)
    # ticks: int64, cumulative, mostly non-decreasing (the robot drives forward)
    for ticks, first, last in ((log.left_ticks, 29221, 211786), (log.right_ticks, 25178, 210289)):
        assert ticks.dtype == np.int64
        assert (ticks[0], ticks[-1]) == (first, last)
        assert np.mean(np.diff(ticks) >= 0) > 0.9
    assert log.left_wheel_rad[-1] == pytest.approx(211786 * 2 * math.pi / 2000)
    # 0 mm (and URG error codes < 20 mm) -> +inf; the rest in metres within the URG span
    raw = np.loadtxt(DATA / "exp1.dat", usecols=range(24, 706), max_rows=5)
    np.testing.assert_array_equal(np.isposinf(log.ranges[:5]), raw < 20)
    np.testing.assert_allclose(log.ranges[:5][raw >= 20], raw[raw >= 20] / 1000.0, rtol=1e-6)
    finite = log.ranges[np.isfinite(log.ranges)]
    assert finite.min() >= 0.02 and finite.max() <= 5.6
    # URG-04LX geometry: 682 beams of 360/1024 deg, centred
    assert log.angle_increment == MINES_ANGLE_INCREMENT == pytest.approx(math.radians(0.3515625))
    assert log.angle_min == MINES_ANGLE_MIN == pytest.approx(math.radians(-119.53125))
    assert math.degrees(log.angle_min + 681 * log.angle_increment) == pytest.approx(119.8828125)
    assert (log.wheel_radius_m, log.half_axle_m, log.ticks_per_rev) == (0.077, 0.165, 2000)


@needs_data
def test_bad_lines(tmp_path):
    lines = (DATA / "exp1.dat").read_text().splitlines(keepends=True)[:6]
    short = " ".join(lines[1].split()[:-3]) + "\n"
    tok = lines[2].split()
    tok[30] = "abc"
    nonnum = " ".join(tok) + "\n"
    tok = lines[3].split()
    tok[30] = "nan"
    nan = " ".join(tok) + "\n"
    p = tmp_path / "bad.dat"
    p.write_text(lines[0] + short + nonnum + nan + lines[4] + lines[5])
    log = read_mines(p)
    assert len(log.stamps_s) == 3
    assert list(log.line_nos) == [1, 5, 6]
    assert log.skipped == {"malformed": 3}
    joined = "\n".join(log.warnings)
    assert "bad.dat:2: expected 707 fields, got 704" in joined
    assert "bad.dat:3: non-numeric" in joined
    assert "bad.dat:4: NaN" in joined


def test_empty_file(tmp_path):
    p = tmp_path / "empty.dat"
    p.write_text("")
    log = read_mines(p)
    assert log.ranges.shape == (0, 682) and len(log.left_ticks) == 0


def test_bad_params(tmp_path):
    with pytest.raises(ValueError, match="ticks_per_rev"):
        read_mines(tmp_path / "x.dat", ticks_per_rev=0)
