"""What varies between simulated car drives beyond the seed: layout, traffic, speeds, stops and
sensor error levels (``pf-slam simulate --world N``).

``CarVariation()`` (the defaults) is the simulator as it always was: a 5 x 5 city grid, 8-12 m/s,
one stop per 150 s, wheels 0.1-0.4 % off, slip 0.003, lidar 2.5 cm / 1 % dropout; a given
``--seed`` writes the same bytes as before. ``CarVariation.draw(world)`` draws another one from
its own seed (the layout is ``LAYOUTS[world % 4]``): worlds and noise levels that settings tuned on the default drives have not seen.

Layouts (``layout``):

* ``city``     -- the default street grid, 55-75 m blocks, dense buildings.
* ``campus``   -- 80-115 m blocks, half the lots open, buildings set back up to 12 m, many trees.
* ``parking``  -- city blocks where a third of the lots are open parking lots full of parked cars.
* ``avenue``   -- long straight east-west avenues (110-160 m between crossings), few, set-back
  buildings, trees: little structure along the street.
"""

from __future__ import annotations

import dataclasses

import numpy as np

LAYOUTS = ("city", "campus", "parking", "avenue")


@dataclasses.dataclass(frozen=True)
class CarVariation:
    world: int | None = None  # the seed it was drawn from (None: the defaults)
    layout: str = "city"
    pitch_x_m: tuple[float, float] = (55.0, 75.0)  # distance between crossing streets
    pitch_y_m: tuple[float, float] = (55.0, 75.0)
    open_lot_p: float = 0.08  # a lot without a building (plaza / parking lot)
    parking_lot_p: float = 0.0  # of the open lots: filled with rows of parked cars
    inset_max_m: float = 2.5  # a building's setback from its lot edge
    parked_car_p: float = 0.45  # kerb parking density
    tree_p: float = 0.5  # sidewalk: tree (else pole)
    furniture_gap_m: tuple[float, float] = (18.0, 35.0)
    speed_mps: tuple[float, float] = (8.0, 12.0)  # cruise speed per leg
    stop_every_s: float = 150.0  # one stop per this much drive time
    stop_hold_s: tuple[float, float] = (3.0, 8.0)
    wheel_scale_err: float | None = None  # common wheel diameter error (None: the default 0.1-0.4 % split)
    wheel_diff_err: float = 0.0  # left-right difference of the diameter errors
    encoder_slip: float = 0.003
    lidar_sigma_m: float = 0.025
    lidar_dropout: float = 0.01  # per beam
    lidar_scan_dropout: float = 0.0  # whole scans without a return (a blinded lidar)
    fog_sigma_rad: float = 2e-6
    fog_bias_max_rad: float = 6e-7  # per sample, magnitude drawn in [1e-7, this]

    @classmethod
    def draw(cls, world: int) -> CarVariation:
        """A seeded variation: layout, speeds, stops and error levels (module docstring)."""
        rng = np.random.default_rng(np.random.SeedSequence([int(world), 7177]))
        layout = LAYOUTS[int(world) % len(LAYOUTS)]  # any 4 consecutive worlds: every layout
        v = dict(world=int(world), layout=layout)
        if layout == "campus":
            v.update(
                pitch_x_m=(80.0, 115.0),
                pitch_y_m=(80.0, 115.0),
                open_lot_p=0.5,
                inset_max_m=12.0,
                parked_car_p=0.2,
                tree_p=0.85,
                furniture_gap_m=(8.0, 20.0),
            )
        elif layout == "parking":
            v.update(open_lot_p=0.35, parking_lot_p=1.0, parked_car_p=0.6)
        elif layout == "avenue":
            v.update(
                pitch_x_m=(110.0, 160.0),
                open_lot_p=0.45,
                inset_max_m=10.0,
                parked_car_p=0.25,
                tree_p=0.7,
                furniture_gap_m=(10.0, 25.0),
            )
        lo = float(rng.uniform(4.0, 9.0))
        v.update(
            speed_mps=(lo, lo + float(rng.uniform(2.0, 6.0))),
            stop_every_s=float(rng.uniform(40.0, 150.0)),
            stop_hold_s=(1.0, float(rng.uniform(4.0, 25.0))),
            wheel_scale_err=float(rng.uniform(-0.01, 0.01)),
            wheel_diff_err=float(rng.uniform(-0.003, 0.003)),
            encoder_slip=float(rng.uniform(0.001, 0.008)),
            lidar_sigma_m=float(rng.uniform(0.01, 0.05)),
            lidar_dropout=float(rng.uniform(0.005, 0.10)),
            lidar_scan_dropout=float(rng.uniform(0.0, 0.03)),
            fog_sigma_rad=float(rng.uniform(1e-6, 4e-6)),
            fog_bias_max_rad=float(rng.uniform(3e-7, 1e-6)),
        )
        return cls(**v)

    def describe(self) -> str:
        """One line for logs and sim_info.yaml."""
        return (
            f"{self.layout}, {self.speed_mps[0]:.1f}-{self.speed_mps[1]:.1f} m/s, a stop per "
            f"{self.stop_every_s:.0f} s, wheels {'0.1-0.4 % split' if self.wheel_scale_err is None else f'{100 * self.wheel_scale_err:+.2f} % (L-R {100 * self.wheel_diff_err:+.2f} %)'}, "
            f"slip {self.encoder_slip:.4f}, lidar {100 * self.lidar_sigma_m:.1f} cm / {100 * self.lidar_dropout:.1f} % "
            f"beams / {100 * self.lidar_scan_dropout:.1f} % scans dropped"
        )
