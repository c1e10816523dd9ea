"""Parameter files for `pf-slam run` (no rclpy needed)."""
import pytest

from pf_slam_nodes.graph import RunError, flatten, load_params, node_params, unflatten


def test_load_merge_and_flatten(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("/**:\n  ros__parameters:\n    filter: {num_particles: 50, seed: 3}\n"
                 "predictor:\n  ros__parameters:\n    filter.num_particles: 10\n")
    layers = [load_params(f)]
    assert node_params(layers, "predictor") == {"filter.num_particles": 10, "filter.seed": 3}
    assert node_params(layers, "mapper") == {"filter.num_particles": 50, "filter.seed": 3}
    assert unflatten(flatten({"a": {"b": 1, "c": {"d": 2}}})) == {"a": {"b": 1, "c": {"d": 2}}}


@pytest.mark.parametrize("text, what", [
    ("predictor: {x: 1}\n", "ros__parameters"),
    ("nosuchnode:\n  ros__parameters: {a: 1}\n", "unknown node"),
    ("[1, 2]\n", "not a ROS 2 parameter file"),
])
def test_bad_parameter_files_name_the_file(tmp_path, text, what):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    with pytest.raises(RunError, match=what) as e:
        load_params(f)
    assert str(f) in str(e.value)
