"""Which parameter profile `pf-slam run BAG` uses without --params (profiles.py): the bag's
converter metadata, else its sensors; --profile forces one; the printed line."""

from __future__ import annotations

from pathlib import Path

import pytest

from pf_slam_nodes import profiles
from pf_slam_nodes.profiles import ProfileError, choose_profile, profile_for_bag

ROOT = Path(__file__).resolve().parents[2]
ODOM = {"scan": "/scan", "odom": "/odom"}
CAR = {"scan": "/scan", "encoders": "/encoders", "fog": "/fog"}


@pytest.mark.parametrize(
    "custom, name",
    [
        ({"pf_slam.format": "kaist"}, "kaist"),
        ({"pf_slam.format": "carmen"}, "indoor"),
        ({"pf_slam.format": "mines"}, "mines"),
        # bags converted before pf_slam.format was written
        ({"pf_slam.source": "kaist:urban08"}, "kaist"),
        ({"pf_slam.source": "exp1.dat", "pf_slam.wheel_radius_m": "0.077", "pf_slam.half_axle_m": "0.165"}, "mines"),
        ({"pf_slam.source": "intel.clf", "pf_slam.odom_source": "laser lines"}, "indoor"),
        ({"pf_slam.sim": "indoor seed=0 duration_s=60"}, "sim_indoor"),
    ],
)
def test_metadata_names_the_profile(custom, name):
    # the sensors say otherwise (a planar lidar with odometry): the metadata wins
    p = choose_profile(custom, ODOM, planar=True)
    assert p.name == name and p.file == profiles.CONFIG_DIR / profiles.PROFILES[name] and p.file.is_file()
    assert "bag metadata pf_slam." in p.why


def test_sensors_without_metadata():
    p = choose_profile({}, CAR, planar=False, rpy_deg=(128.0, 0.0, 0.0), range_max=80.0)
    assert p.name == "kaist" and "tilted 3D lidar mount (roll 128°" in p.why and "no converter metadata" in p.why
    p = choose_profile({}, ODOM, planar=True, range_max=30.0)
    assert p.name == "indoor" and p.why == "LaserScan + Odometry, planar lidar, range_max 30 m; no converter metadata"
    assert choose_profile({}, {"scan": "/scan", "encoders": "/e"}, planar=True, range_max=5.6).name == "mines"
    assert choose_profile({}, {"scan": "/scan", "encoders": "/e"}, planar=True, range_max=30.0).name == "indoor"


def test_forced_profile():
    assert choose_profile({"pf_slam.format": "kaist"}, CAR, False, forced="indoor").name == "indoor"
    assert choose_profile({}, CAR, False, forced="carmen_indoor").name == "indoor"  # the file's name
    none = choose_profile({"pf_slam.format": "kaist"}, CAR, False, forced="none")
    assert none.name == "none" and none.file is None and none.summary()["file"] is None
    with pytest.raises(ProfileError, match=r"--profile outdoor: unknown profile; profiles: auto, none, indoor"):
        choose_profile({}, CAR, False, forced="outdoor")


def test_printed_line():
    p = choose_profile({"pf_slam.format": "kaist"}, CAR, False)
    assert p.line() == (
        "[pf-slam] profile: kaist (bag metadata pf_slam.format=kaist, written by pf-slam "
        "convert kaist); config/kaist.yaml"
    )
    assert p.summary() == {"name": "kaist", "why": p.why, "file": str(profiles.CONFIG_DIR / "kaist.yaml")}


def test_profile_for_the_sample_bags():
    """What the launch file's profile:=auto reads: the car sample -> kaist, the indoor sample -> sim_indoor."""
    assert profile_for_bag(str(ROOT / "bags" / "car_sample")).name == "kaist"
    assert profile_for_bag(str(ROOT / "bags" / "sample_indoor")).name == "sim_indoor"
    assert profile_for_bag(str(ROOT / "bags" / "car_sample"), forced="none").name == "none"
