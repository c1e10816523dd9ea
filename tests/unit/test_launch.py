"""The launch file (run only on a ROS install: `launch` is not in the pip venv) is valid Python
and starts node executables that the package really installs."""
import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[2] / "ros2_ws/src/pf_slam_nodes"
LAUNCH = PKG / "launch" / "pf_slam.launch.py"


def _constant(path: Path, name: str):
    """Value of a module-level literal assignment `name = ...`."""
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == name for t in node.targets):
            return ast.literal_eval(node.value)
    raise AssertionError(f"{path.name}: no {name} = <literal>")


def test_launch_file_compiles_and_names_installed_executables():
    source = LAUNCH.read_text()
    compile(source, str(LAUNCH), "exec")
    assert "def generate_launch_description" in source
    launched = _constant(LAUNCH, "NODES")
    console_scripts = set(_constant(PKG / "setup.py", "NODES"))
    assert set(launched) == console_scripts, (launched, console_scripts)
    for name in launched:
        assert (PKG / "pf_slam_nodes" / "nodes" / f"{name}.py").is_file()
        assert "def main(" in (PKG / "pf_slam_nodes" / "nodes" / f"{name}.py").read_text()
    assert (PKG / "config" / _constant(LAUNCH, "DEFAULT_PARAMS")).is_file()
    for arg in ("bag", "params_file", "use_sim_time", "map"):
        assert f'DeclareLaunchArgument("{arg}"' in source


def test_launch_file_profile_argument():
    """profile:=auto reads the bag through pf_slam_nodes.profiles (as `pf-slam run`), the
    fallback is the indoor profile, and every profile name it documents exists."""
    source = LAUNCH.read_text()
    assert 'DeclareLaunchArgument("profile", default_value="auto"' in source
    assert "profiles.profile_for_bag(bag, forced=profile)" in source
    assert 'profiles.profile_file("indoor")' in source
    from pf_slam_nodes import profiles
    for name in ("indoor", "kaist", "mines", "sim_indoor"):
        assert name in source and profiles.profile_file(name).is_file()
    assert profiles.PROFILES["indoor"] == _constant(LAUNCH, "DEFAULT_PARAMS")
