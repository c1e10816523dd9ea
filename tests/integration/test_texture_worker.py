"""The texture node's worker process (worker: process, the default) gives the same texture and
trajectory bit for bit as its worker thread (worker: thread) on the car sample bag."""

from pathlib import Path

import cv2
import numpy as np

from pf_slam_nodes.graph import run

ROOT = Path(__file__).resolve().parents[2]
CAR = ROOT / "bags" / "car_sample"
KAIST = ROOT / "ros2_ws/src/pf_slam_nodes/config/kaist.yaml"


def test_process_and_thread_workers_give_the_same_texture(tmp_path, ros_domain):
    out = {}
    for mode in ("thread", "process"):
        res = run(
            str(CAR),
            tmp_path / mode,
            params_file=str(KAIST),
            progress=False,
            domain_id=ros_domain,
            snapshot_every=0,
            record=False,
            overrides={"texture": {"worker": mode}},
        )
        t = res.summary["texture"]
        assert t["worker"] == mode and "worker_error" not in t, t
        assert (t["frames_received"], t["frames_processed"], t["frames_skipped"], t["frames_dropped"]) == (
            2,
            2,
            0,
            0,
        ), t
        out[mode] = (
            cv2.imread(str(tmp_path / mode / "texture.png")),
            (tmp_path / mode / "trajectory.tum").read_text(),
        )
    (a, ta), (b, tb) = out["thread"], out["process"]
    assert a is not None and (a.sum(axis=2) > 0).sum() > 5000
    np.testing.assert_array_equal(a, b)
    assert ta == tb
