"""--rate max paces the stereo pairs on the texture node: every pair is textured, none skipped,
and two runs texture the same pairs into the same texture."""

from pathlib import Path

import cv2
import numpy as np

from pf_slam_nodes.graph import run

ROOT = Path(__file__).resolve().parents[2]
CAR = ROOT / "bags" / "car_sample"
KAIST = ROOT / "ros2_ws/src/pf_slam_nodes/config/kaist.yaml"


def test_rate_max_textures_every_pair_deterministically(tmp_path, ros_domain):
    outs = []
    for k in range(2):
        # worker_nice 19: the texture worker gets the least CPU; without pacing, the pair would
        # be replaced by the next one while queued (frames_skipped) on a loaded machine
        res = run(
            str(CAR),
            tmp_path / f"r{k}",
            params_file=str(KAIST),
            progress=False,
            domain_id=ros_domain,
            snapshot_every=0,
            record=False,
            overrides={"texture": {"worker_nice": 19}},
        )
        t = res.summary["texture"]
        assert (t["frames_received"], t["frames_processed"], t["frames_skipped"], t["frames_dropped"]) == (
            2,
            2,
            0,
            0,
        ), t
        assert res.summary["scans_dropped"] == 0
        outs.append(cv2.imread(str(tmp_path / f"r{k}" / "texture.png")))
    assert outs[0] is not None and (outs[0].sum(axis=2) > 0).sum() > 5000
    np.testing.assert_array_equal(outs[0], outs[1])
