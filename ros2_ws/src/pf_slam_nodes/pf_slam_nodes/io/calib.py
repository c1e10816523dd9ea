"""Calibration files of the KAIST Urban car data set (``DIR/param/``), and rotation helpers.

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

import math
import os
import re
from pathlib import Path

import numpy as np

__all__ = [
    'matrix_to_quat',
    'nearest_rotation',
    'parse_encoder_params',
    'parse_extrinsic',
    'parse_lidar_params',
    'parse_stereo_baseline',
    'read_camera_yaml',
    'rpy_to_matrix',
]

#: Largest ``|R R^T - I|`` accepted for a rotation matrix read from a file.
ORTHONORMAL_TOL = 1e-3

_NUMBER = re.compile(r'^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$')


def _key_values(path: str | os.PathLike) -> dict[str, str]:
    """``{lower-cased key: rest of line}`` of the ``key: value`` lines of a text file."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f'{p}: calibration file missing')
    out: dict[str, str] = {}
    with open(p, encoding='utf-8', errors='replace') as fh:
        for line in fh:
            key, sep, rest = line.partition(':')
            if sep and key.strip():
                out.setdefault(key.strip().lower(), rest.strip())
    return out


def _numbers(path: str | os.PathLike, kv: dict[str, str], key: str, n: int | None = None,
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
        want = 'numbers' if n is None else f'{n} numbers'
        raise ValueError(f'{path}: "{key}:" needs {want}, got {kv[key]!r}')
    arr = np.array(vals, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f'{path}: "{key}:" has a non-finite value: {kv[key]!r}')
    return arr


def _unit(kv: dict[str, str], key: str) -> str | None:
    m = re.search(r'\(([^)]*)\)', kv.get(key, ''))
    return m.group(1).strip().lower() if m else None


def rpy_to_matrix(rpy_deg: np.ndarray | list[float]) -> np.ndarray:
    """Roll, pitch, yaw (deg, "XYZ extrinsic") -> ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``, (3, 3)."""
    r, p, y = np.radians(np.asarray(rpy_deg, dtype=np.float64))
    cr, sr = math.cos(r), math.sin(r)
    cp, sp = math.cos(p), math.sin(p)
    cy, sy = math.cos(y), math.sin(y)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def nearest_rotation(rot: np.ndarray) -> np.ndarray:
    """The rotation matrix closest (Frobenius) to ``rot`` (3, 3): ``U @ V^T`` of its SVD.

    Calibration files round R to ~6 digits, so its columns are unit vectors only to ~1e-5.
    """
    u, _, vt = np.linalg.svd(np.asarray(rot, dtype=np.float64))
    if np.linalg.det(u @ vt) < 0.0:
        u[:, -1] = -u[:, -1]
    return u @ vt


def matrix_to_quat(rot: np.ndarray) -> tuple[float, float, float, float]:
    """Rotation matrix (3, 3) -> unit quaternion ``(x, y, z, w)`` with ``w >= 0``.

    Shepperd's method: the largest of ``w, x, y, z`` is taken from the diagonal (no division by
    a small number, exact for 180-degree rotations). A slightly non-orthonormal input (a
    rounded calibration file) gives the quaternion of a nearby rotation, normalised.
    """
    m = np.asarray(rot, dtype=np.float64)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise ValueError(f'rotation must be a finite (3, 3) matrix, got {m!r}')
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    cand = (tr, m[0, 0], m[1, 1], m[2, 2])
    k = int(np.argmax(cand))
    if k == 0:
        s = 2.0 * math.sqrt(max(1.0 + tr, 0.0))
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s)
    elif k == 1:
        s = 2.0 * math.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 0.0))
        q = (0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif k == 2:
        s = 2.0 * math.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 0.0))
        q = ((m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 0.0))
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s)
    qa = np.array(q, dtype=np.float64)
    norm = float(np.linalg.norm(qa))
    if not norm > 0.0:
        raise ValueError(f'not a rotation matrix: {m!r}')
    qa /= norm
    if qa[3] < 0.0:
        qa = -qa
    return float(qa[0]), float(qa[1]), float(qa[2]), float(qa[3])


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
    rpy = _numbers(path, kv, 'rpy', 3)
    rot = _numbers(path, kv, 'r', 9).reshape(3, 3)
    t = _numbers(path, kv, 't', 3)
    err = float(np.abs(rot @ rot.T - np.eye(3)).max())
    if err > ORTHONORMAL_TOL or np.linalg.det(rot) < 0.0:
        raise ValueError(f'{path}: R is not a rotation matrix (|R R^T - I| = {err:.2g}, '
                         f'det = {np.linalg.det(rot):.4f})')
    return rot, t, rpy


def parse_encoder_params(path: str | os.PathLike) -> dict:
    """Read ``EncoderParameter.txt``.

    Returns ``{'resolution': int ticks per wheel revolution, 'left_wheel_diameter_m',
    'right_wheel_diameter_m', 'wheel_base_m': float}``; all must be > 0.
    """
    kv = _key_values(path)
    out = {
        'resolution': _numbers(path, kv, 'encoder resolution', 1)[0],
        'left_wheel_diameter_m': float(_numbers(path, kv, 'encoder left wheel diameter', 1)[0]),
        'right_wheel_diameter_m': float(_numbers(path, kv, 'encoder right wheel diameter', 1)[0]),
        'wheel_base_m': float(_numbers(path, kv, 'encoder wheel base', 1)[0]),
    }
    for key, val in out.items():
        if not val > 0:
            raise ValueError(f'{path}: {key} must be > 0, got {val}')
    if out['resolution'] != int(out['resolution']):
        raise ValueError(f'{path}: encoder resolution must be an integer, got {out["resolution"]}')
    out['resolution'] = int(out['resolution'])
    return out


def parse_lidar_params(path: str | os.PathLike) -> dict:
    """Read ``lidar_param.txt``.

    Returns ``{'fov_deg', 'start_deg', 'end_deg', 'resolution_deg', 'max_range_m'}`` (floats,
    as written: the real file says resolution 0.666, a rounding of 190 / 285 = 2/3 deg).
    """
    kv = _key_values(path)
    out = {
        'fov_deg': float(_numbers(path, kv, 'fov', 1)[0]),
        'start_deg': float(_numbers(path, kv, 'start angle', 1)[0]),
        'end_deg': float(_numbers(path, kv, 'end angle', 1)[0]),
        'resolution_deg': float(_numbers(path, kv, 'angular resolution', 1)[0]),
        'max_range_m': float(_numbers(path, kv, 'max range', 1)[0]),
    }
    if not out['end_deg'] > out['start_deg']:
        raise ValueError(f'{path}: end angle {out["end_deg"]} must exceed start angle '
                         f'{out["start_deg"]}')
    for key in ('resolution_deg', 'max_range_m'):
        if not out[key] > 0:
            raise ValueError(f'{path}: {key} must be > 0, got {out[key]}')
    return out


def parse_stereo_baseline(path: str | os.PathLike) -> float:
    """Read ``stereo_param.txt``: the baseline in metres (the file says mm; a unit is honoured)."""
    kv = _key_values(path)
    key = next((k for k in kv if 'baseline' in k), None)
    if key is None:
        raise ValueError(f'{path}: no "Baseline ...:" line')
    val = float(_numbers(path, kv, key, 1)[0])
    unit = _unit(kv, key) or 'mm'
    scale = {'mm': 1e-3, 'cm': 1e-2, 'm': 1.0}.get(unit)
    if scale is None:
        raise ValueError(f'{path}: unknown baseline unit {unit!r}')
    if not val > 0:
        raise ValueError(f'{path}: baseline must be > 0, got {val}')
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
        raise ValueError(f'{p}: calibration file missing')
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV raises SystemError on a YAML parse error
        raise ValueError(f'{p}: not an OpenCV YAML file: {exc}'.splitlines()[0]) from exc
    if not fs.isOpened():
        raise ValueError(f'{p}: cannot open as an OpenCV YAML file')
    try:
        def node(name: str):  # noqa: ANN202
            n = fs.getNode(name)
            if n.empty():
                raise ValueError(f'{p}: no {name!r}')
            return n

        def mat(name: str, shape: tuple[int, ...]) -> np.ndarray:
            m = node(name).mat()
            if m is None or m.size != int(np.prod(shape)):
                raise ValueError(f'{p}: {name!r} must be a {shape} matrix')
            arr = np.asarray(m, dtype=np.float64).reshape(shape)
            if not np.all(np.isfinite(arr)):
                raise ValueError(f'{p}: {name!r} has non-finite values')
            return arr

        width, height = node('image_width').real(), node('image_height').real()
        if not (width > 0 and height > 0 and width == int(width) and height == int(height)):
            raise ValueError(f'{p}: bad image size {width} x {height}')
        d = node('distortion_coefficients').mat()
        if d is None:
            raise ValueError(f'{p}: \'distortion_coefficients\' must be a matrix')
        name = fs.getNode('camera_name')
        return {
            'width': int(width), 'height': int(height),
            'K': mat('camera_matrix', (3, 3)),
            'D': np.asarray(d, dtype=np.float64).ravel(),
            'R': mat('rectification_matrix', (3, 3)),
            'P': mat('projection_matrix', (3, 4)),
            'distortion_model': node('distortion_model').string(),
            'camera_name': '' if name.empty() else name.string(),
        }
    finally:
        fs.release()
