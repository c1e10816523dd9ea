"""The car through the full graph, against the simulator's ground truth (`pf-slam bench car`).

For each seed (and, with ``worlds``, each world: `pf-slam simulate --world N`, layouts and
error levels the settings were not tuned on): simulate a drive in the KAIST layout (cached),
convert it to a bag with the stereo pairs at 1 Hz (``images``, the default) or without them
(cached; a cached bag of the other kind is converted again), run, for each filter seed, the
graph with config/kaist.yaml in `--rate max` (the texture node on when the bag has images), and
report the trajectory error (ATE after an SE(2) alignment) next to dead reckoning from the same
encoders + FOG, the occupied-cell F1 of the map against the ground-truth grid, the real-time
factor with its ratio to the replay-only ceiling of the same bag (images included), and with
images: the pairs textured, the texture's colour error and coverage against the simulator's
floor and the texture node's time per pair by stage.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np

from pf_slam_nodes.core import metrics
from pf_slam_nodes.core.odometry import GyroBuffer, WheelOdometryIntegrator
from pf_slam_nodes.io.calib import parse_encoder_params
from pf_slam_nodes.io.trajectory import read_trajectory, write_tum
from pf_slam_nodes.profiles import CONFIG_DIR  # noqa: E402  (the runtime package's config/)

from . import stage_table

KAIST_YAML = CONFIG_DIR / "kaist.yaml"


def odometry_streams(dataset_dir: str | Path) -> dict:
    """The drive's encoder and FOG CSVs and encoder parameters, read once: ``enc`` (K, 3) int64
    (stamp, left, right counts), ``fog_t`` (F,) int64 ns, ``fog_yaw`` (F,) rad, ``params``."""
    d = Path(dataset_dir)
    fog = np.loadtxt(
        d / "sensor_data" / "fog.csv",
        delimiter=",",
        usecols=(0, 3),
        ndmin=1,
        dtype={"names": ("t", "yaw"), "formats": ("i8", "f8")},
    )
    return {
        "enc": np.loadtxt(d / "sensor_data" / "encoder.csv", delimiter=",", dtype=np.int64, ndmin=2),
        "fog_t": fog["t"],
        "fog_yaw": fog["yaw"],
        "params": parse_encoder_params(d / "param" / "EncoderParameter.txt"),
    }


def dead_reckoning(
    dataset_dir: str | Path, gyro_rest_bias: bool = False, streams: dict | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Encoders + FOG integrated exactly as the predictor does (no noise, no scans); with
    ``gyro_rest_bias``, the FOG's bias calibrated at standstill (the predictor's
    ``wheels.gyro_rest_bias``), else the raw sensors (the baseline of the car targets).
    ``streams``: :func:`odometry_streams` of the drive, if already read.

    Returns ``(stamps_ns (K,), poses (K, 3))`` at the encoder stamps.
    """
    s = streams or odometry_streams(dataset_dir)
    enc, p = s["enc"], s["params"]
    gyro = GyroBuffer()
    gyro.add(s["fog_t"], s["fog_yaw"])
    wheels = WheelOdometryIntegrator(
        p["left_wheel_diameter_m"], p["right_wheel_diameter_m"], p["wheel_base_m"], gyro_rest_bias=gyro_rest_bias
    )
    k = 2.0 * math.pi / p["resolution"]
    poses, prev = np.empty((enc.shape[0], 3)), None
    for i, (t, left, right) in enumerate(enc):
        if prev is not None:
            wheels.add_gyro(gyro.yaw_between(prev, int(t)))
        poses[i] = wheels.step(left * k, right * k, None if prev is None else (int(t) - prev) / 1e9)
        prev = int(t)
    return enc[:, 0], poses


def _ate(t_est: np.ndarray, p_est: np.ndarray, t_gt: np.ndarray, p_gt: np.ndarray) -> float:
    return float(_ate_full(t_est, p_est, t_gt, p_gt)["rmse"])


def _ate_full(t_est: np.ndarray, p_est: np.ndarray, t_gt: np.ndarray, p_gt: np.ndarray) -> dict:
    pairs = metrics.associate(t_est, t_gt, max_dt=0.02)
    return metrics.ate(p_est[pairs[:, 0]], p_gt[pairs[:, 1]])


def images_in(topics: dict) -> int:
    """Number of ``sensor_msgs/Image`` messages in a bag's ``bag_info()["topics"]``."""
    return sum(n for msgtype, n in topics.values() if msgtype == "sensor_msgs/msg/Image")


def _bench_bag(data: Path, bag: Path, images: bool = False) -> Path:
    """The drive's bag, converted once with or without (``images``) the stereo images. A cached
    bag is reused only if it holds the drive's scans and images (or none: one that carries images
    also runs the texture node and times something else); otherwise it is converted again."""
    from pf_slam_nodes.io.bag import bag_info
    from pf_slam_nodes.io.kaist import convert_kaist

    if (bag / "metadata.yaml").is_file():
        topics = bag_info(bag)["topics"]
        n_img = images_in(topics)
        scans = topics.get("/scan", ("", 0))[1]
        if scans > 0 and (n_img > 0) == images:
            return bag
        print(f"[bench car] {bag}: cached bag holds {n_img} images and {scans} scans; converting again")
        shutil.rmtree(bag)
    convert_kaist(data, bag, images=images)
    return bag


def _drive_name(seed: int, duration_s: float, world: int | None) -> str:
    return f"car_{int(duration_s)}s_seed{seed}" + ("" if world is None else f"_world{world}")


def _simulated(data: Path, seed: int, duration_s: float, world: int | None, stereo_rate_hz: float) -> None:
    """Simulate the drive into ``data`` unless it is there (with stereo pairs when they are wanted)."""
    from pf_slam_tools.sim.car import simulate_car

    left = data / "stereo_images" / "stereo_left"
    has_pairs = left.is_dir() and any(left.glob("*.png"))
    if (data / "ground_truth" / "poses.csv").is_file() and (has_pairs or stereo_rate_hz == 0):
        return
    simulate_car(data, seed=seed, duration_s=duration_s, stereo_rate_hz=stereo_rate_hz, overwrite=True, world=world)


def texture_score(run_dir: Path, data: Path, align: tuple[float, np.ndarray] | None = None) -> dict:
    """The run's ``texture.png`` (final /map geometry) against the simulator's floor texture:
    ``colour_error`` (mean abs RGB over the coloured cells, each compared with the mean of the
    true 0.1 m texels in it), ``coverage`` (coloured / ground the left camera saw within the
    range box from the true poses of the pairs, minus truly occupied cells) and ``cells``.
    ``align``: the trajectory's SE(2) alignment onto the truth (``theta``, ``t``, as the ATE
    takes it): ``colour_error_aligned`` compares each cell with the truth where the alignment
    puts it (the map frame's own offset and rotation, which the ATE ignores, left out)."""
    import cv2

    from pf_slam_nodes.core.texture import TextureConfig, colour_error, interpolate_poses, visible_ground_mask
    from pf_slam_nodes.io.calib import read_stereo_rig
    from pf_slam_nodes.io.mapfile import read_map
    from pf_slam_nodes.io.texture_files import read_floor_texture

    img = cv2.imread(str(run_dir / "texture.png"), cv2.IMREAD_COLOR)
    occ, res, origin = read_map(run_dir / "map.yaml")
    if img is None or img.shape[:2] != occ.shape:
        return {}
    rgb = np.ascontiguousarray(img[::-1, :, ::-1])
    cov = rgb.max(axis=2) > 0
    gt, gres, gorig = read_floor_texture(data / "ground_truth" / "floor_texture.png")
    h, w = occ.shape
    xs = origin[0] + (np.arange(w) + 0.5) * res
    ys = origin[1] + (np.arange(h) + 0.5) * res
    off = (np.arange(max(int(round(res / gres)), 1)) + 0.5) * gres - 0.5 * res  # the texels in a cell

    def truth_cells(theta: float, t) -> np.ndarray:  # the true texels' mean at the cells moved by (theta, t)
        acc = np.zeros((h, w, 3))
        for dy in off:
            for dx in off:
                x, y = np.broadcast_arrays(xs[None, :] + dx, ys[:, None] + dy)
                p = metrics.apply_se2(theta, t, np.stack([x.ravel(), y.ravel()], axis=1))
                gi = np.clip(np.floor((p[:, 0] - gorig[0]) / gres).astype(int), 0, gt.shape[1] - 1)
                gj = np.clip(np.floor((p[:, 1] - gorig[1]) / gres).astype(int), 0, gt.shape[0] - 1)
                acc += gt[gj, gi].reshape(h, w, 3)
        return np.rint(acc / off.size**2).astype(np.uint8)

    gt_cells = truth_cells(0.0, (0.0, 0.0))
    rig = read_stereo_rig(data / "param")
    stamps = sorted(int(p.stem) for p in (data / "stereo_images" / "stereo_left").glob("*.png"))
    t_gt, p_gt = read_trajectory(data / "ground_truth" / "poses.csv")
    poses = interpolate_poses(t_gt, p_gt, np.array(stamps, dtype=np.float64) / 1e9)
    poses = poses[np.isfinite(poses).all(axis=1)]
    cfg = TextureConfig()
    vis = visible_ground_mask(
        poses, rig, cfg, res, origin, (h, w), rectified_here=False
    )  # the simulator renders rectified images
    go, gr, gorig2 = read_map(data / "ground_truth" / "occupancy.yaml")
    oi = np.clip(((xs - gorig2[0]) / gr).astype(int), 0, go.shape[1] - 1)
    oj = np.clip(((ys - gorig2[1]) / gr).astype(int), 0, go.shape[0] - 1)
    vis &= ~(go[oj[:, None], oi[None, :]] >= 65)
    sc = colour_error(rgb, cov, gt_cells, vis)
    out = {"colour_error": sc["mean_abs_rgb_error"], "coverage": sc["coverage"], "cells": sc["cells_coloured"]}
    if align is not None:
        out["colour_error_aligned"] = colour_error(rgb, cov, truth_cells(*align))["mean_abs_rgb_error"]
    return out


def bench(
    out_dir: Path,
    seeds=(0,),
    duration_s: float = 300.0,
    processes: str = "single",
    particles: int | None = None,
    params_file: str | None = None,
    filter_seeds: tuple[int, ...] = (0,),
    images: bool = True,
    worlds: tuple[int | None, ...] = (None,),
    stereo_rate_hz: float = 1.0,
) -> list[dict]:
    """One row per drive (simulator ``seeds``) and filter seed (``filter_seeds``: the filter's
    random stream, ``filter.seed``). The filter is chaotic on these drives (README), so the
    settings are judged on several of each. Dead reckoning, the ceiling and the ground truth are
    computed once per drive."""
    from pf_slam_nodes.graph import run
    from pf_slam_nodes.io.mapfile import read_map
    from pf_slam_tools.bench.ceiling import replay_ceiling

    rows = []
    for seed, world in [(s, w) for w in worlds for s in seeds]:
        name = _drive_name(seed, duration_s, world)
        data = out_dir / name
        _simulated(data, seed, duration_s, world, stereo_rate_hz if images else 0.0)
        bag = _bench_bag(data, out_dir / (name + ("_bag_images" if images else "_bag")), images)
        ceiling = replay_ceiling(str(bag))
        t_gt, p_gt = read_trajectory(data / "ground_truth" / "poses.csv")
        streams = odometry_streams(data)
        t_dr, p_dr = dead_reckoning(data, streams=streams)
        t_dc, p_dc = dead_reckoning(data, gyro_rest_bias=True, streams=streams)
        dr_ate = _ate(t_dr / 1e9, p_dr, t_gt, p_gt)
        dr_rest_bias_ate = _ate(t_dc / 1e9, p_dc, t_gt, p_gt)
        true_bias = _true_fog_bias_rad_s(data, streams["fog_t"])
        true_scale = _true_wheel_scale(data, streams["params"])
        go, gr, gorig = read_map(data / "ground_truth" / "occupancy.yaml")
        for fseed in filter_seeds:
            run_dir = out_dir / (f"{name}_{processes}_filter{fseed}" + ("_images" if images else ""))
            node = {"filter.seed": int(fseed)}
            if particles:
                node["filter.num_particles"] = particles
            res = run(
                str(bag),
                run_dir,
                params_file=params_file or str(KAIST_YAML),
                processes=processes,
                overrides={"/**": node},
                progress=False,
                snapshot_every=0,
                texture=images,
            )
            write_tum(run_dir / "dead_reckoning.tum", t_dr / 1e9, p_dr)
            write_tum(run_dir / "dead_reckoning_rest_bias.tum", t_dc / 1e9, p_dc)
            t_est, p_est = read_trajectory(run_dir / "trajectory.tum")
            eo, er, eorig = read_map(run_dir / "map.yaml")
            f1 = metrics.map_f1(eo, er, eorig[:2], go, gr, gorig[:2])
            s = res.summary
            tex = s.get("texture") or {}
            ate = _ate_full(t_est, p_est, t_gt, p_gt)
            align = (ate["align_theta"], np.asarray(ate["align_t"]))
            score = texture_score(run_dir, data, align) if images and tex.get("files") else {}
            rows.append(
                {
                    "seed": seed,
                    "world": world,
                    "filter_seed": int(fseed),
                    "images": images,
                    "pairs": tex.get("frames_received", 0),
                    "pairs_textured": tex.get("frames_processed", 0),
                    "pairs_skipped": tex.get("frames_skipped", 0),
                    "texture_ms_per_pair": tex.get("ms_per_frame"),
                    "texture_ms_stages": tex.get("ms_stages"),
                    "texture_replaced": tex.get("replaced"),
                    "colour_error": score.get("colour_error"),
                    "colour_error_aligned": score.get("colour_error_aligned"),
                    "coverage": score.get("coverage"),
                    "duration_s": s["bag_duration_s"],
                    "processes": processes,
                    "particles": s["particles"],
                    "scans": s["scans_processed"],
                    "dropped": s["scans_dropped"],
                    "corrected": s["scans_corrected"],
                    "ate_m": float(ate["rmse"]),
                    "dr_ate_m": dr_ate,
                    "dr_rest_bias_ate_m": dr_rest_bias_ate,
                    "gyro_bias_rad_s": s.get("gyro", {}).get("bias_rad_s"),
                    "true_gyro_bias_rad_s": true_bias,
                    "wheel_scale": s.get("odom_scale", {}).get("scale"),
                    "true_wheel_scale": true_scale,
                    "map_f1": f1["f1"],
                    "map_precision": f1["precision"],
                    "map_recall": f1["recall"],
                    "wall_s": s["wall_time_s"],
                    "rtf": s["real_time_factor"],
                    "ceiling_rtf": ceiling["real_time_factor"],
                    "ratio_to_ceiling": round(s["real_time_factor"] / ceiling["real_time_factor"], 3),
                    "peak_rss_mb": s["peak_rss_mb"],
                    "stage_ms_per_scan": s.get("stage_ms_per_scan"),
                }
            )
    return rows


def targets_line(rows: list[dict], ate_max_m: float = 0.35, better_by: float = 3.0, rtf_min: float = 10.0) -> str:
    """The car targets over all rows: ATE mean / worst, how many runs have ATE <= ``ate_max_m``
    and ``better_by`` x below raw dead reckoning, how many run at >= ``rtf_min`` x real time."""
    ate = np.array([r["ate_m"] for r in rows])
    ok = sum(r["ate_m"] <= ate_max_m and r["dr_ate_m"] >= better_by * r["ate_m"] for r in rows)
    fast = sum(r["rtf"] >= rtf_min for r in rows)
    return (
        f"{len(rows)} runs: ATE mean {ate.mean():.3f} m, median {np.median(ate):.3f} m, worst "
        f"{ate.max():.3f} m; ATE <= {ate_max_m} m and >= {better_by:g}x below raw dead reckoning in "
        f"{ok} of {len(rows)}; >= {rtf_min:g}x real time in {fast} of {len(rows)} "
        f"(RTF {min(r['rtf'] for r in rows):.1f}-{max(r['rtf'] for r in rows):.1f}x); "
        f"dropped {sum(r['dropped'] for r in rows)}" + _texture_targets(rows)
    )


def _texture_targets(rows: list[dict], error_max: float = 12.0) -> str:
    """With images: pairs textured of all, colour error median / worst (in the map frame, and with
    the map frame aligned as the ATE aligns the trajectory), coverage median."""
    tex = [r for r in rows if r.get("images") and r.get("pairs")]
    if not tex:
        return ""
    err = [r["colour_error"] for r in tex if r.get("colour_error") is not None]
    cov = [r["coverage"] for r in tex if r.get("coverage") is not None]
    out = (
        f"; stereo pairs textured {sum(r['pairs_textured'] for r in tex)} of {sum(r['pairs'] for r in tex)} "
        f"({sum(r['pairs_skipped'] for r in tex)} skipped)"
    )
    if err:
        out += (
            f"; texture colour error median {np.median(err):.1f}, worst {max(err):.1f} (<= {error_max:g} in "
            f"{sum(e <= error_max for e in err)} of {len(err)})"
        )
    aligned = [r["colour_error_aligned"] for r in tex if r.get("colour_error_aligned") is not None]
    if aligned:
        out += (
            f"; aligned as the ATE: median {np.median(aligned):.1f}, worst {max(aligned):.1f} (<= {error_max:g} in "
            f"{sum(e <= error_max for e in aligned)} of {len(aligned)})"
        )
    if cov:
        out += f", coverage median {np.median(cov):.2f}"
    return out


def _world_text(r: dict) -> str:
    return "–" if r.get("world") is None else str(r["world"])


def _world_layouts(rows: list[dict]) -> str:
    """'world N: <variation>' lines of the worlds in ``rows``."""
    from pf_slam_tools.sim.car_variation import CarVariation

    ws = sorted({r["world"] for r in rows if r.get("world") is not None})
    return "\n".join(f"- world {w}: {CarVariation.draw(w).describe()}" for w in ws)


def format_texture_table(rows: list[dict]) -> str:
    """Rows with images: pairs, textured, skipped, colour error, coverage, how far the final
    placement on the corrected trajectory moved the pairs (median), texture ms per pair by stage."""
    tex = [r for r in rows if r.get("images")]
    if not tex:
        return ""
    stages = []
    for r in tex:
        stages += [k for k in (r.get("texture_ms_stages") or {}) if k not in stages]
    lines = [
        "| seed | world | filter seed | pairs | textured | skipped | colour error | aligned | coverage | "
        "placed again: moved m | ms / pair | " + " | ".join(f"{k} ms" for k in stages) + " |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|" + "---:|" * len(stages),
    ]
    for r in tex:
        st = r.get("texture_ms_stages") or {}
        f = lambda v, fmt: "–" if v is None else format(v, fmt)  # noqa: E731
        lines.append(
            f"| {r['seed']} | {_world_text(r)} | {r['filter_seed']} | {r['pairs']} | {r['pairs_textured']} | "
            f"{r['pairs_skipped']} | {f(r.get('colour_error'), '.1f')} | {f(r.get('colour_error_aligned'), '.1f')} | "
            f"{f(r.get('coverage'), '.2f')} | {f((r.get('texture_replaced') or {}).get('shift_median_m'), '.2f')} | "
            f"{f(r.get('texture_ms_per_pair'), '.0f')} | " + " | ".join(f(st.get(k), ".0f") for k in stages) + " |"
        )
    return "\n".join(lines)


def _sim_info(data: Path) -> dict:
    """The simulator's true values (ground_truth/sim_info.yaml), or {} for real data."""
    info = data / "ground_truth" / "sim_info.yaml"
    if not info.is_file():
        return {}
    import yaml

    return yaml.safe_load(info.read_text()) or {}


def _true_fog_bias_rad_s(data: Path, t: np.ndarray) -> float | None:
    """The simulator's FOG yaw bias (rad/s) from ground_truth/sim_info.yaml and the FOG's stamps
    ``t`` (ns; the bias is per sample), or None for real data."""
    per_sample = _sim_info(data).get("fog_yaw_bias_rad_per_sample")
    return None if per_sample is None or t.size < 2 else float(per_sample) / (float(np.mean(np.diff(t))) / 1e9)


def _true_wheel_scale(data: Path, params: dict) -> float | None:
    """True / odometry travel of the simulated drive: the mean of the true wheel diameters
    (ground_truth/sim_info.yaml) over the mean of the calibration's (``params``), or None for
    real data."""
    true = _sim_info(data).get("wheel_diameter_true_m")
    if not true:
        return None
    return float(np.mean(true)) / (0.5 * (params["left_wheel_diameter_m"] + params["right_wheel_diameter_m"]))


def _scale_pct(v: float | None) -> str:
    return "–" if v is None else f"{100 * (v - 1):+.2f}"


def _urad(v: float | None) -> str:
    return "–" if v is None else f"{1e6 * v:.0f}"


def format_table(rows: list[dict]) -> str:
    lines = [
        "| seed | world | filter seed | drive s | particles | processes | ATE m | dead reckoning ATE m | ratio | DR, FOG bias at "
        "rest, ATE m | FOG bias est. / true µrad/s | wheel scale est. / true % | map F1 (P / R) | wall s | RTF | "
        "replay-only RTF | of ceiling | dropped |",
        "|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['seed']} | {_world_text(r)} | {r['filter_seed']} | {r['duration_s']:.0f} | {r['particles']} | {r['processes']} | {r['ate_m']:.3f} | "
            f"{r['dr_ate_m']:.3f} | {r['dr_ate_m'] / max(r['ate_m'], 1e-9):.1f}× | "
            f"{r['dr_rest_bias_ate_m']:.3f} | {_urad(r['gyro_bias_rad_s'])} / {_urad(r['true_gyro_bias_rad_s'])} | "
            f"{_scale_pct(r.get('wheel_scale'))} / {_scale_pct(r.get('true_wheel_scale'))} | "
            f"{r['map_f1']:.3f} "
            f"({r['map_precision']:.2f} / {r['map_recall']:.2f}) | {r['wall_s']:.1f} | {r['rtf']:.1f}× | "
            f"{r['ceiling_rtf']:.1f}× | {100 * r['ratio_to_ceiling']:.0f} % | {r['dropped']} |"
        )
    return "\n".join(lines)


def main(
    out_dir: str,
    seeds=(0,),
    duration_s: float = 300.0,
    processes: str = "single",
    particles: int | None = None,
    filter_seeds: tuple[int, ...] = (0,),
    images: bool = True,
    worlds: tuple[int | None, ...] = (None,),
) -> str:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = bench(out, seeds, duration_s, processes, particles, filter_seeds=filter_seeds, images=images, worlds=worlds)
    table = format_table(rows) + "\n\n" + targets_line(rows)
    if images:
        table += (
            "\n\nStereo pairs through the texture node (1 Hz, `--rate max`: the replay paces on it), "
            "colour error (the map frame as it is, and aligned onto the truth as the ATE aligns the trajectory) / "
            "coverage vs the simulator's floor, the median move of the pairs when the final texture is placed on "
            "the loop closure's corrected trajectory (from where they were last placed: live, at each closed loop), "
            "texture ms per pair by stage:\n\n" + format_texture_table(rows)
        )
    if any(r.get("world") is not None for r in rows):
        table += "\n\nWorlds (`pf-slam simulate --world N`, not tuned on):\n\n" + _world_layouts(rows)
    if processes == "single":
        table += (
            "\n\nTime per scan by stage (ms; with images, the texture worker's share of the CPU shows "
            "in messaging):\n\n" + stage_table(rows, ("seed", "world", "filter_seed", "particles"))
        )
    tag = f"car_{processes}" + ("" if images else "_noimages") + ("_worlds" if worlds != (None,) else "")
    (out / f"{tag}.md").write_text(table + "\n")
    (out / f"{tag}.json").write_text(json.dumps(rows, indent=2) + "\n")
    return table
