"""`pf-slam simulate --world N`: other layouts and error levels than the default drives."""

import numpy as np
import pytest
import yaml

from pf_slam_tools.sim import car
from pf_slam_tools.sim.car_variation import LAYOUTS, CarVariation
from pf_slam_tools.sim.car_world import KIND_BUILDING, KIND_CAR, build_world


def test_worlds_cover_every_layout_and_wider_errors():
    vs = [CarVariation.draw(w) for w in range(8)]
    assert {v.layout for v in vs[:4]} == set(LAYOUTS)
    assert all(-0.01 <= v.wheel_scale_err <= 0.01 and 0.001 <= v.encoder_slip <= 0.008 for v in vs)
    assert max(v.lidar_dropout for v in vs) > 0.03 and max(v.lidar_scan_dropout for v in vs) > 0.0
    assert len({v.speed_mps for v in vs}) == 8 and CarVariation.draw(5) == CarVariation.draw(5)


@pytest.mark.parametrize("layout_world", [1, 2, 3])
def test_layouts_differ_from_the_city(layout_world):
    rng = lambda: np.random.default_rng(0)  # noqa: E731
    city, lay_c = build_world(rng())
    other, lay_o = build_world(rng(), CarVariation.draw(layout_world))
    v = CarVariation.draw(layout_world)
    buildings = lambda w: int((w.kinds == KIND_BUILDING).sum())  # noqa: E731
    if v.layout in ("campus", "avenue"):  # open: fewer buildings, longer blocks
        assert buildings(other) < 0.8 * buildings(city)
        assert np.diff(lay_o["sx"]).min() > np.diff(lay_c["sx"]).max()
    else:  # parking lots full of cars
        assert (other.kinds == KIND_CAR).sum() > 1.2 * (city.kinds == KIND_CAR).sum()


def test_world_drive_writes_its_variation(tmp_path):
    res = car.simulate_car(tmp_path / "w", seed=1, duration_s=3.0, stereo_rate_hz=0.0, world=6)
    v = CarVariation.draw(6)
    info = yaml.safe_load((tmp_path / "w" / "ground_truth" / "sim_info.yaml").read_text())
    assert info["world"] == 6 and v.layout in info["variation"]
    d = np.array(res.wheel_d_true_m) / np.array([car.cs.WHEEL_D_LEFT_M, car.cs.WHEEL_D_RIGHT_M]) - 1.0
    assert np.allclose(d.mean(), v.wheel_scale_err, atol=1e-9)
    assert info["lidar_sigma_m"] == pytest.approx(v.lidar_sigma_m, rel=1e-5)
