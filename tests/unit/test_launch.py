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
    for arg in ("bag", "params_file", "use_sim_time"):
        assert f'DeclareLaunchArgument("{arg}"' in source
