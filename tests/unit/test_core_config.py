"""Config validation of pf_slam_nodes.core.config."""

import math

import pytest

from pf_slam_nodes.core import config as C


@pytest.mark.parametrize(
    "cls,kwargs,name",
    [
        (C.GridConfig, {"resolution_m": 0.0}, "resolution_m"),
        (C.GridConfig, {"log_odds_miss": 0.5}, "log_odds_miss"),
        (C.GridConfig, {"clip_max": -1.0}, "clip_max"),
        (C.GridConfig, {"origin_x_m": 1.0}, "origin_y_m"),
        (C.GridConfig, {"range_max_usable_m": math.nan}, "range_max_usable_m"),
        (C.CorrelationConfig, {"beam_stride": 0}, "beam_stride"),
        (C.CorrelationConfig, {"sigma_m": -0.1}, "sigma_m"),
        (C.CorrelationConfig, {"occupied_threshold": 101}, "occupied_threshold"),
        (C.CorrelationConfig, {"temperature": 0.0}, "temperature"),
        (C.ResampleConfig, {"neff_threshold": 1.5}, "neff_threshold"),
        (C.ResampleConfig, {"method": "multinomial"}, "method"),
        (C.FilterConfig, {"num_particles": 0}, "num_particles"),
        (C.FilterConfig, {"num_particles": 2.5}, "num_particles"),
        (C.OdometryMotionConfig, {"sigma_xy_per_m": -1.0}, "sigma_xy_per_m"),
        (C.DiffDriveConfig, {"sigma_v": math.inf}, "sigma_v"),
    ],
)
def test_validation_names_parameter_and_value(cls, kwargs, name):
    with pytest.raises(ValueError) as e:
        cls(**kwargs)
    assert name in str(e.value)
    assert repr(next(iter(kwargs.values()))) in str(e.value) or name == "origin_y_m"


def test_from_dict_rejects_unknown_keys():
    with pytest.raises(ValueError, match="bogus_param"):
        C.FilterConfig.from_dict({"num_particles": 10, "bogus_param": 1})


def test_from_dict_roundtrip_and_frozen():
    for cls in (
        C.OdometryMotionConfig,
        C.DiffDriveConfig,
        C.GridConfig,
        C.CorrelationConfig,
        C.ResampleConfig,
        C.FilterConfig,
    ):
        cfg = cls()
        assert cls.from_dict(cfg.to_dict()) == cfg
    cfg = C.FilterConfig.from_dict({"num_particles": 7})
    assert cfg.num_particles == 7
    with pytest.raises(Exception):
        cfg.num_particles = 3  # type: ignore[misc]
