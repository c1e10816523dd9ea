"""core/ stays ROS-free and free of file I/O; geometry formulas live once, in core/geometry.py.

The checks read the package's source (AST), so they hold for modules nothing imports yet and
for imports inside functions. Each rule is also tried on a small bad module, so a checker that
silently matches nothing fails here too.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

import pf_slam_nodes

PKG = Path(pf_slam_nodes.__file__).resolve().parent
CORE = PKG / "core"

#: package parts core/ must not import (core is imported by them, not the other way)
FORBIDDEN_PACKAGE_PARTS = ("io", "nodes", "ros", "graph", "runner", "cli", "bench", "sim", "launch")
#: third-party ROS modules (and ``*_msgs`` / ``*_interfaces`` message packages)
FORBIDDEN_TOP = {
    "rclpy",
    "rosbags",
    "rosbag2_py",
    "rosidl_runtime_py",
    "tf2_ros",
    "launch",
    "launch_ros",
    "ament_index_python",
    "builtin_interfaces",
}
#: standard modules whose job is files, processes or the file system
FORBIDDEN_STDLIB = {
    "os",
    "pathlib",
    "shutil",
    "glob",
    "tempfile",
    "pickle",
    "io",
    "sqlite3",
    "fcntl",
    "subprocess",
    "csv",
    "mmap",
}
#: calls that read or write files (as a plain name or an attribute: ``cv2.imwrite``, ``p.open``)
FILE_CALLS = {
    "open",
    "read_text",
    "write_text",
    "read_bytes",
    "write_bytes",
    "imread",
    "imwrite",
    "imreadmulti",
    "imwritemulti",
    "load",
    "save",
    "savez",
    "savez_compressed",
    "loadtxt",
    "savetxt",
    "genfromtxt",
    "fromfile",
    "tofile",
    "memmap",
    "FileStorage",
    "VideoCapture",
    "VideoWriter",
    "mkdir",
    "unlink",
    "dump",
    "remove",
    "rename",
    "listdir",
    "scandir",
}
MAX_LINES = 800


def _module_package(path: Path) -> list[str]:
    """Dotted package parts a module's relative imports resolve against."""
    rel = path.relative_to(PKG.parent).with_suffix("")
    parts = list(rel.parts)
    return parts if path.name == "__init__.py" else parts[:-1]


def _imported(tree: ast.AST, package: list[str]) -> list[tuple[int, str]]:
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.append((node.lineno, mod))
            # ``from .. import io`` names the forbidden module in the alias
            out += [(node.lineno, f"{mod}.{a.name}") for a in node.names if a.name != "*"]
    return out


def violations(source: str, path: Path) -> list[str]:
    """What in one core module breaks the rules: ``'file:line: what'`` strings."""
    tree = ast.parse(source, filename=str(path))
    name = path.relative_to(PKG.parent)
    bad = []
    for line, mod in _imported(tree, _module_package(path)):
        parts = mod.split(".")
        top = parts[0]
        if top == "pf_slam_nodes" and len(parts) > 1 and parts[1] in FORBIDDEN_PACKAGE_PARTS:
            bad.append(f"{name}:{line}: imports {mod} (core must not depend on {parts[1]})")
        elif top in FORBIDDEN_TOP or top.endswith("_msgs") or top.endswith("_interfaces"):
            bad.append(f"{name}:{line}: imports ROS module {mod}")
        elif top in FORBIDDEN_STDLIB:
            bad.append(f"{name}:{line}: imports {mod} (file system / process access)")
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            called = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
            if called in FILE_CALLS:
                bad.append(f"{name}:{node.lineno}: calls {called}() (file I/O belongs in io/)")
    return bad


def core_modules() -> list[Path]:
    return sorted(CORE.rglob("*.py"))


def test_core_has_modules():
    names = {p.relative_to(CORE).as_posix() for p in core_modules()}
    assert {"geometry.py", "metrics.py", "texture/__init__.py", "texture/texturer.py"} <= names


@pytest.mark.parametrize("path", core_modules(), ids=lambda p: p.relative_to(CORE).as_posix())
def test_core_module_is_pure(path: Path):
    assert violations(path.read_text(encoding="utf-8"), path) == []


@pytest.mark.parametrize("path", core_modules(), ids=lambda p: p.relative_to(CORE).as_posix())
def test_core_module_size(path: Path):
    n = len(path.read_text(encoding="utf-8").splitlines())
    assert n <= MAX_LINES, f"{path.relative_to(PKG)} has {n} lines (split it by stage)"


@pytest.mark.parametrize(
    "snippet, what",
    [
        ("from ..io.calib import read_camera_yaml\n", "imports pf_slam_nodes.io.calib"),
        ("from .. import io\n", "imports pf_slam_nodes.io"),
        ("import pf_slam_nodes.nodes.mapper\n", "imports pf_slam_nodes.nodes.mapper"),
        ("from ..ros import cdr\n", "imports pf_slam_nodes.ros"),
        ("import rclpy\n", "ROS module rclpy"),
        ("from sensor_msgs.msg import Image\n", "ROS module sensor_msgs.msg"),
        ("from pf_slam_interfaces.msg import FogBatch\n", "ROS module pf_slam_interfaces.msg"),
        ("from pathlib import Path\n", "imports pathlib"),
        ("import os\n", "imports os"),
        ("def f(p):\n    return open(p).read()\n", "calls open()"),
        ("def f(p):\n    return p.read_text()\n", "calls read_text()"),
        ("import cv2\ndef f(p, a):\n    cv2.imwrite(p, a)\n", "calls imwrite()"),
        ("import numpy as np\ndef f(p):\n    return np.load(p)\n", "calls load()"),
        ("import numpy as np\ndef f(p, a):\n    np.savetxt(p, a)\n", "calls savetxt()"),
    ],
)
def test_checker_catches(snippet: str, what: str):
    for where in (CORE / "bad.py", CORE / "texture" / "bad.py"):
        if snippet.startswith("from .."):  # one level deeper in core/texture/
            src = snippet.replace("from ..", "from ...") if where.parent.name == "texture" else snippet
        else:
            src = snippet
        found = violations(src, where)
        assert len(found) >= 1 and any(what in v for v in found), (src, found)


def test_checker_passes_pure_code():
    src = (
        "import json\nimport math\nimport cv2\nimport numpy as np\nfrom .geometry import compose\n"
        "def f(a):\n    return cv2.remap(a, a, a, 1), np.asarray(a), json.dumps({}), math.pi\n"
    )
    assert violations(src, CORE / "ok.py") == []


def _definitions(pattern: str) -> list[str]:
    """``file:function`` of every module-level function in the package whose name matches
    ``pattern`` (methods, such as a class's ``rpy`` property, are not helpers)."""
    out = []
    for path in sorted(PKG.rglob("*.py")):
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and re.search(pattern, node.name):
                out.append(f"{path.relative_to(PKG).as_posix()}:{node.name}")
    return out


def test_quaternion_and_se2_helpers_defined_once():
    """Quaternion / rotation / SE(2) helpers are defined in core/geometry.py only, each once."""
    defs = _definitions(r"quat|rpy|nearest_rotation|^wrap_angle$|^_wrap$|^compose$|^relative_pose$")
    assert defs and all(d.startswith("core/geometry.py:") for d in defs), defs
    assert len(defs) == len(set(defs))


def test_one_quaternion_to_matrix_formula():
    """The quaternion -> rotation matrix formula is written once in the package."""
    term = re.compile(r"1(\.0)?\s*-\s*2(\.0)?\s*\*\s*\(\s*y\s*\*\s*y\s*\+\s*z\s*\*\s*z\s*\)")
    hits = [
        p.relative_to(PKG).as_posix()
        for p in sorted(PKG.rglob("*.py"))
        for _ in term.finditer(p.read_text(encoding="utf-8"))
    ]
    assert hits == ["core/geometry.py"], hits


def test_the_runtime_package_does_not_import_the_development_tools():
    """Simulators and benches live in pf_slam_tools; the runtime imports them only in the CLI's
    development subcommands (simulate*, texture, bench), lazily, inside functions."""
    offenders = []
    for path in sorted(PKG.rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            if any(n.split(".")[0] == "pf_slam_tools" for n in names) and path.name != "cli.py":
                offenders.append(f"{path.relative_to(PKG)}:{node.lineno}")
    assert not offenders, offenders
    assert not (PKG / "sim").exists() and not (PKG / "bench").exists()
