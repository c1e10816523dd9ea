"""The scaling bench's pieces that need no graph run: the table, the plot, the stage clocks."""

import time

import cv2
import numpy as np

from pf_slam_nodes.core.stages import STAGE_STEPS, StageClock, stage_seconds
from pf_slam_tools.bench import scaling


class _Stage:
    def __init__(self):
        self.clock = StageClock()


def test_stage_clocks_merge_per_step() -> None:
    a, b = _Stage(), _Stage()
    t0 = time.perf_counter()
    time.sleep(0.01)
    a.clock.add("correlate", t0)
    a.clock.add("correlate", time.perf_counter())
    b.clock.add("map", time.perf_counter())
    seconds, calls = stage_seconds(a, b)
    assert tuple(seconds) == STAGE_STEPS
    assert calls == {"predict": 0, "correlate": 2, "resample": 0, "map": 1, "field": 0, "loops": 0}
    assert 0.009 < seconds["correlate"] < 1.0 and seconds["predict"] == 0.0


def _row(sweep, n, cells, wall):
    return {
        "sweep": sweep,
        "dataset": "intel_910",
        "particles": n,
        "grid_cells": cells,
        "wall_s": wall,
        "rtf": 1800.0 / wall,
        "peak_rss_mb": 300.0 + n,
        "scans": 910,
        "dropped": 0,
        "rel_trans_mean": 0.03,
        "stage_ms_per_scan": {"correlate": 5.0, "messaging": 2.0},
    }


def test_table_and_plots(tmp_path) -> None:
    rows = [_row("particles", n, 2000, 0.5 * n) for n in (10, 100, 1000)]
    rows += [_row("grid", 30, c, 15.0) for c in (500, 4000)]
    table = scaling.format_table(rows).splitlines()
    assert len(table) == 2 + 5
    assert table[2].startswith("| particles | intel_910 | 10 | 2000² | 5.0 | 360.0× | 310 | 0.030 |")
    assert "| 5.00 |" in table[2] and "nan" in table[2]  # a stage the row does not have
    pngs = scaling.plots(rows, tmp_path)
    assert [p.name for p in pngs] == ["scaling_particles.png", "scaling_grid.png"]
    img = cv2.imread(str(pngs[0]))
    assert img.shape == (480, 720, 3)
    # the three series are drawn in their colours
    for bgr in ((180, 90, 30), (40, 40, 200), (40, 150, 40)):
        assert np.count_nonzero(np.all(img == bgr, axis=2)) > 50, bgr
