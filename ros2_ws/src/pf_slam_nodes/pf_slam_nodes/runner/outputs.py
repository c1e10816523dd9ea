"""What `pf-slam run` writes: the output folder, map, trajectory, snapshots, texture, summary.json."""

from __future__ import annotations

import contextlib
import math
import resource
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..io.mapfile import write_map
from ..io.trajectory import write_tum
from ..ros.domain import RosDomain
from .common import RunPlan
from .params import _default_particles
from .recorder import _Recorder

if TYPE_CHECKING:
    from .supervise import GraphOutcome


@dataclass
class RunResult:
    summary: dict
    stamps_ns: list[int] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)


class _OutDir:
    """The run's output folder: created (with snapshots/) by the run, or a user's existing one.
    `remove_new()` undoes what a run that failed before its graph started left there: the
    topmost folder it created, or in an existing folder only the entries it added (never what
    was there before)."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.top = None
        for p in [out, *out.parents]:
            if p.exists():
                break
            self.top = p
        self.before = set(out.iterdir()) if out.is_dir() else set()
        (out / "snapshots").mkdir(parents=True, exist_ok=True)

    def remove_new(self) -> None:
        if self.top is not None:
            shutil.rmtree(self.top, ignore_errors=True)
            return
        for p in set(self.out.iterdir()) - self.before:
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                with contextlib.suppress(OSError):
                    p.unlink()


def _stage_split(nodes, wall_s: float, scans: int) -> dict[str, float]:
    """Wall ms per processed scan in each core stage of the single-process graph (the stages'
    own clocks) and the rest ("messaging": (de)serialisation, odometry parsing, executor and
    recorder). The texture node works on its own thread, in parallel: not part of this split
    (its ms per frame is in the texture summary)."""
    from ..core.stages import stage_seconds

    seconds = stage_seconds(*[n.stage for n in nodes if hasattr(n, "stage")])[0]
    seconds["messaging"] = wall_s - sum(seconds.values())
    return {k: round(1e3 * v / max(scans, 1), 3) for k, v in seconds.items()}


def _write_outputs(out: Path, rec: _Recorder, texture: bool, texture_out) -> dict:
    """map (if one arrived), trajectory (the scans posed so far), final snapshot and texture;
    returns the summary entries they add. Also what a stopped run leaves behind."""
    from ..ros import convert

    online = (np.array(rec.stamps, dtype=np.int64) / 1e9, np.array(rec.poses).reshape(-1, 3))
    final = rec.final_trajectory() if rec.loops else None
    if final is not None:  # the loop closure's final frame; the poses as published beside it
        write_tum(out / "trajectory.tum", final[0] / 1e9, final[1])
        write_tum(out / "trajectory_online.tum", *online)
    else:
        write_tum(out / "trajectory.tum", *online)
    if rec.map_msg is None:
        return {"map": None}
    occ, res, origin = convert.msg_to_grid(rec.map_msg)
    write_map(out, occ, res, origin)
    rec.snapshot("final.png", wait=True)
    return {"texture": _write_texture(out, rec, texture_out, occ, res, origin)} if texture else {}


def _write_texture(out: Path, rec: _Recorder, rendered, occ: np.ndarray, res: float, origin) -> dict:
    """texture.png (+ texture_overlay.png with the occupancy when the geometries agree) and the
    texture node's counters for summary.json."""
    from ..io.texture_files import write_texture_pngs
    from ..nodes.texture import image_array

    rgb = covered = None
    same_geometry = False
    if rendered is not None:  # one process: rendered here in the final /map geometry
        rgb, covered, _ = rendered
        same_geometry = True
    elif rec.texture_msg is not None:  # one process per node: the node's last texture
        rgb = np.array(image_array(rec.texture_msg))
        covered = rgb.any(axis=2)
        m = rec.texture_meta
        same_geometry = (
            m is not None
            and rgb.shape[:2] == occ.shape
            and (int(m.height), int(m.width)) == occ.shape
            and abs(m.resolution - res) < 1e-9
            and abs(m.origin.position.x - origin[0]) < 1e-6
            and abs(m.origin.position.y - origin[1]) < 1e-6
        )
    files: list[str] = []
    if rgb is not None:
        files = [p.name for p in write_texture_pngs(out, rgb, covered, occ if same_geometry else None)]
    status = dict(rec.texture_status or {})
    status.pop("final", None)
    status["files"] = files
    status["cells_coloured"] = int(np.count_nonzero(covered)) if covered is not None else 0
    return status


def odom_scale_line(sc: dict) -> str:
    """The run's closing line on the odometry's translation scale (summary.json ``odom_scale``,
    ``correlation.odom_scale``): true / odometry travel as the scan pairs measured it."""
    if not sc["pairs"]:
        return "odometry scale: no scan pair measured it (nothing along the way to measure travel by); 1 applied"
    se = "" if sc["std_error"] is None else f" +- {100 * sc['std_error']:.2f} %"
    return (
        f"odometry scale: true / odometry travel {sc['measured']:.4f} ({100 * (sc['measured'] - 1):+.2f} %{se}) "
        f"from {sc['pairs']} scan pairs over {sc['travel_m']:.0f} m, {sc['scale']:.4f} applied "
        "(wheel encoders: the calibration's wheel diameters times this)"
    )


def gyro_line(g: dict) -> str:
    """The run's closing line on the gyro's yaw bias (summary.json ``gyro``, ``wheels.gyro_rest_bias``):
    what the standstills calibrated, or a warning that none did."""
    if g["rest_s"] <= 0:
        return (
            "warning: the gyro's yaw bias was never calibrated: the wheels never stood still for "
            "wheels.rest_min_s, so the heading drifts with the gyro's whole bias "
            "and only the particles' heading noise follows it (docs/car.md measures what that costs); "
            "a few seconds of standstill in the bag calibrate it"
        )
    return (
        f"gyro yaw bias: {1e6 * g['bias_rad_s']:+.1f} µrad/s ({math.degrees(g['bias_rad_s']) * 3600:+.2f} deg/h), "
        f"calibrated over {g['rest_s']:.1f} s of standstill and subtracted while moving"
    )


#: the nodes' status entries summary.json carries when a node reported them: (node, key), in order
NODE_STATUS_KEYS = (
    ("predictor", "gyro"),
    ("correlator", "odom_scale"),
    ("correlator", "localization"),
    ("correlator", "recoveries"),
    ("correlator", "laser_noise"),
    ("mapper", "loops"),
)


def build_summary(plan: RunPlan, dom: RosDomain, done: GraphOutcome, extra: dict) -> dict:
    """summary.json: the run's counts, timings, faults, inputs, profile, mount and domain;
    `extra`: what _write_outputs added."""
    bag, bag_duration_s, info, inputs = plan.bag, plan.bag_duration_s, plan.info, plan.inputs
    scans_total, per_node, processes, rate, executor = (
        plan.scans_total,
        plan.per_node,
        plan.processes,
        plan.rate,
        plan.executor,
    )
    checks, prof, mount_text, mount_notes = plan.checks, plan.prof, plan.mount_text, plan.mount_notes
    rec, result, stage_split, wall, stopped_by = done.rec, done.result, done.stage_split, done.wall, done.stopped_by
    covered_s = bag_duration_s  # a stopped run: the real-time factor of the part it processed
    if stopped_by is not None:
        covered_s = (rec.stamps[-1] - info["start_ns"]) / 1e9 if rec.stamps else 0.0
    scans_published = (rec.replay_counts or {}).get(inputs["scan"])  # None: the replay did not finish
    peak = (
        max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
        / 1024.0
    )
    summary = {
        "bag": str(bag),
        "bag_duration_s": round(bag_duration_s, 3),
        "wall_time_s": round(wall, 3),
        "real_time_factor": round(covered_s / wall, 2) if wall > 0 else None,
        "scans_in_bag": scans_total,
        "scans_published": scans_published,
        "scans_processed": len(rec.poses),
        "scans_dropped": None if scans_published is None else int(scans_published) - len(rec.poses),
        "scans_corrected": rec.updates,
        "particles": int(per_node["predictor"].get("filter.num_particles", _default_particles())),
        "processes": processes,
        "rate": rate,
        "executor": executor if processes == "single" else "single (per process)",
        "peak_rss_mb": round(peak, 1),
        "snapshots_written": rec.snapshots_written,
        "snapshots_skipped": rec.snapshots_skipped,
        "faults": {
            **(f := rec.faults()),
            "timestamps_fixed": len(checks["timestamps"]),
            "odom_sync_fallback": f.get("odom_sync_fallback", 0) + int("requested" in checks["odom_sync"]),
        },
        "odom_sync": checks["odom_sync"],
        **({"timestamps": checks["timestamps"]} if checks["timestamps"] else {}),
        **{key: v for node, key in NODE_STATUS_KEYS if (v := rec.node_status.get(node, {}).get(key))},
        "complete": stopped_by is None,
        **({} if stopped_by is None else {"stopped_by": stopped_by}),
        **extra,
    }
    if stage_split is not None:
        summary["stage_ms_per_scan"] = stage_split
    summary["inputs"] = inputs
    summary["profile"] = prof.summary()
    summary["lidar_mount"] = {"used": mount_text, "warnings": mount_notes}
    summary["ros_domain"] = dom.summary()
    if result is not None:
        summary["result_mcap"] = {"file": result.path.name, "messages": dict(result.counts)}
    return summary
