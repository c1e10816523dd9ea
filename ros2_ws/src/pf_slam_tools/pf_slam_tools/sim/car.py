"""Seeded car simulator: a city drive written in the KAIST Urban (ECE276A) data set layout.

    python -m pf_slam_tools.sim.car --out DIR --seed 0 --duration 300

writes exactly the layout of the real car data set (``pf_slam_nodes.io.kaist`` reads both)::

    DIR/sensor_data/encoder.csv   timestamp,left_count,right_count             100 Hz
    DIR/sensor_data/fog.csv       timestamp,delta_roll,delta_pitch,delta_yaw    1 kHz
    DIR/sensor_data/lidar.csv     timestamp,r0..r285                            100 Hz
    DIR/stereo_images/stereo_left/<timestamp>.png, stereo_right/<timestamp>.png
    DIR/param/                    the real calibration files, byte for byte
    DIR/ground_truth/poses.csv    timestamp,x,y,theta (header row), 100 Hz
    DIR/ground_truth/occupancy.pgm + .yaml, floor_texture.png + .yaml, sim_info.yaml

No header rows in ``sensor_data/``; timestamps are int64 nanoseconds; encoder counts are
cumulative integers; FOG deltas are radians per sample; lidar ranges are metres (``%.3f``,
``0.000`` = no return); images are 1280 x 560 8-bit Bayer mosaics
(``cv2.cvtColor(img, cv2.COLOR_BAYER_BG2BGR)`` gives the colours).

* **World / drive** -- see ``car_world``: a 5 x 5 street grid (~350 m across), buildings
  6-40 m, parked cars, poles and trees; a right-lane drive at 8-12 m/s that stands still for
  the first second, stops before intersections (>= 1 stop) and loops back through the start
  street before wandering on.
* **Clocks** -- each stream has its own offset (0-10 ms, 0-1 ms for the FOG) and jitter from
  the ground-truth clock ``EPOCH_NS + k * 10 ms``; stereo at ``stereo_rate_hz``.
* **Encoders** -- 4096 ticks/rev; the true wheel diameters differ from the nominal ones of
  ``EncoderParameter.txt`` by +-0.1..0.4 % (seeded, opposite signs), plus a slip random walk;
  counts are ``floor(true wheel angle * 4096 / 2 pi)`` + a seeded start count.
* **FOG** -- true yaw increment over each sample interval + a constant bias
  (+-1e-7..6e-7 rad/sample) + white noise (2e-6 rad); roll / pitch: white noise only.
* **Lidar** -- LMS511 from the true mounting of ``Vehicle2Lidar.txt`` (beam ``a`` points along
  ``R @ [cos a, sin a, 0]`` in the vehicle frame: 0 deg = left, horizontal; 90 deg = forward
  and 37 deg UP; 180 deg = right; only the beams below 0 deg / above 180 deg reach the ground,
  ~33 m away); ray cast in 3D against the ground and the boxes, N(0, 0.025^2) noise, 1 %
  dropouts; 0 = no return within 80 m. One scan is taken at one instant.
* **Stereo** -- rectified images rendered with ``P`` of the camera YAMLs from the true camera
  pose (``Vehicle2Stereo.txt``: camera z = vehicle forward, camera x = vehicle right, image
  rows down; the rectifying rotation is taken as identity), right camera 0.4751 m along the
  camera +x; per-pixel ray casting of the floor texture, facades, cars, poles, trees and sky;
  then a Bayer mosaic with N(0, 1.5^2) sensor noise.

Ground truth: the world frame is the vehicle's true start pose (x forward at the start, z up);
``poses.csv`` holds the vehicle pose (origin on the ground midway between the wheels) at the
ground-truth clock, theta wrapped to (-pi, pi]. ``occupancy`` (0.2 m, map_server trinary):
footprints of everything that overlaps 0.2-2.0 m above the ground (buildings, cars, poles,
tree trunks). ``floor_texture.png`` (RGB, 0.1 m/px, north up) + ``.yaml`` (``resolution``,
``origin`` of the lower-left corner, as a map_server yaml). The output is byte-identical for
a given seed and arguments.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from pf_slam_nodes.io.mapfile import write_map
from pf_slam_tools.sim import car_sensors as cs
from pf_slam_tools.sim.car_params import PARAM_FILES
from pf_slam_tools.sim.car_variation import CarVariation
from pf_slam_tools.sim.car_world import CarWorld, Drive, build_world, occupancy_grid, plan_route, shift_world

__all__ = ["CarSimResult", "EPOCH_NS", "add_arguments", "build_parser", "main", "run_args", "simulate_car"]

#: Ground-truth clock origin (2023-11-14T22:13:20Z), ns.
EPOCH_NS = 1_700_000_000 * 1_000_000_000
GT_RATE_HZ = 100
ENCODER_RATE_HZ = 100
FOG_RATE_HZ = 1000
LIDAR_RATE_HZ = 100
MAP_RESOLUTION_M = 0.2
FOG_SIGMA_RAD = 2e-6
FOG_RP_SIGMA_RAD = 1e-6
IMAGE_NOISE_SIGMA = 1.5


@dataclass(frozen=True)
class CarSimResult:
    """What ``simulate_car`` wrote, and the truth behind it (``drive``, ``world``)."""

    out_dir: Path
    seed: int
    duration_s: float
    n_encoder: int
    n_fog: int
    n_lidar: int
    n_stereo: int
    path_length_m: float
    wheel_d_true_m: tuple[float, float]
    fog_bias_rad: float
    stop_times_s: tuple[float, ...]
    drive: Drive = field(repr=False)
    world: CarWorld = field(repr=False)


def _stamps(
    rng: np.random.Generator, rate_hz: float, duration_s: float, max_offset_ns: int, jitter_ns: int
) -> np.ndarray:
    """``EPOCH_NS + offset + k / rate + jitter`` (int64 ns), all before ``duration_s``."""
    period = 1e9 / rate_hz
    off = int(rng.integers(0, max_offset_ns + 1))
    n = int(math.floor((duration_s * 1e9 - off - 2 * jitter_ns - 1) / period)) + 1
    k = np.arange(max(n, 0), dtype=np.int64)
    jit = rng.integers(-jitter_ns, jitter_ns + 1, size=len(k)) if jitter_ns else 0
    return EPOCH_NS + off + np.rint(k * period).astype(np.int64) + jit + jitter_ns


def _rel_s(stamps_ns: np.ndarray) -> np.ndarray:
    return (stamps_ns - EPOCH_NS).astype(np.float64) * 1e-9


def _write_rows(
    path: Path, stamps: np.ndarray, values: np.ndarray, fmt: str, header: str | None = None, chunk: int = 2000
) -> None:
    """CSV rows ``stamp,v0,..`` (stamps printed as exact integers)."""
    row_fmt = "%d," + ",".join([fmt] * values.shape[1])
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        if header:
            fh.write(header + "\n")
        for i in range(0, len(stamps), chunk):
            rows = [(int(s),) + tuple(v) for s, v in zip(stamps[i : i + chunk], values[i : i + chunk].tolist())]
            fh.write("".join(row_fmt % r + "\n" for r in rows))


def _shift_drive(drive: Drive, shift_xy: np.ndarray) -> Drive:
    pieces = drive.pieces.copy()
    pieces[:, :2] += shift_xy
    return Drive(pieces=pieces, t_knots=drive.t_knots, s_knots=drive.s_knots)


def simulate_car(
    out_dir: str | os.PathLike,
    seed: int = 0,
    duration_s: float = 300.0,
    stereo_rate_hz: float = 1.0,
    encoder_slip: float = 0.003,
    lidar_noise: bool = True,
    overwrite: bool = False,
    world: int | None = None,
) -> CarSimResult:
    """Simulate the city drive and write the data set layout (module docstring) to ``out_dir``.

    Parameters
    ----------
    out_dir : str or PathLike
        Output directory (created).
    seed : int
        Seeds the world, the drive and every sensor's errors (independent streams).
    duration_s : float
        Simulated time (s), 1..3600.
    stereo_rate_hz : float
        Stereo pair rate (Hz), 0 (no images) .. 10.
    encoder_slip : float
        Wheel slip random walk (rad per sqrt(rad) of wheel rotation); 0 = none.
    lidar_noise : bool
        False writes noise-free ranges without dropouts.
    world : int, optional
        Draws a :class:`~pf_slam_tools.sim.car_variation.CarVariation` from this seed: another
        layout (city, campus, parking lots, avenues), speeds, stops, wheel calibration error
        (+-1 %), slip, lidar noise and dropout, FOG noise (``encoder_slip`` is then the
        variation's). None: the default world and error levels.
    overwrite : bool
        Allow writing into a directory that already has ``sensor_data/`` (the stereo folders
        are emptied first); else ``FileExistsError``.
    """
    if not (isinstance(duration_s, (int, float)) and 1.0 <= duration_s <= 3600.0):
        raise ValueError(f"duration_s must be in [1, 3600] s, got {duration_s!r}")
    if not (isinstance(stereo_rate_hz, (int, float)) and 0.0 <= stereo_rate_hz <= 10.0):
        raise ValueError(f"stereo_rate_hz must be in [0, 10] Hz, got {stereo_rate_hz!r}")
    if not encoder_slip >= 0.0:
        raise ValueError(f"encoder_slip must be >= 0, got {encoder_slip!r}")
    out = Path(out_dir)
    if (out / "sensor_data").exists() and not overwrite:
        raise FileExistsError(f"{out}: already holds sensor_data/ (use overwrite / --force)")
    dirs = {
        k: out / k
        for k in ("sensor_data", "param", "ground_truth", "stereo_images/stereo_left", "stereo_images/stereo_right")
    }
    for d in dirs.values():
        d.mkdir(parents=True, exist_ok=True)
    for side in ("stereo_left", "stereo_right"):
        for f in dirs[f"stereo_images/{side}"].glob("*.png"):
            f.unlink()

    (world_rng, drive_rng, enc_rng, fog_rng, lidar_rng, cam_rng, clock_rng) = (
        np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(7)
    )
    var = CarVariation() if world is None else CarVariation.draw(world)
    if world is not None:
        encoder_slip = var.encoder_slip
    world, layout = build_world(world_rng, var)
    drive, start, _ = plan_route(float(duration_s), layout, drive_rng, var)
    world = shift_world(world, -start)
    drive = _shift_drive(drive, -start)
    dur = float(duration_s)

    # clocks
    t_gt = EPOCH_NS + np.arange(int(round(dur * GT_RATE_HZ)), dtype=np.int64) * (1_000_000_000 // GT_RATE_HZ)
    t_enc = _stamps(clock_rng, ENCODER_RATE_HZ, dur, 10_000_000, 300_000)
    t_fog = _stamps(clock_rng, FOG_RATE_HZ, dur, 1_000_000, 20_000)
    t_lid = _stamps(clock_rng, LIDAR_RATE_HZ, dur, 10_000_000, 200_000)
    t_st = (
        _stamps(clock_rng, stereo_rate_hz, dur, 50_000_000, 1_000_000)
        if stereo_rate_hz > 0
        else np.zeros(0, dtype=np.int64)
    )

    # ground truth
    gt = drive.poses_at(_rel_s(t_gt))
    gt_out = gt.copy()
    gt_out[:, 2] = np.arctan2(np.sin(gt[:, 2]), np.cos(gt[:, 2]))
    _write_rows(dirs["ground_truth"] / "poses.csv", t_gt, gt_out, "%.6f", header="timestamp,x,y,theta")
    occ, origin = occupancy_grid(world, MAP_RESOLUTION_M)
    write_map(dirs["ground_truth"], occ, MAP_RESOLUTION_M, origin, name="occupancy")
    tex_png = dirs["ground_truth"] / "floor_texture.png"
    cv2.imwrite(str(tex_png), np.ascontiguousarray(world.texture[::-1, :, ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 6])
    (dirs["ground_truth"] / "floor_texture.yaml").write_text(
        f"image: {tex_png.name}\n"
        f"resolution: {world.texture_res_m:.6g}\n"
        f"origin: [{world.texture_origin[0]:.6f}, {world.texture_origin[1]:.6f}, 0]\n"
        "# RGB image, row 0 = north (largest y); texel (col, row) covers x = origin_x + "
        "col * resolution .. + resolution\n",
        encoding="utf-8",
    )

    # calibration
    for name, text in PARAM_FILES.items():
        with open(dirs["param"] / name, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)

    # encoders
    mag = enc_rng.uniform(0.001, 0.004, 2)
    sign = 1.0 if enc_rng.random() < 0.5 else -1.0
    d_true = (cs.WHEEL_D_LEFT_M * (1.0 + sign * mag[0]), cs.WHEEL_D_RIGHT_M * (1.0 - sign * mag[1]))
    if var.wheel_scale_err is not None:  # the calibration file is itself 1 % off
        d_true = (
            cs.WHEEL_D_LEFT_M * (1.0 + var.wheel_scale_err + 0.5 * var.wheel_diff_err),
            cs.WHEEL_D_RIGHT_M * (1.0 + var.wheel_scale_err - 0.5 * var.wheel_diff_err),
        )
    offsets = tuple(int(v) for v in enc_rng.integers(0, 1_000_000, 2))
    s_enc = drive.s_at(_rel_s(t_enc))
    th_enc = drive.poses_at(_rel_s(t_enc))[:, 2]
    counts = cs.encoder_counts(s_enc, th_enc, d_true, offsets, encoder_slip, enc_rng)
    with open(dirs["sensor_data"] / "encoder.csv", "w", encoding="ascii", newline="\n") as fh:
        fh.write(
            "".join(f"{a},{b},{c}\n" for a, b, c in zip(t_enc.tolist(), counts[:, 0].tolist(), counts[:, 1].tolist()))
        )

    # FOG: increments over [t_{k-1}, t_k] (the first over the millisecond before t_0)
    bias = float(fog_rng.uniform(1e-7, var.fog_bias_max_rad) * (1.0 if fog_rng.random() < 0.5 else -1.0))
    th_fog = drive.poses_at(_rel_s(t_fog))[:, 2]
    th_prev = np.concatenate([drive.poses_at(_rel_s(t_fog[:1]) - 1e-3)[:, 2], th_fog[:-1]])
    fog = cs.fog_deltas(th_prev, th_fog, bias, var.fog_sigma_rad, FOG_RP_SIGMA_RAD, fog_rng)
    _write_rows(dirs["sensor_data"] / "fog.csv", t_fog, fog, "%.9e", chunk=20000)

    # lidar
    ranges = cs.lidar_ranges(drive.poses_at(_rel_s(t_lid)), world.boxes)
    if lidar_noise:
        ranges = ranges + var.lidar_sigma_m * lidar_rng.normal(size=ranges.shape)
        ranges[lidar_rng.random(size=ranges.shape) < var.lidar_dropout] = np.inf
        if var.lidar_scan_dropout > 0:  # whole scans without a return
            ranges[lidar_rng.random(size=len(ranges)) < var.lidar_scan_dropout] = np.inf
    ranges[~(ranges <= cs.LIDAR_MAX_M)] = 0.0
    ranges = np.maximum(ranges, 0.0)
    _write_rows(dirs["sensor_data"] / "lidar.csv", t_lid, ranges, "%.3f")

    # stereo
    st_poses = drive.poses_at(_rel_s(t_st)) if len(t_st) else np.zeros((0, 3))
    for stamp, pose in zip(t_st.tolist(), st_poses):
        for side, right in (("stereo_left", False), ("stereo_right", True)):
            mosaic = cs.rgb_to_bayer(cs.render_rgb(pose, world, right=right)).astype(np.float32)
            mosaic += IMAGE_NOISE_SIGMA * cam_rng.standard_normal(mosaic.shape, np.float32)
            img = np.clip(np.rint(mosaic), 0, 255).astype(np.uint8)
            cv2.imwrite(str(dirs[f"stereo_images/{side}"] / f"{stamp}.png"), img, [cv2.IMWRITE_PNG_COMPRESSION, 3])

    stops = _stop_times(drive, dur)
    path_len = float(drive.s_at(np.array([dur]))[0])
    (dirs["ground_truth"] / "sim_info.yaml").write_text(
        f"# pf_slam car simulator: the true values behind the data (not part of the real layout)\n"
        f"seed: {int(seed)}\nduration_s: {dur:g}\nstereo_rate_hz: {float(stereo_rate_hz):g}\n"
        f"wheel_diameter_true_m: [{d_true[0]:.9f}, {d_true[1]:.9f}]\n"
        f"wheel_base_m: {cs.WHEEL_BASE_M}\n"
        f"encoder_slip: {float(encoder_slip):g}\n"
        f"fog_yaw_bias_rad_per_sample: {bias:.6e}\n"
        f"fog_yaw_sigma_rad: {var.fog_sigma_rad:g}\n"
        f"lidar_sigma_m: {var.lidar_sigma_m if lidar_noise else 0.0:g}\n"
        + (f'world: {var.world}\nvariation: "{var.describe()}"\n' if var.world is not None else "")
        + f"path_length_m: {path_len:.3f}\n"
        f"stop_times_s: [{', '.join(f'{t:.2f}' for t in stops)}]\n"
        f"ground_truth_epoch_ns: {EPOCH_NS}\n",
        encoding="utf-8",
    )
    return CarSimResult(
        out_dir=out,
        seed=int(seed),
        duration_s=dur,
        n_encoder=len(t_enc),
        n_fog=len(t_fog),
        n_lidar=len(t_lid),
        n_stereo=len(t_st),
        path_length_m=path_len,
        wheel_d_true_m=d_true,
        fog_bias_rad=bias,
        stop_times_s=tuple(stops),
        drive=drive,
        world=world,
    )


def _stop_times(drive: Drive, duration_s: float) -> list[float]:
    """Start times (s) of the stand-stills within the drive (the initial one included)."""
    tk, sk = drive.t_knots, drive.s_knots
    same = np.flatnonzero(np.diff(sk) == 0.0)
    return [float(tk[i]) for i in same if tk[i] < duration_s]


# --------------------------------------------------------------------------------------------
# command line


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the simulator's options to ``parser`` (for ``pf-slam simulate``)."""
    parser.add_argument("--out", required=True, help="output data set directory")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("--duration", type=float, default=300.0, help="simulated seconds (default: 300)")
    parser.add_argument("--stereo-rate", type=float, default=1.0, help="stereo pairs per second, 0 = none (default: 1)")
    parser.add_argument(
        "--world",
        type=int,
        default=None,
        help="draw another world and error levels from this seed: layout (city, campus, "
        "parking lots, avenues), speeds, stops, wheel calibration error, slip, lidar "
        "noise and dropout (default: the standard world)",
    )
    parser.add_argument("--force", action="store_true", help="write into a directory that already holds a data set")
    return parser


def build_parser() -> argparse.ArgumentParser:
    """Stand-alone parser of ``python -m pf_slam_tools.sim.car``."""
    return add_arguments(
        argparse.ArgumentParser(
            prog="python -m pf_slam_tools.sim.car",
            description="Write a seeded city drive in the KAIST car data set layout.",
        )
    )


def run_args(args: argparse.Namespace) -> int:
    """Run the simulator from parsed ``add_arguments`` options; prints a summary."""
    try:
        res = simulate_car(
            args.out,
            seed=args.seed,
            duration_s=args.duration,
            stereo_rate_hz=args.stereo_rate,
            overwrite=args.force,
            world=args.world,
        )
    except (FileExistsError, ValueError) as exc:
        print(f"simulate: error: {exc}", file=sys.stderr)
        return 2
    size = sum(f.stat().st_size for f in res.out_dir.rglob("*") if f.is_file())
    print(
        f"{res.out_dir}: {res.duration_s:g} s, {res.n_encoder} encoder, {res.n_fog} FOG, "
        f"{res.n_lidar} lidar rows, {res.n_stereo} stereo pairs, {size / 1e6:.1f} MB\n"
        f"path {res.path_length_m:.1f} m, stops at "
        f"{', '.join(f'{t:.1f}' for t in res.stop_times_s)} s"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m pf_slam_tools.sim.car --out DIR --seed N --duration S``."""
    return run_args(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
