"""Memory of the growing map against the explored area: the mapping and correlation stages
(ROS-free, the graph's own objects) fed a simulated floor bag's scans at its true poses.

    .venv/bin/python scripts/growmap_memory.py BAG GROUND_TRUTH.tum [initial_size_m]

Prints, at checkpoints along the drive: distance driven, explored bounding box (m^2, cells
ever touched), grid + occupancy + likelihood-field bytes, and the median ms per scan of
integration + patch + field update over the last stretch.
"""

import sys
import time

import numpy as np

from pf_slam_nodes.core import config as cfg
from pf_slam_nodes.core.stages import CorrectionStage, MappingStage
from pf_slam_nodes.io.bag import deserialize, read_bag


def main(bag, gt, size=40.0):
    truth = np.loadtxt(gt)
    scans = [deserialize(raw, mt) for _, mt, _, raw in read_bag(bag, topics=["/scan"])]
    f, c, r = cfg.FilterConfig(), cfg.CorrelationConfig(), cfg.ResampleConfig()
    g = cfg.GridConfig(size_x_m=size, size_y_m=size)
    mapper, corr = MappingStage(f, g), CorrectionStage(f, g, c, r)
    marks = set(np.linspace(len(scans) // 8, len(scans) - 1, 6).astype(int))
    times, dist = [], 0.0
    print("| driven m | explored box m^2 | grid+occ MB | field MB | total MB | MB per 1000 m^2 | ms/scan |")
    print("|---|---|---|---|---|---|---|")
    for k, m in enumerate(scans):
        pose = truth[k, [1, 2]].tolist() + [2 * np.arctan2(truth[k, 6], truth[k, 7])]
        if k:
            dist += float(np.hypot(*(truth[k, 1:3] - truth[k - 1, 1:3])))
        ranges = np.asarray(m.ranges, dtype=np.float64)
        ang = m.angle_min + m.angle_increment * np.arange(ranges.size)
        corr.pose = np.asarray(pose)
        t0 = time.perf_counter()
        corr.apply_patch(mapper.integrate(np.asarray(pose), ranges, ang, m.range_min, m.range_max))
        times.append(time.perf_counter() - t0)
        if k in marks:
            gr, fl = mapper.grid, corr.field
            r0, r1, c0, c1 = gr.touched_bounds
            box = (r1 - r0) * (c1 - c0) * gr.resolution**2
            gm = (gr.log_odds.nbytes + mapper._occ.nbytes) / 2**20
            fm = (
                fl._dist.nbytes
                + fl._loglik.nbytes
                + fl._prob.nbytes
                + fl.obstacles.nbytes
                + (0 if corr.known is None else corr.known.nbytes)
            ) / 2**20
            print(
                f"| {dist:.0f} | {box:.0f} | {gm:.0f} | {fm:.0f} | {gm + fm:.0f} | {1000 * (gm + fm) / box:.1f} "
                f"| {1e3 * np.median(times[-100:]):.2f} |"
            )


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], *(float(v) for v in sys.argv[3:]))
