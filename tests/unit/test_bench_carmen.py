"""The CARMEN bench's targets lines (no graph run)."""

from pf_slam_tools.bench import carmen


def _row(dataset, seed, wall, rel=None, ate=None):
    r = {"dataset": dataset, "seed": seed, "wall_time_s": wall}
    if rel is not None:
        r["rel_trans_mean"] = rel
    if ate is not None:
        r["ate_vs_reference_rmse"] = ate
    return r


def test_targets_lines_count_the_runs_that_meet_each_target():
    rows = [
        _row("intel_2726", 0, 25.0, rel=0.021),
        _row("intel_2726", 1, 60.0, rel=0.286),
        _row("intel_910", 0, 8.0, rel=0.029, ate=0.5),
        _row("mit-csail", 0, 25.0, ate=0.12),
        _row("mit-csail", 1, 24.0, ate=0.10),
    ]
    assert carmen.targets_lines(rows).splitlines() == [
        "intel_910: 1 runs, wall 8.0-8.0 s; relations 0.029 m on average, median 0.029 m, worst run 0.029 m; <= 0.03 m in 1 of 1; "
        "ATE vs GMapping 0.500-0.500 m, median 0.500 m",
        "intel_2726: 2 runs, wall 25.0-60.0 s; relations 0.153 m on average, median 0.021 m, worst run 0.286 m; <= 0.083 m in 1 of 2; "
        "wall <= 56 s in 1 of 2",
        "mit-csail: 2 runs, wall 24.0-25.0 s; ATE vs GMapping 0.100-0.120 m, median 0.100 m",
    ]


def test_the_benches_parameter_files_exist():
    """The benches live in pf_slam_tools; the profiles they run stay in the runtime package."""
    from pf_slam_tools.bench import car

    assert carmen.CARMEN_YAML.is_file() and car.KAIST_YAML.is_file()
