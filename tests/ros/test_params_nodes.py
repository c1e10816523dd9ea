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
from pf_slam_nodes.nodes.texture import TextureNode  # noqa: E402

CONFIG = Path(__file__).resolve().parents[2] / "ros2_ws/src/pf_slam_nodes/config"
SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "sample_indoor"
CLASSES = {
    "bag_replay": BagReplay,
    "predictor": Predictor,
    "correlator": Correlator,
    "mapper": Mapper,
    "texture": TextureNode,
}


def test_every_dataset_has_a_parameter_file():
    assert {"kaist.yaml", "carmen_indoor.yaml", "mines.yaml", "sim_indoor.yaml"} <= {
        p.name for p in CONFIG.glob("*.yaml")
    }


@pytest.mark.parametrize("yaml_file", sorted(CONFIG.glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_yaml_builds_nodes(yaml_file, ros_context):
    """The graph's nodes built from the file (as `pf-slam run` and the launch file do) hold its
    values; shared values sit under '/**' only if several nodes declare them, node-specific ones
    in that node's block."""
    layers = [load_params(yaml_file)]
    declared_by: dict[str, set[str]] = {}
    for name in NODE_NAMES + ("texture",):
        params = node_params(layers, name)
        if name == "bag_replay":
            params["bag"] = str(SAMPLE)
        node = CLASSES[name](
            context=ros_context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]
        )
        try:
            for k, v in params.items():
                if node.has_parameter(k):  # '/**' values reach every node; each takes what it declares
                    assert node.get_parameter(k).value == v, (yaml_file.name, name, k)
                    declared_by.setdefault(k, set()).add(name)
        finally:
            node.destroy_node()
    for section, values in layers[0].items():
        for k in values:
            nodes = declared_by.get(k, set())
            if section == "/**":
                assert len(nodes) >= 2, (
                    f"{yaml_file.name}: '/**' {k} is used by {sorted(nodes) or 'no node'}: put it in that node's block"
                )
            else:
                assert section in nodes, f"{yaml_file.name}: {section} does not declare {k}"


def test_bad_parameter_names_the_parameter(ros_context):
    with pytest.raises(ValueError, match="num_particles"):
        Predictor(context=ros_context, parameter_overrides=[Parameter("filter.num_particles", value=0)])
    with pytest.raises(ValueError, match="odometry_source"):
        Predictor(context=ros_context, parameter_overrides=[Parameter("odometry_source", value="gps")])


@pytest.mark.parametrize(
    ("cls", "params", "match"),
    [
        (Mapper, {"loops.enabled": True, "occupied_thresh": 2.0}, "occupied_thresh"),
        (Correlator, {"correlation.odom_scale": True, "mode": "bogus"}, "mode"),
    ],
    ids=["mapper", "correlator"],
)
def test_bad_parameter_after_the_worker_started_stops_it(cls, params, match, ros_context):
    """The mapper's loop matches and the correlator's scan pairs run in a worker process started
    with the node's stage; a parameter found bad after that stops the worker with the error."""
    import multiprocessing

    before = {p.pid for p in multiprocessing.active_children()}
    with pytest.raises(ValueError, match=match):
        cls(context=ros_context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    assert {p.pid for p in multiprocessing.active_children()} <= before


def test_live_node_warns_about_undeclared_overrides(ros_context):
    """Started by ros2 launch with a --params-file, ROS ignores names the node does not declare;
    the node names those that no node of the graph declares (another node's are fine)."""
    from pf_slam_nodes.nodes.common import warn_undeclared

    node = Predictor(
        context=ros_context,
        parameter_overrides=[
            Parameter("num_partcles", value=5),
            Parameter("grid.resolution_m", value=0.1),
            Parameter("filter.seed", value=1),
        ],
    )
    try:
        assert warn_undeclared(node) == ["num_partcles"]
    finally:
        node.destroy_node()
