"""Calibration of the simulated car: the KAIST Urban ``param/`` files, byte for byte.

The texts are those of the real data set (``param/`` of the ECE276A KAIST subset); the simulator
writes them unchanged and takes every sensor parameter from them (``R`` / ``T`` map sensor-frame
points to the vehicle frame: ``p_vehicle = R @ p_sensor + T``).
"""

from __future__ import annotations

import re

import numpy as np

__all__ = ["PARAM_FILES", "extrinsic", "yaml_matrix"]

#: ``{file name: exact text}`` of ``DIR/param/`` (``stereo_param.txt`` ends with CRLF, as
#: the original).
PARAM_FILES: dict[str, str] = {
    "EncoderParameter.txt": (
        "Encoder calibrated parameter\n"
        "Encoder resolution: 4096\n"
        "Encoder left wheel diameter: 0.623479\n"
        "Encoder right wheel diameter: 0.622806\n"
        "Encoder wheel base: 1.52439\n"
        "\n"
        "* The encoder data is stored as [timestamp, left count, right count].\n"
    ),
    "Vehicle2FOG.txt": (
        "FOG (Fiber Optic Gyro) extrinsic calibration parameter from vehicle\n"
        "RPY(roll/pitch/yaw = XYZ extrinsic, degree), R(rotation matrix), T(translation matrix, meter)\n"  # noqa: E501
        "RPY: 0 0 0\n"
        "R: 1 0 0 0 1 0 0 0 1 \n"
        "T: -0.335 -0.035 0.78\n"
        "\n"
        "* The sensor measurements are stored as [timestamp, delta roll, delta pitch, delta yaw] in radians.\n"  # noqa: E501
    ),
    "Vehicle2Lidar.txt": (
        "Lidar sensor (LMS511) extrinsic calibration parameter from vehicle\n"
        "RPY(roll/pitch/yaw = XYZ extrinsic, degree), R(rotation matrix), T(translation matrix)\n"
        "RPY: 142.759 0.0584636 89.9254\n"
        "R: 0.00130201 0.796097 0.605167 0.999999 -0.000419027 -0.00160026 -0.00102038 0.605169 -0.796097 \n"  # noqa: E501
        "T: 0.8349 -0.0126869 1.76416\n"
    ),
    "Vehicle2Stereo.txt": (
        "Stereo camera (based on left camera) extrinsic calibration parameter from vehicle\n"
        "RPY(roll/pitch/yaw = XYZ extrinsic, degree), R(rotation matrix), T(translation matrix)\n"
        "RPY: -90.878 0.0132 -90.3899\n"
        "R: -0.00680499 -0.0153215 0.99985 -0.999977 0.000334627 -0.00680066 -0.000230383 -0.999883 -0.0153234 \n"  # noqa: E501
        "T: 1.64239 0.247401 1.58411\n"
        "\n"
    ),
    "left_camera.yaml": (
        "%YAML:1.0\n"
        "---\n"
        "image_width: 1280\n"
        "image_height: 560\n"
        "camera_name: /stereo/left\n"
        "camera_matrix: !!opencv-matrix\n"
        "   rows: 3\n"
        "   cols: 3\n"
        "   dt: d\n"
        "   data: [ 8.1690378992770002e+02, 5.0510166700000003e-01,\n"
        "       6.0850726281690004e+02, 0., 8.1156803828490001e+02,\n"
        "       2.6347599764440002e+02, 0., 0., 1. ]\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients: !!opencv-matrix\n"
        "   rows: 1\n"
        "   cols: 5\n"
        "   dt: d\n"
        "   data: [ -5.6143027800000002e-02, 1.3952563200000001e-01,\n"
        "       -1.2155906999999999e-03, -9.7281389999999998e-04,\n"
        "       -8.0878168799999997e-02 ]\n"
        "rectification_matrix: !!opencv-matrix\n"
        "   rows: 3\n"
        "   cols: 3\n"
        "   dt: d\n"
        "   data: [ 9.9996942080938533e-01, 3.6208456669806118e-04,\n"
        "       -7.8119357978017733e-03, -3.4412461339106772e-04,\n"
        "       9.9999729518344416e-01, 2.3002617343453663e-03,\n"
        "       7.8127475572218850e-03, -2.2975031148170580e-03,\n"
        "       9.9996684067775188e-01 ]\n"
        "projection_matrix: !!opencv-matrix\n"
        "   rows: 3\n"
        "   cols: 4\n"
        "   dt: d\n"
        "   data: [ 7.7537235550066748e+02, 0., 6.1947309112548828e+02, 0., 0.,\n"
        "       7.7537235550066748e+02, 2.5718049049377441e+02, 0., 0., 0., 1.,\n"
        "       0. ]\n"
    ),
    "lidar_param.txt": (
        "FOV: 190 (degree)\n"
        "Start angle: -5 (degree)\n"
        "End angle: 185 (degree)\n"
        "Angular resolution: 0.666 (degree)\n"
        "Max range: 80 (meter)\n"
        "\n"
        "* LiDAR rays with value 0.0 represent infinite range observations.\n"
    ),
    "right_camera.yaml": (
        "%YAML:1.0\n"
        "---\n"
        "image_width: 1280\n"
        "image_height: 560\n"
        "camera_name: /stereo/right\n"
        "camera_matrix: !!opencv-matrix\n"
        "   rows: 3\n"
        "   cols: 3\n"
        "   dt: d\n"
        "   data: [ 8.1378205539589999e+02, 3.4880336220000002e-01,\n"
        "       6.1386419539320002e+02, 0., 8.0852165574269998e+02,\n"
        "       2.4941049348650000e+02, 0., 0., 1. ]\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients: !!opencv-matrix\n"
        "   rows: 1\n"
        "   cols: 5\n"
        "   dt: d\n"
        "   data: [ -5.4921981799999998e-02, 1.4243657430000001e-01,\n"
        "       7.5412299999999996e-05, -6.7560530000000001e-04,\n"
        "       -8.5665408299999996e-02 ]\n"
        "rectification_matrix: !!opencv-matrix\n"
        "   rows: 3\n"
        "   cols: 3\n"
        "   dt: d\n"
        "   data: [ 9.9998812489422739e-01, 2.4089155522231892e-03,\n"
        "       -4.2364131513853301e-03, -2.4186483057924992e-03,\n"
        "       9.9999444433315865e-01, -2.2937835970734117e-03,\n"
        "       4.2308640843048539e-03, 2.3040027516418276e-03,\n"
        "       9.9998839561287933e-01 ]\n"
        "projection_matrix: !!opencv-matrix\n"
        "   rows: 3\n"
        "   cols: 4\n"
        "   dt: d\n"
        "   data: [ 7.7537235550066748e+02, 0., 6.1947309112548828e+02,\n"
        "       -3.6841758740842312e+02, 0., 7.7537235550066748e+02,\n"
        "       2.5718049049377441e+02, 0., 0., 0., 1., 0. ]\n"
    ),
    "stereo_param.txt": ("Baseline of stereo cameras: 475.143600050775 (mm)\r\n"),
}


def extrinsic(name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(R (3, 3), T (3,))`` of ``Vehicle2<name>.txt`` (sensor -> vehicle)."""
    text = PARAM_FILES[f"Vehicle2{name}.txt"]
    r = re.search(r"^R:(.*)$", text, re.M)
    t = re.search(r"^T:(.*)$", text, re.M)
    assert r is not None and t is not None
    return (
        np.array(r.group(1).split(), dtype=np.float64).reshape(3, 3),
        np.array(t.group(1).split(), dtype=np.float64),
    )


def yaml_matrix(name: str, key: str) -> np.ndarray:
    """The ``data`` of the ``!!opencv-matrix`` ``key`` of camera YAML ``name``, shaped."""
    text = PARAM_FILES[name]
    m = re.search(
        key + r":\s*!!opencv-matrix\s*rows:\s*(\d+)\s*cols:\s*(\d+)\s*dt:\s*d\s*"
        r"data:\s*\[([^\]]*)\]",
        text,
    )
    assert m is not None
    rows, cols = int(m.group(1)), int(m.group(2))
    return np.array(m.group(3).replace(",", " ").split(), dtype=np.float64).reshape(rows, cols)
