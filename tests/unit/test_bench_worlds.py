"""The worlds bench's parts (no filter run): synthesised odometry, relations from the truth,
the repetitive-corridors and ring drives, the scores, the loop-closure back end's optimiser."""

import math

import numpy as np

from pf_slam_tools.bench import worlds
from pf_slam_tools.sim import worlds as sim
from pf_slam_tools.sim.indoor import distance_to_segments


def _straight(n=101, step=1.0):
    return np.stack([np.arange(n) * step, np.zeros(n), np.zeros(n)], axis=1)


def test_synthesised_odometry_is_seeded_and_has_the_documented_errors():
    truth = _straight()
    a = worlds.synthesise_odometry(truth, np.random.default_rng(3))
    b = worlds.synthesise_odometry(truth, np.random.default_rng(3))
    assert np.array_equal(a, b)
    assert np.array_equal(a[0], truth[0])
    steps = np.hypot(*np.diff(a[:, :2], axis=0).T)
    scale = abs(steps.mean() - 1.0)
    assert 0.005 < scale < 0.035  # 1-3 % scale error (+ noise)
    turn = abs(math.degrees(a[-1, 2])) / 100.0  # heading bias 0.3-1 deg/m (+ noise)
    assert 0.1 < turn < 1.5
    assert np.hypot(*(a[-1, :2] - truth[-1, :2])) > 0.5  # it drifts


def test_relations_include_the_revisits_of_a_loop():
    t = np.linspace(0, 2 * math.pi, 800, endpoint=False)
    truth = np.stack([20 * np.cos(t), 20 * np.sin(t), t + math.pi / 2], axis=1)
    truth = np.concatenate([truth, truth[:200]])  # drives on past the start
    pairs = worlds.relations_from_truth(truth)
    revisits = pairs[pairs[:, 1] - pairs[:, 0] >= 300]
    assert len(revisits) >= 15
    assert np.all(np.hypot(*(truth[revisits[:, 1], :2] - truth[revisits[:, 0], :2]).T) <= 3.0)
    s = worlds.score(truth, truth)
    assert s["ate_rmse"] < 1e-9 and s["rel_mean"] < 1e-9 and s["rel_over_05"] == 0.0


def test_simulated_drives_close_their_loop_and_keep_off_the_walls():
    for name in ("corridors", "ring"):
        world, truth = sim.WORLDS[name](np.random.default_rng(0))
        length = np.hypot(*np.diff(truth[:, :2], axis=0).T).sum()
        assert np.allclose(truth[0], 0.0)
        assert distance_to_segments(truth[::20, :2], world.segments).min() > 0.3
        ext = world.bounds[2:] - world.bounds[:2]
        if name == "ring":
            assert ext.max() > 300 - 1e-6 and length > 850
        else:
            assert length > 250
        # the drive passes its start again (a loop to close)
        late = truth[len(truth) // 2 :, :2]
        assert np.hypot(late[:, 0], late[:, 1]).min() < 1.0


def test_maze_is_another_building_for_every_seed_and_its_drive_loops():
    from pf_slam_tools.sim.maze import maze_layout

    extents = set()
    for seed in range(8):
        world, truth = sim.WORLDS["maze"](np.random.default_rng(seed))
        again, truth2 = sim.WORLDS["maze"](np.random.default_rng(seed))
        assert np.array_equal(world.segments, again.segments) and np.array_equal(truth, truth2)  # seeded
        extents.add(tuple(np.round(world.bounds[2:] - world.bounds[:2], 1)))
        assert np.allclose(truth[0], 0.0)
        assert distance_to_segments(truth[::20, :2], world.segments).min() > 0.25  # in the corridors
        length = np.hypot(*np.diff(truth[:, :2], axis=0).T).sum()
        assert 300 < length < 800
        late = truth[len(truth) // 2 :, :2]
        assert np.hypot(late[:, 0], late[:, 1]).min() < 1.0  # back at the start
        # it passes some place twice far apart in time: loops inside the drive, not only at its end
        step = max(1, len(truth) // 400)
        t = truth[::step, :2]
        gap = np.abs(np.arange(len(t))[:, None] - np.arange(len(t))[None]) * step
        near = np.hypot(*(t[:, None] - t[None]).transpose(2, 0, 1)) < 1.0
        first_half = np.arange(len(t))[:, None] < len(t) // 2
        assert np.any(near & (gap > len(truth) // 5) & first_half)
    assert len(extents) == 8  # eight different floor plans
    world, xs, ys = maze_layout(np.random.default_rng(0))
    assert 3 <= len(xs) <= 5 and 2 <= len(ys) <= 4


def test_range_noise_changes_only_the_ranges_and_has_its_own_section():
    from pf_slam_tools.sim.indoor import ray_cast

    quiet, loud = sim.simulate_world("office", 1, range_sigma_m=0.0), sim.simulate_world("office", 1, 0.03)
    assert np.array_equal(quiet.truth, loud.truth) and np.array_equal(quiet.odom, loud.odom)
    exact = ray_cast(quiet.truth, quiet.angles, quiet.world.segments, quiet.range_max).reshape(quiet.ranges.shape)
    both = np.isfinite(quiet.ranges) & np.isfinite(loud.ranges) & (exact < quiet.range_max - 0.2)
    assert np.allclose(quiet.ranges[both], exact[both], atol=1e-5)  # float32 ranges, no noise
    assert abs(np.std(loud.ranges[both] - exact[both]) - 0.03) < 0.002
    default = sim.simulate_world("office", 1)
    assert abs(np.std(default.ranges[both] - exact[both]) - 0.01) < 0.001  # the simulator's own 1 cm
    assert worlds.section(["ring", "corridors"]) == ("worlds_sim", "simulated buildings with ground truth")
    part, title = worlds.section(["ring"], 0.03)
    assert part == "worlds_sim_noise30mm" and "3 cm" in title


def test_range_noise_is_refused_for_real_scans_and_bad_values():
    import pytest

    with pytest.raises(ValueError, match="edmonton.*real scans"):
        worlds.check_noise(["ring", "edmonton"], 0.03)
    with pytest.raises(ValueError, match="real scans"):
        worlds.check_noise(None, 0.02)  # every world: the buildings among them
    with pytest.raises(ValueError, match=">= 0"):
        worlds.check_noise(["ring"], -0.01)
    with pytest.raises(ValueError, match="range_sigma_m"):
        sim.simulate_world("office", 0, float("nan"))
    worlds.check_noise(["ring", "office"], 0.0)
    worlds.check_noise(["edmonton"], None)


def test_another_laser_is_simulated_and_has_its_own_section():
    import pytest

    dense = sim.simulate_world("office", 1, laser=(1081, 270.0, 30.0))
    default = sim.simulate_world("office", 1)
    assert dense.ranges.shape == (len(default.truth), 1081) and dense.range_max == 30.0
    assert np.array_equal(dense.truth, default.truth) and np.array_equal(dense.odom, default.odom)
    assert np.isclose(dense.angles[0], -np.radians(135.0)) and np.isclose(dense.angles[-1], np.radians(135.0))
    assert np.allclose(np.diff(dense.angles), np.radians(0.25))
    ring = sim.laser_geometry((360, 360.0, 20.0))[0]  # a full circle: no beam twice
    assert np.isclose(ring[-1] - ring[0], np.radians(359.0))
    assert worlds.parse_laser("1081,270,30") == (1081, 270.0, 30.0) and worlds.parse_laser(None) is None
    part, title = worlds.section(["ring"], None, (1081, 270.0, 30.0))
    assert part == "worlds_sim_laser1081x270" and "1081-beam 270 deg laser (0.25 deg), 30 m" in title
    assert worlds.section(["ring"], 0.02, (361, 180.0, 20.0))[0] == "worlds_sim_noise20mm_laser361x180"
    with pytest.raises(ValueError, match="--laser sets the simulated laser.*edmonton"):
        worlds.check_noise(["ring", "edmonton"], None, (1081, 270.0, 30.0))
    for bad in ("1081,270", "many,270,30", "1,270,30", "1081,400,30"):
        with pytest.raises(ValueError, match="laser"):
            worlds.parse_laser(bad)


def test_the_tables_show_the_poses_as_published_beside_the_final_solve():
    """A short stretch of the office through the ROS-free loop: the row carries the ATE of the
    poses as returned scan by scan and of the final frame, and both tables print them."""
    d = worlds.sim_drive("office", 0)
    k = 150
    short = worlds.Drive("office", d.truth[:k], d.odom[:k], d.ranges[:k], d.angles[:k], d.range_max)
    est, info = worlds.run_drive(short, 0)
    assert est.shape == (k, 3) and info["scans"] == k
    assert 0.0 <= info["ate_published_rmse"] < 0.1  # the office's first metres: well inside the target
    row = {
        "world": "office",
        "seed": 0,
        **info,
        **worlds.score(est, short.truth),
        "odom_ate_rmse": 0.5,
        "length_m": 9.0,
    }
    other = {**row, "seed": 1, "ate_published_rmse": 0.25}
    per_run = worlds.format_table([row, other])
    assert "ATE as published (m)" in per_run.splitlines()[0]
    assert f"| {info['ate_published_rmse']:.3f} |" in per_run.splitlines()[2] and "| 0.250 |" in per_run.splitlines()[3]
    summary = worlds.summary_table([row, other])
    median = np.median([info["ate_published_rmse"], 0.25])
    assert f"| {median:.3f} / 0.250 |" in summary.splitlines()[2]
