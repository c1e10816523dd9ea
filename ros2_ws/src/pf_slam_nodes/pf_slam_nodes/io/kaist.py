"""KAIST Urban car data set (UCSD ECE276A layout) -> rosbag2 (``pf-slam convert kaist``).

Layout read (the real data set, unchanged)::

    DIR/sensor_data/encoder.csv   timestamp,left_count,right_count           100 Hz, cumulative
    DIR/sensor_data/fog.csv       timestamp,delta_roll,delta_pitch,delta_yaw   1 kHz, rad/sample
    DIR/sensor_data/lidar.csv     timestamp,r0..r285                          100 Hz, m, 0 = none
    DIR/stereo_images/stereo_left/<timestamp>.png, stereo_right/<timestamp>.png   8-bit Bayer
    DIR/param/EncoderParameter.txt, Vehicle2FOG.txt, Vehicle2Lidar.txt, Vehicle2Stereo.txt,
              lidar_param.txt, stereo_param.txt, left_camera.yaml, right_camera.yaml

Timestamps are integer nanoseconds (parsed as integers: a float64 would lose the last digits).
A CSV may start with a header row (``timestamp,...``); the real files have none.

Topics written (frames in parentheses)
--------------------------------------
* ``/encoders`` ``sensor_msgs/JointState`` (``base_link``): ``['left_wheel', 'right_wheel']``
  cumulative wheel angles (rad) = count * 2 pi / resolution. Wheel geometry goes to the bag's
  ``custom_data``: ``pf_slam.format`` (``kaist``), ``pf_slam.encoder_resolution``, ``pf_slam.left_wheel_diameter_m``,
  ``pf_slam.right_wheel_diameter_m``, ``pf_slam.wheel_base_m``.
* ``/fog`` (``fog``): ``pf_slam_interfaces/FogBatch`` of ``fog_batch`` consecutive samples
  (header stamp = the last sample's; the last batch may be shorter), or, with
  ``fog_format='vector3'``, one ``geometry_msgs/Vector3Stamped`` per sample (x, y, z = delta
  roll, pitch, yaw in rad).
* ``/scan`` ``sensor_msgs/LaserScan`` (``lidar``): ``angle_min`` = start angle,
  ``angle_increment`` = (end - start) / (beams - 1) (2/3 deg: the file's 0.666 is that value
  rounded), ``range_min`` 0, ``range_max`` = max range, 0 -> ``+inf`` (REP 117).
* ``/stereo/left/image_raw``, ``/stereo/right/image_raw`` ``sensor_msgs/Image``
  (``stereo_left`` / ``stereo_right``): the PNG's raw Bayer bytes, ``encoding`` =
  ``BAYER_ENCODING`` (``bayer_rggb8``: cv_bridge decodes it with ``COLOR_BayerBG2BGR``, which
  gives the real images their true colours), plus ``/stereo/*/camera_info``
  ``sensor_msgs/CameraInfo`` from the YAMLs at each image stamp.
* ``/tf_static`` ``tf2_msgs/TFMessage``, one message at the first record time:
  ``base_link -> lidar | fog | stereo_left`` = ``(R, T)`` of ``Vehicle2*.txt`` (R maps sensor
  vectors into the vehicle frame; the nearest exact rotation to the file's rounded R is used),
  ``base_link -> stereo_right`` = ``stereo_left`` moved by the
  baseline along the left camera's x axis (same rotation).

Time
----
Header stamps are the recorded timestamps exactly; the bag record time of every message is its
header stamp; the streams are merged in time order while writing (not re-synchronised). At
equal stamps the order is encoders, FOG, scan, images. Files are streamed row by row.

Bad input
---------
A CSV row with the wrong column count, a non-numeric or non-finite value, or a timestamp that
does not increase (repeat or step back, compared with the last kept row) is skipped, counted in
``ConvertReport.skipped`` under ``'<file>: <reason>'`` and named ``<file>:<line>`` in
``ConvertReport.warnings`` (``io.skips``: the first ``MAX_LINE_WARNINGS`` per file, then one
summary line).
An unreadable PNG (truncated, not 8-bit single-channel, wrong size) is skipped the same way
with the image and its camera_info. A missing parameter or ``sensor_data`` file raises
``ValueError`` naming the path.
"""

from __future__ import annotations

import heapq
import itertools
import math
import os
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from ..core.geometry import matrix_to_quat, nearest_rotation, rpy_to_matrix
from . import calib
from .bag import (
    TYPESTORE,
    BagWriter,
    camera_info,
    image,
    joint_state_wheels,
    laser_scan,
    make_header,
    open_writer,
    tf_static,
)
from .convert import TOPIC_ENCODERS, TOPIC_SCAN, TOPIC_TF_STATIC, ConvertReport
from .skips import SkipLog

__all__ = [
    "BAYER_ENCODING",
    "FOG_BATCH_TYPE",
    "KaistLayout",
    "convert_kaist",
    "kaist_static_transforms",
    "read_kaist_layout",
    "register_fog_batch",
]

#: ROS encoding of the KAIST stereo PNGs: top-left 2x2 cell R G / G B. OpenCV calls this
#: pattern ``BayerBG`` (``COLOR_BAYER_BG2BGR``), cv_bridge maps ``bayer_rggb8`` to it.
BAYER_ENCODING = "bayer_rggb8"
FOG_BATCH_TYPE = "pf_slam_interfaces/msg/FogBatch"
VECTOR3_TYPE = "geometry_msgs/msg/Vector3Stamped"

TOPIC_FOG = "/fog"
TOPIC_IMAGE = {"left": "/stereo/left/image_raw", "right": "/stereo/right/image_raw"}
TOPIC_CAMERA_INFO = {"left": "/stereo/left/camera_info", "right": "/stereo/right/camera_info"}

BASE_FRAME = "base_link"
FRAME_LIDAR = "lidar"
FRAME_FOG = "fog"
FRAME_CAMERA = {"left": "stereo_left", "right": "stereo_right"}

PARAM_FILES = (
    "EncoderParameter.txt",
    "Vehicle2FOG.txt",
    "Vehicle2Lidar.txt",
    "Vehicle2Stereo.txt",
    "lidar_param.txt",
    "stereo_param.txt",
    "left_camera.yaml",
    "right_camera.yaml",
)
SENSOR_FILES = ("encoder.csv", "fog.csv", "lidar.csv")
IMAGE_DIRS = {"left": "stereo_images/stereo_left", "right": "stereo_images/stereo_right"}

#: Largest accepted difference between the file's RPY and its R (max abs element).
RPY_TOL = 1e-3

# Stream priorities at equal stamps: motion before the scan it belongs to.
_PRIO_ENCODER, _PRIO_FOG, _PRIO_SCAN, _PRIO_LEFT, _PRIO_RIGHT = range(5)


# --------------------------------------------------------------------------------------------
# layout


@dataclass
class KaistLayout:
    """What a KAIST data set folder holds.

    ``present`` maps ``'param/<name>'`` / ``'sensor_data/<name>'`` to the path of each file
    found; ``missing`` lists the required ones not found (relative paths); ``images`` counts
    the ``*.png`` files per camera (``'left'``, ``'right'``; 0 if the folder is missing).
    """

    root: Path
    present: dict = field(default_factory=dict)
    missing: list = field(default_factory=list)
    images: dict = field(default_factory=dict)

    def require(self) -> None:
        """Raise ``ValueError`` naming the first missing file (one line)."""
        if self.missing:
            more = f" (and {len(self.missing) - 1} more)" if len(self.missing) > 1 else ""
            raise ValueError(
                f"{self.root / self.missing[0]}: missing{more}; a KAIST folder "
                "needs sensor_data/{encoder,fog,lidar}.csv and param/*"
            )

    def summary(self) -> str:
        """Human-readable lines."""
        lines = [f"{self.root}:"]
        lines += [f"  {k}: {self.present[k].stat().st_size} bytes" for k in sorted(self.present)]
        lines += [f"  stereo_{cam}: {n} PNG" for cam, n in self.images.items()]
        lines += [f"  missing: {m}" for m in self.missing]
        return "\n".join(lines)


def read_kaist_layout(dataset_dir: str | os.PathLike) -> KaistLayout:
    """List the parameter files, sensor CSVs and stereo PNGs present in ``dataset_dir``."""
    root = Path(dataset_dir)
    if not root.is_dir():
        raise ValueError(f"{root}: not a directory")
    lay = KaistLayout(root=root)
    for sub, names in (("sensor_data", SENSOR_FILES), ("param", PARAM_FILES)):
        for name in names:
            rel = f"{sub}/{name}"
            if (root / rel).is_file():
                lay.present[rel] = root / rel
            else:
                lay.missing.append(rel)
    for cam, rel in IMAGE_DIRS.items():
        d = root / rel
        lay.images[cam] = sum(1 for _ in d.glob("*.png")) if d.is_dir() else 0
    return lay


# --------------------------------------------------------------------------------------------
# FogBatch type


def _fog_batch_msg_file() -> Path:
    name = Path("pf_slam_interfaces") / "msg" / "FogBatch.msg"
    here = Path(__file__).resolve()
    candidates = [
        here.parents[3] / name,  # ros2_ws/src/<pkg>/<pkg>/io -> ros2_ws/src
        Path(sys.prefix) / "share" / name,
    ]  # pip install of the interfaces
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / name)
    for c in candidates:
        if c.is_file():
            return c
    raise ValueError(f"cannot find {name} (looked in {', '.join(map(str, candidates))})")


def register_fog_batch() -> str:
    """Add ``pf_slam_interfaces/msg/FogBatch`` to ``bag.TYPESTORE`` from its ``.msg`` file.

    The definition is read from the source tree (``ros2_ws/src/pf_slam_interfaces/msg``), else
    ``share/pf_slam_interfaces/msg`` under ``sys.prefix`` or an ``AMENT_PREFIX_PATH`` entry.
    Its ``std_msgs/Header`` is the Jazzy store's. Idempotent; returns the type name.
    """
    if FOG_BATCH_TYPE not in TYPESTORE.types:
        from rosbags.typesys import get_types_from_msg

        text = _fog_batch_msg_file().read_text(encoding="utf-8")
        TYPESTORE.register(get_types_from_msg(text, FOG_BATCH_TYPE))
    return FOG_BATCH_TYPE


# --------------------------------------------------------------------------------------------
# calibration -> tf


def kaist_static_transforms(param_dir: str | os.PathLike, warnings: list | None = None) -> list[tuple]:
    """``(parent, child, (x, y, z), (qx, qy, qz, qw))`` for lidar, fog, stereo_left/right.

    The rotations are the nearest rotation matrices to the files' (rounded) R; ``warnings``
    (if given) receives a line per file whose RPY disagrees with its R by more than
    ``RPY_TOL`` (R is used).
    """
    p = Path(param_dir)
    out = []
    left = None
    for fname, frame in (
        ("Vehicle2Lidar.txt", FRAME_LIDAR),
        ("Vehicle2FOG.txt", FRAME_FOG),
        ("Vehicle2Stereo.txt", FRAME_CAMERA["left"]),
    ):
        rot, t, rpy = calib.parse_extrinsic(p / fname)
        err = float(np.abs(rpy_to_matrix(rpy) - rot).max())
        if err > RPY_TOL and warnings is not None:
            warnings.append(f"{p / fname}: RPY {rpy.tolist()} disagrees with R by {err:.3g} (R used)")
        rot = nearest_rotation(rot)  # the file rounds R to ~6 digits
        out.append((BASE_FRAME, frame, tuple(t.tolist()), matrix_to_quat(rot)))
        if frame == FRAME_CAMERA["left"]:
            left = (rot, t)
    assert left is not None
    baseline = calib.parse_stereo_baseline(p / "stereo_param.txt")
    rot, t = left
    t_right = t + rot @ np.array([baseline, 0.0, 0.0])
    out.append((BASE_FRAME, FRAME_CAMERA["right"], tuple(t_right.tolist()), matrix_to_quat(rot)))
    return out


# --------------------------------------------------------------------------------------------
# CSV streaming


def _parse_stamp(tok: str) -> int:
    tok = tok.strip()
    try:
        return int(tok)
    except ValueError:
        pass
    try:  # '1544582648735466220.0' or '1.5445826487354662e+18': exact, if integral
        d = Decimal(tok)
    except InvalidOperation:
        raise ValueError("non-numeric timestamp") from None
    if not d.is_finite():
        raise ValueError("NaN or inf timestamp")
    if d != d.to_integral_value():
        raise ValueError("timestamp not an integer number of ns")
    return int(d)


def _is_header(tok: str) -> bool:
    tok = tok.strip()
    if not tok[:1].isalpha():
        return False
    try:
        float(tok)  # 'nan', 'inf': a data row
    except ValueError:
        return True
    return False


class _Rows:
    """Rows ``(line_no, stamp_ns, values (n_values,) float64)`` of one sensor CSV, streamed.

    Bad rows are skipped and reported into ``skips``; see the module docstring.
    """

    def __init__(self, path: Path, n_values: int, skips: SkipLog) -> None:
        self.path, self.n_values, self.skips = path, n_values, skips

    def _bad(self, line_no: int, reason: str) -> None:
        self.skips.skip(str(self.path), line_no, reason, key=f"{self.path.name}: {reason}", what="row")

    def __iter__(self) -> Iterator[tuple[int, int, np.ndarray]]:
        last = -1
        first = True
        n_cols = self.n_values + 1
        with open(self.path, encoding="utf-8", errors="replace") as fh:
            for line_no, line in enumerate(fh, start=1):
                line = line.strip()
                if not line or line.startswith("#"):
                    continue
                tok = line.split(",")
                if first:
                    first = False
                    if _is_header(tok[0]):  # e.g. 'timestamp,left_count,right_count'
                        continue
                if len(tok) != n_cols:
                    self._bad(line_no, f"expected {n_cols} columns, got {len(tok)}")
                    continue
                try:
                    stamp = _parse_stamp(tok[0])
                except ValueError as exc:
                    self._bad(line_no, str(exc))
                    continue
                try:
                    vals = np.array(tok[1:], dtype=np.float64)
                except ValueError:
                    self._bad(line_no, "non-numeric value")
                    continue
                if not np.all(np.isfinite(vals)):
                    self._bad(line_no, "NaN or inf value")
                    continue
                if stamp < 0:
                    self._bad(line_no, "negative timestamp")
                    continue
                if stamp <= last:
                    self._bad(line_no, "timestamp repeats" if stamp == last else "timestamp steps back")
                    continue
                last = stamp
                yield line_no, stamp, vals


# Each stream yields (stamp_ns, priority, write); write(bag) writes that event (False: skipped).
_Event = tuple[int, int, Callable[[BagWriter], object]]


def _encoder_events(rows: _Rows, resolution: int) -> Iterator[_Event]:
    scale = 2.0 * math.pi / resolution
    for _, stamp, v in rows:
        msg = joint_state_wheels(stamp, v[0] * scale, v[1] * scale, frame_id=BASE_FRAME)
        yield stamp, _PRIO_ENCODER, lambda bag, s=stamp, m=msg: bag.write(TOPIC_ENCODERS, s, m)


def _fog_batch_msg(stamps: list[int], vals: list[np.ndarray]) -> object:
    d = np.array(vals, dtype=np.float64).reshape(-1, 3)
    return TYPESTORE.types[FOG_BATCH_TYPE](
        header=make_header(stamps[-1], FRAME_FOG),
        stamps_ns=np.array(stamps, dtype=np.int64),
        delta_roll=np.ascontiguousarray(d[:, 0]),
        delta_pitch=np.ascontiguousarray(d[:, 1]),
        delta_yaw=np.ascontiguousarray(d[:, 2]),
    )


def _fog_events(rows: _Rows, fog_format: str, fog_batch: int) -> Iterator[_Event]:
    types = TYPESTORE.types
    if fog_format == "vector3":
        vec3, v3s = types["geometry_msgs/msg/Vector3"], types[VECTOR3_TYPE]
        for _, stamp, v in rows:
            msg = v3s(header=make_header(stamp, FRAME_FOG), vector=vec3(x=float(v[0]), y=float(v[1]), z=float(v[2])))
            yield stamp, _PRIO_FOG, lambda bag, s=stamp, m=msg: bag.write(TOPIC_FOG, s, m)
        return
    stamps: list[int] = []
    vals: list[np.ndarray] = []
    for _, stamp, v in rows:
        stamps.append(stamp)
        vals.append(v)
        if len(stamps) == fog_batch:
            msg = _fog_batch_msg(stamps, vals)
            yield stamp, _PRIO_FOG, lambda bag, s=stamp, m=msg: bag.write(TOPIC_FOG, s, m)
            stamps, vals = [], []
    if stamps:
        msg = _fog_batch_msg(stamps, vals)
        s_last = stamps[-1]
        yield s_last, _PRIO_FOG, lambda bag, s=s_last, m=msg: bag.write(TOPIC_FOG, s, m)


def _scan_events(rows: _Rows, angle_min: float, angle_increment: float, range_max: float) -> Iterator[_Event]:
    for _, stamp, v in rows:
        r = v.astype(np.float32)
        r[v == 0.0] = np.inf
        msg = laser_scan(stamp, FRAME_LIDAR, angle_min, angle_increment, r, 0.0, range_max)
        yield stamp, _PRIO_SCAN, lambda bag, s=stamp, m=msg: bag.write(TOPIC_SCAN, s, m)


# --------------------------------------------------------------------------------------------
# images


def _image_files(folder: Path, skips: SkipLog) -> list[tuple[int, Path]]:
    """``(stamp_ns, path)`` of the ``*.png`` in ``folder``, sorted by stamp."""
    out = []
    for f in folder.glob("*.png"):
        try:
            stamp = int(f.stem)
        except ValueError:
            stamp = -1
        if stamp < 0:
            skips.skip(
                str(f),
                None,
                "file name is not a ns timestamp",
                key=f"{folder.name}: file name not a timestamp",
                what="image",
            )
            continue
        out.append((stamp, f))
    out.sort()
    return out


def _image_events(cam: str, files: list[tuple[int, Path]], cam_info: dict, skips: SkipLog) -> Iterator[_Event]:
    import cv2  # local: OpenCV is only needed for images

    prio = _PRIO_LEFT if cam == "left" else _PRIO_RIGHT
    frame = FRAME_CAMERA[cam]
    shape = (cam_info["height"], cam_info["width"])
    folder = IMAGE_DIRS[cam].split("/")[-1]

    def write(bag: BagWriter, stamp: int, path: Path) -> bool:
        why = None
        try:
            buf = np.fromfile(path, dtype=np.uint8)
            img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
        except (OSError, cv2.error) as exc:
            img, why = None, f"cannot read: {exc}"
        if img is None:
            why = why or "not a readable PNG (truncated or corrupt)"
        elif img.dtype != np.uint8 or img.ndim != 2:
            why = f"expected 8-bit single-channel Bayer, got {img.dtype} {img.shape}"
        elif img.shape != shape:
            why = f"size {img.shape[1]}x{img.shape[0]} differs from the camera YAML {shape[1]}x{shape[0]}"
        if why is not None:
            skips.skip(str(path), None, why, key=f"{folder}: bad image", what="image")
            return False
        bag.write(TOPIC_IMAGE[cam], stamp, image(stamp, frame, img, BAYER_ENCODING))
        bag.write(
            TOPIC_CAMERA_INFO[cam],
            stamp,
            camera_info(
                stamp,
                frame,
                cam_info["width"],
                cam_info["height"],
                cam_info["distortion_model"],
                cam_info["D"],
                cam_info["K"],
                cam_info["R"],
                cam_info["P"],
            ),
        )
        return True

    for stamp, path in files:
        yield stamp, prio, lambda bag, s=stamp, p=path: write(bag, s, p)


# --------------------------------------------------------------------------------------------
# conversion


def convert_kaist(
    dataset_dir: str | os.PathLike,
    out_bag: str | os.PathLike,
    storage: str = "mcap",
    fog_batch: int = 10,
    fog_format: str = "batch",
    images: bool = True,
) -> ConvertReport:
    """Convert a KAIST Urban (ECE276A) data set folder to a rosbag2. See the module docstring.

    Parameters
    ----------
    dataset_dir : path
        Folder with ``sensor_data/``, ``param/`` and (optionally) ``stereo_images/``.
    out_bag : path
        New rosbag2 directory (refuses an existing path: ``BagError``).
    storage : {'mcap', 'sqlite3'}
    fog_batch : int
        FOG samples per ``FogBatch`` message (``fog_format='batch'``): 10 -> 100 Hz, 1 -> 1 kHz.
    fog_format : {'batch', 'vector3'}
        ``FogBatch`` messages, or one ``geometry_msgs/Vector3Stamped`` per sample.
    images : bool
        Write the stereo images and camera infos (a missing ``stereo_images/`` folder then
        gives a warning, not an error).

    Returns
    -------
    ConvertReport
        ``counts`` per topic, ``skipped`` rows per ``'<file>: <reason>'``, ``warnings``,
        ``start_ns`` / ``end_ns`` (first / last record time); ``retimed`` is always 0.

    Raises ``ValueError`` for a missing required file, a bad argument or a data set without
    any usable row.
    """
    if fog_format not in ("batch", "vector3"):
        raise ValueError(f"fog_format must be 'batch' or 'vector3', got {fog_format!r}")
    if isinstance(fog_batch, bool) or not isinstance(fog_batch, (int, np.integer)) or fog_batch < 1:
        raise ValueError(f"fog_batch must be an integer >= 1, got {fog_batch!r}")
    layout = read_kaist_layout(dataset_dir)
    layout.require()
    root = layout.root
    param, sensors = root / "param", root / "sensor_data"
    report = ConvertReport(source=str(root), out_bag=str(out_bag), storage=storage)
    skips = SkipLog(report.skipped, report.warnings)

    enc = calib.parse_encoder_params(param / "EncoderParameter.txt")
    lid = calib.parse_lidar_params(param / "lidar_param.txt")
    transforms = kaist_static_transforms(param, report.warnings)
    n_beams = int(round((lid["end_deg"] - lid["start_deg"]) / lid["resolution_deg"])) + 1
    inc_deg = (lid["end_deg"] - lid["start_deg"]) / (n_beams - 1)
    if abs(inc_deg - lid["resolution_deg"]) > 1e-3 + 1e-9:
        report.warnings.append(
            f"{param / 'lidar_param.txt'}: angular resolution "
            f"{lid['resolution_deg']} deg; (end - start) / {n_beams - 1} = "
            f"{inc_deg:.6f} deg used"
        )
    if fog_format == "batch":
        register_fog_batch()

    streams = [
        _encoder_events(_Rows(sensors / "encoder.csv", 2, skips), enc["resolution"]),
        _fog_events(_Rows(sensors / "fog.csv", 3, skips), fog_format, int(fog_batch)),
        _scan_events(
            _Rows(sensors / "lidar.csv", n_beams, skips),
            math.radians(lid["start_deg"]),
            math.radians(inc_deg),
            lid["max_range_m"],
        ),
    ]
    cams: dict[str, dict] = {}
    if images:
        files = {}
        for cam, rel in IMAGE_DIRS.items():
            if not (root / rel).is_dir():
                report.warnings.append(f"{root / rel}: missing; no {cam} images written")
                continue
            cams[cam] = calib.read_camera_yaml(param / f"{cam}_camera.yaml")
            files[cam] = _image_files(root / rel, skips)
            streams.append(_image_events(cam, files[cam], cams[cam], skips))
        if len(files) == 2:
            lone = {s for s, _ in files["left"]} ^ {s for s, _ in files["right"]}
            if lone:
                report.warnings.append(
                    f"{len(lone)} stereo images have no partner with the same timestamp in the other camera"
                )

    events = heapq.merge(*streams, key=lambda e: (e[0], e[1]))
    first = next(events, None)
    if first is None:
        raise ValueError(f"{root}: no usable row in sensor_data/ (skipped: {report.skipped})")
    t0 = first[0]
    with open_writer(out_bag, storage=storage) as bag:
        bag.add_connection(TOPIC_TF_STATIC, "tf2_msgs/msg/TFMessage")
        bag.add_connection(TOPIC_ENCODERS, "sensor_msgs/msg/JointState")
        bag.add_connection(TOPIC_FOG, FOG_BATCH_TYPE if fog_format == "batch" else VECTOR3_TYPE)
        bag.add_connection(TOPIC_SCAN, "sensor_msgs/msg/LaserScan")
        for cam in cams:
            bag.add_connection(TOPIC_IMAGE[cam], "sensor_msgs/msg/Image")
            bag.add_connection(TOPIC_CAMERA_INFO[cam], "sensor_msgs/msg/CameraInfo")
        bag.set_custom_data("pf_slam.format", "kaist")  # pf-slam run: the kaist (car) profile
        bag.set_custom_data("pf_slam.source", f"kaist:{root.resolve().name}")
        bag.set_custom_data("pf_slam.encoder_resolution", str(enc["resolution"]))
        bag.set_custom_data("pf_slam.left_wheel_diameter_m", repr(enc["left_wheel_diameter_m"]))
        bag.set_custom_data("pf_slam.right_wheel_diameter_m", repr(enc["right_wheel_diameter_m"]))
        bag.set_custom_data("pf_slam.wheel_base_m", repr(enc["wheel_base_m"]))
        if fog_format == "batch":
            bag.set_custom_data("pf_slam.fog_batch", str(int(fog_batch)))
        bag.write(TOPIC_TF_STATIC, t0, tf_static(t0, transforms))
        last = t0
        for stamp, _, write in itertools.chain([first], events):
            if write(bag) is not False:  # False: an image skipped
                last = stamp
        report.counts = dict(bag.counts)
    skips.finish()
    report.start_ns, report.end_ns = t0, last
    return report
