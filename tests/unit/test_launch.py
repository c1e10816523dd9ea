"""The launch file (run only on a ROS install: `launch` is not in the pip venv) is valid Python
and starts node executables that the package really installs."""

import ast
import os
import re
from pathlib import Path

PKG = Path(__file__).resolve().parents[2] / "ros2_ws/src/pf_slam_nodes"
LAUNCH = PKG / "launch" / "pf_slam.launch.py"


def _sq(text: str) -> str:
    """Code text without white space: the checks hold however the formatter wraps the calls."""
    return re.sub(r"\s+", "", text)


def _squeezed(path: Path) -> str:
    return _sq(path.read_text())


def _constant(path: Path, name: str):
    """Value of a module-level literal assignment `name = ...`."""
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == name for t in node.targets):
            return ast.literal_eval(node.value)
    raise AssertionError(f"{path.name}: no {name} = <literal>")


def test_launch_file_compiles_and_names_installed_executables():
    compile(LAUNCH.read_text(), str(LAUNCH), "exec")
    source = _squeezed(LAUNCH)
    assert _sq("def generate_launch_description") in source
    launched = _constant(LAUNCH, "NODES")
    console_scripts = set(_constant(PKG / "setup.py", "NODES"))
    assert set(launched) == console_scripts, (launched, console_scripts)
    for name in launched:
        assert (PKG / "pf_slam_nodes" / "nodes" / f"{name}.py").is_file()
        assert "def main(" in (PKG / "pf_slam_nodes" / "nodes" / f"{name}.py").read_text()
    assert (PKG / "config" / _constant(LAUNCH, "DEFAULT_PARAMS")).is_file()
    for arg in ("bag", "params_file", "use_sim_time", "map"):
        assert _sq(f'DeclareLaunchArgument("{arg}"') in source


def test_launch_file_profile_argument():
    """profile:=auto reads the bag through pf_slam_nodes.profiles (as `pf-slam run`), the
    fallback is the indoor profile, and every profile name it documents exists."""
    source = _squeezed(LAUNCH)
    assert _sq('DeclareLaunchArgument("profile", default_value="auto"') in source
    assert _sq("profiles.profile_for_bag(bag, forced=profile)") in source
    assert _sq('profiles.profile_file("indoor")') in source
    from pf_slam_nodes import profiles

    for name in ("indoor", "kaist", "mines", "sim_indoor"):
        assert _sq(name) in source and profiles.profile_file(name).is_file()
    assert profiles.PROFILES["indoor"] == _constant(LAUNCH, "DEFAULT_PARAMS")


def test_launch_plan_live_and_bag():
    """Without bag:= no bag_replay (live topics) and no base_link -> lidar of the mapper's own;
    use_sim_time auto is left unset (the nodes follow /clock), true/false is passed as a bool,
    never to bag_replay (the clock's source); odometry_source reaches the predictor."""
    import pytest

    from pf_slam_nodes.launch_plan import graph_nodes

    live = graph_nodes()
    assert list(live) == ["predictor", "correlator", "mapper"]
    assert all("use_sim_time" not in p for p in live.values())
    assert live["mapper"]["publish_sensor_tf"] is False
    assert all(live[n]["mount_from_tf"] is True for n in ("predictor", "correlator", "mapper"))
    bag = graph_nodes(
        bag="/data/bag", use_sim_time="true", texture="true", odometry_source="tf", scan_topic="/front/scan"
    )
    assert list(bag) == ["bag_replay", "predictor", "correlator", "mapper", "texture"]
    assert bag["bag_replay"] == {"bag": "/data/bag", "scan_topic": "/front/scan"}
    assert all(bag[n]["use_sim_time"] is True for n in ("predictor", "correlator", "mapper", "texture"))
    assert bag["predictor"]["odometry_source"] == "tf" and bag["mapper"]["publish_sensor_tf"] is True
    assert "mount_from_tf" not in bag["mapper"]  # pf-slam run's way: the bag's /tf_static, read before
    assert graph_nodes(use_sim_time="false")["mapper"]["use_sim_time"] is False
    assert graph_nodes(publish_sensor_tf="true")["mapper"]["publish_sensor_tf"] is True
    assert graph_nodes(sensor_qos="best_effort")["predictor"]["sensor_qos"] == "best_effort"
    loc = graph_nodes(map="maps/office.yaml")  # localization only, on live topics
    assert loc["correlator"]["mode"] == "localization" and loc["mapper"]["mode"] == "localization"
    assert loc["mapper"]["map_file"] == os.path.abspath("maps/office.yaml")
    for bad in (dict(use_sim_time="yes"), dict(odometry_source="gps"), dict(texture="maybe")):
        with pytest.raises(ValueError, match="launch argument"):
            graph_nodes(**bad)
    source = _squeezed(LAUNCH)
    assert _sq("graph_nodes(") in source and _sq('DeclareLaunchArgument("bag", default_value=""') in source
    for arg in ("odometry_source", "publish_sensor_tf"):
        assert _sq(f'DeclareLaunchArgument("{arg}"') in source
