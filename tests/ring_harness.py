"""The along-track drift of the matches on the simulated ring floor's first leg (a test helper).

Each scan (true increments, one particle) is matched against the map built from the previous
matches, through the graph's own CorrectionStage and MappingStage: with perfect odometry any
summed correction is drift the matcher made itself."""

import dataclasses

import numpy as np

from pf_slam_nodes.core.geometry import compose, relative_pose
from pf_slam_nodes.core.stages import CorrectionStage, MappingStage


def along_track_drift(
    overrides: dict, steps: int = 300, noise_m: float = 0.0, angles: np.ndarray | None = None
) -> tuple[float, float]:
    """The summed along-track correction (m) and its rms per scan (m) over the first ``steps``
    scans, with the indoor profile plus ``overrides`` and ranges with Gaussian noise ``noise_m``
    (seed 0); ``angles``: the laser's beams (rad; default the simulator's 181 over 180 deg)."""
    from pf_slam_tools.bench.worlds import indoor_configs, sim_drive
    from pf_slam_tools.sim.indoor import ray_cast
    from pf_slam_tools.sim.worlds import simulate_world

    world, drive = simulate_world("ring", 0), sim_drive("ring", 0)
    truth = drive.truth[:steps]
    angles = drive.angles[0] if angles is None else np.asarray(angles, dtype=np.float64)
    ranges = ray_cast(truth, angles, world.world.segments, drive.range_max).reshape(steps, -1)
    ranges = ranges + noise_m * np.random.default_rng(0).normal(size=ranges.shape)
    filt, _, grid, corr, res = indoor_configs(0, overrides)[:5]
    filt = dataclasses.replace(filt, num_particles=1)
    correction, mapping = CorrectionStage(filt, grid, corr, res), MappingStage(filt, grid)
    est = truth[0].copy()
    correction.apply_patch(mapping.integrate(est, ranges[0], angles, 0.0, drive.range_max))
    along = []
    for k in range(1, steps):
        start = compose(est, relative_pose(truth[k - 1], truth[k]))
        est = correction.correct(start[None], np.zeros(1), ranges[k], angles, 0.0, drive.range_max).pose
        along.append(float(np.asarray(relative_pose(start, est)).reshape(3)[0]))
        correction.apply_patch(mapping.integrate(est, ranges[k], angles, 0.0, drive.range_max))
    a = np.array(along)
    return float(a.sum()), float(np.sqrt(np.mean(a**2)))
