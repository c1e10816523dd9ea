"""`pf-slam run` inspects a bag in one pass that stops as soon as it has what it needs."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("rosbags")

from pf_slam_nodes import graph  # noqa: E402
from pf_slam_nodes.io.bag import bag_info  # noqa: E402
from pf_slam_nodes.runner import sample as sample_mod  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "bags" / "sample_indoor"
CAR = ROOT / "bags" / "car_sample"


@pytest.fixture
def counted(monkeypatch):
    """Counts the passes over a bag and the messages each pass yields."""
    passes: list[int] = []
    real = sample_mod.read_bag

    def counting(bag, topics=None):
        passes.append(0)
        for m in real(bag, topics=topics):
            passes[-1] += 1
            yield m

    monkeypatch.setattr(sample_mod, "read_bag", counting)
    return passes


@pytest.mark.parametrize("bag", [SAMPLE, CAR], ids=["indoor", "car"])
def test_planning_a_run_reads_the_bag_once_and_stops_early(bag, counted):
    plan = graph._plan(
        str(bag),
        None,
        "max",
        "single",
        None,
        False,
        False,
        None,
        None,
        dict(
            executor="events",
            record_map_every_s=None,
            snapshot_every=0,
            progress=False,
            idle_timeout_s=60.0,
            drain_timeout_s=5.0,
            texture_timeout_s=120.0,
        ),
    )
    assert plan.per_node["predictor"]["odometry_source"] in ("odom", "encoders")
    assert len(counted) == 1, counted  # mount, stamps, pairing and profile from one pass
    info = bag_info(bag)
    scans = info["topics"][plan.inputs["scan"]][1]
    assert scans > 200 and counted[0] < info["message_count"], (counted, info["message_count"])


def test_the_sample_holds_what_the_inspection_needs():
    info = bag_info(SAMPLE)
    s = sample_mod.sample_bag(str(SAMPLE), info, {"scan": "/scan", "odom": "/odom"})
    assert len(s.of("/scan")) == 200 and s.error is None
    assert len(s.of("/tf_static")) == info["topics"]["/tf_static"][1]
    last_scan_rec = s.of("/scan")[-1][1]
    odom = s.of("/odom")
    assert odom and all(rec <= last_scan_rec for _, rec, _ in odom)  # the odometry among the scans
