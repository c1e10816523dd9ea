"""Texture-map benchmarks: a simulated drive against its ground-truth floor, and the real pair.

    python -m pf_slam_tools.bench.texture sim DATASET_DIR --out OUT [--trajectory TUM]
    python -m pf_slam_tools.bench.texture real ../shared/data/kaist_sample --out OUT
    python -m pf_slam_tools.bench.texture {sim DATASET_DIR | real KAIST_DIR} --out OUT --sweep

``sim``: runs :class:`pf_slam_nodes.core.texture.StereoTexturer` over every stereo pair of a
dataset in the KAIST layout written by ``pf-slam simulate`` (poses: ``ground_truth/poses.csv``
interpolated at each image stamp, or a trajectory file, TUM or ``timestamp x y theta``), then
compares the texture with ``ground_truth/floor_texture.png`` on its 0.1 m grid: mean absolute
RGB error over the cells coloured, coverage of the ground the left camera saw within the range
box (``visible_ground_mask``, minus the cells the ground-truth occupancy marks occupied:
parked cars, buildings; occlusion behind them is not modelled). Writes ``texture.png`` (0.1 m,
north up, cropped to the coloured area), ``texture_overlay.png`` (the texture on the
ground-truth occupancy grid, 0.2 m; occupied red) and ``texture_sim.json``.

``real``: :func:`pf_slam_nodes.core.texture.measure_stereo_pair` on
``DIR/stereo/image_left.png`` + ``image_right.png`` with ``DIR/param``: disparity density on
the ego-lane road region (5-15 m ahead, +-1.75 m), the fitted road plane (camera height,
normal, tilt). Writes ``disparity.png`` (colour map, black = invalid, road region outlined),
``rectified_left.png`` and ``texture_real.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from pf_slam_nodes.core.texture import (
    StereoTexturer,
    TextureConfig,
    TextureMap,
    colour_error,
    interpolate_poses,
    measure_stereo_pair,
    north_up_bgr,
    overlay_occupancy,
    visible_ground_mask,
)
from pf_slam_nodes.io.calib import read_stereo_rig
from pf_slam_nodes.io.texture_files import read_floor_texture, write_texture_pngs
from pf_slam_nodes.io.trajectory import read_trajectory

__all__ = ["SWEEP", "main", "measure_real_pair", "sweep_real", "sweep_sim_bias", "texture_from_dataset"]


def _stereo_stamps(root: Path) -> list[int]:
    left = root / "stereo_images" / "stereo_left"
    right = root / "stereo_images" / "stereo_right"
    stamps = sorted(int(p.stem) for p in left.glob("*.png") if p.stem.isdigit())
    return [s for s in stamps if (right / f"{s}.png").is_file()]


def texture_from_dataset(
    dataset_dir: str | Path,
    out_dir: str | Path | None = None,
    cfg: TextureConfig | None = None,
    trajectory: str | Path | None = None,
    max_pairs: int | None = None,
    log=print,
) -> dict:
    """Texture a simulated drive; compare it with the ground-truth floor texture.

    Parameters
    ----------
    dataset_dir :
        KAIST-layout folder with ``param/``, ``stereo_images/`` and ``ground_truth/``
        (``poses.csv``, ``floor_texture.png`` + ``.yaml``, ``occupancy.pgm`` + ``.yaml``).
    out_dir :
        Where to write ``texture.png``, ``texture_overlay.png``, ``texture_sim.json``
        (nothing written when None).
    trajectory :
        Poses to use instead of ``ground_truth/poses.csv`` (TUM or ``t x y theta``).
    max_pairs :
        Process only the first pairs.

    Returns
    -------
    dict
        ``pairs``, ``pairs_textured`` (a pose was available), ``mean_abs_rgb_error``,
        ``median_abs_rgb_error``, ``coverage``, ``cells_coloured``, ``cells_visible``,
        ``marking_cells`` / ``marking_luminance`` / ``marking_luminance_truth`` (mean grey of
        the coloured cells that are white markings in the truth, in the texture and the truth),
        ``ms_per_pair`` (mean, and ``ms_per_pair_p90``), per-stage means ``ms_stages``,
        ``plane_fitted_fraction``, ``rectified_here``, ``tiles``, ``memory_mb``.
    """
    from pf_slam_nodes.io.mapfile import read_map

    root = Path(dataset_dir)
    cfg = cfg or TextureConfig()
    rig = read_stereo_rig(root / "param")
    gt_dir = root / "ground_truth"
    gt_rgb, gt_res, gt_origin = read_floor_texture(gt_dir / "floor_texture.png")
    traj = Path(trajectory) if trajectory else gt_dir / "poses.csv"
    t_s, poses = read_trajectory(traj)
    stamps = _stereo_stamps(root)
    if max_pairs is not None:
        stamps = stamps[:max_pairs]
    if not stamps:
        raise ValueError(f"{root}: no stereo pairs in stereo_images/")
    tex = StereoTexturer(rig, cfg)
    tmap = TextureMap.from_config(cfg, anchor_xy=gt_origin)
    pair_poses = interpolate_poses(t_s, poses, np.array(stamps, dtype=np.float64) / 1e9)
    times, stages, fitted, used = [], [], 0, []
    for stamp, pose in zip(stamps, pair_poses):
        if not np.all(np.isfinite(pose)):
            continue
        left = cv2.imread(str(root / "stereo_images/stereo_left" / f"{stamp}.png"), cv2.IMREAD_UNCHANGED)
        right = cv2.imread(str(root / "stereo_images/stereo_right" / f"{stamp}.png"), cv2.IMREAD_UNCHANGED)
        t0 = time.perf_counter()
        res = tex.integrate(tmap, left, right, pose)
        times.append(1e3 * (time.perf_counter() - t0))
        stages.append(res.timings_ms)
        fitted += int(res.plane_fitted)
        used.append(pose)
    rgb, cov = tmap.render(gt_origin, gt_res, gt_rgb.shape[1], gt_rgb.shape[0])
    vis = visible_ground_mask(
        np.array(used), rig, cfg, gt_res, gt_origin, gt_rgb.shape[:2], rectified_here=bool(tex.rectify)
    )
    occ, occ_res, occ_origin = read_map(gt_dir / "occupancy.yaml")
    # ground-truth occupied cells (0.2 m) on the 0.1 m texture grid: not floor the camera sees
    ys = gt_origin[1] + (np.arange(gt_rgb.shape[0]) + 0.5) * gt_res
    xs = gt_origin[0] + (np.arange(gt_rgb.shape[1]) + 0.5) * gt_res
    oj = np.clip(((ys - occ_origin[1]) / occ_res).astype(int), 0, occ.shape[0] - 1)
    oi = np.clip(((xs - occ_origin[0]) / occ_res).astype(int), 0, occ.shape[1] - 1)
    vis &= ~(occ[oj[:, None], oi[None, :]] >= 65)
    score = colour_error(rgb, cov, gt_rgb, vis)
    # white markings (ground truth brighter than 190 grey): do they come out white?
    mark = cov & (gt_rgb.astype(np.float32).mean(axis=2) > 190)
    score["marking_cells"] = int(mark.sum())
    score["marking_luminance"] = float(rgb[mark].astype(np.float32).mean()) if mark.any() else float("nan")
    score["marking_luminance_truth"] = float(gt_rgb[mark].astype(np.float32).mean()) if mark.any() else float("nan")
    out = {
        "dataset": str(root),
        "trajectory": str(traj),
        "pairs": len(stamps),
        "pairs_textured": len(used),
        **{k: (round(v, 4) if isinstance(v, float) else v) for k, v in score.items()},
        "ms_per_pair": round(float(np.mean(times)), 1) if times else None,
        "ms_per_pair_p90": round(float(np.percentile(times, 90)), 1) if times else None,
        "ms_stages": {k: round(float(np.mean([s[k] for s in stages])), 1) for k in (stages[0] if stages else {})},
        "plane_fitted_fraction": round(fitted / max(len(used), 1), 3),
        "rectified_here": tex.rectify,
        "tiles": len(tmap.tiles),
        "memory_mb": round(tmap.memory_bytes / 2**20, 1),
    }
    if out_dir is not None:
        o = Path(out_dir)
        o.mkdir(parents=True, exist_ok=True)
        rows, cols = np.nonzero(cov)
        if rows.size:
            r0, r1 = max(rows.min() - 20, 0), min(rows.max() + 21, cov.shape[0])
            c0, c1 = max(cols.min() - 20, 0), min(cols.max() + 21, cov.shape[1])
            write_texture_pngs(o, rgb[r0:r1, c0:c1], cov[r0:r1, c0:c1])
            gt_crop = gt_rgb[r0:r1, c0:c1].copy()
            gt_crop[~vis[r0:r1, c0:c1]] //= 3
            write_texture_pngs(o, gt_crop, np.ones(gt_crop.shape[:2], bool), name="texture_gt")
        # overlay on the ground-truth occupancy grid (its 0.2 m geometry), cropped likewise
        orgb, ocov = tmap.render(occ_origin, occ_res, occ.shape[1], occ.shape[0])
        rows, cols = np.nonzero(ocov)
        if rows.size:
            r0, r1 = max(rows.min() - 50, 0), min(rows.max() + 51, occ.shape[0])
            c0, c1 = max(cols.min() - 50, 0), min(cols.max() + 51, occ.shape[1])
            over = overlay_occupancy(orgb[r0:r1, c0:c1], ocov[r0:r1, c0:c1], occ[r0:r1, c0:c1])
            cv2.imwrite(str(o / "texture_overlay.png"), north_up_bgr(over))
        (o / "texture_sim.json").write_text(json.dumps(out, indent=2) + "\n")
    log(json.dumps(out, indent=2))
    return out


def measure_real_pair(
    kaist_dir: str | Path, out_dir: str | Path | None = None, cfg: TextureConfig | None = None, log=print
) -> dict:
    """Disparity density on the road region and road plane of ``DIR/stereo/image_*.png``."""
    root = Path(kaist_dir)
    cfg = cfg or TextureConfig()
    rig = read_stereo_rig(root / "param")
    left = cv2.imread(str(root / "stereo" / "image_left.png"), cv2.IMREAD_UNCHANGED)
    right = cv2.imread(str(root / "stereo" / "image_right.png"), cv2.IMREAD_UNCHANGED)
    if left is None or right is None:
        raise ValueError(f"{root}/stereo: image_left.png / image_right.png missing")
    t0 = time.perf_counter()
    m = measure_stereo_pair(left, right, rig, cfg)
    total_ms = 1e3 * (time.perf_counter() - t0)
    out = {
        "pair": str(root / "stereo"),
        **m.as_dict(),
        "calibrated_camera_height_m": round(float(rig.t_vehicle_cam[2]), 4),
        "road_region": "5-15 m ahead of the camera, |lateral| <= 1.75 m, nominal ground",
        "road_region_pixels": int(m.road_mask.sum()),
        "ms_total_incl_rectify_check": round(total_ms, 1),
    }
    if out_dir is not None:
        o = Path(out_dir)
        o.mkdir(parents=True, exist_ok=True)
        d = m.disparity_full
        ok = np.isfinite(d)
        vis = np.zeros(d.shape, np.uint8)
        vis[ok] = np.clip(d[ok] / cfg.num_disparities * 255, 0, 255).astype(np.uint8)
        img = cv2.applyColorMap(vis, cv2.COLORMAP_JET)
        img[~ok] = 0
        contours, _ = cv2.findContours(m.road_mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(img, contours, -1, (255, 255, 255), 2)
        cv2.imwrite(str(o / "disparity.png"), img)
        tex = StereoTexturer(rig, cfg)
        tex._rectify = m.rectified_here  # same decision, no second ORB check
        from pf_slam_nodes.core.texture import debayer

        lrgb = debayer(left)
        if m.rectified_here:
            lrgb = cv2.remap(lrgb, *rig.rectify_maps("left"), cv2.INTER_LINEAR)
        cv2.imwrite(str(o / "rectified_left.png"), lrgb[..., ::-1])
        (o / "texture_real.json").write_text(json.dumps(out, indent=2) + "\n")
    log(json.dumps(out, indent=2))
    return out


#: Matching variants compared by ``--sweep`` (TextureConfig overrides).
SWEEP = (
    ("default (hh4, 2x down, no contrast filter)", {}),
    ("full resolution", {"downscale": 1}),
    ("clahe", {"prefilter": "clahe"}),
    ("equalize", {"prefilter": "equalize"}),
    ("full resolution + clahe", {"downscale": 1, "prefilter": "clahe"}),
    ("sgbm 3way", {"sgbm_mode": "3way"}),
    ("sgbm hh (8 paths)", {"sgbm_mode": "hh"}),
    ("uniqueness 10", {"uniqueness_ratio": 10}),
    ("block 5", {"block_size": 5}),
)


def sweep_real(kaist_dir: str | Path, log=print) -> list[dict]:
    """:func:`measure_real_pair` for each :data:`SWEEP` variant (no files written)."""
    rows = []
    for name, over in SWEEP:
        m = measure_real_pair(kaist_dir, None, TextureConfig.from_dict(over), log=lambda s: None)
        rows.append(
            {
                "variant": name,
                **{
                    k: m[k]
                    for k in ("road_density", "road_inlier_fraction", "camera_height_m", "tilt_deg", "disparity_ms")
                },
            }
        )
        log(
            f"{name:45s} density {m['road_density']:.3f}  within 5 cm {m['road_inlier_fraction']:.3f}"
            f"  height {m['camera_height_m']:.3f} m  tilt {m['tilt_deg']:.2f} deg"
            f"  {m['disparity_ms']:.0f} ms"
        )
    return rows


def sweep_sim_bias(dataset_dir: str | Path, pairs: int = 6, log=print) -> list[dict]:
    """Height bias of the stereo points on a simulated drive (true ground: z = 0) per
    :data:`SWEEP` variant: median height (m) of the points within 0.3 m of the ground, by
    distance ahead of the camera, over ``pairs`` pairs from the middle of the drive."""
    root = Path(dataset_dir)
    rig = read_stereo_rig(root / "param")
    stamps = _stereo_stamps(root)
    mid = max(len(stamps) // 2 - pairs // 2, 0)
    imgs = [
        (
            cv2.imread(str(root / "stereo_images/stereo_left" / f"{s}.png"), cv2.IMREAD_UNCHANGED),
            cv2.imread(str(root / "stereo_images/stereo_right" / f"{s}.png"), cv2.IMREAD_UNCHANGED),
        )
        for s in stamps[mid : mid + pairs]
    ]
    bins = ((4, 8), (8, 12), (12, 16), (16, 20))
    rows = []
    for name, over in SWEEP:
        cfg = TextureConfig.from_dict({"rectify": "no", **over})
        tex = StereoTexturer(rig, cfg)
        hs: list[list[float]] = [[] for _ in bins]
        for left, right in imgs:
            res = tex.process(left, right)
            g = tex.point_grid(res.disparity, False)
            ok = np.isfinite(g[..., 2]) & (np.abs(g[..., 2]) < 0.3)
            p = g[ok]
            ahead = p[:, 0] - rig.t_vehicle_cam[0]
            for k, (a, b) in enumerate(bins):
                sel = (ahead >= a) & (ahead < b)
                if sel.any():
                    hs[k].append(float(np.median(p[sel, 2])))
        med = [round(float(np.mean(h)), 4) if h else None for h in hs]
        rows.append({"variant": name, "median_height_m_by_range": dict(zip([f"{a}-{b} m" for a, b in bins], med))})
        log(
            f"{name:45s} median height (m) at "
            + ", ".join(f"{a}-{b} m: {m:+.4f}" for (a, b), m in zip(bins, med) if m is not None)
        )
    return rows


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="pf-slam texture", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="what", required=True)
    s = sub.add_parser("sim", help="texture a simulated drive, compare with its floor texture")
    s.add_argument("dataset", help="folder written by pf-slam simulate (with stereo images)")
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument("--trajectory", help='poses to use (TUM or "t x y theta"); default: ground_truth/poses.csv')
    s.add_argument("--max-pairs", type=int, help="only the first N pairs")
    r = sub.add_parser("real", help="disparity density and road plane of the real pair")
    r.add_argument("kaist_dir", help="folder with param/ and stereo/image_{left,right}.png")
    r.add_argument("--out", required=True, help="output folder")
    for a in (s, r):
        a.add_argument(
            "--sweep",
            action="store_true",
            help="compare the matching variants (real: density / plane; sim: height bias of the stereo points) instead",
        )
        a.add_argument(
            "--set",
            action="append",
            default=[],
            metavar="KEY=VALUE",
            help="TextureConfig field, e.g. --set downscale=1 (repeatable)",
        )
    return p


def _config(sets: Sequence[str]) -> TextureConfig:
    import dataclasses

    fields = {f.name: f for f in dataclasses.fields(TextureConfig)}
    vals = {}
    for kv in sets:
        k, _, v = kv.partition("=")
        if k not in fields:
            raise ValueError(f"unknown texture parameter {k!r}; known: {sorted(fields)}")
        default = getattr(TextureConfig(), k)
        if isinstance(default, bool):
            vals[k] = v.lower() in ("1", "true", "yes")
        elif isinstance(default, int):
            vals[k] = int(v)
        elif isinstance(default, float):
            vals[k] = float(v)
        else:
            vals[k] = v
    return TextureConfig.from_dict(vals)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg = _config(args.set)
        if args.what == "sim" and args.sweep:
            rows = sweep_sim_bias(args.dataset)
        elif args.what == "sim":
            texture_from_dataset(args.dataset, args.out, cfg, args.trajectory, args.max_pairs)
        elif args.sweep:
            rows = sweep_real(args.kaist_dir)
        else:
            measure_real_pair(args.kaist_dir, args.out, cfg)
        if args.sweep:
            Path(args.out).mkdir(parents=True, exist_ok=True)
            (Path(args.out) / f"texture_sweep_{args.what}.json").write_text(json.dumps(rows, indent=2) + "\n")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
