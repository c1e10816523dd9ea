"""The car through the full graph, against the simulator's ground truth (`pf-slam bench car`).

For each seed: simulate a drive in the KAIST layout (cached), convert it to a bag without stereo
images (cached; a cached bag with images is converted again), run, for each filter seed,
the graph with config/kaist.yaml in `--rate max`, and report the trajectory error (ATE after an
SE(2) alignment) next to dead reckoning from the same encoders + FOG, the occupied-cell F1 of the
map against the ground-truth grid, and the real-time factor with its ratio to the replay-only
ceiling of the same bag.
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
from . import stage_table

KAIST_YAML = Path(__file__).resolve().parents[2] / "config" / "kaist.yaml"


def odometry_streams(dataset_dir: str | Path) -> dict:
    """The drive's encoder and FOG CSVs and encoder parameters, read once: ``enc`` (K, 3) int64
    (stamp, left, right counts), ``fog_t`` (F,) int64 ns, ``fog_yaw`` (F,) rad, ``params``."""
    d = Path(dataset_dir)
    fog = np.loadtxt(d / "sensor_data" / "fog.csv", delimiter=",", usecols=(0, 3), ndmin=1,
                     dtype={"names": ("t", "yaw"), "formats": ("i8", "f8")})
    return {"enc": np.loadtxt(d / "sensor_data" / "encoder.csv", delimiter=",", dtype=np.int64, ndmin=2),
            "fog_t": fog["t"], "fog_yaw": fog["yaw"],
            "params": parse_encoder_params(d / "param" / "EncoderParameter.txt")}


def dead_reckoning(dataset_dir: str | Path, gyro_rest_bias: bool = False,
                   streams: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
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
    wheels = WheelOdometryIntegrator(p["left_wheel_diameter_m"], p["right_wheel_diameter_m"], p["wheel_base_m"],
                                     gyro_rest_bias=gyro_rest_bias)
    k = 2.0 * math.pi / p["resolution"]
    poses, prev = np.empty((enc.shape[0], 3)), None
    for i, (t, left, right) in enumerate(enc):
        if prev is not None:
            wheels.add_gyro(gyro.yaw_between(prev, int(t)))
        poses[i] = wheels.step(left * k, right * k, None if prev is None else (int(t) - prev) / 1e9)
        prev = int(t)
    return enc[:, 0], poses


def _ate(t_est: np.ndarray, p_est: np.ndarray, t_gt: np.ndarray, p_gt: np.ndarray) -> float:
    pairs = metrics.associate(t_est, t_gt, max_dt=0.02)
    return float(metrics.ate(p_est[pairs[:, 0]], p_gt[pairs[:, 1]])["rmse"])


def images_in(topics: dict) -> int:
    """Number of ``sensor_msgs/Image`` messages in a bag's ``bag_info()["topics"]``."""
    return sum(n for msgtype, n in topics.values() if msgtype == "sensor_msgs/msg/Image")


def _bench_bag(data: Path, bag: Path) -> Path:
    """The drive's bag, converted once without stereo images. A cached bag is reused only if it
    holds the drive's messages and no images (one that carries images also runs the texture
    node and times something else); otherwise it is converted again."""
    from pf_slam_nodes.io.bag import bag_info
    from pf_slam_nodes.io.kaist import convert_kaist

    if (bag / "metadata.yaml").is_file():
        topics = bag_info(bag)["topics"]
        images = images_in(topics)
        scans = topics.get("/scan", ("", 0))[1]
        if images == 0 and scans > 0:
            return bag
        print(f"[bench car] {bag}: cached bag holds {images} images and {scans} scans; converting again")
        shutil.rmtree(bag)
    convert_kaist(data, bag, images=False)
    return bag


def bench(out_dir: Path, seeds=(0,), duration_s: float = 300.0, processes: str = "single",
          particles: int | None = None, params_file: str | None = None,
          filter_seeds: tuple[int, ...] = (0,)) -> list[dict]:
    """One row per drive (simulator ``seeds``) and filter seed (``filter_seeds``: the filter's
    random stream, ``filter.seed``). The filter is chaotic on these drives (README), so the
    settings are judged on several of each. Dead reckoning, the ceiling and the ground truth are
    computed once per drive."""
    from pf_slam_tools.bench.ceiling import replay_ceiling
    from pf_slam_nodes.graph import run
    from pf_slam_nodes.io.mapfile import read_map
    from pf_slam_tools.sim.car import simulate_car

    rows = []
    for seed in seeds:
        data = out_dir / f"car_{int(duration_s)}s_seed{seed}"
        if not (data / "ground_truth" / "poses.csv").is_file():
            simulate_car(data, seed=seed, duration_s=duration_s, stereo_rate_hz=0.0, overwrite=True)
        bag = _bench_bag(data, out_dir / f"car_{int(duration_s)}s_seed{seed}_bag")
        ceiling = replay_ceiling(str(bag))
        t_gt, p_gt = read_trajectory(data / "ground_truth" / "poses.csv")
        streams = odometry_streams(data)
        t_dr, p_dr = dead_reckoning(data, streams=streams)
        t_dc, p_dc = dead_reckoning(data, gyro_rest_bias=True, streams=streams)
        dr_ate = _ate(t_dr / 1e9, p_dr, t_gt, p_gt)
        dr_rest_bias_ate = _ate(t_dc / 1e9, p_dc, t_gt, p_gt)
        true_bias = _true_fog_bias_rad_s(data, streams["fog_t"])
        go, gr, gorig = read_map(data / "ground_truth" / "occupancy.yaml")
        for fseed in filter_seeds:
            run_dir = out_dir / f"car_{int(duration_s)}s_seed{seed}_{processes}_filter{fseed}"
            node = {"filter.seed": int(fseed)}
            if particles:
                node["filter.num_particles"] = particles
            res = run(str(bag), run_dir, params_file=params_file or str(KAIST_YAML), processes=processes,
                      overrides={"/**": node}, progress=False, snapshot_every=0)
            write_tum(run_dir / "dead_reckoning.tum", t_dr / 1e9, p_dr)
            write_tum(run_dir / "dead_reckoning_rest_bias.tum", t_dc / 1e9, p_dc)
            t_est, p_est = read_trajectory(run_dir / "trajectory.tum")
            eo, er, eorig = read_map(run_dir / "map.yaml")
            f1 = metrics.map_f1(eo, er, eorig[:2], go, gr, gorig[:2])
            s = res.summary
            rows.append({
                "seed": seed, "filter_seed": int(fseed), "duration_s": s["bag_duration_s"],
                "processes": processes,
                "particles": s["particles"], "scans": s["scans_processed"], "dropped": s["scans_dropped"],
                "corrected": s["scans_corrected"], "ate_m": _ate(t_est, p_est, t_gt, p_gt),
                "dr_ate_m": dr_ate, "dr_rest_bias_ate_m": dr_rest_bias_ate,
                "gyro_bias_rad_s": s.get("gyro", {}).get("bias_rad_s"), "true_gyro_bias_rad_s": true_bias,
                "map_f1": f1["f1"],
                "map_precision": f1["precision"], "map_recall": f1["recall"],
                "wall_s": s["wall_time_s"], "rtf": s["real_time_factor"],
                "ceiling_rtf": ceiling["real_time_factor"],
                "ratio_to_ceiling": round(s["real_time_factor"] / ceiling["real_time_factor"], 3),
                "peak_rss_mb": s["peak_rss_mb"], "stage_ms_per_scan": s.get("stage_ms_per_scan")})
    return rows


def targets_line(rows: list[dict], ate_max_m: float = 0.5, better_by: float = 3.0, rtf_min: float = 10.0) -> str:
    """The car targets over all rows: ATE mean / worst, how many runs have ATE <= ``ate_max_m``
    and ``better_by`` x below raw dead reckoning, how many run at >= ``rtf_min`` x real time."""
    ate = np.array([r["ate_m"] for r in rows])
    ok = sum(r["ate_m"] <= ate_max_m and r["dr_ate_m"] >= better_by * r["ate_m"] for r in rows)
    fast = sum(r["rtf"] >= rtf_min for r in rows)
    return (f"{len(rows)} runs: ATE mean {ate.mean():.3f} m, median {np.median(ate):.3f} m, worst "
            f"{ate.max():.3f} m; ATE <= {ate_max_m} m and >= {better_by:g}x below raw dead reckoning in "
            f"{ok} of {len(rows)}; >= {rtf_min:g}x real time in {fast} of {len(rows)} "
            f"(RTF {min(r['rtf'] for r in rows):.1f}-{max(r['rtf'] for r in rows):.1f}x); "
            f"dropped {sum(r['dropped'] for r in rows)}")


def _true_fog_bias_rad_s(data: Path, t: np.ndarray) -> float | None:
    """The simulator's FOG yaw bias (rad/s) from ground_truth/sim_info.yaml and the FOG's stamps
    ``t`` (ns; the bias is per sample), or None for real data."""
    info = data / "ground_truth" / "sim_info.yaml"
    if not info.is_file():
        return None
    import yaml
    per_sample = yaml.safe_load(info.read_text()).get("fog_yaw_bias_rad_per_sample")
    return None if per_sample is None or t.size < 2 else float(per_sample) / (float(np.mean(np.diff(t))) / 1e9)


def _urad(v: float | None) -> str:
    return "–" if v is None else f"{1e6 * v:.0f}"


def format_table(rows: list[dict]) -> str:
    lines = ["| seed | filter seed | drive s | particles | processes | ATE m | dead reckoning ATE m | ratio | DR, FOG bias at "
             "rest, ATE m | FOG bias est. / true µrad/s | map F1 (P / R) | wall s | RTF | replay-only RTF | "
             "of ceiling | dropped |",
             "|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(
            f"| {r['seed']} | {r['filter_seed']} | {r['duration_s']:.0f} | {r['particles']} | {r['processes']} | {r['ate_m']:.3f} | "
            f"{r['dr_ate_m']:.3f} | {r['dr_ate_m'] / max(r['ate_m'], 1e-9):.1f}× | "
            f"{r['dr_rest_bias_ate_m']:.3f} | {_urad(r['gyro_bias_rad_s'])} / {_urad(r['true_gyro_bias_rad_s'])} | "
            f"{r['map_f1']:.3f} "
            f"({r['map_precision']:.2f} / {r['map_recall']:.2f}) | {r['wall_s']:.1f} | {r['rtf']:.1f}× | "
            f"{r['ceiling_rtf']:.1f}× | {100 * r['ratio_to_ceiling']:.0f} % | {r['dropped']} |")
    return "\n".join(lines)


def main(out_dir: str, seeds=(0,), duration_s: float = 300.0, processes: str = "single",
         particles: int | None = None, filter_seeds: tuple[int, ...] = (0,)) -> str:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = bench(out, seeds, duration_s, processes, particles, filter_seeds=filter_seeds)
    table = format_table(rows) + "\n\n" + targets_line(rows)
    if processes == "single":
        table += "\n\nTime per scan by stage (ms):\n\n" + stage_table(rows, ("seed", "filter_seed", "particles"))
    (out / f"car_{processes}.md").write_text(table + "\n")
    (out / f"car_{processes}.json").write_text(json.dumps(rows, indent=2) + "\n")
    return table
