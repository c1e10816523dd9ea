"""Occupancy maps in map_server format (``.pgm`` + ``.yaml``) and trajectory snapshots (PNG).

Map files follow nav2 ``map_saver`` in ``trinary`` mode: occupied pixels 0 (black), free 254,
unknown 205; image row 0 is the top (largest y), i.e. the ``OccupancyGrid`` (row 0 = lowest y)
flipped vertically. The YAML records ``occupied_thresh: 0.65`` and ``free_thresh: 0.196``:
these are the load thresholds that map the three pixel values back to 100 / 0 / -1 in
nav2 ``map_server`` (with 0.25, grey 205 = occupancy 0.196 would load as *free*; nav2 PR #5278
fixed its saver to write 0.196 for the same reason). The thresholds used to classify cells
when saving are ``write_map``'s ``occupied_thresh`` / ``free_thresh`` arguments
(0.65 / 0.25 by default, as nav2's saver).
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

__all__ = ["read_map", "render_snapshot", "write_map"]

PIX_OCCUPIED, PIX_FREE, PIX_UNKNOWN = 0, 254, 205
YAML_OCCUPIED_THRESH = 0.65
YAML_FREE_THRESH = 0.196


def trinary(occupancy: np.ndarray, occupied_thresh: float = 0.65, free_thresh: float = 0.25) -> np.ndarray:
    """OccupancyGrid data 0..100 / -1 -> int8 100 (occupied), 0 (free), -1 (unknown), as
    map_server's trinary mode: ``occ >= 100 * occupied_thresh`` is occupied, ``0 <= occ <=
    100 * free_thresh`` free, the rest (and -1) unknown. What /map carries and map.pgm stores."""
    if not 0.0 <= free_thresh < occupied_thresh <= 1.0:
        raise ValueError(f"need 0 <= free_thresh < occupied_thresh <= 1, got {free_thresh}, {occupied_thresh}")
    o = np.asarray(occupancy).astype(np.int16)
    out = np.full(o.shape, -1, dtype=np.int8)
    known = (o >= 0) & (o <= 100)
    out[known & (o <= round(free_thresh * 100))] = 0
    out[known & (o >= round(occupied_thresh * 100))] = 100
    return out


def write_map(
    out_dir: str | os.PathLike,
    occupancy: np.ndarray,
    resolution: float,
    origin_xy: tuple[float, float] | np.ndarray,
    name: str = "map",
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.25,
) -> Path:
    """Write ``<name>.pgm`` (P5) and ``<name>.yaml`` into ``out_dir``; returns the YAML path.

    Parameters
    ----------
    occupancy : np.ndarray
        ``(H, W)`` int8 ``OccupancyGrid`` data: -1 unknown, 0..100; row 0 = lowest y.
    resolution : float
        Cell size (m).
    origin_xy : (2,)
        World position (m) of the lower-left corner of cell ``(0, 0)``.
    occupied_thresh, free_thresh : float
        A cell with ``occ >= 100 * occupied_thresh`` is written occupied, ``0 <= occ <=
        100 * free_thresh`` free, anything else (incl. -1) unknown (nav2 ``map_saver`` rule).
    """
    occ = np.asarray(occupancy)
    if occ.ndim != 2 or occ.size == 0:
        raise ValueError(f"occupancy must be a non-empty (H, W) array, got shape {occ.shape}")
    if not resolution > 0:
        raise ValueError(f"resolution must be > 0, got {resolution}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tri = trinary(occ, occupied_thresh, free_thresh)
    img = np.full(tri.shape, PIX_UNKNOWN, dtype=np.uint8)
    img[tri == 0] = PIX_FREE
    img[tri == 100] = PIX_OCCUPIED
    img = np.ascontiguousarray(img[::-1])  # north up
    h, w = img.shape
    pgm = out / f"{name}.pgm"
    with open(pgm, "wb") as fh:
        fh.write(f"P5\n# CREATOR: pf_slam {resolution:.3f} m/pix\n{w} {h}\n255\n".encode("ascii"))
        fh.write(img.tobytes())
    ox, oy = (float(v) for v in np.asarray(origin_xy, dtype=np.float64).ravel()[:2])
    yml = out / f"{name}.yaml"
    yml.write_text(
        f"image: {pgm.name}\n"
        "mode: trinary\n"
        f"resolution: {float(resolution):.6g}\n"
        f"origin: [{ox:.6f}, {oy:.6f}, 0]\n"
        "negate: 0\n"
        f"occupied_thresh: {YAML_OCCUPIED_THRESH}\n"
        f"free_thresh: {YAML_FREE_THRESH}\n",
        encoding="utf-8",
    )
    return yml


def _parse_yaml(path: Path) -> dict[str, str]:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(
            f"{path}: cannot read the map yaml ({exc.__class__.__name__}: {getattr(exc, 'strerror', None) or exc})"
        ) from None
    out: dict[str, str] = {}
    for line in text.splitlines():
        s = line.split("#", 1)[0].strip()
        if not s or ":" not in s:
            continue
        k, v = s.split(":", 1)
        out[k.strip()] = v.strip().strip('"').strip("'")
    return out


def _read_image(path: Path, yaml_path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """The map image as grey levels 0..255 (colour: the mean of the channels, as map_server) and
    its alpha channel (None without one)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{yaml_path}: image {path}: missing or not an image")
    if img.dtype != np.uint8:
        raise ValueError(f"{yaml_path}: image {path}: expected 8 bits per channel, got {img.dtype}")
    alpha = None
    if img.ndim == 3:
        if img.shape[2] in (2, 4):
            alpha = img[..., -1]
        img = img[..., : 3 if img.shape[2] >= 3 else 1].astype(np.float64).mean(axis=2)
    return img.astype(np.float64), alpha


def read_map(yaml_path: str | os.PathLike) -> tuple[np.ndarray, float, np.ndarray]:
    """Read a map_server map (``.yaml`` + image), as nav2 ``map_server`` loads it.

    ``mode`` trinary (default), scale or raw; ``negate``; ``occupied_thresh`` / ``free_thresh``;
    ``image`` relative to the yaml or absolute. With ``p = (255 - v) / 255`` (``v / 255`` with
    negate) for a grey level ``v``: ``p > occupied_thresh`` is 100, ``p < free_thresh`` is 0, the
    rest -1 (trinary) or ``rint(100 (p - free) / (occupied - free))`` (scale); raw: ``v`` itself
    (0..100; other values -1). A transparent pixel (alpha < 255) is unknown in scale mode.

    Returns
    -------
    occupancy : np.ndarray
        ``(H, W)`` int8, -1 / 0 / 100 (trinary) or -1 / 0..100 (``scale``, ``raw``); row 0 = lowest y.
    resolution : float
        Cell size (m).
    origin : np.ndarray
        ``(3,)`` ``[x, y, yaw]`` of the lower-left corner.

    Raises ``ValueError`` naming the file and what is wrong.
    """
    yp = Path(yaml_path)
    meta = _parse_yaml(yp)
    try:
        image = yp.parent / meta["image"]
        resolution = float(meta["resolution"])
        origin = np.array([float(v) for v in meta["origin"].strip("[]").split(",")], dtype=np.float64)
        negate = int(meta.get("negate", "0"))
        occ_t = float(meta.get("occupied_thresh", YAML_OCCUPIED_THRESH))
        free_t = float(meta.get("free_thresh", YAML_FREE_THRESH))
    except (KeyError, ValueError) as exc:
        what = f"missing key {exc}" if isinstance(exc, KeyError) else str(exc)
        raise ValueError(f"{yp}: bad map yaml ({what})") from None
    if not (resolution > 0 and np.isfinite(resolution)):
        raise ValueError(f"{yp}: bad map yaml (resolution must be > 0, got {resolution})")
    if origin.size not in (2, 3) or not np.isfinite(origin).all():
        raise ValueError(f"{yp}: bad map yaml (origin must be [x, y, yaw], got {meta['origin']})")
    mode = meta.get("mode", "trinary")
    if mode not in ("trinary", "scale", "raw"):
        raise ValueError(f"{yp}: bad map yaml (mode must be trinary, scale or raw, got {mode!r})")
    if not 0.0 <= free_t < occ_t <= 1.0:
        raise ValueError(f"{yp}: bad map yaml (need 0 <= free_thresh < occupied_thresh <= 1, got {free_t}, {occ_t})")
    img, alpha = _read_image(image, yp)
    occ = np.full(img.shape, -1, dtype=np.int8)
    if mode == "raw":
        ok = img <= 100
        occ[ok] = img[ok].astype(np.int8)
        return np.ascontiguousarray(occ[::-1]), resolution, np.resize(origin, 3)
    shade = img / 255.0
    p = shade if negate else 1.0 - shade
    if mode == "scale":
        mid = (p >= free_t) & (p <= occ_t)
        occ[mid] = np.rint(100.0 * (p[mid] - free_t) / (occ_t - free_t)).astype(np.int8)
    occ[p > occ_t] = 100
    occ[p < free_t] = 0
    if mode == "scale" and alpha is not None:
        occ[alpha < 255] = -1
    return np.ascontiguousarray(occ[::-1]), resolution, np.resize(origin, 3)


def render_snapshot(
    occupancy: np.ndarray,
    resolution: float,
    origin: np.ndarray | tuple,
    trajectory_xy: np.ndarray,
    out_png: str | os.PathLike,
    pose: np.ndarray | None = None,
    scale: int = 1,
    title: str | None = None,
) -> None:
    """Save a PNG: grey map (white free, black occupied, grey unknown), path in red, pose.

    Parameters
    ----------
    occupancy : np.ndarray
        ``(H, W)`` -1 / 0..100, row 0 = lowest y (north up in the image).
    resolution, origin
        Cell size (m) and ``[x, y(, yaw)]`` of cell (0, 0)'s lower-left corner.
    trajectory_xy : np.ndarray
        ``(K, 2)`` positions (m) drawn as a red polyline.
    pose : (3,), optional
        Current ``[x, y, theta]``: a blue dot with a heading tick.
    scale : int
        Integer upscaling of the image (nearest neighbour) for small maps.
    title : str, optional
        Text drawn in the top-left corner.
    """
    occ = np.asarray(occupancy).astype(np.int16)
    grey = np.full(occ.shape, 128, dtype=np.uint8)
    known = occ >= 0
    grey[known] = (255 - np.clip(occ[known], 0, 100) * 255 // 100).astype(np.uint8)
    img = cv2.cvtColor(np.ascontiguousarray(grey[::-1]), cv2.COLOR_GRAY2BGR)
    scale = max(int(scale), 1)
    if scale > 1:
        img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    h = occ.shape[0]
    ox, oy = float(origin[0]), float(origin[1])
    shift = 4  # sub-pixel precision of cv2 drawing

    def to_px(xy: np.ndarray) -> np.ndarray:
        u = (xy[:, 0] - ox) / resolution * scale
        v = (h - (xy[:, 1] - oy) / resolution) * scale
        return np.rint(np.column_stack([u, v]) * (1 << shift)).astype(np.int32)

    traj = np.asarray(trajectory_xy, dtype=np.float64).reshape(-1, 2)
    thick = max(1, scale // 2 + 1)
    if len(traj) >= 2:
        cv2.polylines(img, [to_px(traj).reshape(-1, 1, 2)], False, (0, 0, 255), thick, cv2.LINE_AA, shift)
    if pose is not None:
        x, y, th = (float(v) for v in np.asarray(pose).ravel()[:3])
        c = to_px(np.array([[x, y]]))[0]
        tip = c + np.rint(np.array([np.cos(th), -np.sin(th)]) * 12 * (1 << shift)).astype(np.int32)
        cv2.circle(img, (int(c[0]), int(c[1])), 4 << shift, (255, 0, 0), -1, cv2.LINE_AA, shift)
        cv2.line(img, (int(c[0]), int(c[1])), (int(tip[0]), int(tip[1])), (255, 0, 0), 2, cv2.LINE_AA, shift)
    if title:
        cv2.putText(img, title, (5, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 128, 0), 1, cv2.LINE_AA)
    Path(out_png).parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out_png), img):
        raise OSError(f"{out_png}: cannot write PNG")
