"""CARMEN logs whose stamps do not order the file (the carmen_corrected logs: ODOM lines stamped
0, negative or 3.4e-86 between good ones; scans all 0 or constant), gzip-compressed logs, and
the converters' `pf_slam.format` metadata (the profile `pf-slam run` picks)."""

from __future__ import annotations

import gzip

import numpy as np
import pytest
from conftest import DATA

from pf_slam_nodes.io.bag import bag_info, deserialize, read_bag, stamp_ns_of
from pf_slam_nodes.io.carmen import read_carmen
from pf_slam_nodes.io.convert import convert_carmen, convert_mines

CORRECTED = DATA / "carmen_corrected"


def _flaser(x, t, n=4):
    ranges = " ".join(["2.0"] * n)
    return f"FLASER {n} {ranges} {x} 0 0 {x} 0 0 {t} h {t}\n"


def _odom(x, t):
    return f"ODOM {x} 0 0 0 0 0 {t} h {t}\n"


def _stamps(bag, topic):
    return [stamp_ns_of(deserialize(raw, mt)) for _, mt, _, raw in read_bag(bag, topics=[topic])]


def _relative_log_with_garbage_odom() -> str:
    """Relative seconds; the ODOM line after each scan stamped 0, -1.63023 or 3.4e-86 (as the
    GMapping-corrected logs are)."""
    text, junk = "", ["0", "-1.63023", "3.44361e-86"]
    for i in range(10):
        t = 20.0 + i
        text += _odom(0.1 * i, f"{t:.3f}") + _flaser(0.1 * i + 0.01, f"{t:.3f}")
        text += _odom(0.1 * i + 0.02, junk[i % 3])
    return text


def test_garbage_odom_stamps_take_their_place_in_the_file(tmp_path):
    """Today: BagError 'stamp_ns must be >= 0, got -1630230000', naming neither file nor line."""
    log = tmp_path / "rel.log"
    log.write_text(_relative_log_with_garbage_odom())
    rep = convert_carmen(log, tmp_path / "b")
    assert rep.counts == {"/tf_static": 1, "/odom": 20, "/scan": 10}
    assert rep.line_order == 10 and rep.time_source == "log, 10 by line order"
    warn = [w for w in rep.warnings if "out of the log" in w]
    assert len(warn) == 1 and warn[0].startswith("rel.log:3: 10 ODOM timestamps") and "-1.63023" not in warn[0]
    scans = np.array(_stamps(tmp_path / "b", "/scan"))
    assert (scans == (20.0 + np.arange(10)) * 1e9).all()  # the scans keep the log's times exactly
    odom = np.array(_stamps(tmp_path / "b", "/odom"))
    assert (odom >= 0).all() and (np.diff(odom) >= 0).all()  # ordered as the file is
    # a retimed ODOM lies between the scan before it and the next ODOM line (by line number)
    assert 20.0e9 < odom[1] < 21.0e9
    assert bag_info(tmp_path / "b")["custom_data"]["pf_slam.time_source"] == "log, 10 by line order"


def test_scans_all_zero_are_ordered_by_line(tmp_path):
    """Scans all stamped 0 (freiburg-campus, orebro) or one constant (belgioioso): one scan per
    second in file order, the odometry from the laser lines, the ODOM lines counted as skipped."""
    for name, t in (("zero.log", "0"), ("const.log", "1.01893e+09")):
        log = tmp_path / name
        log.write_text("".join(_odom(0.1 * i, "4.85e-86") + _flaser(0.1 * i, t) for i in range(6)))
        rep = convert_carmen(log, tmp_path / (name + ".bag"))
        assert rep.counts == {"/tf_static": 1, "/odom": 6, "/scan": 6}
        assert rep.time_source == "line order" and rep.odom_sync == "exact"
        assert rep.skipped["ODOM (log times unusable)"] == 6
        assert any(
            w.startswith(f"{name}:2: scan timestamps do not order the log (only 0 of 5 steps go forward")
            for w in rep.warnings
        )
        base = 0 if t == "0" else 1018930000 * 10**9
        assert _stamps(tmp_path / (name + ".bag"), "/scan") == [base + i * 10**9 for i in range(6)]
        odom = [
            deserialize(raw, mt).pose.pose.position.x
            for _, mt, _, raw in read_bag(tmp_path / (name + ".bag"), topics=["/odom"])
        ]
        assert odom == pytest.approx([0.1 * i for i in range(6)])  # the laser lines' own poses


def test_small_steps_back_keep_the_log_times(tmp_path):
    """A bursty logger (the Intel logs: up to 1.7 s off) keeps its own stamps, exactly."""
    log = tmp_path / "burst.clf"
    ts = [100.0, 101.0, 103.2, 102.0, 102.0, 104.0, 103.5, 105.0]
    log.write_text("".join(_flaser(0.1 * i, f"{t:.1f}") for i, t in enumerate(ts)))
    rep = convert_carmen(log, tmp_path / "b")
    assert rep.time_source == "log" and rep.line_order == 0
    assert _stamps(tmp_path / "b", "/scan") == [round(t * 1e9) for t in ts]


def test_gzip_log_read_directly_and_cut_off_stream(tmp_path):
    text = _relative_log_with_garbage_odom()
    gz = tmp_path / "rel.log.gz"
    gz.write_bytes(gzip.compress(text.encode()))
    assert len(read_carmen(gz).scans) == 10
    rep = convert_carmen(gz, tmp_path / "b")
    assert rep.counts["/scan"] == 10
    # cut off: the lines before the damage are kept, one warning names the file and line
    data = gzip.compress((text * 50).encode())
    cut = tmp_path / "cut.log.gz"
    cut.write_bytes(data[: len(data) // 2])
    log = read_carmen(cut)
    assert 0 < len(log.scans) < 500 and log.skipped["damaged gzip"] == 1
    assert any(w.startswith("cut.log.gz:") and "compressed stream damaged after line" in w for w in log.warnings)


def test_converters_write_their_format(tmp_path):
    """pf_slam.format: what `pf-slam run` picks its profile from (profiles.py)."""
    log = tmp_path / "a.clf"
    log.write_text(_flaser(0.0, "1.0") + _flaser(0.1, "2.0"))
    convert_carmen(log, tmp_path / "c")
    assert bag_info(tmp_path / "c")["custom_data"]["pf_slam.format"] == "carmen"
    dat = tmp_path / "m.dat"
    row = ["0"] * 707
    dat.write_text("\n".join(" ".join([str(1000 * i)] + row[1:24] + ["1000"] * 682 + ["0"]) for i in range(3)) + "\n")
    convert_mines(dat, tmp_path / "m")
    assert bag_info(tmp_path / "m")["custom_data"]["pf_slam.format"] == "mines"


#: the eight carmen_corrected logs: FLASER scans each (shared/data/README.md)
CORRECTED_SCANS = {
    "acapulco": 861,
    "belgioioso": 395,
    "edmonton": 340,
    "fhw": 488,
    "freiburg-101": 292,
    "freiburg-campus": 2008,
    "orebro": 237,
    "seattle": 241,
}


@pytest.mark.skipif(not CORRECTED.is_dir(), reason=f"{CORRECTED} not available")
@pytest.mark.parametrize("name", sorted(CORRECTED_SCANS))
def test_carmen_corrected_logs_convert(tmp_path, name):
    """Today every one is refused ('stamp_ns must be >= 0'); now each converts, every scan."""
    rep = convert_carmen(CORRECTED / f"{name}-corrected.log.gz", tmp_path / name)
    assert rep.counts["/scan"] == CORRECTED_SCANS[name]
    stamps = np.array(_stamps(tmp_path / name, "/scan"))
    assert (stamps >= 0).all() and (np.diff(stamps) > 0).all()
    line_order = name in ("belgioioso", "freiburg-campus", "orebro")
    assert (rep.time_source == "line order") == line_order
    if not line_order:  # the garbage ODOM stamps (one after each scan) were placed by line
        assert rep.line_order == CORRECTED_SCANS[name] and rep.counts["/odom"] > rep.counts["/scan"]
