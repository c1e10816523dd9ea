"""The filter over seeds and worlds: real buildings with synthesised odometry, simulated buildings.

`pf-slam bench worlds` runs the ROS-free loop (:class:`~pf_slam_nodes.core.slam.ParticleFilterSlam`,
the graph's stages in one loop, byte-identical to the graph on the sample) with the default
indoor profile (``config/carmen_indoor.yaml``, what `pf-slam run` picks for a planar-lidar robot:
no per-world parameter) over:

* the eight **corrected-pose buildings** of ``DATA/carmen_corrected`` (real scans, GMapping-corrected
  poses): the odometry is synthesised from the corrected poses (:func:`synthesise_odometry`), and
  the trajectory is scored against the corrected poses;
* the **simulated buildings** of :mod:`pf_slam_tools.sim.worlds` (office, repetitive corridors,
  the 300 m ring), scored against their ground truth.

Per run: ATE (RMSE and max after SE(2) alignment, every scan), and relations in the manner of
Kümmerle et al. (:func:`relations_from_truth`): mean translational error and the share above
0.5 m. Per world: median and worst over the seeds. A seed ``s`` is filter seed ``s`` and
odometry (or drive) seed ``s``: every seed is another drive of the same building.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

from pf_slam_nodes.core import config as cfg
from pf_slam_nodes.core.geometry import compose
from pf_slam_nodes.core.metrics import ate, relative_se2
from pf_slam_nodes.core.slam import ParticleFilterSlam
from pf_slam_nodes.profiles import profile_file
from pf_slam_nodes.runner.params import load_params, node_params

#: the eight corrected-pose buildings (files in DATA/carmen_corrected)
BUILDINGS = ("acapulco", "belgioioso", "edmonton", "fhw", "freiburg-101", "freiburg-campus", "orebro", "seattle")
SIM_WORLDS = ("office", "corridors", "ring", "maze")

#: synthesised odometry (per run, from the odometry seed): a scale error, a heading bias, noise
ODOM_SCALE = (0.01, 0.03)  # |scale error| drawn in this range, random sign
ODOM_HEADING_BIAS_DEG_PER_M = (0.3, 1.0)  # |heading bias| drawn in this range, random sign
ODOM_SIGMA_XY_PER_M = 0.02  # translation noise std per metre of the step (m/m)
ODOM_SIGMA_XY_MIN_M = 0.005  # and per step (m)
ODOM_SIGMA_TH_PER_RAD = 0.02  # rotation noise std per radian turned (rad/rad)
ODOM_SIGMA_TH_PER_M = 0.005  # per metre travelled (rad/m)


def indoor_configs(seed: int, overrides: dict | None = None) -> tuple:
    """The configs of the default indoor profile (filter, motion, grid, correlation, resample,
    laser, loops), as `pf-slam run` gives them to the predictor, the correlator and the mapper;
    ``overrides`` a flat ``{dotted name: value}`` layer on top (experiments), ``filter.seed`` =
    ``seed``."""
    layers = [load_params(profile_file("indoor")), {"/**": {"filter.seed": int(seed), **(overrides or {})}}]
    pred, corr = node_params(layers, "predictor"), node_params(layers, "correlator")
    mapper = node_params(layers, "mapper")

    def section(cls, params, prefix):
        names = {f.name: f for f in dataclasses.fields(cls)}
        vals = {k[len(prefix) + 1 :]: v for k, v in params.items() if k.startswith(prefix + ".")}
        return cls.from_dict(
            {
                k: (float(v) if isinstance(names[k].default, float) and isinstance(v, int) else v)
                for k, v in vals.items()
            }
        )

    return (
        section(cfg.FilterConfig, corr, "filter"),
        section(cfg.OdometryMotionConfig, pred, "motion"),
        section(cfg.GridConfig, corr, "grid"),
        section(cfg.CorrelationConfig, corr, "correlation"),
        section(cfg.ResampleConfig, corr, "resample"),
        section(cfg.LaserConfig, corr, "laser"),
        section(cfg.LoopClosureConfig, mapper, "loops"),
    )


def synthesise_odometry(truth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Odometry ``(K, 3)`` from true poses ``(K, 3)``: each true increment ``(dx, dy, dth)``
    (robot frame) becomes ``(dx (1 + e) + n_x, dy (1 + e) + n_y, dth + b |t| + n_th)``, composed
    from ``truth[0]``: ``e`` a scale error (``ODOM_SCALE``), ``b`` a heading bias
    (``ODOM_HEADING_BIAS_DEG_PER_M``), ``n_x, n_y ~ N(0, ODOM_SIGMA_XY_PER_M |t| + ODOM_SIGMA_XY_MIN_M)``,
    ``n_th ~ N(0, ODOM_SIGMA_TH_PER_RAD |dth| + ODOM_SIGMA_TH_PER_M |t|)``, ``t`` the step length."""
    p = np.asarray(truth, dtype=np.float64)
    e = rng.choice([-1.0, 1.0]) * rng.uniform(*ODOM_SCALE)
    b = rng.choice([-1.0, 1.0]) * math.radians(rng.uniform(*ODOM_HEADING_BIAS_DEG_PER_M))
    d = relative_se2(p[:-1], p[1:])
    t = np.hypot(d[:, 0], d[:, 1])
    s_xy = ODOM_SIGMA_XY_PER_M * t + ODOM_SIGMA_XY_MIN_M
    s_th = ODOM_SIGMA_TH_PER_RAD * np.abs(d[:, 2]) + ODOM_SIGMA_TH_PER_M * t
    n = rng.normal(size=(len(d), 3))
    dn = np.stack(
        [d[:, 0] * (1 + e) + n[:, 0] * s_xy, d[:, 1] * (1 + e) + n[:, 1] * s_xy, d[:, 2] + b * t + n[:, 2] * s_th],
        axis=1,
    )
    out = np.empty_like(p)
    out[0] = p[0]
    for k in range(len(dn)):
        out[k + 1] = compose(out[k], dn[k])
    return out


def relations_from_truth(
    truth: np.ndarray, stride: int = 10, lags=(10, 100), revisit_m: float = 3.0, revisit_gap: int = 300
) -> np.ndarray:
    """``(R, 2)`` index pairs ``(i, j)`` for relations (Kümmerle et al.): for every ``stride``-th
    scan ``i``, ``i + lag`` for each lag (short and medium spans), and the revisit: the scan
    nearest to ``i`` among those ``revisit_gap`` or more scans later, if within ``revisit_m``."""
    k = len(truth)
    pairs = []
    xy = truth[:, :2]
    for i in range(0, k, stride):
        pairs += [(i, i + lag) for lag in lags if i + lag < k]
        if i + revisit_gap < k:
            d = np.hypot(*(xy[i + revisit_gap :] - xy[i]).T)
            j = int(np.argmin(d))
            if d[j] <= revisit_m:
                pairs.append((i, i + revisit_gap + j))
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def score(est: np.ndarray, truth: np.ndarray) -> dict:
    """ATE (aligned) and relations of a trajectory against the truth (same scans)."""
    a = ate(est, truth)
    pairs = relations_from_truth(truth)
    err = relative_se2(
        relative_se2(truth[pairs[:, 0]], truth[pairs[:, 1]]), relative_se2(est[pairs[:, 0]], est[pairs[:, 1]])
    )
    tr = np.hypot(err[:, 0], err[:, 1])
    return {
        "ate_rmse": a["rmse"],
        "ate_max": a["max"],
        "rel_mean": float(tr.mean()),
        "rel_median": float(np.median(tr)),
        "rel_over_05": float(np.mean(tr > 0.5)),
        "rel_max": float(tr.max()),
        "n_rel": int(len(pairs)),
    }


@dataclasses.dataclass
class Drive:
    """A world's scans with odometry and truth: what the filter gets and what it is scored on."""

    name: str
    truth: np.ndarray  # (K, 3)
    odom: np.ndarray  # (K, 3)
    ranges: list  # K arrays (B,)
    angles: list  # K arrays (B,)
    range_max: float


def building_drive(data_dir: Path, name: str, seed: int, _cache: dict = {}) -> Drive:  # noqa: B006 (a per-process cache on purpose)
    """Corrected-pose building ``name`` with odometry synthesised with ``seed``."""
    if name not in _cache:
        from pf_slam_nodes.io.carmen import read_carmen

        log = read_carmen(Path(data_dir) / "carmen_corrected" / f"{name}-corrected.log.gz")
        truth = np.array([s.odom_pose for s in log.scans], dtype=np.float64)
        ranges = [np.asarray(s.ranges, dtype=np.float64) for s in log.scans]
        angles = [s.angle_min + s.angle_increment * np.arange(len(s.ranges)) for s in log.scans]
        _cache[name] = (truth, ranges, angles, float(log.scans[0].range_max))
    truth, ranges, angles, rmax = _cache[name]
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7]))
    return Drive(name, truth, synthesise_odometry(truth, rng), ranges, angles, rmax)


def sim_drive(name: str, seed: int, range_sigma_m: float | None = None, laser: tuple | None = None) -> Drive:
    """Simulated world ``name`` with ``seed``; ``range_sigma_m``: the laser's range noise (m;
    None: the simulator's 0.01); ``laser``: ``(beams, fov_deg, range_max_m)`` (None: the
    simulator's 181 beams over 180 deg, 20 m)."""
    from pf_slam_tools.sim.indoor import RANGE_SIGMA_M
    from pf_slam_tools.sim.worlds import simulate_world

    d = simulate_world(name, seed, RANGE_SIGMA_M if range_sigma_m is None else range_sigma_m, laser)
    r = [row.astype(np.float64) for row in d.ranges]
    return Drive(name, d.truth, d.odom, r, [d.angles] * len(r), d.range_max)


def run_drive(drive: Drive, seed: int, overrides: dict | None = None) -> tuple[np.ndarray, dict]:
    """The drive through the ROS-free loop: ``(K, 3)`` poses (in the loop closure's final frame)
    and the run's numbers, among them ``ate_published_rmse``: the ATE of the poses as the loop
    returned them scan by scan (as /pose publishes them), before the final solve."""
    slam = ParticleFilterSlam(*indoor_configs(seed, overrides))
    t0 = time.perf_counter()
    published = np.array(
        [
            slam.process_odometry_scan(0.0, drive.odom[k], drive.ranges[k], drive.angles[k], 0.0, drive.range_max)
            for k in range(len(drive.truth))
        ]
    )
    est = slam.trajectory(np.arange(len(published), dtype=np.float64), published)  # the final frame
    wall = time.perf_counter() - t0
    lc = slam.mapper.loops
    loops = {} if lc is None else {"loops_closed": len(lc.loops), "map_renders": slam.mapper.rebuilds}
    info = {"wall_s": wall, "scans": len(est), "corrections": slam.num_updates, **loops}
    return est, {**info, "ate_published_rmse": ate(published, drive.truth)["rmse"]}


def bench(
    data_dir: Path | None,
    names,
    seeds,
    overrides: dict | None = None,
    out_dir: Path | None = None,
    log=print,
    range_sigma_m: float | None = None,
    laser: tuple | None = None,
) -> list[dict]:
    rows = []
    for name in names:
        for seed in seeds:
            sim = name in SIM_WORLDS
            drive = sim_drive(name, seed, range_sigma_m, laser) if sim else building_drive(data_dir, name, seed)
            est, info = run_drive(drive, seed, overrides)
            odo = score(drive.odom, drive.truth)
            row = {
                "world": name,
                "seed": seed,
                **info,
                **score(est, drive.truth),
                "odom_ate_rmse": odo["ate_rmse"],
                "length_m": float(np.hypot(*np.diff(drive.truth[:, :2], axis=0).T).sum()),
            }
            rows.append(row)
            if out_dir is not None:
                tag = _noise_tag(range_sigma_m) + _laser_tag(laser)
                np.savetxt(Path(out_dir) / f"{name}{tag}_seed{seed}.txt", est, fmt="%.6f")
            log(
                f"{name} seed {seed}: ATE {row['ate_rmse']:.3f} m (max {row['ate_max']:.2f}), relations "
                f"{row['rel_mean']:.3f} m, {100 * row['rel_over_05']:.1f} % > 0.5 m, {row['wall_s']:.1f} s"
            )
    return rows


def format_table(rows: list[dict]) -> str:
    lines = [
        "| world | seed | scans | length m | wall s | ATE rmse (m) | ATE max (m) | ATE as published (m) | "
        "relations mean (m) | relations > 0.5 m | odometry ATE (m) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['world']} | {r['seed']} | {r['scans']} | {r['length_m']:.0f} | {r['wall_s']:.1f} | "
            f"{r['ate_rmse']:.3f} | {r['ate_max']:.2f} | {r['ate_published_rmse']:.3f} | {r['rel_mean']:.3f} | "
            f"{100 * r['rel_over_05']:.1f} % | {r['odom_ate_rmse']:.2f} |"
        )
    return "\n".join(lines)


def summary_table(rows: list[dict]) -> str:
    """Per world over its seeds: median and worst ATE and relations."""
    lines = [
        "| world | seeds | ATE median (m) | ATE worst (m) | as published: median / worst (m) | "
        "relations median (m) | relations worst (m) | worst share > 0.5 m |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name in dict.fromkeys(r["world"] for r in rows):
        rs = [r for r in rows if r["world"] == name]
        a = [r["ate_rmse"] for r in rs]
        p = [r["ate_published_rmse"] for r in rs]
        m = [r["rel_mean"] for r in rs]
        lines.append(
            f"| {name} | {len(rs)} | {np.median(a):.3f} | {max(a):.3f} | {np.median(p):.3f} / {max(p):.3f} | "
            f"{np.median(m):.3f} | {max(m):.3f} | {100 * max(r['rel_over_05'] for r in rs):.1f} % |"
        )
    return "\n".join(lines)


def _noise_tag(range_sigma_m: float | None) -> str:
    """``""`` for the simulator's own range noise, else ``"_noise30mm"`` (file and section names)."""
    return "" if range_sigma_m is None else f"_noise{1000 * range_sigma_m:g}mm"


def _laser_tag(laser: tuple | None) -> str:
    """``""`` for the simulator's own laser, else ``"_laser1081x270"`` (file and section names)."""
    return "" if laser is None else f"_laser{int(laser[0])}x{float(laser[1]):g}"


def parse_laser(text: str | None) -> tuple | None:
    """``--laser BEAMS,FOV_DEG,RANGE_M`` (e.g. ``1081,270,30``) -> ``(beams, fov_deg, range_m)``."""
    if text is None:
        return None
    from pf_slam_tools.sim.worlds import laser_geometry

    parts = text.split(",")
    try:
        if len(parts) != 3:
            raise ValueError
        laser = int(parts[0]), float(parts[1]), float(parts[2])
    except ValueError:
        raise ValueError(f"--laser must be BEAMS,FOV_DEG,RANGE_M (e.g. 1081,270,30), got {text!r}") from None
    laser_geometry(laser)  # refuses a laser that cannot be
    return laser


def check_noise(names, range_sigma_m: float | None, laser: tuple | None = None) -> None:
    """A range noise or another laser applies to the simulated worlds only: refuse it with a building."""
    if range_sigma_m is None and laser is None:
        return
    if range_sigma_m is not None and not (np.isfinite(range_sigma_m) and range_sigma_m >= 0):
        raise ValueError(f"--range-noise must be a finite number >= 0 (m), got {range_sigma_m!r}")
    real = [n for n in (names or (BUILDINGS + SIM_WORLDS)) if n not in SIM_WORLDS]
    if real:
        what = "--range-noise sets the simulated laser's noise" if laser is None else "--laser sets the simulated laser"
        raise ValueError(
            f"{what}, and {', '.join(real)}: real scans, "
            f"not simulated (use --datasets with {', '.join(SIM_WORLDS)} only)"
        )


def section(names, range_sigma_m: float | None = None, laser: tuple | None = None) -> tuple[str, str]:
    """The results section and its title for a run over ``names`` (None: every world)."""
    names = set(names or (BUILDINGS + SIM_WORLDS))
    if names <= set(SIM_WORLDS) and (range_sigma_m is not None or laser is not None):
        what = [] if range_sigma_m is None else [f"range noise {100 * range_sigma_m:g} cm"]
        if laser is not None:
            from pf_slam_tools.sim.worlds import laser_geometry

            step = math.degrees(float(np.diff(laser_geometry(laser)[0][:2])[0]))
            what.append(f"a {int(laser[0])}-beam {float(laser[1]):g} deg laser ({step:.2g} deg), {float(laser[2]):g} m")
        return (
            "worlds_sim" + _noise_tag(range_sigma_m) + _laser_tag(laser),
            "simulated buildings with ground truth, " + ", ".join(what),
        )
    if names <= set(SIM_WORLDS):
        return "worlds_sim", "simulated buildings with ground truth"
    if names <= set(BUILDINGS):
        return "worlds_buildings", "corrected-pose buildings, synthesised odometry"
    return "worlds", "corrected-pose buildings and simulated buildings"


def main(
    data_dir: str,
    out_dir: str,
    names=None,
    seeds=(0, 1, 2, 3, 4),
    sim_seeds=None,
    overrides: dict | None = None,
    range_sigma_m: float | None = None,
    laser: tuple | None = None,
) -> str:
    """Every world of ``names`` over ``seeds``; ``range_sigma_m``: the simulated worlds' range
    noise (m; None: the simulator's 0.01), ``laser``: their laser (:func:`sim_drive`); both
    refused with a building."""
    check_noise(names, range_sigma_m, laser)
    out = Path(out_dir) / "worlds"
    out.mkdir(parents=True, exist_ok=True)
    names = list(names or (BUILDINGS + SIM_WORLDS))
    rows = []
    for name in names:
        s = sim_seeds if (name in SIM_WORLDS and sim_seeds) else seeds
        rows += bench(Path(data_dir), [name], s, overrides, out, range_sigma_m=range_sigma_m, laser=laser)
    text = (
        "Median and worst over the seeds:\n\n"
        + summary_table(rows)
        + "\n\nEvery run:\n\n"
        + format_table(rows)
        + "\n\nOdometry of the corrected-pose buildings synthesised from their corrected poses per seed: "
        f"scale error {ODOM_SCALE[0]:.0%}-{ODOM_SCALE[1]:.0%}, heading bias {ODOM_HEADING_BIAS_DEG_PER_M[0]}-"
        f"{ODOM_HEADING_BIAS_DEG_PER_M[1]} deg/m (random signs), noise {ODOM_SIGMA_XY_PER_M} m/m + "
        f"{ODOM_SIGMA_XY_MIN_M} m per step, {ODOM_SIGMA_TH_PER_RAD} rad/rad + {ODOM_SIGMA_TH_PER_M} rad/m. "
        "Relations: every 10th scan to 10 and 100 scans later, and to its revisit (nearest scan 300 or more "
        "scans later within 3 m)."
    )
    part = section(names, range_sigma_m, laser)[0]
    (out / f"{part}.md").write_text(text + "\n")
    (out / f"{part}.json").write_text(json.dumps(rows, indent=2) + "\n")
    return text
