"""THOR humanoid logs (UCSD ECE276A / Penn ESE650 ``.mat`` layout) -> rosbag2 (``pf-slam convert thor``).

Files read (MATLAB ``.mat``, via ``scipy.io.loadmat``; scipy is imported only here and in the
simulator)
-------------------------------------------------------------------------------------------------
* LIDAR file, variable ``lidar``: one record per scan, each with the fields, in this order,
  ``t`` (UNIX s), optionally a relative-odometry field, ``pose`` (x, y, theta: absolute
  odometry, +x forward, +y left), ``res`` (0.0044 rad), ``rpy`` (IMU roll, pitch, yaw), ``scan``
  (1081 ranges, -135 .. +135 deg in 0.25 deg steps, m). The published files hold a 1xN *cell*
  array of 1x1 structs (records may have 5 or 6 fields, which a struct array cannot); a 1xN
  struct array is read as well. Fields are taken by name when the five known names are there,
  else by position (``t`` first; ``pose``, ``res``, ``rpy``, ``scan`` the last four), as the
  published loader does.
* JOINT file: ``ts`` (1xM UNIX s) and ``head_angles`` (2xM rad: row 0 neck yaw, row 1 head
  pitch); ``acc``, ``rpy``, ``gyro``, ``pos``, ``ft_l``, ``ft_r`` are not used.
* RGB / DEPTH files: variable ``RGB`` / ``DEPTH``, records with the fields ``t, width,
  imu_rpy, id, odom, head_angles, c, sz, vel, rsz, body_height, tr, bpp, name, height`` and then
  ``image`` (1080x1920x3 uint8) / ``depth`` (424x512, mm); both stored mirrored left-right.

``read_*`` load a file; ``*_from_mat`` take what ``loadmat`` returned (any of ``squeeze_me`` /
``struct_as_record`` / ``simplify_cells``), so callers holding the data need not re-read it.
A missing file, variable or field, or a field of the wrong shape raises ``ValueError`` naming
the file, the variable, the record and the field.

Topics and frames written: see ``docs/thor.md`` (the THOR bag contract).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.geometry import matrix_to_quat, rpy_to_quat
from .bag import TYPESTORE, BagWriter, camera_info, image, laser_scan, make_header, odometry, open_writer, tf_static
from .convert import TOPIC_ODOM, TOPIC_SCAN, TOPIC_TF_STATIC, ConvertReport

__all__ = [
    "ANGLE_INCREMENT_RAD",
    "ANGLE_MIN_RAD",
    "DEPTH_K",
    "DEPTH_SIZE",
    "DEPTH_TO_RGB_R",
    "DEPTH_TO_RGB_T_M",
    "KINECT_FIELDS",
    "N_BEAMS",
    "RGB_K",
    "RGB_SIZE",
    "ThorJoint",
    "ThorKinect",
    "ThorLidar",
    "convert_thor",
    "head_rotation",
    "joint_from_mat",
    "kinect_from_mat",
    "lidar_from_mat",
    "read_joint",
    "read_kinect",
    "read_lidar",
    "static_transforms",
]

# --------------------------------------------------------------------------------------------
# the robot (THOR contract, docs/thor.md)

COM_HEIGHT_M = 0.93  #: centre of mass above the ground (base_link is on the ground)
HEAD_ABOVE_COM_M = 0.33  #: head joint above the centre of mass
LIDAR_ABOVE_HEAD_M = 0.15
KINECT_ABOVE_HEAD_M = 0.07
HEAD_HEIGHT_M = COM_HEIGHT_M + HEAD_ABOVE_COM_M  #: base_link -> head translation z

N_BEAMS = 1081
ANGLE_MIN_RAD = math.radians(-135.0)
ANGLE_INCREMENT_RAD = math.radians(0.25)
RANGE_MIN_M = 0.1
RANGE_MAX_M = 30.0
SCAN_TIME_S = 0.025  #: Hokuyo UTM-30LX: 40 Hz

#: Kinect v2 image sizes (height, width) and intrinsics (fx, fy, cx, cy) of the un-mirrored images
RGB_SIZE = (1080, 1920)
DEPTH_SIZE = (424, 512)
RGB_K = (1049.33, 1051.32, 956.91, 533.45)
DEPTH_K = (364.457, 364.543, 258.422, 202.487)
DEPTH_VALID_MM = (400, 4500)

#: P_rgb = R * P_depth + T. Only R's first row is published (0.99997, 0.00590, 0.00530): R is the
#: rotation exp([w]x) with w = (0, 0.00530, -0.00590) rad (no rotation about x assumed), whose
#: first row matches it to 1e-5.
DEPTH_TO_RGB_W = (0.0, 0.00530, -0.00590)
DEPTH_TO_RGB_T_M = (0.05227, 0.00152, -0.00061)

BASE_FRAME, ODOM_FRAME, HEAD_FRAME, LIDAR_FRAME = "base_link", "odom", "head", "lidar"
KINECT_FRAME, RGB_OPTICAL_FRAME, DEPTH_OPTICAL_FRAME = "kinect", "kinect_rgb_optical", "kinect_depth_optical"
JOINT_NAMES = ("neck", "head")

TOPIC_TF = "/tf"
TOPIC_JOINTS = "/joint_states"
TOPIC_RGB, TOPIC_RGB_INFO = "/kinect/rgb/image_raw", "/kinect/rgb/camera_info"
TOPIC_DEPTH, TOPIC_DEPTH_INFO = "/kinect/depth/image_raw", "/kinect/depth/camera_info"

LIDAR_FIELDS = ("t", "pose", "res", "rpy", "scan")
KINECT_FIELDS = (
    "t",
    "width",
    "imu_rpy",
    "id",
    "odom",
    "head_angles",
    "c",
    "sz",
    "vel",
    "rsz",
    "body_height",
    "tr",
    "bpp",
    "name",
    "height",
)  # then 'image' / 'depth'

# stream order at equal stamps: joints (the head) and odometry before the scan they belong to
_PRIO_JOINT, _PRIO_ODOM, _PRIO_DEPTH, _PRIO_RGB = range(4)


def _rodrigues(w: tuple[float, float, float]) -> np.ndarray:
    w = np.asarray(w, dtype=np.float64)
    th = float(np.linalg.norm(w))
    if th == 0.0:
        return np.eye(3)
    k = w / th
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(th) * kx + (1.0 - math.cos(th)) * kx @ kx


DEPTH_TO_RGB_R = _rodrigues(DEPTH_TO_RGB_W)
#: kinect (x forward, y left, z up) -> optical (z forward, x right, y down): columns = optical axes
OPTICAL_R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def head_rotation(neck_yaw: np.ndarray | float, head_pitch: np.ndarray | float) -> np.ndarray:
    """``Rz(neck_yaw) @ Ry(head_pitch)``: ``(..., 3, 3)``; positive pitch tilts the nose down."""
    y = np.asarray(neck_yaw, dtype=np.float64)
    p = np.asarray(head_pitch, dtype=np.float64)
    cy, sy, cp, sp = np.cos(y), np.sin(y), np.cos(p), np.sin(p)
    z = np.zeros_like(cy + cp)
    return np.stack(
        [
            np.stack([cy * cp, -sy + z, cy * sp], -1),
            np.stack([sy * cp, cy + z, sy * sp], -1),
            np.stack([-sp + z, z, cp + z], -1),
        ],
        -2,
    )


def static_transforms() -> list[tuple[str, str, tuple, tuple]]:
    """``/tf_static`` of the contract: ``(parent, child, (x, y, z), (qx, qy, qz, qw))``."""
    ident = (0.0, 0.0, 0.0, 1.0)
    return [
        (HEAD_FRAME, LIDAR_FRAME, (0.0, 0.0, LIDAR_ABOVE_HEAD_M), ident),
        (HEAD_FRAME, KINECT_FRAME, (0.0, 0.0, KINECT_ABOVE_HEAD_M), ident),
        (KINECT_FRAME, RGB_OPTICAL_FRAME, (0.0, 0.0, 0.0), matrix_to_quat(OPTICAL_R)),
        (
            RGB_OPTICAL_FRAME,
            DEPTH_OPTICAL_FRAME,
            tuple(float(v) for v in DEPTH_TO_RGB_T_M),
            matrix_to_quat(DEPTH_TO_RGB_R),
        ),
    ]


# --------------------------------------------------------------------------------------------
# .mat structure access, whatever loadmat options were used


def loadmat(path: str | os.PathLike, **kwargs: Any) -> dict:
    """``scipy.io.loadmat`` with a one-line ``ValueError`` naming the file on failure."""
    try:
        import scipy.io
    except ModuleNotFoundError as exc:  # pragma: no cover - scipy is in requirements.in
        raise ValueError(f"{path}: reading .mat files needs scipy (pip install scipy)") from exc
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{p}: no such file")
    try:
        return scipy.io.loadmat(str(p), **kwargs)
    except Exception as exc:  # scipy raises ValueError, TypeError, MatReadError, OSError...
        raise ValueError(f"{p}: cannot read as a MATLAB .mat file: {type(exc).__name__}: {exc}") from exc


def _is_struct(x: Any) -> bool:
    return (
        isinstance(x, dict)
        or hasattr(x, "_fieldnames")
        or (isinstance(x, (np.ndarray, np.void)) and x.dtype.names is not None)
    )


def _records(obj: Any, where: str) -> list:
    """The struct records of a cell array of structs, a struct array or a single struct, flat,
    in MATLAB column-major order for 2-D arrays (1xN and Nx1 alike)."""
    if isinstance(obj, dict) or hasattr(obj, "_fieldnames") or isinstance(obj, np.void):
        return [obj]
    if isinstance(obj, (list, tuple)):
        out = []
        for i, o in enumerate(obj):
            out += _records(o, f"{where}[{i}]")
        return out
    if isinstance(obj, np.ndarray):
        if obj.dtype.names is not None:
            return list(obj.ravel(order="F"))
        if obj.dtype == object:
            out = []
            for i, o in enumerate(obj.ravel(order="F")):
                out += _records(o, f"{where}{{{i}}}")
            return out
    raise ValueError(
        f"{where}: expected a struct or a cell array of structs, got "
        f"{type(obj).__name__} {getattr(obj, 'dtype', '')} {getattr(obj, 'shape', '')}".rstrip()
    )


def _fields(rec: Any) -> tuple[list[str], list]:
    """``(names, values)`` of one struct record, in the file's field order."""
    if isinstance(rec, dict):
        return list(rec), list(rec.values())
    if hasattr(rec, "_fieldnames"):
        names = list(rec._fieldnames)
        return names, [getattr(rec, n) for n in names]
    if isinstance(rec, np.ndarray) and rec.dtype.names is not None:  # 0-d or 1x1 struct
        if rec.size != 1:
            raise ValueError(f"a struct array of {rec.size} inside a record")
        rec = rec.ravel()[0]
    names = list(rec.dtype.names)
    return names, [rec[i] for i in range(len(names))]


def _unwrap(v: Any) -> Any:
    """Strip 1x1 object (cell) wrappers."""
    while isinstance(v, np.ndarray) and v.dtype == object and v.size == 1:
        v = v.ravel()[0]
    return v


def _numeric(v: Any, where: str, n: int | None = None, dtype: Any = np.float64) -> np.ndarray:
    """A numeric field as a flat array (of ``n`` values if given)."""
    v = _unwrap(v)
    try:
        a = np.asarray(v)
        if a.dtype.kind not in "biuf":
            raise TypeError
        a = a.astype(dtype, copy=False).ravel(order="F")
    except (TypeError, ValueError):
        raise ValueError(
            f"{where}: expected numbers, got {type(v).__name__} {getattr(v, 'dtype', '')}".rstrip()
        ) from None
    if n is not None and a.size != n:
        raise ValueError(f"{where}: expected {n} values, got shape {np.shape(v)}")
    return a


def _variable(data: dict, name: str, where: str) -> Any:
    if name not in data:
        found = ", ".join(k for k in data if not k.startswith("__")) or "none"
        raise ValueError(f"{where}: no variable {name!r} (variables: {found})")
    return data[name]


# --------------------------------------------------------------------------------------------
# lidar


@dataclass
class ThorLidar:
    """The scans of a LIDAR file: ``t`` (N,) UNIX s; ``pose`` (N, 3) x, y, theta; ``res`` (N,);
    ``rpy`` (N, 3); ``scan`` (N, 1081) float32 m (as stored); ``n_fields``: 5 or 6 (per file, the
    most common); ``source``: the path."""

    t: np.ndarray
    pose: np.ndarray
    res: np.ndarray
    rpy: np.ndarray
    scan: np.ndarray
    n_fields: int = 5
    source: str = ""


def lidar_from_mat(data: dict, source: str = "lidar.mat", var: str = "lidar") -> ThorLidar:
    """The ``lidar`` variable of a loaded LIDAR file (see the module doc)."""
    recs = _records(_variable(data, var, source), f"{source}: {var}")
    if not recs:
        raise ValueError(f"{source}: {var}: no records")
    n = len(recs)
    t = np.empty(n)
    pose, rpy = np.empty((n, 3)), np.empty((n, 3))
    res = np.empty(n)
    scan = np.empty((n, N_BEAMS), dtype=np.float32)
    counts: dict[int, int] = {}
    for i, rec in enumerate(recs):
        where = f"{source}: {var} record {i}"
        names, vals = _fields(rec)
        counts[len(names)] = counts.get(len(names), 0) + 1
        if all(f in names for f in LIDAR_FIELDS):
            got = {f: vals[names.index(f)] for f in LIDAR_FIELDS}
        elif len(names) in (5, 6):
            got = {"t": vals[0], "pose": vals[-4], "res": vals[-3], "rpy": vals[-2], "scan": vals[-1]}
        else:
            missing = [f for f in LIDAR_FIELDS if f not in names]
            raise ValueError(
                f"{where}: {len(names)} fields ({', '.join(names)}), expected t, [odometry,] "
                f"pose, res, rpy, scan: missing field {missing[0]!r}"
            )
        t[i] = _numeric(got["t"], f"{where} field t", 1)[0]
        pose[i] = _numeric(got["pose"], f"{where} field pose", 3)
        res[i] = _numeric(got["res"], f"{where} field res", 1)[0]
        rpy[i] = _numeric(got["rpy"], f"{where} field rpy", 3)
        scan[i] = _numeric(got["scan"], f"{where} field scan (-135..135 deg in 0.25 deg)", N_BEAMS, np.float32)
    return ThorLidar(
        t=t, pose=pose, res=res, rpy=rpy, scan=scan, n_fields=max(counts, key=lambda k: counts[k]), source=source
    )


def read_lidar(path: str | os.PathLike) -> ThorLidar:
    """Read a THOR LIDAR ``.mat`` file."""
    return lidar_from_mat(loadmat(path), str(path))


# --------------------------------------------------------------------------------------------
# joints


@dataclass
class ThorJoint:
    """``ts`` (M,) UNIX s; ``neck`` (M,) neck yaw, ``head`` (M,) head pitch (rad)."""

    ts: np.ndarray
    neck: np.ndarray
    head: np.ndarray
    source: str = ""


def joint_from_mat(data: dict, source: str = "joint.mat") -> ThorJoint:
    """``ts`` and ``head_angles`` of a loaded JOINT file."""
    if _is_struct(data.get("joint")) and "ts" not in data:  # the variables wrapped in one struct
        names, vals = _fields(_records(data["joint"], f"{source}: joint")[0])
        data = dict(zip(names, vals))
    ts = _numeric(_variable(data, "ts", source), f"{source}: ts")
    ha = np.asarray(_unwrap(_variable(data, "head_angles", source)))
    if ha.dtype.kind not in "biuf":
        raise ValueError(f"{source}: head_angles: expected numbers, got {ha.dtype}")
    m = ts.size
    if ha.ndim == 2 and ha.shape == (2, m):
        neck, head = ha[0], ha[1]
    elif ha.ndim == 2 and ha.shape == (m, 2):
        neck, head = ha[:, 0], ha[:, 1]
    elif ha.ndim == 1 and m == 1 and ha.size == 2:  # squeeze_me with one sample
        neck, head = ha[:1], ha[1:]
    else:
        raise ValueError(
            f"{source}: head_angles: expected 2x{m} (neck yaw, head pitch; ts has {m} samples), got shape {ha.shape}"
        )
    if m == 0:
        raise ValueError(f"{source}: ts: no samples")
    return ThorJoint(
        ts=ts, neck=np.asarray(neck, dtype=np.float64), head=np.asarray(head, dtype=np.float64), source=source
    )


def read_joint(path: str | os.PathLike) -> ThorJoint:
    """Read a THOR JOINT ``.mat`` file."""
    return joint_from_mat(loadmat(path), str(path))


# --------------------------------------------------------------------------------------------
# kinect


@dataclass
class ThorKinect:
    """Frames of an RGB or DEPTH file: ``t`` (K,) UNIX s; ``images``: list of arrays as stored
    (mirrored): RGB ``(1080, 1920, 3)`` uint8, depth ``(424, 512)`` (mm)."""

    kind: str
    t: np.ndarray
    images: list
    source: str = ""


def kinect_from_mat(data: dict, kind: str, source: str = "") -> ThorKinect:
    """The ``RGB`` (kind ``'rgb'``) or ``DEPTH`` (``'depth'``) variable of a loaded file."""
    if kind not in ("rgb", "depth"):
        raise ValueError(f"kind must be 'rgb' or 'depth', got {kind!r}")
    var, img_field = ("RGB", "image") if kind == "rgb" else ("DEPTH", "depth")
    source = source or f"{kind}.mat"
    recs = _records(_variable(data, var, source), f"{source}: {var}")
    t, images = np.empty(len(recs)), []
    want = (*RGB_SIZE, 3) if kind == "rgb" else DEPTH_SIZE
    for i, rec in enumerate(recs):
        where = f"{source}: {var} record {i}"
        names, vals = _fields(rec)
        if "t" in names and img_field in names:
            tv, img = vals[names.index("t")], vals[names.index(img_field)]
        elif len(names) == len(KINECT_FIELDS) + 1:
            tv, img = vals[0], vals[-1]
        else:
            miss = "t" if "t" not in names else img_field
            raise ValueError(
                f"{where}: no field {miss!r} ({len(names)} fields: {', '.join(names)}; expected "
                f"{len(KINECT_FIELDS) + 1}, {img_field} last)"
            )
        t[i] = _numeric(tv, f"{where} field t", 1)[0]
        a = np.asarray(_unwrap(img))
        if a.shape != want or a.dtype.kind not in "biuf":
            raise ValueError(
                f"{where} field {img_field}: expected {'x'.join(map(str, want))} numbers, "
                f"got {a.dtype} {'x'.join(map(str, a.shape))}"
            )
        if kind == "rgb" and a.dtype != np.uint8:
            a = np.clip(a, 0, 255).astype(np.uint8)
        images.append(a)
    return ThorKinect(kind=kind, t=t, images=images, source=source)


def read_kinect(path: str | os.PathLike, kind: str) -> ThorKinect:
    """Read a THOR RGB (``kind='rgb'``) or DEPTH (``'depth'``) ``.mat`` file."""
    return kinect_from_mat(loadmat(path), kind, str(path))


def depth_mm(stored: np.ndarray) -> np.ndarray:
    """Un-mirrored uint16 depth (mm) with 0 outside the valid 400..4500 mm."""
    d = np.asarray(stored)[:, ::-1].astype(np.float64)
    d = np.where(np.isfinite(d) & (d >= DEPTH_VALID_MM[0]) & (d <= DEPTH_VALID_MM[1]), np.rint(d), 0.0)
    return np.ascontiguousarray(d.astype(np.uint16))


def _image16(stamp_ns: int, frame_id: str, pixels: np.ndarray) -> Any:
    """``sensor_msgs/Image`` ``16UC1`` (little endian) of a ``uint16`` array."""
    a = np.ascontiguousarray(pixels, dtype="<u2")
    h, w = a.shape
    return TYPESTORE.types["sensor_msgs/msg/Image"](
        header=make_header(stamp_ns, frame_id),
        height=int(h),
        width=int(w),
        encoding="16UC1",
        is_bigendian=0,
        step=int(2 * w),
        data=a.view(np.uint8).reshape(-1),
    )


def _camera_info(stamp_ns: int, frame_id: str, k: tuple, size: tuple[int, int], scale: float = 1.0) -> Any:
    fx, fy, cx, cy = k
    if scale != 1.0:  # pixel centres: u' + 0.5 = s (u + 0.5)
        fx, fy, cx, cy = fx * scale, fy * scale, (cx + 0.5) * scale - 0.5, (cy + 0.5) * scale - 0.5
    kk = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
    return camera_info(
        stamp_ns,
        frame_id,
        size[1],
        size[0],
        "plumb_bob",
        [0.0] * 5,
        kk,
        [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
        [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    )


# --------------------------------------------------------------------------------------------
# converter


def _ns(t_s: np.ndarray) -> np.ndarray:
    """UNIX seconds -> integer ns (microsecond-rounded: float64 UNIX times carry ~0.2 us)."""
    return np.round(np.asarray(t_s, dtype=np.float64) * 1e6).astype(np.int64) * 1000


def _increasing(stamps: np.ndarray, finite: np.ndarray, what: str, report: ConvertReport) -> np.ndarray:
    """Mask of the records kept: finite values and a stamp above the last kept one's."""
    keep = np.zeros(len(stamps), dtype=bool)
    last, bad_order, first_bad = -1, 0, None
    for i, (s, ok) in enumerate(zip(stamps.tolist(), finite.tolist())):
        if not ok or s <= last or s < 0:
            if first_bad is None:
                first_bad = i
            bad_order += 1
            continue
        keep[i], last = True, s
    if bad_order:
        report.skipped[what] = bad_order
        report.warnings.append(
            f"{what}: skipped {bad_order} records (non-finite values or a time that "
            f"does not increase; first: record {first_bad})"
        )
    return keep


def convert_thor(
    lidar_path: str | os.PathLike,
    joint_path: str | os.PathLike,
    out_bag: str | os.PathLike,
    rgb_path: str | os.PathLike | None = None,
    depth_path: str | os.PathLike | None = None,
    storage: str = "mcap",
    rgb_scale: float = 1.0,
) -> ConvertReport:
    """Convert THOR LIDAR + JOINT (+ RGB + DEPTH) ``.mat`` files to a rosbag2 (``docs/thor.md``).

    ``rgb_scale`` (0 < s <= 1) shrinks the RGB images (``cv2.INTER_AREA``) and their
    ``CameraInfo`` by that factor; 1 (default) writes them at 1920x1080. Raises ``ValueError``
    on unusable input, ``BagError`` if ``out_bag`` exists.
    """
    if (rgb_path is None) != (depth_path is None):
        raise ValueError("convert thor: give both --rgb and --depth, or neither")
    if not 0.0 < rgb_scale <= 1.0:
        raise ValueError(f"rgb_scale must be in (0, 1], got {rgb_scale}")
    lid = read_lidar(lidar_path)
    jnt = read_joint(joint_path)
    rgb = read_kinect(rgb_path, "rgb") if rgb_path is not None else None
    dep = read_kinect(depth_path, "depth") if depth_path is not None else None
    report = ConvertReport(source=str(lidar_path), out_bag=str(out_bag), storage=storage)
    report.odom_sync = "exact"

    ls = _ns(lid.t)
    lkeep = _increasing(
        ls, np.isfinite(lid.t) & np.isfinite(lid.pose).all(axis=1), f"{Path(lidar_path).name}: lidar", report
    )
    js = _ns(jnt.ts)
    jkeep = _increasing(
        js,
        np.isfinite(jnt.ts) & np.isfinite(jnt.neck) & np.isfinite(jnt.head),
        f"{Path(joint_path).name}: joint",
        report,
    )
    if not lkeep.any():
        raise ValueError(f"{lidar_path}: no usable lidar record")
    if not jkeep.any():
        raise ValueError(f"{joint_path}: no usable joint sample")
    events: list[tuple[int, int, int]] = []  # (stamp ns, priority, index)
    events += [(int(s), _PRIO_JOINT, i) for i, s in enumerate(js.tolist()) if jkeep[i]]
    events += [(int(s), _PRIO_ODOM, i) for i, s in enumerate(ls.tolist()) if lkeep[i]]
    kin: dict[int, ThorKinect] = {}
    for prio, k in ((_PRIO_DEPTH, dep), (_PRIO_RGB, rgb)):
        if k is None:
            continue
        ks = _ns(k.t)
        keep = _increasing(ks, np.isfinite(k.t), f"{Path(k.source).name}: {k.kind}", report)
        events += [(int(s), prio, i) for i, s in enumerate(ks.tolist()) if keep[i]]
        kin[prio] = k
    events.sort()
    lo, hi = min(ls[lkeep].min(), js[jkeep].min()), max(ls[lkeep].max(), js[jkeep].max())
    if ls[lkeep].max() < js[jkeep].min() or js[jkeep].max() < ls[lkeep].min():
        report.warnings.append(
            f"the lidar ({ls[lkeep].min() / 1e9:.3f}..{ls[lkeep].max() / 1e9:.3f} s) and "
            f"joint ({js[jkeep].min() / 1e9:.3f}..{js[jkeep].max() / 1e9:.3f} s) times do "
            "not overlap: are they from the same run?"
        )
    # base_link -> head = Rz(neck) * Ry(pitch): roll 0, pitch, yaw
    quat = [rpy_to_quat((0.0, p, y)) for y, p in zip(jnt.neck.tolist(), jnt.head.tolist())]
    T = TYPESTORE.types
    scale_note = None
    if rgb is not None and rgb_scale != 1.0:
        import cv2

        rgb_size = (int(round(RGB_SIZE[0] * rgb_scale)), int(round(RGB_SIZE[1] * rgb_scale)))
        scale_note = f"RGB images scaled by {rgb_scale:g} to {rgb_size[1]}x{rgb_size[0]}"
        report.warnings.append(scale_note)
    else:
        rgb_size = RGB_SIZE

    with open_writer(out_bag, storage=storage) as bag:
        bag.add_connection(TOPIC_TF_STATIC, "tf2_msgs/msg/TFMessage")
        bag.add_connection(TOPIC_TF, "tf2_msgs/msg/TFMessage", latched=False)
        bag.add_connection(TOPIC_JOINTS, "sensor_msgs/msg/JointState")
        bag.add_connection(TOPIC_ODOM, "nav_msgs/msg/Odometry")
        bag.add_connection(TOPIC_SCAN, "sensor_msgs/msg/LaserScan")
        if kin:
            bag.add_connection(TOPIC_DEPTH, "sensor_msgs/msg/Image")
            bag.add_connection(TOPIC_DEPTH_INFO, "sensor_msgs/msg/CameraInfo")
            bag.add_connection(TOPIC_RGB, "sensor_msgs/msg/Image")
            bag.add_connection(TOPIC_RGB_INFO, "sensor_msgs/msg/CameraInfo")
        bag.set_custom_data("pf_slam.format", "thor")  # pf-slam run: the thor profile
        bag.set_custom_data("pf_slam.source", f"thor:{Path(lidar_path).name}")
        bag.set_custom_data("pf_slam.odom_sync", "exact")  # one /odom per /scan, same stamp
        bag.set_custom_data("pf_slam.lidar_fields", str(lid.n_fields))
        if scale_note:
            bag.set_custom_data("pf_slam.rgb_scale", repr(float(rgb_scale)))
        t0 = int(lo)
        bag.write(TOPIC_TF_STATIC, t0, tf_static(t0, static_transforms()))
        for st, prio, i in events:
            if prio == _PRIO_JOINT:
                _write_joint(bag, T, st, float(jnt.neck[i]), float(jnt.head[i]), quat[i])
            elif prio == _PRIO_ODOM:
                bag.write(TOPIC_ODOM, st, odometry(st, ODOM_FRAME, BASE_FRAME, lid.pose[i]))
                bag.write(
                    TOPIC_SCAN,
                    st,
                    laser_scan(
                        st,
                        LIDAR_FRAME,
                        ANGLE_MIN_RAD,
                        ANGLE_INCREMENT_RAD,
                        lid.scan[i],
                        RANGE_MIN_M,
                        RANGE_MAX_M,
                        scan_time=SCAN_TIME_S,
                    ),
                )
            elif prio == _PRIO_DEPTH:
                d = depth_mm(kin[prio].images[i])
                bag.write(TOPIC_DEPTH, st, _image16(st, DEPTH_OPTICAL_FRAME, d))
                bag.write(TOPIC_DEPTH_INFO, st, _camera_info(st, DEPTH_OPTICAL_FRAME, DEPTH_K, DEPTH_SIZE))
            else:
                px = np.ascontiguousarray(kin[prio].images[i][:, ::-1])
                if rgb_size != RGB_SIZE:
                    px = cv2.resize(px, (rgb_size[1], rgb_size[0]), interpolation=cv2.INTER_AREA)
                bag.write(TOPIC_RGB, st, image(st, RGB_OPTICAL_FRAME, px, "rgb8"))
                bag.write(
                    TOPIC_RGB_INFO, st, _camera_info(st, RGB_OPTICAL_FRAME, RGB_K, rgb_size, rgb_size[1] / RGB_SIZE[1])
                )
        report.counts = dict(bag.counts)
    report.start_ns, report.end_ns = t0, int(max(hi, events[-1][0]))
    return report


def _write_joint(bag: BagWriter, T: Any, st: int, neck: float, head: float, q: tuple) -> None:
    bag.write(
        TOPIC_JOINTS,
        st,
        T["sensor_msgs/msg/JointState"](
            header=make_header(st, ""),
            name=list(JOINT_NAMES),
            position=np.array([neck, head]),
            velocity=np.zeros(0),
            effort=np.zeros(0),
        ),
    )
    tr = T["geometry_msgs/msg/Transform"](
        translation=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=HEAD_HEIGHT_M),
        rotation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
    )
    bag.write(
        TOPIC_TF,
        st,
        T["tf2_msgs/msg/TFMessage"](
            transforms=[
                T["geometry_msgs/msg/TransformStamped"](
                    header=make_header(st, BASE_FRAME), child_frame_id=HEAD_FRAME, transform=tr
                )
            ]
        ),
    )
