"""map_server map files and snapshot rendering."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pf_slam_nodes.io.mapfile import read_map, render_snapshot, write_map


def _grid():
    occ = np.full((40, 60), -1, dtype=np.int8)
    occ[5:35, 5:55] = 0
    occ[5, 5:55] = 100  # bottom wall (lowest y)
    occ[10:20, 30] = 80
    occ[25, 10:15] = 40  # in between thresholds -> unknown
    return occ


def test_round_trip(tmp_path):
    occ = _grid()
    yml = write_map(tmp_path / "out", occ, 0.05, (-1.5, 2.25))
    assert yml.name == "map.yaml" and (tmp_path / "out" / "map.pgm").is_file()
    text = yml.read_text()
    for line in (
        "image: map.pgm",
        "mode: trinary",
        "resolution: 0.05",
        "negate: 0",
        "occupied_thresh: 0.65",
        "free_thresh: 0.196",
        "origin: [-1.500000, 2.250000, 0]",
    ):
        assert line in text
    raw = (tmp_path / "out" / "map.pgm").read_bytes()
    assert raw.startswith(b"P5\n")
    img = cv2.imread(str(tmp_path / "out" / "map.pgm"), cv2.IMREAD_UNCHANGED)
    assert img.shape == (40, 60) and set(np.unique(img)) == {0, 205, 254}
    assert np.all(img[-1 - 5, 5:55] == 0)  # lowest-y row is at the bottom of the image
    occ2, res, origin = read_map(yml)
    assert res == 0.05
    np.testing.assert_allclose(origin, [-1.5, 2.25, 0.0])
    expect = np.where(occ >= 65, 100, np.where((occ >= 0) & (occ <= 25), 0, -1))
    np.testing.assert_array_equal(occ2, expect)
    assert occ2.dtype == np.int8


def test_bad_input(tmp_path):
    with pytest.raises(ValueError):
        write_map(tmp_path, np.zeros((0, 3), np.int8), 0.05, (0, 0))
    with pytest.raises(ValueError):
        write_map(tmp_path, np.zeros((3, 3), np.int8), 0.0, (0, 0))
    (tmp_path / "bad.yaml").write_text("image: nothing.pgm\n")
    with pytest.raises(ValueError, match="bad.yaml"):
        read_map(tmp_path / "bad.yaml")


def test_snapshot(tmp_path):
    occ = _grid()
    traj = np.array([[-1.0, 2.8], [0.0, 3.0], [0.5, 3.5]])
    out = tmp_path / "snap" / "s.png"
    render_snapshot(occ, 0.05, (-1.5, 2.25), traj, out, pose=(0.5, 3.5, 0.3), scale=2, title="scan 10")
    img = cv2.imread(str(out))
    assert img.shape == (80, 120, 3)
    red = (img[:, :, 2] > 200) & (img[:, :, 0] < 80) & (img[:, :, 1] < 80)
    blue = (img[:, :, 0] > 200) & (img[:, :, 2] < 80)
    assert red.sum() > 20 and blue.sum() > 10
    # a trajectory point at world (0, 3) lands at pixel ((0+1.5)/0.05*2, (40-(0.75/0.05))*2)
    u, v = 60, 50
    assert red[v - 2 : v + 3, u - 2 : u + 3].any()


def test_trinary_is_map_server_thresholds():
    from pf_slam_nodes.io.mapfile import trinary

    occ = np.array([[-1, 0, 25, 26, 64, 65, 100]], dtype=np.int8)
    assert trinary(occ).tolist() == [[-1, 0, 0, -1, -1, 100, 100]]
    assert trinary(occ, occupied_thresh=0.5, free_thresh=0.3).tolist() == [[-1, 0, 0, 0, 100, 100, 100]]
    with pytest.raises(ValueError, match="free_thresh"):
        trinary(occ, occupied_thresh=0.2, free_thresh=0.3)
