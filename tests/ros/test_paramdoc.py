"""docs/parameters.md lists every parameter the nodes declare, with the code's defaults."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("rclpy")
from pf_slam_nodes import paramdoc  # noqa: E402

DOC = Path(__file__).resolve().parents[2] / "docs" / "parameters.md"


def test_parameters_md_matches_the_declared_parameters(ros_domain):
    declared = paramdoc.declared_parameters(domain_id=ros_domain)
    assert {
        "map_frame",
        "filter.num_particles",
        "grid.resolution_m",
        "correlation.search_x_m",
        "motion.sigma_xy_per_m",
        "wheels.base_m",
        "texture.cell_m",
        "bag",
    } <= set(declared)
    block = paramdoc.generated_block(DOC.read_text())
    missing = [n for n in declared if f"| `{n}` |" not in block]
    assert not missing, f"docs/parameters.md lacks {missing}: run pf-slam params --write docs/parameters.md"
    assert block == paramdoc.markdown_table(declared), (
        "docs/parameters.md is stale (defaults / descriptions): run pf-slam params --write docs/parameters.md"
    )


def test_every_parameter_has_a_description_and_unit_rules():
    assert paramdoc.unit_of("grid.resolution_m", "Cell edge length (m).") == "m"
    assert paramdoc.unit_of("motion.sigma_xy_per_m", "per metre (m/m).") == "m/m"
    assert paramdoc.unit_of("queue_depth", "pairs; the oldest (skipped)") == "–"
    with pytest.raises(ValueError, match="no description"):
        paramdoc.markdown_table({"x": {"nodes": ["mapper"], "default": 1, "description": ""}})


def test_the_static_table_of_declared_parameters_matches_the_nodes(ros_domain):
    """`pf-slam run` checks parameter files against nodes.declared without building nodes: the
    table must name every parameter each node really declares, with the same default."""
    from pf_slam_nodes.nodes.declared import declared, declared_by

    real = paramdoc.declared_parameters(domain_id=ros_domain)
    assert {n: sorted(r["nodes"]) for n, r in real.items()} == {n: sorted(v) for n, v in declared_by().items()}
    for name, row in real.items():
        if row["default"] is not paramdoc._UNSET:
            value = row["default"]
            value = list(value) if type(value).__name__ == "array" or isinstance(value, tuple) else value
            assert value == declared(row["nodes"][0])[name], name
