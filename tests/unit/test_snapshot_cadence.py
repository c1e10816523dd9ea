"""`pf-slam run --snapshot-every`: N scans or N seconds of bag time (the default, 30 s: a 100 Hz car
drive no longer writes a PNG every 2 s of it)."""

from __future__ import annotations

import pytest

from pf_slam_nodes.runner.common import SnapshotCadence, snapshot_cadence


def test_snapshot_cadence_parses_scans_and_seconds():
    assert snapshot_cadence(200) == (200, 0.0)
    assert snapshot_cadence("200") == (200, 0.0)
    assert snapshot_cadence("30s") == (0, 30.0)
    assert snapshot_cadence("2.5s") == (0, 2.5)
    assert snapshot_cadence(0) == (0, 0.0)
    for bad in ("-1", "abc", "30 m", "-5s", "s", "infs", "nans"):
        with pytest.raises(ValueError, match="--snapshot-every"):
            snapshot_cadence(bad)


def due_at(every, stamps_s):
    cad = SnapshotCadence(every)
    return [k for k, t in enumerate(stamps_s, start=1) if cad(k, int(round(t * 1e9)))]


def test_snapshots_by_bag_time_whatever_the_scan_rate():
    car = [i / 100.0 for i in range(30_000)]  # 300 s at 100 Hz
    indoor = [i / 5.0 for i in range(1500)]  # 300 s at 5 Hz
    assert len(due_at("30s", car)) == 9 == len(due_at("30s", indoor))  # at 30, 60, ..., 270 s
    assert due_at("30s", car)[0] == 3001 and due_at("30s", indoor)[0] == 151
    assert len(due_at(200, car)) == 150 and len(due_at(200, indoor)) == 7
    assert due_at(0, car) == [] and due_at("0s", car) == []


def test_a_gap_in_the_bag_gives_one_snapshot_not_a_burst():
    stamps = [0.0, 10.0, 20.0, 25.0, 100.0, 101.0, 130.0]  # 25 -> 100 s: no scans
    assert due_at("10s", stamps) == [2, 3, 5, 7]


def test_a_bad_cadence_stops_the_run_before_it_starts(tmp_path):
    from pf_slam_nodes.graph import RunError, run

    with pytest.raises(RunError, match="'3m' is neither"):
        run(str(tmp_path / "no_bag"), tmp_path / "out", snapshot_every="3m")
    assert not (tmp_path / "out").exists()
