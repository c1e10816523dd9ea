"""The calibrated stereo pair (:class:`StereoRig`): camera models, mounting, rectification maps.

Built from arrays (``CameraInfo``-like mappings); from the KAIST ``param/`` files by
:func:`pf_slam_nodes.io.calib.read_stereo_rig`."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np

# --------------------------------------------------------------------------------------------
# the rig


@dataclasses.dataclass
class StereoRig:
    """A calibrated stereo pair: camera models and the left camera's mounting.

    Attributes
    ----------
    width, height : int
        Image size (px).
    left, right : dict
        ``K`` (3, 3), ``D`` (n,), ``R`` (3, 3) rectifying rotation, ``P`` (3, 4) rectified
        projection, as :func:`pf_slam_nodes.io.calib.read_camera_yaml` returns (or the
        ``k, d, r, p`` of a ``sensor_msgs/CameraInfo``).
    R_vehicle_cam : numpy.ndarray
        (3, 3) left (unrectified) camera frame -> vehicle frame (``Vehicle2Stereo.txt`` R).
    t_vehicle_cam : numpy.ndarray
        (3,) left camera origin in the vehicle frame (m).
    """

    width: int
    height: int
    left: dict
    right: dict
    R_vehicle_cam: np.ndarray
    t_vehicle_cam: np.ndarray
    _maps: dict = dataclasses.field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        for side in ("left", "right"):
            cam = getattr(self, side)
            cam = {k: np.asarray(v, dtype=np.float64) for k, v in cam.items() if k in ("K", "D", "R", "P")}
            for key, shape in (("K", (3, 3)), ("R", (3, 3)), ("P", (3, 4))):
                if key not in cam or cam[key].size != int(np.prod(shape)):
                    raise ValueError(f"{side} camera: {key} must be a {shape} matrix")
                cam[key] = cam[key].reshape(shape)
            cam["D"] = cam.get("D", np.zeros(0)).ravel()
            setattr(self, side, cam)
        self.R_vehicle_cam = np.asarray(self.R_vehicle_cam, dtype=np.float64).reshape(3, 3)
        self.t_vehicle_cam = np.asarray(self.t_vehicle_cam, dtype=np.float64).reshape(3)
        if not self.width > 0 or not self.height > 0:
            raise ValueError(f"bad image size {self.width} x {self.height}")
        if not self.baseline_m > 0:
            raise ValueError(f"right P must have P[0, 3] = -f * baseline < 0, got {self.right['P'][0, 3]!r}")

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_camera_infos(
        cls, left: Mapping[str, Any], right: Mapping[str, Any], R_vehicle_cam: np.ndarray, t_vehicle_cam: np.ndarray
    ) -> StereoRig:
        """From two ``sensor_msgs/CameraInfo``-like mappings (``width``, ``height``, ``k``,
        ``d``, ``r``, ``p``: flat sequences) and the mounting."""

        def cam(m: Mapping[str, Any]) -> dict:
            return {"K": m["k"], "D": m["d"], "R": m["r"], "P": m["p"]}

        return cls(int(left["width"]), int(left["height"]), cam(left), cam(right), R_vehicle_cam, t_vehicle_cam)

    # ---------------------------------------------------------------- intrinsics
    @property
    def f(self) -> float:
        """Rectified focal length along x (px)."""
        return float(self.left["P"][0, 0])

    @property
    def fy(self) -> float:
        return float(self.left["P"][1, 1])

    @property
    def cx(self) -> float:
        return float(self.left["P"][0, 2])

    @property
    def cy(self) -> float:
        return float(self.left["P"][1, 2])

    @property
    def cx_offset(self) -> float:
        """``cx_left - cx_right`` of the rectified pair (px; 0 for the KAIST calibration)."""
        return float(self.left["P"][0, 2] - self.right["P"][0, 2])

    @property
    def baseline_m(self) -> float:
        """``-P_right[0, 3] / P_right[0, 0]`` (m; 0.47515 m for KAIST)."""
        return float(-self.right["P"][0, 3] / self.right["P"][0, 0])

    def rect_to_vehicle(self, rectified_here: bool) -> tuple[np.ndarray, np.ndarray]:
        """``(R (3, 3), t (3,))`` with ``p_vehicle = R @ p_rect + t``.

        ``rectified_here``: the images are rectified by :meth:`rectify_maps` (the rectified
        camera is the raw one turned by ``R_left``); else they are taken as rectified already
        in the mounting frame (identity rectifying rotation, as the simulator renders them).
        """
        r = self.R_vehicle_cam @ self.left["R"].T if rectified_here else self.R_vehicle_cam
        return r, self.t_vehicle_cam.copy()

    def rectify_maps(self, side: str) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap`` maps (float32 x, y; full image) of one camera (cached)."""
        if side not in self._maps:
            c = getattr(self, side)
            self._maps[side] = cv2.initUndistortRectifyMap(
                c["K"], c["D"], c["R"], c["P"][:, :3], (self.width, self.height), cv2.CV_32FC1
            )
        return self._maps[side]

    def rectified_valid(self, side: str = "left") -> np.ndarray:
        """Bool ``(H, W)``: rectified pixels that come from inside the raw image."""
        key = f"valid_{side}"
        if key not in self._maps:
            mx, my = self.rectify_maps(side)
            self._maps[key] = (mx >= 0) & (mx <= self.width - 1) & (my >= 0) & (my <= self.height - 1)
        return self._maps[key]

    def pixel_rays(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Rectified-camera rays ``[(u - cx) / f, (v - cy) / fy, 1]`` (N, 3) of pixels."""
        return np.stack(
            [
                (np.asarray(u, np.float64) - self.cx) / self.f,
                (np.asarray(v, np.float64) - self.cy) / self.fy,
                np.ones(np.shape(u)),
            ],
            axis=-1,
        )
