"""The car bench's table, targets line, cached bags and ground-truth FOG bias (no graph run)."""

import numpy as np

from pf_slam_nodes.io.bag import bag_info
from pf_slam_nodes.io.kaist import convert_kaist
from pf_slam_tools.bench import car
from pf_slam_tools.sim.car import simulate_car


def test_true_fog_bias_per_second_and_table(tmp_path):
    (tmp_path / "ground_truth").mkdir()
    (tmp_path / "ground_truth" / "sim_info.yaml").write_text(
        "fog_yaw_bias_rad_per_sample: 2.0e-07\nwheel_diameter_true_m: [0.6286, 0.6280]\n"
    )
    cal = {"left_wheel_diameter_m": 0.6234, "right_wheel_diameter_m": 0.6228}
    assert abs(car._true_wheel_scale(tmp_path, cal) - 0.6283 / 0.6231) < 1e-12
    assert car._true_wheel_scale(tmp_path / "nowhere", cal) is None
    t = 1_700_000_000_000_000_000 + np.arange(100, dtype=np.int64) * 1_000_000  # 1 kHz
    assert abs(car._true_fog_bias_rad_s(tmp_path, t) - 2.0e-4) < 1e-12
    assert car._true_fog_bias_rad_s(tmp_path / "nowhere", t) is None
    row = dict(
        seed=3,
        filter_seed=1,
        duration_s=300.0,
        particles=100,
        processes="single",
        ate_m=0.25,
        dr_ate_m=2.5,
        dr_rest_bias_ate_m=0.3,
        gyro_bias_rad_s=1.9e-4,
        true_gyro_bias_rad_s=2.0e-4,
        wheel_scale=1.0081,
        true_wheel_scale=1.0084,
        map_f1=0.5,
        map_precision=0.7,
        map_recall=0.4,
        wall_s=30.0,
        rtf=10.0,
        ceiling_rtf=60.0,
        ratio_to_ceiling=0.167,
        dropped=0,
    )
    line = car.format_table([row]).splitlines()[2]
    assert line.startswith("| 3 | – | 1 | 300 |")
    assert "| 0.250 | 2.500 | 10.0× | 0.300 | 190 / 200 | +0.81 / +0.84 | 0.500 (0.70 / 0.40) |" in line
    assert "| – / – |" in car.format_table([dict(row, wheel_scale=None, true_wheel_scale=None)]).splitlines()[2]
    worse = dict(row, ate_m=0.9, rtf=8.0, dropped=2)
    assert car.targets_line([row, worse]) == (
        "2 runs: ATE mean 0.575 m, median 0.575 m, worst 0.900 m; ATE <= 0.35 m and >= 3x below raw dead "
        "reckoning in 1 of 2; >= 10x real time in 1 of 2 (RTF 8.0-10.0x); dropped 2"
    )
    tex = dict(
        row,
        world=2,
        images=True,
        pairs=300,
        pairs_textured=300,
        pairs_skipped=0,
        colour_error=10.5,
        colour_error_aligned=8.0,
        coverage=0.8,
        texture_ms_per_pair=120.0,
        texture_ms_stages={"disparity": 40.0, "ground": 30.0},
        texture_replaced={"pairs_moved": 300, "shift_median_m": 0.214, "shift_max_m": 0.5},
    )
    assert car.targets_line([tex, dict(tex, colour_error=13.0)]).endswith(
        "; stereo pairs textured 600 of 600 (0 skipped); texture colour error median 11.8, worst 13.0 "
        "(<= 12 in 1 of 2); aligned as the ATE: median 8.0, worst 8.0 (<= 12 in 2 of 2), coverage median 0.80"
    )
    t = car.format_texture_table([tex]).splitlines()
    assert t[0].endswith("| ms / pair | disparity ms | ground ms |")
    assert t[2] == "| 3 | 2 | 1 | 300 | 300 | 0 | 10.5 | 8.0 | 0.80 | 0.21 | 120 | 40 | 30 |"
    assert car.format_texture_table([dict(tex, texture_replaced=None)]).splitlines()[2].count("| – |") == 1


def _images(bag):
    return car.images_in(bag_info(bag)["topics"])


def test_cached_bag_with_images_is_converted_again(tmp_path):
    """A cached bag that carries stereo images would also run the texture node (and slow the
    bench): the bench converts the drive again without them, and reuses a clean one."""
    data = tmp_path / "drive"
    simulate_car(data, seed=1, duration_s=2.0, stereo_rate_hz=1.0)
    bag = tmp_path / "bag"
    convert_kaist(data, bag)
    assert _images(bag) > 0
    assert car._bench_bag(data, bag) == bag
    assert _images(bag) == 0 and bag_info(bag)["topics"]["/scan"][1] > 0
    stamp = (bag / "metadata.yaml").stat().st_mtime_ns
    car._bench_bag(data, bag)
    assert (bag / "metadata.yaml").stat().st_mtime_ns == stamp  # clean: reused as it is


def test_texture_score_of_a_perfect_and_a_shifted_texture(tmp_path):
    """texture_score reads texture.png (north up, /map geometry) against the floor truth: the truth
    itself, averaged into the run's 0.2 m cells, scores ~0 and covers what the camera saw; the same
    texture 1 m off scores far worse, unless scored with the alignment that moves it back."""
    import cv2

    from pf_slam_nodes.core.texture import north_up_bgr
    from pf_slam_nodes.io.mapfile import read_map, write_map
    from pf_slam_nodes.io.texture_files import read_floor_texture

    data = tmp_path / "drive"
    simulate_car(data, seed=2, duration_s=2.0, stereo_rate_hz=1.0)
    gt, gres, gorig = read_floor_texture(data / "ground_truth" / "floor_texture.png")
    occ, res, origin = read_map(data / "ground_truth" / "occupancy.yaml")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    write_map(run_dir, occ, res, origin)
    k = int(round(res / gres))

    def cells(shift_cells: int) -> np.ndarray:  # truth texels averaged into the run's cells
        h, w = occ.shape
        out = np.zeros((h, w, 3), np.uint8)
        oi, oj = int(round((origin[0] - gorig[0]) / gres)), int(round((origin[1] - gorig[1]) / gres))
        blk = gt[oj : oj + h * k, oi + shift_cells : oi + shift_cells + w * k].astype(np.float64)
        hh, ww = blk.shape[0] // k, blk.shape[1] // k
        out[:hh, :ww] = np.rint(blk[: hh * k, : ww * k].reshape(hh, k, ww, k, 3).mean(axis=(1, 3)))
        return np.maximum(out, 1)

    cv2.imwrite(str(run_dir / "texture.png"), north_up_bgr(cells(0)))
    good = car.texture_score(run_dir, data)
    assert good["colour_error"] < 1.0 and good["coverage"] > 0.99, good
    cv2.imwrite(str(run_dir / "texture.png"), north_up_bgr(cells(10)))
    shifted = car.texture_score(run_dir, data, (0.0, np.array([10 * gres, 0.0])))
    assert shifted["colour_error"] > 5.0 + good["colour_error"]
    assert shifted["colour_error_aligned"] < 1.0, shifted
