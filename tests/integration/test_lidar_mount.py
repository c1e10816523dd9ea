"""The lidar's mount and the scan's own range limits, through the whole graph.

Bags are simulated (sim/indoor.py, seed 0, the sample's 60 s drive) with the laser mounted
as /tf_static says and its ranges cast from that mount; the trajectories are compared with
the ground truth *without alignment* (the simulator's world frame is the SLAM's map frame),
so a map turned by the mount shows as a heading error.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from pf_slam_nodes.core.metrics import associate, wrap_angle  # noqa: E402
from pf_slam_nodes.graph import run  # noqa: E402
from pf_slam_nodes.io.bag import bag_info, deserialize, open_writer, read_bag, tf_static  # noqa: E402
from pf_slam_nodes.io.evaluation import evaluate  # noqa: E402
from pf_slam_nodes.io.mapfile import read_map  # noqa: E402
from pf_slam_nodes.io.trajectory import read_trajectory  # noqa: E402
from pf_slam_tools.sim.indoor import simulate_indoor  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "bags" / "sample_indoor"
PARAMS = str(ROOT / "ros2_ws" / "src" / "pf_slam_nodes" / "config" / "sim_indoor.yaml")
PI = math.pi

#: name -> the mount chain from base_link (parent, child, xyz, rpy rad); the last child is the scan frame
MOUNTS = {
    "plain": None,
    "yaw180": [("base_link", "laser", (0.0, 0.0, 0.2), (0.0, 0.0, PI))],
    "yaw90_offset": [("base_link", "laser", (0.3, 0.1, 0.2), (0.0, 0.0, PI / 2))],
    "upside_down": [("base_link", "laser", (0.15, -0.05, 0.3), (PI, 0.0, 0.0))],
    # TurtleBot 4: base_link -> shell_link -> rplidar_link, the lidar turned by +90 deg
    "chain": [
        ("base_link", "shell_link", (0.0, 0.0, 0.09), (0.0, 0.0, 0.0)),
        ("shell_link", "rplidar_link", (-0.04, 0.0, 0.1), (0.0, 0.0, PI / 2)),
    ],
}


def errors(traj: Path, gt: Path) -> dict:
    """Unaligned position RMSE (m) and the largest heading error (deg) against the ground truth."""
    t_e, p_e = read_trajectory(traj)
    t_g, p_g = read_trajectory(gt)
    pairs = associate(t_e, t_g, max_dt=0.02)
    e, g = p_e[pairs[:, 0]], p_g[pairs[:, 1]]
    d = np.hypot(e[:, 0] - g[:, 0], e[:, 1] - g[:, 1])
    return {
        "n": len(pairs),
        "pos_rmse": float(np.sqrt(np.mean(d * d))),
        "heading_max_deg": float(np.degrees(np.abs(wrap_angle(e[:, 2] - g[:, 2]))).max()),
    }


@pytest.fixture(scope="module")
def runs(tmp_path_factory, module_ros_domain):
    """Every mount of MOUNTS: simulated, then run through the graph (--rate max)."""
    out = {}
    for name, chain in MOUNTS.items():
        d = tmp_path_factory.mktemp(name)
        sim = simulate_indoor(d / "sim", seed=0, laser_mount=chain)
        res = run(str(sim.bag_path), d / "run", params_file=PARAMS, progress=False, domain_id=module_ros_domain)
        out[name] = (sim, d / "run", res.summary, errors(d / "run" / "trajectory.tum", sim.ground_truth_path))
    return out


@pytest.mark.parametrize("name", [n for n in MOUNTS if n != "plain"])
def test_every_mount_is_applied(runs, name):
    """Measured: heading error <= 0.5 deg and position RMSE 0.009-0.013 m for every mount (main:
    yaw 180 -> heading error 180 deg, yaw 90 -> 90 deg, upside down -> a mirrored map)."""
    sim, out, s, err = runs[name]
    plain = runs["plain"][3]
    assert s["complete"] and s["scans_processed"] == 600 and not any(s["faults"].values())
    assert err["n"] == 600
    assert err["heading_max_deg"] < 2.0, err
    # the views differ (a lidar looking backwards sees other walls): unaligned RMSE 0.04-0.35 m
    # (plain 0.078), ATE after alignment 0.015-0.087 m (plain 0.014) with the map turned < 0.5 deg
    assert err["pos_rmse"] < 0.5, (err, plain)
    ev = evaluate(out / "trajectory.tum", sim.ground_truth_path)["ate"]
    assert ev["rmse"] < 0.1 and abs(math.degrees(ev["align_theta"])) < 1.0, ev
    used = s["lidar_mount"]["used"]
    assert used.startswith("lidar mount from /tf_static: base_link -> ") and not s["lidar_mount"]["warnings"]
    if name == "chain":
        assert "base_link -> shell_link -> rplidar_link: x -0.04 y 0.00 z 0.19, yaw 90.0°" in used, used
    if name == "upside_down":
        assert "roll 180.0°" in used and "upside down" in used, used
    if name == "yaw90_offset":
        assert "x 0.30 y 0.10 z 0.20, yaw 90.0° (planar" in used, used


def test_offset_changes_the_trajectory_and_is_more_accurate(runs, tmp_path, module_ros_domain):
    """The same bag with the mount's yaw but no offset (the parameters replace the bag's mount,
    with a warning): a different, worse trajectory (main gave byte-identical ones)."""
    sim, out, _, err = runs["yaw90_offset"]
    no_offset = {
        "/**": {
            "filter.sensor_offset_x_m": 0.0,
            "filter.sensor_offset_y_m": 0.0,
            "filter.sensor_offset_yaw_rad": PI / 2,
        }
    }
    res = run(
        str(sim.bag_path),
        tmp_path / "r",
        params_file=PARAMS,
        overrides=no_offset,
        progress=False,
        domain_id=module_ros_domain,
    )
    assert res.summary["lidar_mount"]["used"].startswith("lidar mount from the parameters: ")
    assert any("replaces the bag's" in w for w in res.summary["lidar_mount"]["warnings"])
    with_offset = (out / "trajectory.tum").read_bytes()
    assert (tmp_path / "r" / "trajectory.tum").read_bytes() != with_offset
    worse = errors(tmp_path / "r" / "trajectory.tum", sim.ground_truth_path)
    assert worse["pos_rmse"] > 3.0 * err["pos_rmse"], (worse, err)


def test_a_mount_equals_scans_turned_to_match_it(runs, tmp_path, module_ros_domain):
    """The yaw-180 bag with its scans turned instead (angle_min + pi, the frame at base_link):
    the same trajectory (to float rounding of the beam angles) as applying the mount."""
    sim, out, _, _ = runs["yaw180"]
    turned = tmp_path / "turned"

    def turn(k, msg):
        msg.angle_min += PI
        msg.angle_max += PI
        return msg

    _copy_bag(sim.bag_path, turned, scan=turn, drop_tf=True)
    run(str(turned), tmp_path / "r", params_file=PARAMS, progress=False, domain_id=module_ros_domain)
    t_a, p_a = read_trajectory(out / "trajectory.tum")
    t_b, p_b = read_trajectory(tmp_path / "r" / "trajectory.tum")
    assert np.array_equal(t_a, t_b)
    assert np.abs(p_a[:, :2] - p_b[:, :2]).max() < 0.01 and np.abs(wrap_angle(p_a[:, 2] - p_b[:, 2])).max() < 0.005


def _copy_bag(src: Path, dst: Path, tf=None, scan=None, drop_tf: bool = False) -> None:
    """`src` rewritten: /tf_static messages replaced by `tf(msg)` (or dropped), scans by `scan(k, msg)`."""
    info = bag_info(src)
    with open_writer(dst) as w:
        for topic, (msgtype, _) in info["topics"].items():
            if not (drop_tf and topic == "/tf_static"):
                w.add_connection(topic, msgtype)
        k = 0
        for topic, msgtype, t, raw in read_bag(src):
            if topic == "/tf_static":
                if not drop_tf:
                    w.write(topic, t, tf(deserialize(raw, msgtype)) if tf else deserialize(raw, msgtype))
            elif topic == "/scan" and scan is not None:
                w.write(topic, t, scan(k, deserialize(raw, msgtype)))
                k += 1
            else:
                w.write_raw(topic, t, raw)


def test_scan_frame_missing_from_tf_static_warns_and_the_parameters_apply(runs, tmp_path, module_ros_domain):
    """/tf_static without the scan's frame: a warning naming it and what /tf_static has; the
    parameters' mount (here the true one) applies and the mapper publishes it."""
    sim = runs["yaw90_offset"][0]
    bag = tmp_path / "no_laser_tf"
    _copy_bag(
        sim.bag_path,
        bag,
        tf=lambda m: tf_static(
            m.transforms[0].header.stamp.sec * 10**9 + m.transforms[0].header.stamp.nanosec,
            [("base_link", "imu_link", (0.0, 0.0, 0.1), (0.0, 0.0, 0.0, 1.0))],
        ),
    )
    mount = {
        "/**": {
            "filter.sensor_offset_x_m": 0.3,
            "filter.sensor_offset_y_m": 0.1,
            "filter.sensor_offset_yaw_rad": PI / 2,
        }
    }
    res = run(
        str(bag), tmp_path / "r", params_file=PARAMS, overrides=mount, progress=False, domain_id=module_ros_domain
    )
    w = res.summary["lidar_mount"]["warnings"]
    assert len(w) == 1 and "no transform to the scan's frame 'laser'" in w[0] and "base_link -> imu_link" in w[0], w
    err = errors(tmp_path / "r" / "trajectory.tum", sim.ground_truth_path)
    assert err["heading_max_deg"] < 2.0 and err["pos_rmse"] < 0.1, err
    # without /tf_static at all, the parameters are the mount too: the same trajectory
    bare = tmp_path / "no_tf_static"
    _copy_bag(sim.bag_path, bare, drop_tf=True)
    res2 = run(
        str(bare), tmp_path / "r2", params_file=PARAMS, overrides=mount, progress=False, domain_id=module_ros_domain
    )
    assert not res2.summary["lidar_mount"]["warnings"]
    assert (tmp_path / "r2" / "trajectory.tum").read_bytes() == (tmp_path / "r" / "trajectory.tum").read_bytes()


# ------------------------------------------------------------------------- 17.3: range limits
RANGE_MAX = 12.0


def _limited(spurious: bool):
    """Scan editor: header range_max 12 m; real returns beyond it kept (as an RPLidar reports
    them, up to 20 m here) and ~5 % of the beams replaced by spurious 15-22 m values
    (`spurious`), or both NaN (the reference: beams every stage ignores)."""

    def edit(k, msg):
        r = np.array(msg.ranges, dtype=np.float32)
        rng = np.random.default_rng([7, k])
        junk = rng.random(r.size) < 0.05
        beyond = junk | (np.isfinite(r) & (r > RANGE_MAX))
        if spurious:
            r[junk] = rng.uniform(15.0, 22.0, size=int(junk.sum()))
        else:
            r[beyond] = np.nan
        msg.range_max = RANGE_MAX
        msg.ranges = r
        return msg

    return edit


def _known_outside_building(map_dir: Path, sim_gt_map: Path) -> int:
    """Map cells (free or occupied) more than 0.3 m outside the building's outer walls."""
    occ, res, origin = read_map(map_dir / "map.yaml")
    gocc, gres, gorigin = read_map(sim_gt_map)
    rows, cols = np.nonzero(gocc >= 65)
    wx, wy = gorigin[0] + (cols + 0.5) * gres, gorigin[1] + (rows + 0.5) * gres
    r, c = np.nonzero(occ >= 0)
    x, y = origin[0] + (c + 0.5) * res, origin[1] + (r + 0.5) * res
    out = (x < wx.min() - 0.3) | (x > wx.max() + 0.3) | (y < wy.min() - 0.3) | (y > wy.max() + 0.3)
    return int(out.sum())


def test_returns_beyond_range_max_are_neither_hits_nor_free_space(tmp_path, module_ros_domain):
    """Values beyond the scan's range_max (real far walls and spurious 15-22 m values) give the
    same trajectory and map, byte for byte, as the same beams set to NaN. On main they were
    traced as free space through the walls: 91,947 known cells outside the building (1,267 here)."""
    ref, junk = tmp_path / "ref", tmp_path / "junk"
    _copy_bag(SAMPLE, ref, scan=_limited(False))
    _copy_bag(SAMPLE, junk, scan=_limited(True))
    run(str(ref), tmp_path / "a", params_file=PARAMS, progress=False, domain_id=module_ros_domain)
    b = run(str(junk), tmp_path / "b", params_file=PARAMS, progress=False, domain_id=module_ros_domain)
    assert b.summary["complete"] and b.summary["scans_processed"] == 600
    assert b.summary["faults"]["scan_bad_ranges"] == 0  # beyond range_max is no return, not a fault
    assert (tmp_path / "b" / "trajectory.tum").read_bytes() == (tmp_path / "a" / "trajectory.tum").read_bytes()
    assert (tmp_path / "b" / "map.pgm").read_bytes() == (tmp_path / "a" / "map.pgm").read_bytes()
    gt_map = SAMPLE.parent / "ground_truth_map.yaml"
    # (the sim's dropouts are +inf, traced as free space through the walls: ~1,300 cells in both)
    assert _known_outside_building(tmp_path / "b", gt_map) == _known_outside_building(tmp_path / "a", gt_map)
    ev = evaluate(tmp_path / "b" / "trajectory.tum", SAMPLE.parent / "ground_truth.tum")["ate"]
    # still localised on 12 m of range (filter seeds 0-3 give 0.043-0.068 m; lost would be metres)
    assert ev["rmse"] < 0.08, ev


def test_scans_with_unusable_limits_are_counted_and_posed_from_odometry(tmp_path, module_ros_domain):
    """range_max 0 (scans 100-139), range_min > range_max (140-149), NaN range_max (150-154):
    counted as scan_bad_limits, posed from odometry, never corrected or mapped with (main: no
    fault, 332 'corrected' scans)."""

    def edit(k, msg):
        if 100 <= k < 140:
            msg.range_max = 0.0
        elif 140 <= k < 150:
            msg.range_min, msg.range_max = 5.0, 2.0
        elif 150 <= k < 155:
            msg.range_max = float("nan")
        return msg

    bag = tmp_path / "bad_limits"
    _copy_bag(SAMPLE, bag, scan=edit)
    res = run(str(bag), tmp_path / "r", params_file=PARAMS, progress=False, domain_id=module_ros_domain)
    s = res.summary
    assert s["complete"] and s["scans_processed"] == 600 and s["scans_dropped"] == 0
    assert s["faults"]["scan_bad_limits"] == 55
    assert s["faults"]["scan_count_mismatch"] == 0
    assert s["scans_corrected"] < 332 - 20  # the bad scans were not corrected with
    err = errors(tmp_path / "r" / "trajectory.tum", SAMPLE.parent / "ground_truth.tum")
    assert err["pos_rmse"] < 0.1, err
