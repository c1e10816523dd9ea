"""Which parameter profile (a file of config/) fits a bag: `pf-slam run BAG` without --params.

A profile is the tuning of one kind of robot: the indoor robots with a planar lidar and
odometry (the CARMEN logs: carmen_indoor.yaml, the same for every log), the car (wheel encoders
+ FOG + tilted lidar: kaist.yaml), the Mines robot (encoders + a 5.6 m URG: mines.yaml), the
project's simulated indoor sample (sim_indoor.yaml). The choice, first that applies:

1. ``--profile NAME`` (or ``none``: the nodes' built-in defaults);
2. the converter's metadata in the bag (``pf_slam.format: carmen|kaist|mines``, written by
   ``pf-slam convert``; bags converted before it was written: the older keys
   ``pf_slam.source: kaist:...``, ``pf_slam.wheel_radius_m``, ``pf_slam.odom_source``), or the
   simulator's (``pf_slam.sim: indoor ...``);
3. the sensors: a tilted (3D) lidar mount -> the car; a planar lidar -> indoor, or the Mines
   profile for wheel encoders with a short-range lidar (range_max <= 6 m).

Where it goes: the lowest user-visible layer. The parameters of `pf-slam run` are layered
built-in defaults < profile < what the bag says about itself (detect_inputs: odometry source,
pairing, gyro format, wheel geometry, lidar mount) < --params FILE < command-line flags.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"

#: profile name -> its file in config/
PROFILES = {
    "indoor": "carmen_indoor.yaml",
    "kaist": "kaist.yaml",
    "mines": "mines.yaml",
    "sim_indoor": "sim_indoor.yaml",
    "thor": "thor.yaml",
}
#: other names accepted by --profile (the files' own names)
ALIASES = {"carmen": "indoor", "carmen_indoor": "indoor", "car": "kaist"}
#: the converters' pf_slam.format -> profile
FORMAT_PROFILES = {"carmen": "indoor", "kaist": "kaist", "mines": "mines", "thor": "thor"}
#: a planar lidar with wheel encoders and at most this range is a small robot's (URG-04LX: 5.6 m)
SHORT_RANGE_M = 6.0


class ProfileError(ValueError):
    """An unknown --profile name."""


@dataclass(frozen=True)
class Profile:
    name: str  # a key of PROFILES, or "none"
    why: str  # one line: what in the bag (or the command line) chose it
    file: Path | None  # None for "none"

    def line(self) -> str:
        """'[pf-slam] profile: kaist (bag metadata pf_slam.format=kaist, written by pf-slam convert kaist); config/kaist.yaml'."""
        where = f"; {self.file.parent.name}/{self.file.name}" if self.file else ""
        return f"[pf-slam] profile: {self.name} ({self.why}){where}"

    def summary(self) -> dict[str, Any]:
        """summary.json "profile"."""
        return {"name": self.name, "why": self.why, "file": str(self.file) if self.file else None}


def profile_file(name: str) -> Path:
    return CONFIG_DIR / PROFILES[name]


def _named(name: str, why: str) -> Profile:
    return Profile(name, why, profile_file(name))


def forced_profile(name: str) -> Profile:
    """The profile `--profile NAME` names; ProfileError for an unknown one (listing the names)."""
    key = ALIASES.get(name, name)
    if key == "none":
        return Profile("none", "--profile none: the nodes' built-in defaults", None)
    if key not in PROFILES:
        raise ProfileError(
            f"--profile {name}: unknown profile; profiles: auto, none, "
            + ", ".join(f"{n} ({f})" for n, f in PROFILES.items())
        )
    return _named(key, f"--profile {name}")


def from_metadata(custom: dict[str, str]) -> Profile | None:
    """The profile a converter's (or the simulator's) custom data names, or None."""
    fmt = custom.get("pf_slam.format")
    if fmt in FORMAT_PROFILES:
        return _named(FORMAT_PROFILES[fmt], f"bag metadata pf_slam.format={fmt}, written by pf-slam convert {fmt}")
    src = str(custom.get("pf_slam.source", ""))
    if src.startswith("kaist:"):
        return _named("kaist", f"bag metadata pf_slam.source={src}, written by pf-slam convert kaist")
    if "pf_slam.wheel_radius_m" in custom and "pf_slam.half_axle_m" in custom:
        return _named("mines", "bag metadata pf_slam.wheel_radius_m, written by pf-slam convert mines")
    if "pf_slam.odom_source" in custom:
        return _named(
            "indoor",
            f"bag metadata pf_slam.source={src or '?'}, pf_slam.odom_source, written by pf-slam convert carmen",
        )
    sim = str(custom.get("pf_slam.sim", ""))
    if sim.split(" ", 1)[0] == "indoor":
        return _named("sim_indoor", f"bag metadata pf_slam.sim={sim}, written by pf-slam simulate-indoor")
    return None


def from_sensors(
    inputs: dict[str, str], planar: bool, rpy_deg: tuple[float, float, float] | None, range_max: float | None
) -> Profile:
    """The profile the bag's sensors imply (no converter metadata): `inputs` as select_inputs()
    chose them, the lidar mount's planarity (and roll/pitch, for the text), the scans' range_max."""
    motion = "Odometry" if "odom" in inputs else "wheel encoders"
    gyro = " + gyro (" + ("FOG" if "fog" in inputs else "Imu") + ")" if ("fog" in inputs or "imu" in inputs) else ""
    rng = f", range_max {range_max:g} m" if range_max is not None and math.isfinite(range_max) else ""
    if not planar:
        tilt = f" (roll {rpy_deg[0]:.0f}°, pitch {rpy_deg[1]:.0f}°)" if rpy_deg else ""
        return _named("kaist", f"LaserScan + {motion}{gyro}, tilted 3D lidar mount{tilt}: a car; no converter metadata")
    if "encoders" in inputs and range_max is not None and range_max <= SHORT_RANGE_M:
        return _named(
            "mines",
            f"LaserScan + {motion}{gyro}, planar lidar{rng} (<= {SHORT_RANGE_M:g} m): "
            "a small robot; no converter metadata",
        )
    return _named("indoor", f"LaserScan + {motion}{gyro}, planar lidar{rng}; no converter metadata")


def choose_profile(
    custom: dict[str, str],
    inputs: dict[str, str],
    planar: bool,
    rpy_deg: tuple[float, float, float] | None = None,
    range_max: float | None = None,
    forced: str | None = None,
) -> Profile:
    """--profile, else the bag's metadata, else its sensors (module docstring)."""
    if forced not in (None, "", "auto"):
        return forced_profile(forced)
    return from_metadata(custom) or from_sensors(inputs, planar, rpy_deg, range_max)


def profile_for_bag(bag: str, forced: str | None = None) -> Profile:
    """choose_profile() for a bag on disk (the launch file's `profile:=auto`): reads its metadata,
    picks its inputs as `pf-slam run` does, looks up the lidar mount and the first scan."""
    from .graph import inspect_stamps, lidar_mount, sample_bag, select_inputs
    from .io.bag import bag_info

    if forced not in (None, "", "auto"):
        return forced_profile(forced)
    info = bag_info(bag)
    inputs = select_inputs(bag, info)
    sample = sample_bag(bag, info, inputs, max_scans=1)  # the bag read once
    stamps = inspect_stamps(sample, inputs)
    mount = lidar_mount(sample, info, inputs, scan_frame=stamps["scan_frame"])
    return choose_profile(
        info.get("custom_data", {}),
        inputs,
        mount.planar,
        tuple(math.degrees(v) for v in mount.rpy),
        stamps.get("scan_range_max"),
    )
