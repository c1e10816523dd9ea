"""Odometry/scan pairing never hangs: a CARMEN log whose odometry comes in its
own ODOM lines, converted and run with the CARMEN parameter file, and the same bag with exact
pairing forced, before the run (bag inspection) and at run time (no inspection: live use)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

pytest.importorskip("rclpy")

from pf_slam_nodes import graph  # noqa: E402
from pf_slam_nodes.core import metrics  # noqa: E402
from pf_slam_nodes.io.bag import bag_info  # noqa: E402
from pf_slam_nodes.io.convert import convert_carmen  # noqa: E402
from pf_slam_nodes.io.trajectory import read_relations, read_trajectory  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CARMEN_YAML = ROOT / "ros2_ws/src/pf_slam_nodes/config/carmen_indoor.yaml"
N = 300


def _odom_lines_log(data_dir: Path, out: Path) -> Path:
    """The first N scans of intel_910 with the odometry moved into ODOM lines logged 13 ms after
    each scan (as a robot that publishes odometry on its own); the FLASER lines keep their
    fields (the converter takes the ODOM lines when a log has them)."""
    lines = [ln for ln in (data_dir / "carmen" / "intel_910.clf").read_text().splitlines() if ln.startswith("FLASER")][
        :N
    ]
    outl = []
    for ln in lines:
        tok = ln.split()
        n = int(tok[1])
        x, y, th = tok[5 + n : 8 + n]
        t = float(tok[8 + n]) + 0.013
        outl += [ln, f"ODOM {x} {y} {th} 0 0 0 {t:.6f} derived {t:.6f}"]
    out.write_text("\n".join(outl) + "\n")
    return out


@pytest.fixture(scope="module")
def bags(data_dir, tmp_path_factory):
    d = tmp_path_factory.mktemp("pairing")
    clf = _odom_lines_log(data_dir, d / "odom_lines.clf")
    return d, clf


def _relations(out: Path, data_dir: Path) -> dict:
    """Kümmerle relations error of the run on the segment (both stamps inside it)."""
    t, p = read_trajectory(out / "trajectory.tum")
    rs, rd = read_relations(data_dir / "carmen" / "intel_910.relations")
    inside = (rs[:, 0] <= t[-1]) & (rs[:, 1] <= t[-1])
    rel = metrics.relations_error(t, p, rs[inside], rd[inside])
    assert rel["n_used"] >= 20
    return rel


def test_convert_records_the_pairing_and_carmen_params_run(bags, data_dir, tmp_path, module_ros_domain):
    """`pf-slam convert carmen` on the ODOM-line log writes pf_slam.odom_sync: interpolate (and
    says so); `pf-slam run --params config/carmen_indoor.yaml` poses all 300 scans, close to the
    run on the same scans with the odometry in the laser lines. On main the parameter file forced
    exact pairing: '0/300 scans processed', stopped after 60 s."""
    _, clf = bags
    out = subprocess.run(
        [sys.executable, "-m", "pf_slam_nodes.cli", "convert", "carmen", str(clf), str(tmp_path / "bag")],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    assert "odom_sync interpolate" in out.stdout + out.stderr
    assert bag_info(tmp_path / "bag")["custom_data"]["pf_slam.odom_sync"] == "interpolate"
    res = graph.run(
        str(tmp_path / "bag"),
        tmp_path / "out",
        params_file=str(CARMEN_YAML),
        progress=False,
        domain_id=module_ros_domain,
        snapshot_every=0,
        idle_timeout_s=30.0,
    )
    s = res.summary
    assert s["complete"] and s["scans_processed"] == N, s.get("stopped_by")
    assert s["odom_sync"] == {"used": "interpolate", "scans_checked": 200, "with_odometry_stamp": 0}
    assert s["faults"]["odom_missing"] == 0 and s["faults"]["odom_sync_fallback"] == 0
    # measured 0.035 m / 0.31 deg (the same scans with the odometry in the laser lines: 0.021 m)
    assert _relations(tmp_path / "out", data_dir)["trans_mean"] < 0.05


def test_forced_exact_falls_back_before_the_run(bags, data_dir, tmp_path, module_ros_domain, capfd):
    """A parameter file that forces odom_sync: exact (main's carmen_indoor.yaml) on that bag:
    one warning with the numbers, interpolation, all scans, and summary.json says so."""
    d, clf = bags
    convert_carmen(clf, tmp_path / "bag")
    forced = yaml.safe_load(CARMEN_YAML.read_text())
    forced["predictor"]["ros__parameters"]["odom_sync"] = "exact"
    (tmp_path / "forced.yaml").write_text(yaml.safe_dump(forced))
    res = graph.run(
        str(tmp_path / "bag"),
        tmp_path / "out",
        params_file=str(tmp_path / "forced.yaml"),
        progress=False,
        domain_id=module_ros_domain,
        snapshot_every=0,
        idle_timeout_s=30.0,
    )
    err = capfd.readouterr().err
    assert "odom_sync exact" in err and "only 0 of the first 200 scans have an odometry message" in err, err
    s = res.summary
    assert s["complete"] and s["scans_processed"] == N, s.get("stopped_by")
    assert s["odom_sync"] == {
        "used": "interpolate",
        "requested": "exact",
        "scans_checked": 200,
        "with_odometry_stamp": 0,
    }
    assert s["faults"]["odom_sync_fallback"] == 1
    assert _relations(tmp_path / "out", data_dir)["trans_mean"] < 0.05


def test_exact_without_partners_falls_back_at_run_time(bags, data_dir, tmp_path, module_ros_domain, monkeypatch, capfd):
    """Live use (no bag to inspect): exact pairing, odometry at other times. The predictor sees
    5 scans without a partner while odometry stamped between them arrives, warns once and
    interpolates from there: all scans, within seconds (the run's idle limit is 20 s)."""
    d, clf = bags
    convert_carmen(clf, tmp_path / "bag")
    real = graph.inspect_stamps

    def as_if_live(bag, inputs, max_scans=200):  # the bag inspection sees nothing wrong
        out = real(bag, inputs, max_scans)
        out["pairing"] = (out["pairing"][1], out["pairing"][1])
        return out

    monkeypatch.setattr(graph, "inspect_stamps", as_if_live)
    res = graph.run(
        str(tmp_path / "bag"),
        tmp_path / "out",
        progress=False,
        domain_id=module_ros_domain,
        snapshot_every=0,
        idle_timeout_s=20.0,
        overrides={"predictor": {"odom_sync": "exact"}},
    )
    err = capfd.readouterr().err
    s = res.summary
    assert s["complete"] and s["scans_processed"] == N, s.get("stopped_by")
    assert s["odom_sync"]["used"] == "exact" and s["faults"]["odom_sync_fallback"] == 1, s["faults"]
    switch = re.search(r"pairing by interpolation from scan (\d+) on", err)
    assert switch is not None and int(switch.group(1)) <= 5, err  # within the first few scans
    # the first scans (before the switch) had no partner: posed from the odometry around them
    assert s["faults"]["odom_missing"] <= 5
    assert _relations(tmp_path / "out", data_dir)["trans_mean"] < 0.05
