"""A log shaped like the held-out campus log, the way a user runs it: an outdoor campus's real
scans (freiburg-campus, its first 300: 241 m of driving, 172 m across) as a ROBOTLASER1-only log
(odometry inside the laser lines, synthesised with seed 0: 30 m of dead-reckoning ATE; the laser
0.25 m ahead of the robot), "no return" written as exactly 50 m; `pf-slam convert carmen`, then
`pf-slam run` with no parameter file.

The converter infers the 50 m sentinel (every such beam becomes +inf) and the mount from the
lines' laser and robot poses, the indoor profile applies from the bag's metadata, the map grows
past the 100 m grid it starts with and keeps its walls, and the robot's trajectory stays within
decimetres of the corrected poses."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

pytest.importorskip("rclpy")

from pf_slam_nodes.core.geometry import compose  # noqa: E402
from pf_slam_nodes.core.grid import from_occupancy  # noqa: E402
from pf_slam_nodes.core.metrics import ate  # noqa: E402
from pf_slam_nodes.core.scan import scan_to_points, transform_points  # noqa: E402
from pf_slam_nodes.graph import run  # noqa: E402
from pf_slam_nodes.io.convert import convert_carmen  # noqa: E402
from pf_slam_nodes.io.mapfile import read_map  # noqa: E402
from pf_slam_nodes.io.trajectory import read_trajectory  # noqa: E402
from pf_slam_tools.bench.worlds import building_drive  # noqa: E402
from pf_slam_tools.sim.robotlaser import building_as_robotlaser1  # noqa: E402

SCANS = 300
MOUNT_X_M = 0.25


@pytest.fixture(scope="module")
def campus(data_dir, tmp_path_factory, module_ros_domain):
    if not (data_dir / "carmen_corrected" / "freiburg-campus-corrected.log.gz").is_file():
        pytest.skip("freiburg-campus-corrected.log.gz not in the shared data")
    d = tmp_path_factory.mktemp("campus")
    stamps, truth = building_as_robotlaser1(data_dir, "freiburg-campus", 0, d / "campus.clf", SCANS, MOUNT_X_M)
    report = convert_carmen(d / "campus.clf", d / "bag")
    res = run(
        str(d / "bag"),
        d / "run",
        progress=False,
        domain_id=module_ros_domain,
        texture=False,
        record=False,
        snapshot_every=0,
    )
    drive = building_drive(data_dir, "freiburg-campus", 0)
    return report, res, d / "run", truth, drive


def test_the_50_m_sentinel_is_inferred_and_the_odometry_comes_from_the_laser_lines(campus):
    report, _, _, _, drive = campus
    no_return = sum(int(np.sum(~(np.asarray(r) < 50.0))) for r in drive.ranges[:SCANS])
    assert no_return > 10_000  # the campus's open spaces: 30 314 beams without return
    assert report.sentinel_m == 50.0 and report.sentinel_count == no_return
    assert report.counts["/scan"] == report.counts["/odom"] == SCANS


def test_default_profile_tracks_the_campus_and_the_map_grows_with_its_walls(campus):
    _, res, out, truth, drive = campus
    s = res.summary
    assert s["profile"]["name"] == "indoor"
    assert s["scans_processed"] == SCANS and s["scans_dropped"] == 0
    assert "base_link -> laser: x 0.25 y 0.00" in s["lidar_mount"]["used"]
    # a noisy laser (about 2.5 cm, ranges in cm): the indoor profile smooths most of its scans
    noise = s["laser_noise"]
    assert 0.015 < noise["noise_m_median"] < 0.05, noise
    assert noise["scans"]["smoothed"] > sum(noise["scans"].values()) / 2 and noise["scans"]["rounded"] == 0, noise
    _, poses = read_trajectory(out / "trajectory.tum")
    err = ate(poses, truth)["rmse"]
    dead_reckoning = ate(drive.odom[:SCANS], drive.truth[:SCANS])["rmse"]
    print(f"ATE {err:.3f} m, dead reckoning {dead_reckoning:.1f} m")
    assert dead_reckoning > 10.0
    assert err < 0.4, err  # measured 0.230-0.316 m over odometry/filter seeds 0-4
    # the map grew from its 100 m x 100 m start to the explored box (172 m of driving across)
    occ, res_m, origin = read_map(out / "map.yaml")
    extent = np.array(occ.shape[::-1]) * res_m
    assert extent[0] > 180.0, extent
    # walls stay: the scans' ends (every tenth scan, from the run's poses) lie on its occupied cells
    lasers = compose(poses, np.array([MOUNT_X_M, 0.0, 0.0]))
    grid = from_occupancy(occ, res_m, origin)
    walls = cv2.dilate((occ >= 65).astype(np.uint8), np.ones((3, 3), np.uint8))
    on = total = 0
    for k in range(0, SCANS, 10):
        ends = transform_points(scan_to_points(drive.ranges[k], drive.angles[k], 0.0, 20.0), lasers[k])
        col, row = grid.world_to_cell(ends).T
        inside = (col >= 0) & (col < grid.width) & (row >= 0) & (row < grid.height)
        on += int(walls[row[inside], col[inside]].sum())
        total += len(ends)
    print(f"scan ends on the map's walls: {on / total:.3f}")
    assert on / total > 0.8  # measured 0.917-0.922 over seeds 0-4
