"""The parameter reference (docs/parameters.md) generated from what the nodes declare.

`pf-slam params --write docs/parameters.md` builds every node with its defaults (the predictor
twice: odometry and encoders + gyro, which declare different parameters), reads each declared
parameter's default and description (its ParameterDescriptor: the config dataclasses'
docstrings, `nodes.common.PARAM_DOCS`) and rewrites the table between the markers; a test fails
when the file and the code disagree.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

BEGIN = "<!-- BEGIN pf-slam params (generated: pf-slam params --write docs/parameters.md) -->"
END = "<!-- END pf-slam params -->"
SAMPLE_BAG = Path(__file__).resolve().parents[4] / "bags" / "sample_indoor"
#: (node, parameter overrides) built to collect the declarations
VARIANTS: list[tuple[str, dict[str, Any]]] = [
    ("bag_replay", {}),
    ("predictor", {}),
    ("predictor", {"odometry_source": "encoders", "fog_format": "batch"}),
    ("correlator", {}),
    ("mapper", {}),
    ("texture", {}),
]
_ROS_OWN = ("use_sim_time", "start_type_description_service", "qos_overrides.")
_UNSET = object()  # only seen overridden: a required parameter
_UNITS = {"m", "rad", "s", "px", "deg", "%", "cells", "probability", "m/m", "m/rad", "rad/m", "rad/rad", "s/s", "m/s"}
_SUFFIX_UNITS = (
    ("_mps", "m/s"),
    ("_deg", "deg"),
    ("_px", "px"),
    ("_per_m", "1/m"),
    ("_per_rad", "1/rad"),
    ("_m", "m"),
    ("_rad", "rad"),
    ("_s", "s"),
)


def declared_parameters(bag: str | Path = SAMPLE_BAG, domain_id: int | None = None) -> dict[str, dict[str, Any]]:
    """name -> {nodes, default, description} over every node of the graph (ROS's own excluded).
    The nodes are built on an isolated domain (ros.domain.ros_context) unless `domain_id` or
    ROS_DOMAIN_ID names one."""
    from .graph import _make_node
    from .ros.domain import ros_context

    out: dict[str, dict[str, Any]] = {}
    with ros_context(domain_id) as (ctx, _dom):
        for name, overrides in VARIANTS:
            if name == "bag_replay":
                overrides = dict(overrides, bag=str(bag))
            node = _make_node(name, ctx, overrides)
            try:
                for pname, p in node._parameters.items():
                    if pname.startswith(_ROS_OWN):
                        continue
                    row = out.setdefault(
                        pname,
                        {"nodes": [], "default": _UNSET, "description": node.describe_parameter(pname).description},
                    )
                    if name not in row["nodes"]:
                        row["nodes"].append(name)
                    if pname not in overrides:  # an overridden value is not the default
                        row["default"] = p.value
            finally:
                node.destroy_node()
    return out


def unit_of(name: str, description: str) -> str:
    """The unit: a trailing "(unit)" of the description, else the name's suffix, else '–'."""
    m = re.search(r"\(([^()]{1,14})\)\W*$", description)
    if m and m.group(1).strip() in _UNITS:
        return m.group(1).strip()
    return next((u for s, u in _SUFFIX_UNITS if name.endswith(s)), "–")


def _fmt(v: Any) -> str:
    if v is _UNSET:
        return "(required)"
    if isinstance(v, str):
        return f"`'{v}'`"
    if isinstance(v, (list, tuple)) or type(v).__name__ == "array":
        v = list(v)
        return f"`[{v[0]!r}] * {len(v)}`" if v and all(x == v[0] for x in v) else f"`{v!r}`"
    return f"`{v!r}`"


def markdown_table(params: dict[str, dict[str, Any]]) -> str:
    """One table per section (plain parameters first), rows sorted by name."""
    sections: dict[str, list[str]] = {}
    for name in sorted(params, key=lambda n: ("." in n, n)):
        row = params[name]
        if not row["description"]:
            raise ValueError(
                f"parameter {name!r} ({', '.join(row['nodes'])}) has no description: "
                "add it to nodes.common.PARAM_DOCS or the config class's docstring"
            )
        sec = name.split(".")[0] if "." in name else ""
        desc = row["description"].replace("|", "\\|")
        sections.setdefault(sec, []).append(
            f"| `{name}` | {', '.join(row['nodes'])} | {_fmt(row['default'])} | {unit_of(name, desc)} | {desc} |"
        )
    parts = []
    for sec, rows in sections.items():
        title = "Node parameters" if not sec else f"`{sec}.*`"
        parts.append(
            f"### {title}\n\n| parameter | nodes | default | unit | effect |\n|---|---|---|---|---|\n" + "\n".join(rows)
        )
    return "\n\n".join(parts)


def generated_block(text: str) -> str:
    """The part of docs/parameters.md between the markers."""
    try:
        return text.split(BEGIN, 1)[1].split(END, 1)[0].strip()
    except IndexError:
        raise ValueError(f"markers {BEGIN!r} ... {END!r} not found") from None


def write(path: str | Path, table: str) -> None:
    p = Path(path)
    text = p.read_text()
    generated_block(text)  # markers present
    head, rest = text.split(BEGIN, 1)
    p.write_text(f"{head}{BEGIN}\n\n{table}\n\n{END}{rest.split(END, 1)[1]}")
