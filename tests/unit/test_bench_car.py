"""The car bench's table and its ground-truth FOG bias (no graph run)."""
import numpy as np

from pf_slam_nodes.bench import car


def test_true_fog_bias_per_second_and_table(tmp_path):
    (tmp_path / "ground_truth").mkdir()
    (tmp_path / "ground_truth" / "sim_info.yaml").write_text("fog_yaw_bias_rad_per_sample: 2.0e-07\n")
    t = 1_700_000_000_000_000_000 + np.arange(100, dtype=np.int64) * 1_000_000  # 1 kHz
    assert abs(car._true_fog_bias_rad_s(tmp_path, t) - 2.0e-4) < 1e-12
    assert car._true_fog_bias_rad_s(tmp_path / "nowhere", t) is None
    row = dict(seed=3, duration_s=300.0, particles=100, processes="single", ate_m=0.25, dr_ate_m=2.5,
               dr_rest_bias_ate_m=0.3, gyro_bias_rad_s=1.9e-4, true_gyro_bias_rad_s=2.0e-4, map_f1=0.5,
               map_precision=0.7, map_recall=0.4, wall_s=30.0, rtf=10.0, ceiling_rtf=60.0,
               ratio_to_ceiling=0.167, dropped=0)
    line = car.format_table([row]).splitlines()[2]
    assert "| 0.250 | 2.500 | 10.0× | 0.300 | 190 / 200 |" in line
