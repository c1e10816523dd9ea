"""How the full graph scales (`pf-slam bench scaling`): particles and grid size.

Each point is one `pf-slam run --rate max --processes single` in its own process (so its peak
RSS is its own), on a CARMEN log converted once: wall time, real-time factor, peak memory, the
per-stage split of a scan from `summary.json` and the Kümmerle relations error (so a speed-up
that breaks the filter shows). Prints a markdown table, writes it with the raw rows into the
output folder and draws two PNG plots (log-log wall time and peak memory).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from pf_slam_nodes.io.evaluation import evaluate

from . import STAGE_COLUMNS, stage_cells
from .carmen import CARMEN_YAML, DATASETS, carmen_bag

PARTICLES = (10, 30, 100, 300, 1000)
GRID_CELLS = (500, 1000, 2000, 4000)


def _params_with_grid(run_dir: Path, cells: int) -> Path:
    """carmen_indoor.yaml with a ``cells`` x ``cells`` grid (same resolution)."""
    p = yaml.safe_load(CARMEN_YAML.read_text())
    g = p["/**"]["ros__parameters"]["grid"]
    g["size_x_m"] = g["size_y_m"] = cells * g["resolution_m"]
    path = run_dir / "params.yaml"
    path.write_text(yaml.safe_dump(p, sort_keys=False))
    return path


def run_point(bag: Path, run_dir: Path, particles: int, params: Path, seed: int = 0) -> dict:
    """One `pf-slam run` in a child process; returns its summary.json."""
    run_dir.mkdir(parents=True, exist_ok=True)
    cmd = [
        sys.executable,
        "-c",
        "import sys; from pf_slam_nodes.cli import main; sys.exit(main())",
        "run",
        str(bag),
        "--out",
        str(run_dir),
        "--params",
        str(params),
        "--rate",
        "max",
        "--particles",
        str(particles),
        "--seed",
        str(seed),
        "--no-texture",
        "--snapshot-every",
        "0",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return json.loads((run_dir / "summary.json").read_text())


def bench(
    data_dir: Path,
    out_dir: Path,
    particles=PARTICLES,
    grid_cells=GRID_CELLS,
    particles_log: str = "intel_2726",
    grid_log: str = "intel_910",
    seed: int = 0,
) -> list[dict]:
    """Particle sweep on ``particles_log`` (default grid), grid sweep on ``grid_log`` (30 particles)."""
    rows = []
    sweeps = [("particles", particles_log, n, None) for n in particles]
    sweeps += [("grid", grid_log, 30, c) for c in grid_cells]
    for sweep, name, n, cells in sweeps:
        bag = carmen_bag(data_dir, out_dir, name)
        run_dir = out_dir / "scaling" / (f"{name}_n{n}" if cells is None else f"{name}_grid{cells}")
        run_dir.mkdir(parents=True, exist_ok=True)
        params = CARMEN_YAML if cells is None else _params_with_grid(run_dir, cells)
        s = run_point(bag, run_dir, n, params, seed)
        rel = DATASETS[name][1]
        ev = evaluate(run_dir / "trajectory.tum", None, relations_path=data_dir / "carmen" / rel, max_dt=1e-3)
        g = yaml.safe_load(Path(params).read_text())["/**"]["ros__parameters"]["grid"]
        rows.append(
            {
                "sweep": sweep,
                "dataset": name,
                "particles": n,
                "grid_cells": cells or round(g["size_x_m"] / g["resolution_m"]),
                "wall_s": s["wall_time_s"],
                "rtf": s["real_time_factor"],
                "peak_rss_mb": s["peak_rss_mb"],
                "scans": s["scans_processed"],
                "dropped": s["scans_dropped"],
                "stage_ms_per_scan": s.get("stage_ms_per_scan", {}),
                "rel_trans_mean": ev["relations"]["trans_mean"],
            }
        )
    return rows


def format_table(rows: list[dict]) -> str:
    head = (
        "| sweep | log | particles | grid | wall s | RTF | peak RSS MB | relations (m) | "
        + " | ".join(f"{k} ms" for k in STAGE_COLUMNS)
        + " |"
    )
    lines = [head, "|" + "---|" * 8 + "---:|" * len(STAGE_COLUMNS)]
    for r in rows:
        lines.append(
            f"| {r['sweep']} | {r['dataset']} | {r['particles']} | {r['grid_cells']}² | "
            f"{r['wall_s']:.1f} | {r['rtf']:.1f}× | {r['peak_rss_mb']:.0f} | "
            f"{r['rel_trans_mean']:.3f} | {stage_cells(r)} |"
        )
    return "\n".join(lines)


def plot_loglog(path: Path, title: str, xlabel: str, ylabel: str, series: dict[str, tuple]) -> None:
    """A log-log line plot with OpenCV (the project's only drawing dependency): ``series`` maps a
    label to ``(x, y)``; decade grid lines, labelled ticks, a legend."""
    import cv2

    w, h, left, right, top, bottom = 720, 480, 80, 40, 40, 60
    xs = np.concatenate([np.asarray(v[0], float) for v in series.values()])
    ys = np.concatenate([np.asarray(v[1], float) for v in series.values()])
    lx = (math.floor(math.log10(xs.min())), math.ceil(math.log10(xs.max())))
    ly = (math.floor(math.log10(ys.min())), math.ceil(math.log10(ys.max())))
    if ly[0] == ly[1]:
        ly = (ly[0], ly[0] + 1)

    def px(x, y):
        u = left + (math.log10(x) - lx[0]) / (lx[1] - lx[0]) * (w - left - right)
        v = h - bottom - (math.log10(y) - ly[0]) / (ly[1] - ly[0]) * (h - top - bottom)
        return int(round(u)), int(round(v))

    img = np.full((h, w, 3), 255, np.uint8)
    font, grey, black = cv2.FONT_HERSHEY_SIMPLEX, (210, 210, 210), (0, 0, 0)
    for e in range(lx[0], lx[1] + 1):
        u, _ = px(10.0**e, 10.0 ** ly[0])
        cv2.line(img, (u, top), (u, h - bottom), grey, 1)
        cv2.putText(img, f"{10.0**e:g}", (u - 15, h - bottom + 20), font, 0.45, black, 1, cv2.LINE_AA)
    for e in range(ly[0], ly[1] + 1):
        _, v = px(10.0 ** lx[0], 10.0**e)
        cv2.line(img, (left, v), (w - right, v), grey, 1)
        cv2.putText(img, f"{10.0**e:g}", (8, v + 5), font, 0.45, black, 1, cv2.LINE_AA)
    cv2.rectangle(img, (left, top), (w - right, h - bottom), black, 1)
    cv2.putText(img, title, (left, 25), font, 0.6, black, 1, cv2.LINE_AA)
    cv2.putText(img, xlabel, (w // 2 - 60, h - 15), font, 0.5, black, 1, cv2.LINE_AA)
    cv2.putText(img, ylabel, (left + 8, top + 18), font, 0.45, black, 1, cv2.LINE_AA)
    colours = [(180, 90, 30), (40, 40, 200), (40, 150, 40), (150, 40, 150)]
    for i, (x, y) in enumerate(series.values()):
        pts = [px(a, b) for a, b in zip(x, y)]
        for p0, p1 in zip(pts, pts[1:]):
            cv2.line(img, p0, p1, colours[i % len(colours)], 2, cv2.LINE_AA)
        for p in pts:
            cv2.circle(img, p, 4, colours[i % len(colours)], -1, cv2.LINE_AA)
    x0, y0 = w - right - 190, h - bottom - 14 - 20 * len(series)  # legend, bottom right
    cv2.rectangle(img, (x0, y0), (w - right - 4, h - bottom - 4), (255, 255, 255), -1)
    cv2.rectangle(img, (x0, y0), (w - right - 4, h - bottom - 4), grey, 1)
    for i, label in enumerate(series):
        cv2.putText(img, label, (x0 + 10, y0 + 22 + 20 * i), font, 0.45, colours[i % len(colours)], 1, cv2.LINE_AA)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


def plots(rows: list[dict], plot_dir: Path) -> list[Path]:
    out = []
    for sweep, key, xlabel in (("particles", "particles", "particles"), ("grid", "grid_cells", "grid cells per side")):
        rs = [r for r in rows if r["sweep"] == sweep]
        if len(rs) < 2:
            continue
        x = [r[key] for r in rs]
        name = rs[0]["dataset"]
        path = plot_dir / f"scaling_{sweep}.png"
        plot_loglog(
            path,
            f"{name}: full graph, one process, --rate max",
            xlabel,
            "s or MB",
            {
                "wall time (s)": (x, [r["wall_s"] for r in rs]),
                "peak RSS (MB)": (x, [r["peak_rss_mb"] for r in rs]),
                "data duration (s)": (x, [r["wall_s"] * r["rtf"] for r in rs]),
            },
        )
        out.append(path)
    return out


def main(
    data_dir: str, out_dir: str, particles=None, grid_cells=None, plot_dir: str = "docs/img", seed: int = 0
) -> str:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = bench(
        Path(data_dir),
        out,
        tuple(PARTICLES if particles is None else particles),
        tuple(GRID_CELLS if grid_cells is None else grid_cells),
        seed=seed,
    )
    table = format_table(rows)
    (out / "scaling.md").write_text(table + "\n")
    (out / "scaling.json").write_text(json.dumps(rows, indent=2) + "\n")
    pngs = plots(rows, Path(plot_dir))
    return table + "".join(f"\nplot: {p}" for p in pngs)
