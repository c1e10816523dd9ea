"""Every shipped parameter file builds the graph's nodes; bad parameters fail with their name."""
from __future__ import annotations

from pathlib import Path

import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.parameter import Parameter  # noqa: E402

from pf_slam_nodes.graph import NODE_NAMES, load_params, node_params  # noqa: E402
from pf_slam_nodes.nodes.bag_replay import BagReplay  # noqa: E402
from pf_slam_nodes.nodes.correlator import Correlator  # noqa: E402
from pf_slam_nodes.nodes.mapper import Mapper  # noqa: E402
from pf_slam_nodes.nodes.predictor import Predictor  # noqa: E402

CONFIG = Path(__file__).resolve().parents[2] / "ros2_ws/src/pf_slam_nodes/config"
SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "sample_indoor"
CLASSES = {"predictor": Predictor, "correlator": Correlator, "mapper": Mapper}


@pytest.mark.parametrize("yaml_file", sorted(CONFIG.glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_yaml_builds_nodes(yaml_file, ros_context):
    layers = [load_params(yaml_file)]
    used: set[str] = set()
    for name in NODE_NAMES:
        params = node_params(layers, name)
        if name == "bag_replay":
            params["bag"] = str(SAMPLE)
        cls = CLASSES.get(name, BagReplay)
        node = cls(context=ros_context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
        for k, v in params.items():
            if node.has_parameter(k):  # '/**' values reach every node; each takes what it declares
                assert node.get_parameter(k).value == v, (yaml_file.name, name, k)
                used.add(k)
        node.destroy_node()
    every_key = {k for layer in layers for section in layer.values() for k in section}
    assert every_key <= used, f"{yaml_file.name}: parameters no node declares: {sorted(every_key - used)}"


def test_bad_parameter_names_the_parameter(ros_context):
    with pytest.raises(ValueError, match="num_particles"):
        Predictor(context=ros_context, parameter_overrides=[Parameter("filter.num_particles", value=0)])
    with pytest.raises(ValueError, match="odometry_source"):
        Predictor(context=ros_context, parameter_overrides=[Parameter("odometry_source", value="gps")])
