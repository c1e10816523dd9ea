"""Timestamps that cannot be right: scan and odometry stamps offset from each
other by seconds, header stamps that never advance, header stamps that are garbage. `pf-slam run`
compares the header stamps with the bag's record times before the run, warns once with the
numbers, replays the stream with what can be trusted (record time, or the offset removed), and
counts it in summary.json. Each bag gives a result worse than dead reckoning on main."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")

from test_faults_shutdown import SAMPLE, _edit_bag, _errors  # noqa: E402

from pf_slam_nodes import graph  # noqa: E402
from pf_slam_nodes.io.bag import make_time, stamp_ns_of  # noqa: E402
from pf_slam_nodes.io.trajectory import read_trajectory  # noqa: E402

N = 300
RNG_SEED = 7


def _stamp(msg, ns: int) -> None:
    msg.header.stamp = make_time(ns)


CASES = {
    # odometry stamped 3 s late against its record time (and the scans')
    "odom_offset": lambda rng: (
        lambda topic, k, msg: _stamp(msg, stamp_ns_of(msg) + 3_000_000_000) if topic == "/odom" else None
    ),
    # the scans' header stamps never advance (a driver that stamps once)
    "scan_stuck": lambda rng: (
        lambda topic, k, msg: _stamp(msg, 1_700_000_000_000_000_000) if topic == "/scan" else None
    ),
    # the scans' header stamps are garbage (a clock that jumps about by up to +-100 s)
    "scan_garbage": lambda rng: (
        lambda topic, k, msg: (
            _stamp(msg, stamp_ns_of(msg) + int(rng.integers(-(10**11), 10**11))) if topic == "/scan" else None
        )
    ),
    # the odometry's header stamps never advance
    "odom_stuck": lambda rng: (
        lambda topic, k, msg: _stamp(msg, 1_700_000_000_000_000_000) if topic == "/odom" else None
    ),
}
EXPECT = {
    "odom_offset": ("/odom", "-3.000 s"),
    "scan_stuck": ("/scan", "record time"),
    "scan_garbage": ("/scan", "record time"),
    "odom_stuck": ("/odom", "record time"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_impossible_stamps_are_detected_and_replayed_right(case, tmp_path, ros_domain, capfd):
    _edit_bag(SAMPLE, tmp_path / "bag", N, CASES[case](np.random.default_rng(RNG_SEED)))
    topic, fix = EXPECT[case]
    insp = graph.inspect_stamps(str(tmp_path / "bag"), {"scan": "/scan", "odom": "/odom"})
    assert set(insp["restamp"]) == {topic} and insp["pairing"] == (200, 200), insp
    res = graph.run(
        str(tmp_path / "bag"),
        tmp_path / "out",
        progress=False,
        domain_id=ros_domain,
        snapshot_every=0,
        idle_timeout_s=30.0,
    )
    err = capfd.readouterr().err
    assert err.count(f"warning: {tmp_path / 'bag'}: {topic}: ") == 1, err  # once, with the numbers
    s = res.summary
    assert s["complete"] and s["scans_processed"] == N, s.get("stopped_by")
    assert s["timestamps"][topic]["fix"] == fix and s["faults"]["timestamps_fixed"] == 1, s.get("timestamps")
    assert s["odom_sync"]["used"] == "exact" and s["faults"]["odom_missing"] == 0, s["faults"]
    e = _errors(tmp_path / "out", N)
    # the clean sample: 0.014 m over 600 scans; dead reckoning over these 300: see the commit
    assert np.sqrt(np.mean(e**2)) < 0.03 and e.max() < 0.08, (np.sqrt(np.mean(e**2)), e.max())
    if topic == "/scan":  # the trajectory carries the stamps the scans were replayed with
        t, _ = read_trajectory(tmp_path / "out" / "trajectory.tum")
        t_gt, _ = read_trajectory(SAMPLE.parent / "ground_truth.tum")
        np.testing.assert_allclose(t, t_gt[:N], atol=1e-6)


def test_live_offset_is_reported(tmp_path, ros_domain, monkeypatch, capfd):
    """Without a bag to inspect (as live, paced at --rate 10): odometry stamped 3 s ahead of the
    scans is reported once with the numbers and counted; the clean bag at the same rate is not."""
    real = graph.inspect_stamps

    def as_if_live(bag, inputs, max_scans=200):  # the bag inspection finds nothing to fix
        out = real(bag, inputs, max_scans)
        out["restamp"], out["notes"] = {}, {}
        return out

    monkeypatch.setattr(graph, "inspect_stamps", as_if_live)
    n = 100
    _edit_bag(SAMPLE, tmp_path / "bag", n, CASES["odom_offset"](None))
    res = graph.run(
        str(tmp_path / "bag"),
        tmp_path / "out",
        rate="10",
        progress=False,
        domain_id=ros_domain,
        snapshot_every=0,
        idle_timeout_s=30.0,
        overrides={"predictor": {"odom_sync": "interpolate"}},
    )
    err = capfd.readouterr().err
    s = res.summary
    assert s["scans_processed"] == n, s.get("stopped_by")
    assert "odometry stamps 3.0" in err and "ahead of the scan stamps" in err, err
    assert s["faults"]["odom_stamp_offset"] >= n - 5, s["faults"]  # from the 3rd scan in a row on
    clean = graph.run(
        str(SAMPLE), tmp_path / "clean", rate="10", progress=False, domain_id=ros_domain, snapshot_every=0
    )
    assert clean.summary["faults"]["odom_stamp_offset"] == 0, clean.summary["faults"]
