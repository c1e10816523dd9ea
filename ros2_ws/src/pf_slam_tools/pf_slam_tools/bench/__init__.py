"""Benchmarks behind `pf-slam bench` (see the README's Results section)."""

from __future__ import annotations

import math

from pf_slam_nodes.core.stages import STAGE_STEPS

#: the per-scan split of summary.json's ``stage_ms_per_scan`` (single process)
STAGE_COLUMNS = STAGE_STEPS + ("messaging",)


def stage_cells(row: dict) -> str:
    """``| a | b | ...`` cells of a row's per-stage ms per scan (nan where not measured)."""
    st = row.get("stage_ms_per_scan") or {}
    return " | ".join(f"{st.get(k, math.nan):.2f}" for k in STAGE_COLUMNS)


def stage_table(rows: list[dict], labels: tuple[str, ...]) -> str:
    """Markdown table: the ``labels`` columns of each row, then its ms per scan in each stage."""
    lines = [
        "| " + " | ".join(labels) + " | " + " | ".join(f"{k} ms" for k in STAGE_COLUMNS) + " |",
        "|" + "---|" * len(labels) + "---:|" * len(STAGE_COLUMNS),
    ]
    for r in rows:
        lines.append("| " + " | ".join(str(r[k]) for k in labels) + " | " + stage_cells(r) + " |")
    return "\n".join(lines)
