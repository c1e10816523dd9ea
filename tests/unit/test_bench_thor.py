"""`pf-slam bench thor`'s evaluation parts on small files: the texture colour error's geometry
(texture in /map's grid vs the simulator's floor colour in its own grid), the table, the targets."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pf_slam_nodes.io.mapfile import write_map
from pf_slam_nodes.io.texture_files import write_texture_pngs
from pf_slam_tools.bench import thor


def _floor(d, colour, res=0.05, origin=(-1.0, -2.0), shape=(80, 60)):
    """floor_colour.png + .yaml (north up) of a left half ``colour[0]`` and right half ``colour[1]``."""
    rgb = np.zeros(shape + (3,), np.uint8)
    rgb[:, : shape[1] // 2] = colour[0]
    rgb[:, shape[1] // 2 :] = colour[1]
    cv2.imwrite(str(d / "floor_colour.png"), np.ascontiguousarray(rgb[::-1, :, ::-1]))
    (d / "floor_colour.yaml").write_text(
        f"image: floor_colour.png\nresolution: {res}\norigin: [{origin[0]}, {origin[1]}, 0]\n"
    )
    return origin[0] + shape[1] // 2 * res  # x of the colour change


def test_texture_error_in_the_maps_geometry(tmp_path):
    sim, run = tmp_path / "sim", tmp_path / "run"
    sim.mkdir()
    x_change = _floor(sim, [(200, 40, 40), (40, 40, 200)])
    # the run's map: another origin and resolution (0.1 m), the texture coloured right
    res, origin, (h, w) = 0.1, np.array([-0.55, -1.45]), (30, 25)
    write_map(run, np.zeros((h, w), np.int8), res, origin)
    cols = np.arange(w)
    x = origin[0] + (cols + 0.5) * res
    tex = np.zeros((h, w, 3), np.uint8)
    tex[:, x < x_change] = (200, 40, 40)
    tex[:, x >= x_change] = (40, 40, 200)
    tex[:5] = 0  # not coloured
    write_texture_pngs(run, tex, tex.any(axis=2))
    err = thor.texture_error(run, sim)
    assert err["texture_cells"] == (h - 5) * w
    assert err["texture_error"] == 0.0
    # the same texture shifted by 0.3 m: the stripe near the change is wrong
    tex2 = np.roll(tex, 3, axis=1)
    tex2[5:, :3] = (200, 40, 40)
    write_texture_pngs(run, tex2, tex2.any(axis=2))
    err2 = thor.texture_error(run, sim)
    assert err2["texture_error"] == pytest.approx(3 * 320 / 3 / w)  # 3 of 25 columns off by (160, 0, 160)
    # aligned as the ATE would align a trajectory 0.3 m east of the truth: nothing is off
    err3 = thor.texture_error(run, sim, (0.0, np.array([-0.3, 0.0])))
    assert err3["texture_error"] == err2["texture_error"] and err3["texture_error_aligned"] == pytest.approx(0.0)
    # and a rotation about the map origin moves the stripes: the aligned error is no longer 0
    err4 = thor.texture_error(run, sim, (np.radians(20.0), np.array([-0.3, 0.0])))
    assert err4["texture_error_aligned"] > 1.0


def test_table_and_targets():
    row = {
        "seed": 0,
        "filter_seed": 1,
        "duration_s": 60.0,
        "particles": 100,
        "scans": 2400,
        "corrected": 120,
        "mostly_floor": 3,
        "ate_m": 0.05,
        "odom_ate_m": 0.4,
        "map_f1": 0.9,
        "map_precision": 0.95,
        "map_recall": 0.85,
        "texture_error": 9.5,
        "texture_error_aligned": 7.25,
        "texture_cells": 4000,
        "rgbd_pairs": 30,
        "rgbd_received": 30,
        "plane_fits": 29,
        "wall_s": 5.0,
        "rtf": 12.0,
    }
    bad = dict(row, seed=1, ate_m=0.2, texture_error=20.0, texture_error_aligned=16.0, rtf=4.0)
    table = thor.format_table([row, bad])
    assert "| 0 | 1 | 60 | 100 | 2400 (120, 3) | 0.050 | 0.400 | 0.900 (0.95 / 0.85) | 9.5 | 7.2 |" in table
    line = thor.targets_line([row, bad])
    assert "2 runs (2 worlds x 1 filter seeds)" in line
    assert "<= 0.1 m in 1 of 2" in line and "<= 15 in 1 of 2" in line and ">= 10x in 1 of 2" in line
    assert "aligned as the ATE: mean 11.6, worst 16.0, <= 15 in 1 of 2" in line
