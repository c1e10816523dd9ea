"""Parameter files for `pf-slam run` (no rclpy needed)."""

import pytest

from pf_slam_nodes.graph import RunError, flatten, load_params, node_params, unflatten


def test_load_merge_and_flatten(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text(
        "/**:\n  ros__parameters:\n    filter: {num_particles: 50, seed: 3}\n"
        "predictor:\n  ros__parameters:\n    filter.num_particles: 10\n"
    )
    layers = [load_params(f)]
    assert node_params(layers, "predictor") == {"filter.num_particles": 10, "filter.seed": 3}
    assert node_params(layers, "mapper") == {"filter.num_particles": 50, "filter.seed": 3}
    assert unflatten(flatten({"a": {"b": 1, "c": {"d": 2}}})) == {"a": {"b": 1, "c": {"d": 2}}}


@pytest.mark.parametrize(
    "text, what",
    [
        ("predictor: {x: 1}\n", "ros__parameters"),
        ("nosuchnode:\n  ros__parameters: {a: 1}\n", "unknown node"),
        ("[1, 2]\n", "not a ROS 2 parameter file"),
    ],
)
def test_bad_parameter_files_name_the_file(tmp_path, text, what):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    with pytest.raises(RunError, match=what) as e:
        load_params(f)
    assert str(f) in str(e.value)


@pytest.mark.parametrize(
    "section, body, key, nearest",
    [
        ("/**", "num_partcles: 500", "num_partcles", "filter.num_particles"),  # the case
        ("/**", "filter: {num_partilces: 500}", "filter.num_partilces", "filter.num_particles"),
        ("predictor", "odom_synk: exact", "odom_synk", "odom_sync"),
        ("correlator", "correlation.sigma: 0.1", "correlation.sigma", "correlation.sigma_m"),
        ("mapper", "correlation.sigma_m: 0.1", "correlation.sigma_m", None),  # another node's
        ("/**", "topics: {scann: /front/scan}", "topics.scann", "topics.scan"),  # run's own, unknown input
    ],
)
def test_unknown_parameter_names_the_file_section_key_and_nearest(tmp_path, section, body, key, nearest):
    """ROS ignores overrides a node does not declare, so a typo silently kept the default:
    load_params refuses a name no node reads, naming where it is and what was probably meant."""
    f = tmp_path / "typo.yaml"
    f.write_text(f"{section}:\n  ros__parameters:\n    {body}\n")
    with pytest.raises(RunError) as e:
        load_params(f)
    msg = str(e.value)
    assert msg.startswith(f"{f}: section '{section}': unknown parameter '{key}'"), msg
    if nearest:
        assert msg.endswith(f"nearest known: '{nearest}'"), msg
    if section == "mapper":
        assert "declared by correlator" in msg, msg
    assert "\n" not in msg


def test_known_names_load(tmp_path):
    """Every declared name loads: a node's own in its section, any node's under '/**', topics.*;
    predictor's wheels.* (declared with encoders only) too; every shipped file loads."""
    from pathlib import Path

    from pf_slam_nodes.nodes.declared import declared, declared_by

    f = tmp_path / "ok.yaml"
    f.write_text(
        "/**:\n  ros__parameters:\n    topics: {scan: /front/scan}\n    filter.seed: 2\n"
        "    correlation.sigma_m: 0.1\npredictor:\n  ros__parameters:\n    wheels.base_m: 0.5\n"
    )
    assert load_params(f)["predictor"] == {"wheels.base_m": 0.5}
    assert set(declared("predictor")) >= {"filter.num_particles", "motion.sigma_xy_per_m", "wheels.base_m"}
    assert declared_by()["grid.resolution_m"] == ["correlator", "mapper"]
    for shipped in (Path(__file__).resolve().parents[2] / "ros2_ws/src/pf_slam_nodes/config").glob("*.yaml"):
        load_params(shipped)


@pytest.mark.parametrize(
    "node, params, name, what",
    [
        ("predictor", {"filter.num_particles": 0}, "filter.num_particles", "num_particles must be >= 1, got 0"),
        ("correlator", {"filter.num_particles": "many"}, "filter.num_particles", "must be an int"),
        ("correlator", {"correlation.refine_residual": "abs"}, "correlation.refine_residual", "refine_residual"),
        ("mapper", {"grid.resolution_m": -1.0}, "grid.resolution_m", "resolution_m"),
        ("mapper", {"occupied_thresh": "high"}, "occupied_thresh", "must be float, got 'high'"),
        ("bag_replay", {"max_in_flight": 2.5}, "max_in_flight", "must be int"),
        ("predictor", {"filter.seed": None}, "filter.seed", "is not a parameter value"),
        ("predictor", {"map_frame": [1, "a"]}, "map_frame", "is not a parameter value"),
    ],
)
def test_bad_values_are_found_before_any_node_is_built(node, params, name, what):
    from pf_slam_nodes.nodes.declared import check_values

    bad = check_values(node, params)
    assert bad is not None and bad[0] == name and what in bad[1], bad
    assert (
        check_values(
            node,
            {
                "filter.num_particles": 10,
                "map_frame": "world",
                "max_in_flight": 5,
                "correlation.sigma_m": 1,
                "grid.resolution_m": 0.1,
            },
        )
        is None
    )
