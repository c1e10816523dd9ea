"""Calibration files of the KAIST Urban car data set (``DIR/param/``).

The rotation helpers (``rpy_to_matrix``, ``nearest_rotation``, ``matrix_to_quat``) are in
:mod:`pf_slam_nodes.core.geometry`.

Text files (``key: values`` lines; other lines ignored):

* ``Vehicle2<Sensor>.txt``: ``RPY: roll pitch yaw`` (degrees, "XYZ extrinsic", i.e.
  ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``), ``R: r11 r12 .. r33`` (row-major) and ``T: x y z``
  (m). ``R`` and ``T`` map a point from the sensor frame into the vehicle frame,
  ``p_vehicle = R @ p_sensor + T`` (checked on the real files: the stereo camera's optical
  axis, its z, is the vehicle's forward x; its x is the vehicle's -y, its y the vehicle's -z).
  That is the ``base_link -> sensor`` transform of tf (rotation ``R``, translation ``T``).
* ``EncoderParameter.txt``: ticks per revolution, wheel diameters and wheel base (m).
* ``lidar_param.txt``: FOV, start / end angle, angular resolution (deg), max range (m).
* ``stereo_param.txt``: the stereo baseline (mm in the file; returned in m).

Camera YAMLs (``left_camera.yaml``, ``right_camera.yaml``) are OpenCV ``%YAML:1.0`` files with
``!!opencv-matrix`` nodes, read with ``cv2.FileStorage``.

Every parser raises ``ValueError`` naming the file (and the key) when the file is missing or a
value is absent or malformed.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.geometry import nearest_rotation

if TYPE_CHECKING:
    from ..core.texture import StereoRig

__all__ = [
    "parse_encoder_params",
    "parse_extrinsic",
    "parse_lidar_params",
    "parse_stereo_baseline",
    "read_camera_yaml",
    "read_stereo_rig",
]

#: Largest ``|R R^T - I|`` accepted for a rotation matrix read from a file.
ORTHONORMAL_TOL = 1e-3

_NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def _key_values(path: str | os.PathLike) -> dict[str, str]:
    """``{lower-cased key: rest of line}`` of the ``key: value`` lines of a text file."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{p}: calibration file missing")
    out: dict[str, str] = {}
    with open(p, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            key, sep, rest = line.partition(":")
            if sep and key.strip():
                out.setdefault(key.strip().lower(), rest.strip())
    return out


def _numbers(
    path: str | os.PathLike,
    kv: dict[str, str],
    key: str,
    n: int | None = None,
) -> np.ndarray:
    """The leading numbers of ``kv[key]`` (a unit in parentheses after them is ignored)."""
    if key not in kv:
        raise ValueError(f'{path}: no "{key}:" line')
    vals = []
    for tok in kv[key].split():
        if not _NUMBER.match(tok):
            break
        vals.append(float(tok))
    if not vals or (n is not None and len(vals) != n):
        want = "numbers" if n is None else f"{n} numbers"
        raise ValueError(f'{path}: "{key}:" needs {want}, got {kv[key]!r}')
    arr = np.array(vals, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f'{path}: "{key}:" has a non-finite value: {kv[key]!r}')
    return arr


def _unit(kv: dict[str, str], key: str) -> str | None:
    m = re.search(r"\(([^)]*)\)", kv.get(key, ""))
    return m.group(1).strip().lower() if m else None


def parse_extrinsic(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read a ``Vehicle2<Sensor>.txt`` file.

    Returns
    -------
    R : (3, 3) float64
        Rotation, sensor frame -> vehicle frame (``p_vehicle = R @ p_sensor + T``), as written
        (row-major in the file).
    T : (3,) float64
        Sensor origin in the vehicle frame (m).
    rpy_deg : (3,) float64
        Roll, pitch, yaw (deg) as written; ``rpy_to_matrix(rpy_deg)`` agrees with ``R`` to
        the file's rounding (the caller decides what to do when it does not).

    Raises ``ValueError`` if a line is missing or ``R`` is not a rotation (``|R R^T - I|``
    above ``ORTHONORMAL_TOL`` or ``det(R) < 0``).
    """
    kv = _key_values(path)
    rpy = _numbers(path, kv, "rpy", 3)
    rot = _numbers(path, kv, "r", 9).reshape(3, 3)
    t = _numbers(path, kv, "t", 3)
    err = float(np.abs(rot @ rot.T - np.eye(3)).max())
    if err > ORTHONORMAL_TOL or np.linalg.det(rot) < 0.0:
        raise ValueError(
            f"{path}: R is not a rotation matrix (|R R^T - I| = {err:.2g}, det = {np.linalg.det(rot):.4f})"
        )
    return rot, t, rpy


def parse_encoder_params(path: str | os.PathLike) -> dict:
    """Read ``EncoderParameter.txt``.

    Returns ``{'resolution': int ticks per wheel revolution, 'left_wheel_diameter_m',
    'right_wheel_diameter_m', 'wheel_base_m': float}``; all must be > 0.
    """
    kv = _key_values(path)
    out = {
        "resolution": _numbers(path, kv, "encoder resolution", 1)[0],
        "left_wheel_diameter_m": float(_numbers(path, kv, "encoder left wheel diameter", 1)[0]),
        "right_wheel_diameter_m": float(_numbers(path, kv, "encoder right wheel diameter", 1)[0]),
        "wheel_base_m": float(_numbers(path, kv, "encoder wheel base", 1)[0]),
    }
    for key, val in out.items():
        if not val > 0:
            raise ValueError(f"{path}: {key} must be > 0, got {val}")
    if out["resolution"] != int(out["resolution"]):
        raise ValueError(f"{path}: encoder resolution must be an integer, got {out['resolution']}")
    out["resolution"] = int(out["resolution"])
    return out


def parse_lidar_params(path: str | os.PathLike) -> dict:
    """Read ``lidar_param.txt``.

    Returns ``{'fov_deg', 'start_deg', 'end_deg', 'resolution_deg', 'max_range_m'}`` (floats,
    as written: the real file says resolution 0.666, a rounding of 190 / 285 = 2/3 deg).
    """
    kv = _key_values(path)
    out = {
        "fov_deg": float(_numbers(path, kv, "fov", 1)[0]),
        "start_deg": float(_numbers(path, kv, "start angle", 1)[0]),
        "end_deg": float(_numbers(path, kv, "end angle", 1)[0]),
        "resolution_deg": float(_numbers(path, kv, "angular resolution", 1)[0]),
        "max_range_m": float(_numbers(path, kv, "max range", 1)[0]),
    }
    if not out["end_deg"] > out["start_deg"]:
        raise ValueError(f"{path}: end angle {out['end_deg']} must exceed start angle {out['start_deg']}")
    for key in ("resolution_deg", "max_range_m"):
        if not out[key] > 0:
            raise ValueError(f"{path}: {key} must be > 0, got {out[key]}")
    return out


def parse_stereo_baseline(path: str | os.PathLike) -> float:
    """Read ``stereo_param.txt``: the baseline in metres (the file says mm; a unit is honoured)."""
    kv = _key_values(path)
    key = next((k for k in kv if "baseline" in k), None)
    if key is None:
        raise ValueError(f'{path}: no "Baseline ...:" line')
    val = float(_numbers(path, kv, key, 1)[0])
    unit = _unit(kv, key) or "mm"
    scale = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}.get(unit)
    if scale is None:
        raise ValueError(f"{path}: unknown baseline unit {unit!r}")
    if not val > 0:
        raise ValueError(f"{path}: baseline must be > 0, got {val}")
    return val * scale


def read_camera_yaml(path: str | os.PathLike) -> dict:
    """Read an OpenCV camera YAML (``image_width``, ``camera_matrix``, ...).

    Returns
    -------
    dict
        ``width``, ``height`` (int px), ``K`` (3, 3), ``D`` (n,), ``R`` (3, 3), ``P`` (3, 4)
        (float64), ``distortion_model`` (str, e.g. ``'plumb_bob'``), ``camera_name`` (str,
        may be empty).
    """
    import cv2  # local: OpenCV is only needed for camera files

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{p}: calibration file missing")
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV raises SystemError on a YAML parse error
        raise ValueError(f"{p}: not an OpenCV YAML file: {exc}".splitlines()[0]) from exc
    if not fs.isOpened():
        raise ValueError(f"{p}: cannot open as an OpenCV YAML file")
    try:

        def node(name: str):  # noqa: ANN202
            n = fs.getNode(name)
            if n.empty():
                raise ValueError(f"{p}: no {name!r}")
            return n

        def mat(name: str, shape: tuple[int, ...]) -> np.ndarray:
            m = node(name).mat()
            if m is None or m.size != int(np.prod(shape)):
                raise ValueError(f"{p}: {name!r} must be a {shape} matrix")
            arr = np.asarray(m, dtype=np.float64).reshape(shape)
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{p}: {name!r} has non-finite values")
            return arr

        width, height = node("image_width").real(), node("image_height").real()
        if not (width > 0 and height > 0 and width == int(width) and height == int(height)):
            raise ValueError(f"{p}: bad image size {width} x {height}")
        d = node("distortion_coefficients").mat()
        if d is None:
            raise ValueError(f"{p}: 'distortion_coefficients' must be a matrix")
        name = fs.getNode("camera_name")
        return {
            "width": int(width),
            "height": int(height),
            "K": mat("camera_matrix", (3, 3)),
            "D": np.asarray(d, dtype=np.float64).ravel(),
            "R": mat("rectification_matrix", (3, 3)),
            "P": mat("projection_matrix", (3, 4)),
            "distortion_model": node("distortion_model").string(),
            "camera_name": "" if name.empty() else name.string(),
        }
    finally:
        fs.release()


def read_stereo_rig(param_dir: str | os.PathLike) -> StereoRig:
    """The stereo rig of the KAIST layout's ``param/``: ``left_camera.yaml``,
    ``right_camera.yaml``, ``Vehicle2Stereo.txt`` (raises ``ValueError`` naming a missing / bad
    file); the mounting rotation is made orthonormal (:func:`nearest_rotation`)."""
    from ..core.texture import StereoRig  # local: the texture core pulls in OpenCV

    d = Path(param_dir)
    left = read_camera_yaml(d / "left_camera.yaml")
    right = read_camera_yaml(d / "right_camera.yaml")
    rot, t, _ = parse_extrinsic(d / "Vehicle2Stereo.txt")
    return StereoRig(int(left["width"]), int(left["height"]), left, right, nearest_rotation(rot), t)
