"""Texture image files: the simulator's ground-truth floor texture (read) and the texture PNGs of a
run (written). The arrays are :mod:`pf_slam_nodes.core.texture`'s (``OccupancyGrid`` layout,
RGB, row 0 = lowest y); the PNGs are north up.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ..core.texture import north_up_bgr, overlay_occupancy

__all__ = ["read_floor_texture", "write_texture_pngs"]


def read_floor_texture(
    png_path: str | os.PathLike,
    yaml_path: str | os.PathLike | None = None,
) -> tuple[np.ndarray, float, np.ndarray]:
    """The simulator's ``floor_texture.png`` + ``.yaml`` -> ``(rgb, resolution, origin_xy)``.

    The PNG is north up (as ``cv2.imwrite`` wrote the RGB texture's rows reversed and its
    channels swapped); returned ``rgb`` is ``(H, W, 3)`` uint8 RGB in the ``OccupancyGrid``
    layout (row 0 = lowest y), ``origin_xy`` the world corner of cell (0, 0) (m).
    """
    png = Path(png_path)
    ym = Path(yaml_path) if yaml_path is not None else png.with_suffix(".yaml")
    img = cv2.imread(str(png), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"{png}: cannot read")
    res, origin = None, None
    for line in ym.read_text(encoding="utf-8").splitlines():
        key, _, val = line.partition(":")
        if key.strip() == "resolution":
            res = float(val)
        elif key.strip() == "origin":
            origin = np.array([float(v) for v in val.strip().strip("[]").split(",")[:2]])
    if res is None or origin is None:
        raise ValueError(f"{ym}: needs resolution and origin")
    return np.ascontiguousarray(img[::-1, :, ::-1]), res, origin


def write_texture_pngs(
    out_dir: str | os.PathLike,
    rgb: np.ndarray,
    covered: np.ndarray,
    occupancy: np.ndarray | None = None,
    name: str = "texture",
) -> list[Path]:
    """Write ``<name>.png`` (north up) and, with ``occupancy`` (same geometry),
    ``<name>_overlay.png`` into ``out_dir``; returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{name}.png"]
    cv2.imwrite(str(paths[0]), north_up_bgr(rgb))
    if occupancy is not None:
        paths.append(out / f"{name}_overlay.png")
        cv2.imwrite(str(paths[1]), north_up_bgr(overlay_occupancy(rgb, covered, occupancy)))
    return paths
