"""Texture map: colour the floor of the SLAM map from a stereo camera (ROS-free core).

Per stereo pair (:meth:`StereoTexturer.process`):

1. **Debayer** both raw images (:func:`debayer`; the KAIST PNGs are ``bayer_rggb8``, which
   OpenCV calls ``BayerBG``).
2. **Rectify** with the camera model (``K``, ``D``, ``R``, ``P`` of each camera) unless the
   images already are rectified (:attr:`TextureConfig.rectify`, ``'auto'`` decides on the first
   pair by the vertical offset of ORB matches; the real KAIST pair needs it, ~9 px of vertical
   offset raw, 0.0 px rectified; the simulator renders rectified images directly). Only the
   rows that can see the ground within ``max_range_m`` are processed (``first_row`` onwards).
3. **Disparity** with OpenCV SGBM (mode ``HH4``: unbiased on the slanted road, see
   :class:`TextureConfig`) on grey images averaged down by ``downscale`` (2: INTER_AREA, the
   pre-filter that works on the dark road), both images padded on the left by the search range
   so that the left image band is not lost.
4. **3D** at the disparity resolution: ``Z = f b / (d - (cx_l - cx_r))``,
   ``X = (u - cx) Z / f``, ``Y = (v - cy) Z / fy`` in the rectified left camera frame, then
   into the vehicle frame (``p_v = R_vs R1^T p_rect + T_vs``, ``R_vs, T_vs`` =
   ``Vehicle2Stereo.txt`` / tf ``base_link -> stereo_left``; ``R1`` = the left rectifying
   rotation, identity when the images are not rectified here).
5. **Ground**: a plane ``n . p + c = 0`` (vehicle frame, ``n`` unit, up) is fitted by RANSAC
   + least squares to the points near the nominal ground ``z = 0``; a fit tilted more than
   ``plane_max_tilt_deg`` or offset more than ``plane_max_offset_m`` from the nominal plane is
   rejected (the nominal plane is used, ``FrameResult.plane_fitted`` False). Pixels whose
   stereo point lies within ``height_tol_m`` of the plane and inside the range box are ground,
   except within ``obstacle_margin_px`` of a point above the plane (matching fattens objects).
6. **Placement**: each ground pixel at full resolution is placed where its viewing ray meets the
   plane (``snap_to_plane``; no disparity noise in the position), dropped to the map plane
   (``x, y``) and moved into the world with the 2D vehicle pose ``(x, y, theta)``.
   Near rows are subsampled (``pixel_stride_max``); cells in view that no pixel fell in (far
   away a row spans more than a cell) get the bilinear colour at their centre's projection
   (``fill_gaps``).
7. **Accumulation** (:class:`TextureMap`): running mean RGB per cell, every sample weighs 1.

Frames: rectified left camera x right, y down, z forward (origin = left optical centre);
vehicle (``base_link``) x forward, y left, z up, origin on the ground; world / map = the frame
of the 2D poses (the vehicle is assumed flat on a flat map: world z = vehicle z).

Memory (:class:`TextureMap`): the world is cut into square tiles of ``tile_cells`` x
``tile_cells`` cells allocated on first use (16 bytes per cell: float32 mean RGB + float32
count; 256 KiB per 128 x 128 tile = 12.8 m x 12.8 m at 0.1 m), never a dense 4000 x 4000
grid; at most ``max_tiles`` tiles (default 1024 = 256 MiB), samples that would need more are
dropped and counted (``TextureMap.samples_dropped``).

Texture images (:meth:`TextureMap.render`) use the ``OccupancyGrid`` layout: ``(H, W, 3)``
``uint8`` RGB, row 0 = lowest y; pixel ``(row, col)`` is the cell whose centre is
``x = origin_x + (col + 0.5) * res``, ``y = origin_y + (row + 0.5) * res``. Cells without
observation are ``(0, 0, 0)``; observed cells are never pure black (clamped to ``(1, 1, 1)``),
so black means "no colour". :func:`north_up_bgr` flips it for a PNG (north up).
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from pathlib import Path
from typing import Any, Mapping, Optional

import cv2
import numpy as np

from .config import _check_finite, _check_int, _check_nonneg, _check_pos, _ConfigBase

__all__ = [
    'BAYER_CODES',
    'FrameResult',
    'PairMeasurement',
    'Plane',
    'StereoRig',
    'StereoTexturer',
    'TextureConfig',
    'TextureMap',
    'colour_error',
    'debayer',
    'detect_rectified',
    'fit_ground_plane',
    'grey',
    'interpolate_poses',
    'measure_stereo_pair',
    'north_up_bgr',
    'overlay_occupancy',
    'read_floor_texture',
    'road_region_mask',
    'visible_ground_mask',
    'write_texture_pngs',
]

#: ROS image encoding -> OpenCV conversion to RGB (OpenCV names a Bayer pattern by the colours
#: of the second row's second and third pixels: ``rggb`` is OpenCV's ``BayerBG``).
BAYER_CODES = {
    'bayer_rggb8': cv2.COLOR_BAYER_BG2RGB,
    'bayer_bggr8': cv2.COLOR_BAYER_RG2RGB,
    'bayer_gbrg8': cv2.COLOR_BAYER_GR2RGB,
    'bayer_grbg8': cv2.COLOR_BAYER_GB2RGB,
}
_BAYER_CV = {'bayer_rggb8': 'BG', 'bayer_bggr8': 'RG', 'bayer_gbrg8': 'GR', 'bayer_grbg8': 'GB'}
_DEMOSAIC = {'bilinear': '', 'ea': '_EA', 'vng': '_VNG'}
_PREFILTERS = ('none', 'clahe', 'equalize')
_SGBM_MODES = {'sgbm': cv2.STEREO_SGBM_MODE_SGBM, '3way': cv2.STEREO_SGBM_MODE_SGBM_3WAY,
               'hh': cv2.STEREO_SGBM_MODE_HH, 'hh4': cv2.STEREO_SGBM_MODE_HH4}
_RECTIFY = ('auto', 'yes', 'no')


# --------------------------------------------------------------------------------------------
# configuration


@dataclasses.dataclass(frozen=True)
class TextureConfig(_ConfigBase):
    """Stereo texture mapping (:class:`StereoTexturer`, :class:`TextureMap`).

    Stereo matching is OpenCV ``StereoSGBM``. The defaults come from
    ``python -m pf_slam_nodes.bench.texture {real,sim} ... --sweep`` (``docs/texture.md``):

    * Pre-filter: on the real KAIST pair (dark asphalt, ego-lane road region 5-15 m ahead)
      full resolution gives 52 % valid disparity; CLAHE / histogram equalisation *lower* the
      density at the same resolution (they amplify the sensor noise of the dark road,
      differently in the two cameras); averaging 2 x 2 pixels down (``downscale`` 2, INTER_AREA)
      is the filter that works: 92 % valid, 6x faster. SGBM's own x-derivative pre-filter
      (``pre_filter_cap``) already normalises the contrast.
    * Mode: ``SGBM_3WAY`` (and the single-pass ``SGBM``) aggregate costs from above only; on
      the road, whose disparity grows row by row, that biases the disparity by -0.3 px (points
      2 cm too low at 16-20 m on the simulator, a 0.4 deg false tilt on the real pair).
      ``HH4`` aggregates both ways: bias < 0.05 px (< 4 mm at 20 m), 92 % density, ~2x the
      time of ``SGBM_3WAY``.
    * Uniqueness 5 (vs 10: 87 % density), block 7 at half resolution (5: 90 %).

    Attributes
    ----------
    rectify : str
        ``'yes'``: rectify with ``K, D, R, P``; ``'no'``: the images are rectified already
        (the simulator's); ``'auto'``: decide on the first pair with enough ORB matches
        (median vertical offset of the matches raw vs rectified).
    demosaic : str
        Colour reconstruction of the left image: ``'bilinear'``, ``'ea'`` or ``'vng'`` (11 ms;
        least colour moire on far stripes: colour error 6.6 vs 7.4 bilinear on a 6 s
        simulated drive). Matching always uses OpenCV's Bayer-to-grey.
    sgbm_mode : str
        ``'hh4'`` (default), ``'hh'``, ``'3way'`` or ``'sgbm'`` (see above).
    downscale : int
        Disparity is computed on images averaged down by this factor (1, 2 or 4).
    num_disparities : int
        Disparity search range (full-resolution px, ``0 .. num_disparities - 1``); a multiple
        of ``16 * downscale``. 128 px = 2.9 m at the KAIST rig (f 775 px, b 0.475 m); the road
        at the image bottom is ~91 px.
    block_size : int
        SGBM matching window (px at the downscaled resolution, odd).
    p1, p2 : float
        SGBM smoothness penalties per window pixel: ``P1 = p1 * block_size**2``,
        ``P2 = p2 * block_size**2`` (OpenCV's recommended 8 and 32).
    uniqueness_ratio : int
        SGBM uniqueness margin (%): the best cost must beat the second best by this much.
    disp12_max_diff : int
        Left-right consistency check tolerance (px at the downscaled resolution; -1 = off).
    speckle_window : int
        Disparity blobs smaller than this (px) are removed (0 = off).
    speckle_range : int
        Largest disparity step (px) inside one blob of the speckle filter.
    pre_filter_cap : int
        SGBM's x-derivative pre-filter clip (1..63).
    prefilter : str
        Extra contrast pre-filter of the grey images: ``'none'`` (default, see above),
        ``'clahe'`` (clip 2, 8 x 8 tiles) or ``'equalize'``.
    min_range_m, max_range_m : float
        Ground kept from ``min_range_m`` to ``max_range_m`` ahead of the camera (vehicle x
        distance, m). Beyond ~20 m a 0.1 m cell is less than a pixel tall.
    max_lateral_m : float
        Ground kept within this distance left / right of the camera (m).
    row_margin_px : int
        Rows above the nominal image row of the ground at ``max_range_m`` also processed
        (full-resolution px; room for the car's pitch).
    height_tol_m : float
        A stereo point within this height of the road plane is ground (m).
    obstacle_margin_px : int
        Ground pixels within this many disparity pixels of a point higher than
        ``height_tol_m`` (a car, a pole, a facade) are not used: block matching gives the
        object's border pixels the disparity of the ground behind it, which would smear the
        object's colour along the viewing rays.
    plane_fit : bool
        Fit the road plane per pair (else the nominal plane ``z = 0`` of the vehicle frame).
    ransac_iterations : int
        RANSAC hypotheses per pair.
    ransac_tol_m : float
        RANSAC / least-squares inlier distance (m).
    ransac_max_points : int
        Points (random subset) the RANSAC scores hypotheses on.
    plane_max_tilt_deg, plane_max_offset_m : float
        A fitted plane whose normal is tilted more than this from the vehicle's z, or that
        passes farther than this from the vehicle origin's ground, is rejected.
    snap_to_plane : bool
        Place ground pixels where their ray meets the plane (True) or at their stereo point.
    pixel_stride_max : int
        Near rows, where a cell holds many pixels, only every ``s``-th row / column
        (``s <= pixel_stride_max``) is splatted (see ``StereoTexturer._stride_mask``); 1 =
        every pixel.
    fill_gaps : bool
        Cells in view that no ground pixel fell in (far away, where image rows are sparser
        than cells) get the colour at their centre's projection (one sample).
    cell_m : float
        Texture cell size (m).
    tile_cells : int
        Texture tile edge (cells).
    max_tiles : int
        Tiles allocated at most (``16 * tile_cells**2`` bytes each).
    seed : int
        RANSAC random seed.
    """

    rectify: str = 'auto'
    demosaic: str = 'vng'
    sgbm_mode: str = 'hh4'
    downscale: int = 2
    num_disparities: int = 128
    block_size: int = 7
    p1: float = 8.0
    p2: float = 32.0
    uniqueness_ratio: int = 5
    disp12_max_diff: int = 1
    speckle_window: int = 100
    speckle_range: int = 2
    pre_filter_cap: int = 31
    prefilter: str = 'none'
    min_range_m: float = 3.0
    max_range_m: float = 20.0
    max_lateral_m: float = 12.0
    row_margin_px: int = 32
    height_tol_m: float = 0.1
    obstacle_margin_px: int = 3
    plane_fit: bool = True
    ransac_iterations: int = 64
    ransac_tol_m: float = 0.05
    ransac_max_points: int = 4000
    plane_max_tilt_deg: float = 5.0
    plane_max_offset_m: float = 0.3
    snap_to_plane: bool = True
    pixel_stride_max: int = 3
    fill_gaps: bool = True
    cell_m: float = 0.1
    tile_cells: int = 128
    max_tiles: int = 1024
    seed: int = 0

    def __post_init__(self) -> None:
        if self.rectify not in _RECTIFY:
            raise ValueError(f'rectify must be one of {_RECTIFY}, got {self.rectify!r}')
        if self.demosaic not in _DEMOSAIC:
            raise ValueError(f'demosaic must be one of {tuple(_DEMOSAIC)}, got {self.demosaic!r}')
        if self.sgbm_mode not in _SGBM_MODES:
            raise ValueError(f'sgbm_mode must be one of {tuple(_SGBM_MODES)}, got '
                             f'{self.sgbm_mode!r}')
        if self.prefilter not in _PREFILTERS:
            raise ValueError(f'prefilter must be one of {_PREFILTERS}, got {self.prefilter!r}')
        _check_int('downscale', self.downscale, 1)
        if self.downscale not in (1, 2, 4):
            raise ValueError(f'downscale must be 1, 2 or 4, got {self.downscale!r}')
        _check_int('num_disparities', self.num_disparities, 16)
        if self.num_disparities % (16 * self.downscale):
            raise ValueError(f'num_disparities must be a multiple of 16 * downscale = '
                             f'{16 * self.downscale}, got {self.num_disparities!r}')
        _check_int('block_size', self.block_size, 1)
        if self.block_size % 2 == 0:
            raise ValueError(f'block_size must be odd, got {self.block_size!r}')
        _check_pos('p1', self.p1)
        _check_pos('p2', self.p2)
        if self.p2 <= self.p1:
            raise ValueError(f'p2 must be > p1, got p1={self.p1!r}, p2={self.p2!r}')
        _check_int('uniqueness_ratio', self.uniqueness_ratio, 0)
        _check_int('disp12_max_diff', self.disp12_max_diff, -1)
        _check_int('speckle_window', self.speckle_window, 0)
        _check_int('speckle_range', self.speckle_range, 0)
        _check_int('pre_filter_cap', self.pre_filter_cap, 1)
        if self.pre_filter_cap > 63:
            raise ValueError(f'pre_filter_cap must be <= 63, got {self.pre_filter_cap!r}')
        _check_nonneg('min_range_m', self.min_range_m)
        _check_pos('max_range_m', self.max_range_m)
        if self.max_range_m <= self.min_range_m:
            raise ValueError(f'max_range_m must be > min_range_m, got {self.max_range_m!r}')
        _check_pos('max_lateral_m', self.max_lateral_m)
        _check_int('row_margin_px', self.row_margin_px, 0)
        _check_pos('height_tol_m', self.height_tol_m)
        _check_int('obstacle_margin_px', self.obstacle_margin_px, 0)
        if not isinstance(self.plane_fit, bool):
            raise ValueError(f'plane_fit must be a bool, got {self.plane_fit!r}')
        if not isinstance(self.fill_gaps, bool):
            raise ValueError(f'fill_gaps must be a bool, got {self.fill_gaps!r}')
        if not isinstance(self.snap_to_plane, bool):
            raise ValueError(f'snap_to_plane must be a bool, got {self.snap_to_plane!r}')
        _check_int('ransac_iterations', self.ransac_iterations, 1)
        _check_pos('ransac_tol_m', self.ransac_tol_m)
        _check_int('ransac_max_points', self.ransac_max_points, 3)
        _check_pos('plane_max_tilt_deg', self.plane_max_tilt_deg)
        _check_pos('plane_max_offset_m', self.plane_max_offset_m)
        _check_int('pixel_stride_max', self.pixel_stride_max, 1)
        _check_pos('cell_m', self.cell_m)
        _check_int('tile_cells', self.tile_cells, 8)
        _check_int('max_tiles', self.max_tiles, 1)
        _check_int('seed', self.seed, 0)
        _check_finite('cell_m', self.cell_m)


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
        for side in ('left', 'right'):
            cam = getattr(self, side)
            cam = {k: np.asarray(v, dtype=np.float64) for k, v in cam.items()
                   if k in ('K', 'D', 'R', 'P')}
            for key, shape in (('K', (3, 3)), ('R', (3, 3)), ('P', (3, 4))):
                if key not in cam or cam[key].size != int(np.prod(shape)):
                    raise ValueError(f'{side} camera: {key} must be a {shape} matrix')
                cam[key] = cam[key].reshape(shape)
            cam['D'] = cam.get('D', np.zeros(0)).ravel()
            setattr(self, side, cam)
        self.R_vehicle_cam = np.asarray(self.R_vehicle_cam, dtype=np.float64).reshape(3, 3)
        self.t_vehicle_cam = np.asarray(self.t_vehicle_cam, dtype=np.float64).reshape(3)
        if not self.width > 0 or not self.height > 0:
            raise ValueError(f'bad image size {self.width} x {self.height}')
        if not self.baseline_m > 0:
            raise ValueError(f'right P must have P[0, 3] = -f * baseline < 0, got '
                             f'{self.right["P"][0, 3]!r}')

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_param_dir(cls, param_dir: str | os.PathLike) -> StereoRig:
        """The KAIST layout's ``param/``: ``left_camera.yaml``, ``right_camera.yaml``,
        ``Vehicle2Stereo.txt`` (raises ``ValueError`` naming a missing / bad file)."""
        from ..io.calib import nearest_rotation, parse_extrinsic, read_camera_yaml

        d = Path(param_dir)
        left = read_camera_yaml(d / 'left_camera.yaml')
        right = read_camera_yaml(d / 'right_camera.yaml')
        rot, t, _ = parse_extrinsic(d / 'Vehicle2Stereo.txt')
        return cls(int(left['width']), int(left['height']), left, right,
                   nearest_rotation(rot), t)

    @classmethod
    def from_camera_infos(cls, left: Mapping[str, Any], right: Mapping[str, Any],
                          R_vehicle_cam: np.ndarray, t_vehicle_cam: np.ndarray) -> StereoRig:
        """From two ``sensor_msgs/CameraInfo``-like mappings (``width``, ``height``, ``k``,
        ``d``, ``r``, ``p``: flat sequences) and the mounting."""
        def cam(m: Mapping[str, Any]) -> dict:
            return {'K': m['k'], 'D': m['d'], 'R': m['r'], 'P': m['p']}
        return cls(int(left['width']), int(left['height']), cam(left), cam(right),
                   R_vehicle_cam, t_vehicle_cam)

    # ---------------------------------------------------------------- intrinsics
    @property
    def f(self) -> float:
        """Rectified focal length along x (px)."""
        return float(self.left['P'][0, 0])

    @property
    def fy(self) -> float:
        return float(self.left['P'][1, 1])

    @property
    def cx(self) -> float:
        return float(self.left['P'][0, 2])

    @property
    def cy(self) -> float:
        return float(self.left['P'][1, 2])

    @property
    def cx_offset(self) -> float:
        """``cx_left - cx_right`` of the rectified pair (px; 0 for the KAIST calibration)."""
        return float(self.left['P'][0, 2] - self.right['P'][0, 2])

    @property
    def baseline_m(self) -> float:
        """``-P_right[0, 3] / P_right[0, 0]`` (m; 0.47515 m for KAIST)."""
        return float(-self.right['P'][0, 3] / self.right['P'][0, 0])

    def rect_to_vehicle(self, rectified_here: bool) -> tuple[np.ndarray, np.ndarray]:
        """``(R (3, 3), t (3,))`` with ``p_vehicle = R @ p_rect + t``.

        ``rectified_here``: the images are rectified by :meth:`rectify_maps` (the rectified
        camera is the raw one turned by ``R_left``); else they are taken as rectified already
        in the mounting frame (identity rectifying rotation, as the simulator renders them).
        """
        r = self.R_vehicle_cam @ self.left['R'].T if rectified_here else self.R_vehicle_cam
        return r, self.t_vehicle_cam.copy()

    def rectify_maps(self, side: str) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap`` maps (float32 x, y; full image) of one camera (cached)."""
        if side not in self._maps:
            c = getattr(self, side)
            self._maps[side] = cv2.initUndistortRectifyMap(
                c['K'], c['D'], c['R'], c['P'][:, :3], (self.width, self.height), cv2.CV_32FC1)
        return self._maps[side]

    def rectified_valid(self, side: str = 'left') -> np.ndarray:
        """Bool ``(H, W)``: rectified pixels that come from inside the raw image."""
        key = f'valid_{side}'
        if key not in self._maps:
            mx, my = self.rectify_maps(side)
            self._maps[key] = ((mx >= 0) & (mx <= self.width - 1) & (my >= 0)
                               & (my <= self.height - 1))
        return self._maps[key]

    def pixel_rays(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Rectified-camera rays ``[(u - cx) / f, (v - cy) / fy, 1]`` (N, 3) of pixels."""
        return np.stack([(np.asarray(u, np.float64) - self.cx) / self.f,
                         (np.asarray(v, np.float64) - self.cy) / self.fy,
                         np.ones(np.shape(u))], axis=-1)


# --------------------------------------------------------------------------------------------
# image helpers


def debayer(img: np.ndarray, encoding: str = 'bayer_rggb8', demosaic: str = 'bilinear',
            ) -> np.ndarray:
    """Raw image -> ``(H, W, 3)`` uint8 RGB.

    ``encoding`` is the ROS name: a Bayer pattern (:data:`BAYER_CODES`), ``'rgb8'``,
    ``'bgr8'`` or ``'mono8'``. ``demosaic``: OpenCV's ``'bilinear'`` (0.6 ms for 1280 x 560),
    edge-aware ``'ea'`` or ``'vng'`` (variable number of gradients, 11 ms: less colour moire
    on fine far stripes; 10 % lower colour error on a simulated drive).
    """
    a = np.asarray(img)
    if a.dtype != np.uint8:
        raise ValueError(f'image must be uint8, got {a.dtype}')
    enc = encoding.lower()
    if enc in BAYER_CODES:
        if a.ndim != 2:
            raise ValueError(f'{encoding} image must be (H, W), got {a.shape}')
        if demosaic not in _DEMOSAIC:
            raise ValueError(f'demosaic must be one of {tuple(_DEMOSAIC)}, got {demosaic!r}')
        return cv2.cvtColor(a, getattr(cv2, f'COLOR_BAYER_{_BAYER_CV[enc]}2RGB'
                                             f'{_DEMOSAIC[demosaic]}'))
    if enc == 'rgb8' and a.ndim == 3:
        return a
    if enc == 'bgr8' and a.ndim == 3:
        return np.ascontiguousarray(a[..., ::-1])
    if enc in ('mono8', '8uc1') and a.ndim == 2:
        return cv2.cvtColor(a, cv2.COLOR_GRAY2RGB)
    raise ValueError(f'unsupported image encoding {encoding!r} for shape {a.shape}')


def grey(img: np.ndarray, encoding: str = 'bayer_rggb8') -> np.ndarray:
    """Raw image -> ``(H, W)`` uint8 grey (Bayer images straight from the mosaic)."""
    a = np.asarray(img)
    enc = encoding.lower()
    if enc in BAYER_CODES and a.ndim == 2 and a.dtype == np.uint8:
        return cv2.cvtColor(a, getattr(cv2, f'COLOR_BAYER_{_BAYER_CV[enc]}2GRAY'))
    if enc in ('mono8', '8uc1') and a.ndim == 2 and a.dtype == np.uint8:
        return a
    return cv2.cvtColor(debayer(a, encoding), cv2.COLOR_RGB2GRAY)


def _orb_vertical_offset(a: np.ndarray, b: np.ndarray) -> tuple[float, int]:
    """Median ``|v_b - v_a|`` (px) of cross-checked ORB matches between grey images, count."""
    orb = cv2.ORB_create(2000)
    ka, da = orb.detectAndCompute(a, None)
    kb, db = orb.detectAndCompute(b, None)
    if da is None or db is None:
        return math.inf, 0
    m = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(da, db)
    if not m:
        return math.inf, 0
    pa = np.array([ka[x.queryIdx].pt for x in m])
    pb = np.array([kb[x.trainIdx].pt for x in m])
    dy = np.abs(pb[:, 1] - pa[:, 1])
    dx = pa[:, 0] - pb[:, 0]
    ok = (dy < 20.0) & (dx > -2.0)  # plausible stereo matches (right image shifted left)
    if ok.sum() < 1:
        return math.inf, 0
    return float(np.median(dy[ok])), int(ok.sum())


def detect_rectified(left: np.ndarray, right: np.ndarray, rig: StereoRig,
                     min_matches: int = 30) -> Optional[bool]:
    """Whether a pair (grey or RGB, full size) is rectified already: True / False, None when
    undecided.

    Compares the median vertical offset of ORB matches of the images as they are and after
    rectification with the rig's maps; the smaller one wins (needs ``min_matches`` matches).
    """
    gl = left if left.ndim == 2 else cv2.cvtColor(left, cv2.COLOR_RGB2GRAY)
    gr = right if right.ndim == 2 else cv2.cvtColor(right, cv2.COLOR_RGB2GRAY)
    raw, n_raw = _orb_vertical_offset(gl, gr)
    rl = cv2.remap(gl, *rig.rectify_maps('left'), cv2.INTER_LINEAR)
    rr = cv2.remap(gr, *rig.rectify_maps('right'), cv2.INTER_LINEAR)
    rect, n_rect = _orb_vertical_offset(rl, rr)
    if n_raw < min_matches and n_rect < min_matches:
        return None
    return bool(raw <= rect)


def interpolate_poses(stamps: np.ndarray, poses: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Poses ``(x, y, theta)`` at ``query`` times, linear between the two neighbours.

    ``stamps`` (K,) increasing (any time unit; int64 ns works), ``poses`` (K, 3); theta is
    unwrapped before interpolating and wrapped to (-pi, pi] after. Queries outside
    ``[stamps[0], stamps[-1]]`` get NaN rows.
    """
    st = np.asarray(stamps)
    ps = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    q = np.atleast_1d(np.asarray(query))
    out = np.full((len(q), 3), np.nan)
    if len(st) == 0:
        return out
    ok = (q >= st[0]) & (q <= st[-1])
    if not ok.any():
        return out
    i = np.clip(np.searchsorted(st, q[ok], side='right') - 1, 0, max(len(st) - 2, 0))
    j = np.minimum(i + 1, len(st) - 1)
    span = (st[j] - st[i]).astype(np.float64)
    with np.errstate(invalid='ignore', divide='ignore'):
        w = np.where(span > 0, (q[ok] - st[i]).astype(np.float64) / span, 0.0)
    th = np.unwrap(ps[:, 2])
    out[ok, 0] = ps[i, 0] + w * (ps[j, 0] - ps[i, 0])
    out[ok, 1] = ps[i, 1] + w * (ps[j, 1] - ps[i, 1])
    t = th[i] + w * (th[j] - th[i])
    out[ok, 2] = np.arctan2(np.sin(t), np.cos(t))
    return out


# --------------------------------------------------------------------------------------------
# plane


@dataclasses.dataclass(frozen=True)
class Plane:
    """Plane ``n . p + c = 0`` in the vehicle frame (``n`` unit, ``n_z > 0``).

    ``height_of(p) = n . p + c`` is the signed height above it (m).
    """

    normal: np.ndarray
    c: float

    @staticmethod
    def nominal() -> Plane:
        """The vehicle frame's ground ``z = 0``."""
        return Plane(np.array([0.0, 0.0, 1.0]), 0.0)

    def height_of(self, p: np.ndarray) -> np.ndarray:
        """Signed heights ``(...)`` of points ``(..., 3)`` above the plane (m)."""
        return _dot3(np.asarray(p), self.normal) + self.c

    @property
    def tilt_deg(self) -> float:
        """Angle between ``n`` and the vehicle z axis (deg)."""
        return float(np.degrees(np.arccos(np.clip(self.normal[2], -1.0, 1.0))))


def fit_ground_plane(points: np.ndarray, iterations: int = 64, tol_m: float = 0.05,
                     max_points: int = 4000, max_tilt_deg: float = 10.0,
                     rng: Optional[np.random.Generator] = None,
                     ) -> tuple[Optional[Plane], np.ndarray]:
    """RANSAC (vectorised over hypotheses) + least-squares plane through 3D points.

    Parameters
    ----------
    points : (N, 3)
        Vehicle-frame points (m), mostly ground.
    iterations, tol_m, max_points :
        Hypotheses, inlier distance (m), points scored (random subset).
    max_tilt_deg :
        Hypotheses tilted more than this from z are not considered.

    Returns
    -------
    plane : Plane or None
        None with fewer than 3 points or no acceptable hypothesis.
    inliers : (N,) bool
        Points within ``tol_m`` of the refined plane.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n_pts = len(p)
    if n_pts < 3:
        return None, np.zeros(n_pts, dtype=bool)
    rng = np.random.default_rng(0) if rng is None else rng
    sub = p if n_pts <= max_points else p[rng.choice(n_pts, max_points, replace=False)]
    idx = rng.integers(0, len(sub), size=(iterations, 3))
    a, b, c = sub[idx[:, 0]], sub[idx[:, 1]], sub[idx[:, 2]]
    nrm = np.cross(b - a, c - a)
    norm = np.linalg.norm(nrm, axis=1)
    good = norm > 1e-9
    nrm[good] /= norm[good, None]
    nrm *= np.where(nrm[:, 2] < 0, -1.0, 1.0)[:, None]
    good &= nrm[:, 2] >= math.cos(math.radians(max_tilt_deg))
    if not good.any():
        return None, np.zeros(n_pts, dtype=bool)
    nrm, a = nrm[good], a[good]
    off = -np.einsum('ij,ij->i', nrm, a)
    score = (np.abs(np.einsum('nj,hj->nh', sub, nrm) + off) < tol_m).sum(axis=0)
    k = int(np.argmax(score))
    normal, c0 = nrm[k], float(off[k])
    # least-squares refinement on the scored subset (twice: the inlier set moves with the
    # plane); explicit sums, no BLAS threads (they only contend on a busy 2-core machine)
    for _ in range(2):
        inl = np.abs(_dot3(sub, normal) + c0) < tol_m
        if inl.sum() < 3:
            return None, np.zeros(n_pts, dtype=bool)
        q = sub[inl]
        mean = q.mean(axis=0)
        d = q - mean
        _, vecs = np.linalg.eigh(np.einsum('ni,nj->ij', d, d) / len(d))
        normal = vecs[:, 0] * (1.0 if vecs[2, 0] >= 0 else -1.0)
        c0 = -float(mean @ normal)
    return Plane(normal, c0), np.abs(_dot3(p, normal) + c0) < tol_m


def _dot3(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``p @ n`` for ``(..., 3)`` points, as three multiply-adds (no BLAS)."""
    return p[..., 0] * n[0] + p[..., 1] * n[1] + p[..., 2] * n[2]


# --------------------------------------------------------------------------------------------
# the accumulator


class TextureMap:
    """Running-mean RGB per world cell, in tiles allocated on demand.

    Cell ``(i, j)`` (column i along x, row j along y) covers
    ``[anchor_x + i * cell_m, + cell_m) x [anchor_y + j * cell_m, + cell_m)``; tiles are
    ``tile_cells`` x ``tile_cells`` cells. Memory: 16 bytes per cell of an allocated tile.

    Parameters
    ----------
    cell_m : float
        Cell size (m).
    tile_cells : int
        Tile edge (cells).
    max_tiles : int
        Tiles allocated at most; samples in further tiles are dropped (``samples_dropped``).
    anchor_xy : (2,)
        World corner of cell ``(0, 0)`` (m): align it with the map whose geometry the
        texture will be rendered in (``/map``'s origin) to avoid resampling shifts.
    """

    def __init__(self, cell_m: float = 0.1, tile_cells: int = 128, max_tiles: int = 1024,
                 anchor_xy: tuple[float, float] | np.ndarray = (0.0, 0.0)) -> None:
        if not cell_m > 0 or tile_cells < 1 or max_tiles < 1:
            raise ValueError(f'bad texture map geometry: cell {cell_m}, tile {tile_cells}, '
                             f'max tiles {max_tiles}')
        self.cell_m = float(cell_m)
        self.tile_cells = int(tile_cells)
        self.max_tiles = int(max_tiles)
        self.anchor = np.asarray(anchor_xy, dtype=np.float64).reshape(2).copy()
        #: (tx, ty) -> (mean (T, T, 3) float32, count (T, T) float32); row = y, column = x
        self.tiles: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self.samples_added = 0
        self.samples_dropped = 0

    @classmethod
    def from_config(cls, cfg: TextureConfig, anchor_xy: tuple[float, float] | np.ndarray = (0.0, 0.0),
                    ) -> TextureMap:
        return cls(cfg.cell_m, cfg.tile_cells, cfg.max_tiles, anchor_xy)

    @property
    def memory_bytes(self) -> int:
        return 16 * self.tile_cells ** 2 * len(self.tiles)

    def cells_of(self, xy: np.ndarray) -> np.ndarray:
        """World ``(N, 2)`` (m) -> int64 cell indices ``(N, 2)`` ``[i (x), j (y)]``."""
        return np.floor((np.asarray(xy, dtype=np.float64) - self.anchor) / self.cell_m
                        ).astype(np.int64)

    def add(self, xy: np.ndarray, rgb: np.ndarray) -> int:
        """Add samples: world points ``(N, 2)`` (m) with colours ``(N, 3)`` (0..255).

        Every sample weighs 1: a cell's colour is the mean of all samples that fell in it
        (``mean += (sum - n mean) / (count + n)`` per cell and call). Returns the number of
        samples added (the rest needed a tile beyond ``max_tiles``).
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        col = np.asarray(rgb, dtype=np.float32).reshape(-1, 3)
        if len(xy) != len(col):
            raise ValueError(f'{len(xy)} points but {len(col)} colours')
        ok = np.isfinite(xy).all(axis=1)
        if not ok.all():
            xy, col = xy[ok], col[ok]
        if not len(xy):
            return 0
        t = self.tile_cells
        cells = self.cells_of(xy)
        tiles = np.floor_divide(cells, t)
        tlo, thi = tiles.min(axis=0), tiles.max(axis=0)
        ntx, nty = (thi - tlo + 1).tolist()
        if ntx * nty > 64:  # scattered input: one call per group of nearby samples
            key = (tiles[:, 0] - tlo[0]) // 8 * (nty // 8 + 1) + (tiles[:, 1] - tlo[1]) // 8
            order = np.argsort(key, kind='stable')
            ks = key[order]
            cuts = np.flatnonzero(ks[1:] != ks[:-1]) + 1
            return sum(self.add(xy[g], col[g]) for g in np.split(order, cuts))
        # dense bincount over the tile-aligned bounding box of this batch
        gw, gh = ntx * t, nty * t
        loc = cells - tlo * t
        flat = loc[:, 1] * gw + loc[:, 0]
        n = np.bincount(flat, minlength=gw * gh).reshape(gh, gw)
        sums = np.stack([np.bincount(flat, weights=col[:, ch], minlength=gw * gh)
                         for ch in range(3)], axis=-1).reshape(gh, gw, 3)
        added = 0
        for jy in range(nty):
            for ix in range(ntx):
                nn = n[jy * t:(jy + 1) * t, ix * t:(ix + 1) * t]
                touched = nn > 0
                if not touched.any():
                    continue
                n_here = int(nn.sum())
                tk = (int(tlo[0]) + ix, int(tlo[1]) + jy)
                tile = self.tiles.get(tk)
                if tile is None:
                    if len(self.tiles) >= self.max_tiles:
                        self.samples_dropped += n_here
                        continue
                    tile = (np.zeros((t, t, 3), np.float32), np.zeros((t, t), np.float32))
                    self.tiles[tk] = tile
                mean, count = tile
                ss = sums[jy * t:(jy + 1) * t, ix * t:(ix + 1) * t][touched]
                nt = nn[touched].astype(np.float64)
                c_new = count[touched] + nt
                m = mean[touched]
                mean[touched] = m + ((ss - nt[:, None] * m) / c_new[:, None]).astype(np.float32)
                count[touched] = c_new
                added += n_here
        self.samples_added += added
        return added

    def covered_bounds(self) -> Optional[tuple[float, float, float, float]]:
        """World ``(xmin, ymin, xmax, ymax)`` of the allocated tiles (m), or None."""
        if not self.tiles:
            return None
        k = np.array(list(self.tiles), dtype=np.int64)
        ext = self.tile_cells * self.cell_m
        lo = self.anchor + k.min(axis=0) * ext
        hi = self.anchor + (k.max(axis=0) + 1) * ext
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    def cell_count(self) -> int:
        """Cells with at least one sample."""
        return int(sum(int((c > 0).sum()) for _, c in self.tiles.values()))

    def render(self, origin_xy: tuple[float, float] | np.ndarray, resolution: float,
               width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """The texture in a map geometry (``OccupancyGrid`` layout, row 0 = lowest y).

        An output cell coarser than 1.5 texture cells is the sample-weighted mean of the
        texture cells whose centres fall in it; a finer (or similar) one takes the texture cell
        containing its centre (exact when the grids are aligned). Work memory is per block of
        256 x 256 output cells; only the output itself (4 bytes per cell) is whole.

        Returns
        -------
        rgb : (height, width, 3) uint8
            Observed cells never ``(0, 0, 0)`` (clamped to 1); unobserved cells 0.
        covered : (height, width) bool
        """
        w, h = int(width), int(height)
        if w <= 0 or h <= 0 or not resolution > 0:
            raise ValueError(f'bad render geometry {w} x {h} at {resolution!r} m')
        o = np.asarray(origin_xy, dtype=np.float64).reshape(-1)[:2]
        res = float(resolution)
        t, cm = self.tile_cells, self.cell_m
        ext = t * cm
        coarse = res >= 1.5 * cm
        rgb = np.zeros((h, w, 3), np.uint8)
        covered = np.zeros((h, w), bool)
        blk = 256
        # output cell range each tile can write, and the output blocks it meets
        jobs: dict[tuple[int, int], list] = {}
        for key in self.tiles:
            corner = self.anchor + np.array(key, dtype=np.float64) * ext
            if coarse:  # cells containing the texture cell centres
                lo = np.floor((corner + 0.5 * cm - o) / res).astype(np.int64)
                hi = np.floor((corner + ext - 0.5 * cm - o) / res).astype(np.int64) + 1
            else:  # cells whose centres lie in the tile
                lo = np.ceil((corner - o) / res - 0.5).astype(np.int64)
                hi = np.ceil((corner + ext - o) / res - 0.5).astype(np.int64)
            lo = np.maximum(lo, 0)
            hi = np.minimum(hi, [w, h])
            if (lo >= hi).any():
                continue
            for by in range(int(lo[1]) // blk, (int(hi[1]) - 1) // blk + 1):
                for bx in range(int(lo[0]) // blk, (int(hi[0]) - 1) // blk + 1):
                    jobs.setdefault((bx, by), []).append((key, corner))
        for (bx, by), tiles in jobs.items():
            c0, r0 = bx * blk, by * blk
            c1, r1 = min(c0 + blk, w), min(r0 + blk, h)
            bw, bh = c1 - c0, r1 - r0
            if coarse:
                sums = np.zeros((bh * bw, 3), np.float64)
                cnts = np.zeros(bh * bw, np.float64)
            else:
                mean_b = np.zeros((bh, bw, 3), np.float32)
                cnt_b = np.zeros((bh, bw), np.float32)
            for key, corner in tiles:
                mean, count = self.tiles[key]
                if coarse:
                    jj, ii = np.nonzero(count > 0)
                    oc = np.floor((corner[0] + (ii + 0.5) * cm - o[0]) / res).astype(np.int64) - c0
                    orow = np.floor((corner[1] + (jj + 0.5) * cm - o[1]) / res).astype(np.int64) - r0
                    ok = (oc >= 0) & (oc < bw) & (orow >= 0) & (orow < bh)
                    if not ok.any():
                        continue
                    fl = orow[ok] * bw + oc[ok]
                    cw = count[jj[ok], ii[ok]].astype(np.float64)
                    cnts += np.bincount(fl, weights=cw, minlength=bh * bw)
                    m = mean[jj[ok], ii[ok]]
                    for ch in range(3):
                        sums[:, ch] += np.bincount(fl, weights=m[:, ch] * cw, minlength=bh * bw)
                else:
                    xs = o[0] + (np.arange(c0, c1) + 0.5) * res
                    ys = o[1] + (np.arange(r0, r1) + 0.5) * res
                    ii = np.floor((xs - corner[0]) / cm).astype(np.int64)
                    jj = np.floor((ys - corner[1]) / cm).astype(np.int64)
                    ci = np.flatnonzero((ii >= 0) & (ii < t))
                    ri = np.flatnonzero((jj >= 0) & (jj < t))
                    if not ci.size or not ri.size:
                        continue
                    sel = np.ix_(ri, ci)
                    mean_b[sel] = mean[jj[ri][:, None], ii[ci][None, :]]
                    cnt_b[sel] = count[jj[ri][:, None], ii[ci][None, :]]
            if coarse:
                cov_b = (cnts > 0).reshape(bh, bw)
                mean_b = (sums / np.maximum(cnts, 1e-12)[:, None]).reshape(bh, bw, 3)
            else:
                cov_b = cnt_b > 0
            out = np.clip(np.rint(mean_b), 0, 255).astype(np.uint8)
            out[cov_b] = np.maximum(out[cov_b], 1)
            out[~cov_b] = 0
            rgb[r0:r1, c0:c1] = out
            covered[r0:r1, c0:c1] = cov_b
        return rgb, covered

    def render_native(self) -> Optional[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """``(rgb, covered, origin_xy)`` over the allocated tiles at ``cell_m``, or None."""
        b = self.covered_bounds()
        if b is None:
            return None
        n = np.rint((np.array(b[2:]) - np.array(b[:2])) / self.cell_m).astype(int)
        rgb, cov = self.render(b[:2], self.cell_m, int(n[0]), int(n[1]))
        return rgb, cov, np.array(b[:2])


# --------------------------------------------------------------------------------------------
# per-pair processing


@dataclasses.dataclass
class FrameResult:
    """What one stereo pair gave.

    Attributes
    ----------
    xy_world : (N, 2)
        World positions of the ground samples (m; empty without a pose): the pixel samples,
        then the ``n_fill`` gap-filling samples (cell centres).
    xy_vehicle : (N - n_fill, 2)
        The pixel samples in the vehicle frame (m; also without a pose).
    rgb : (N, 3) uint8
        The colours of ``xy_world`` (of ``xy_vehicle`` without a pose).
    plane : Plane
        Road plane used (vehicle frame).
    plane_fitted : bool
        False: the fit failed or was rejected; the nominal plane was used.
    rectified_here : bool
        The pair was rectified by this frame's processing.
    disparity : (h, w) float32
        Disparity (full-resolution px, NaN invalid) at the downscaled resolution of the
        processed rows; pixel ``(i, j)`` covers full-resolution rows
        ``first_row + k i .. + k - 1`` and columns ``k j .. + k - 1`` (``k = downscale``).
    first_row : int
        First full-resolution row processed.
    valid_fraction : float
        Valid disparity fraction over the processed rows.
    timings_ms : dict
        ``'debayer'``, ``'rectify'``, ``'disparity'``, ``'ground'``, ``'total'`` (ms).
    n_fill : int
        Samples (the last ones) from gap filling.
    """

    xy_world: np.ndarray
    xy_vehicle: np.ndarray
    rgb: np.ndarray
    plane: Plane
    plane_fitted: bool
    rectified_here: bool
    disparity: np.ndarray
    first_row: int
    valid_fraction: float
    timings_ms: dict
    n_fill: int = 0


class StereoTexturer:
    """Turns stereo pairs into coloured ground samples (see the module docstring).

    Parameters
    ----------
    rig : StereoRig
    cfg : TextureConfig
    """

    def __init__(self, rig: StereoRig, cfg: Optional[TextureConfig] = None) -> None:
        self.rig = rig
        self.cfg = cfg or TextureConfig()
        self.rng = np.random.default_rng(self.cfg.seed)
        self._rectify: Optional[bool] = {'yes': True, 'no': False}.get(self.cfg.rectify)
        k = self.cfg.downscale
        nd = self.cfg.num_disparities // k
        bs = self.cfg.block_size
        self._pad = nd
        self._sgbm = cv2.StereoSGBM_create(
            minDisparity=0, numDisparities=nd, blockSize=bs,
            P1=int(round(self.cfg.p1 * bs * bs)), P2=int(round(self.cfg.p2 * bs * bs)),
            disp12MaxDiff=self.cfg.disp12_max_diff, uniquenessRatio=self.cfg.uniqueness_ratio,
            speckleWindowSize=self.cfg.speckle_window, speckleRange=self.cfg.speckle_range,
            preFilterCap=self.cfg.pre_filter_cap, mode=_SGBM_MODES[self.cfg.sgbm_mode])
        self._clahe = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 8))
        self.first_row = self._first_row()
        self._stride_cache: dict[tuple[int, int], np.ndarray] = {}

    @property
    def rectify(self) -> Optional[bool]:
        """Whether pairs are rectified here (None: ``'auto'`` has not decided yet)."""
        return self._rectify

    def _first_row(self) -> int:
        """First full-resolution row that can see the ground within ``max_range_m``
        (nominal plane, rectified camera), minus ``row_margin_px``; a multiple of downscale."""
        cfg, rig = self.cfg, self.rig
        r_vc, t = rig.rect_to_vehicle(True)
        p = np.array([t[0] + cfg.max_range_m, t[1], 0.0])  # ground straight ahead
        q = r_vc.T @ (p - t)
        v = rig.cy + rig.fy * q[1] / q[2] if q[2] > 0 else 0.0
        v0 = int(math.floor(v)) - cfg.row_margin_px
        v0 = min(max(v0, 0), rig.height - 8 * cfg.downscale)
        return v0 - v0 % cfg.downscale

    # ---------------------------------------------------------------- stages
    def prepare(self, left: np.ndarray, right: np.ndarray, encoding: str = 'bayer_rggb8',
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, Optional[np.ndarray], dict]:
        """Demosaic + rectify the processed rows (``first_row:``).

        Returns ``(left_rgb, left_grey, right_grey, valid, timings)``: the left colour image
        (``demosaic`` method), the grey images for matching (OpenCV's Bayer-to-grey, the same
        for both cameras), ``valid`` (bool) marking rectified pixels from inside the raw image
        (None when not rectified here), and ``timings`` (ms, plus ``'rectified_here'``).
        """
        t0 = time.perf_counter()
        lrgb = debayer(left, encoding, self.cfg.demosaic)
        lg, rg = grey(left, encoding), grey(right, encoding)
        for img in (lrgb, rg):
            if img.shape[:2] != (self.rig.height, self.rig.width):
                raise ValueError(f'image is {img.shape[1]} x {img.shape[0]}, the calibration '
                                 f'{self.rig.width} x {self.rig.height}')
        t1 = time.perf_counter()
        if self._rectify is None:
            already = detect_rectified(lg, rg, self.rig)
            self._rectify = None if already is None else not already
        rect = True if self._rectify is None else self._rectify
        v0 = self.first_row
        valid = None
        if rect:
            outs = []
            for side, img in (('left', lrgb), ('left', lg), ('right', rg)):
                mx, my = self.rig.rectify_maps(side)
                outs.append(cv2.remap(img, mx[v0:], my[v0:], cv2.INTER_LINEAR,
                                      borderMode=cv2.BORDER_CONSTANT))
            lrgb, lg, rg = outs
            valid = self.rig.rectified_valid('left')[v0:]
        else:
            lrgb, lg, rg = lrgb[v0:], lg[v0:], rg[v0:]
        t2 = time.perf_counter()
        return lrgb, lg, rg, valid, {'debayer': 1e3 * (t1 - t0), 'rectify': 1e3 * (t2 - t1),
                                     'rectified_here': rect}

    def disparity(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """SGBM disparity of (cropped) rectified grey (or RGB) images.

        Returns ``(h // k, w // k)`` float32 disparity in full-resolution px (NaN = invalid),
        ``k = downscale``.
        """
        k = self.cfg.downscale
        gl = left if left.ndim == 2 else cv2.cvtColor(left, cv2.COLOR_RGB2GRAY)
        gr = right if right.ndim == 2 else cv2.cvtColor(right, cv2.COLOR_RGB2GRAY)
        if self.cfg.prefilter == 'clahe':
            gl, gr = self._clahe.apply(gl), self._clahe.apply(gr)
        elif self.cfg.prefilter == 'equalize':
            gl, gr = cv2.equalizeHist(gl), cv2.equalizeHist(gr)
        h, w = gl.shape
        h, w = h - h % k, w - w % k
        if k > 1:
            gl = cv2.resize(gl[:h, :w], (w // k, h // k), interpolation=cv2.INTER_AREA)
            gr = cv2.resize(gr[:h, :w], (w // k, h // k), interpolation=cv2.INTER_AREA)
        pad = self._pad
        gl = cv2.copyMakeBorder(gl, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0)
        gr = cv2.copyMakeBorder(gr, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0)
        raw = self._sgbm.compute(gl, gr)[:, pad:]
        disp = raw.astype(np.float32) * np.float32(k / 16.0)
        disp[raw <= 0] = np.nan
        return disp

    def _grid_rays(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Separable rectified-camera ray components ``(ry (h, 1), rx (1, w))`` float32 of
        full-resolution pixel rows / columns (``ray = [rx, ry, 1]``)."""
        rig = self.rig
        ry = ((np.asarray(rows, np.float64) - rig.cy) / rig.fy).astype(np.float32)[:, None]
        rx = ((np.asarray(cols, np.float64) - rig.cx) / rig.f).astype(np.float32)[None, :]
        return ry, rx

    def point_grid(self, disp: np.ndarray, rectified_here: bool) -> np.ndarray:
        """Vehicle-frame points ``(h, w, 3)`` float32 of a disparity image (NaN = invalid).

        Pixel ``(i, j)`` of ``disp`` is the mean of full-resolution pixels
        ``first_row + k i .. + k - 1``, ``k j .. + k - 1``: its centre is
        ``(k j + (k - 1) / 2, first_row + k i + (k - 1) / 2)``.
        """
        k = self.cfg.downscale
        h, w = disp.shape
        ry, rx = self._grid_rays(self.first_row + k * np.arange(h) + 0.5 * (k - 1),
                                 k * np.arange(w) + 0.5 * (k - 1))
        d = disp - np.float32(self.rig.cx_offset)
        with np.errstate(divide='ignore', invalid='ignore'):
            z = np.where(d > 0, np.float32(self.rig.f * self.rig.baseline_m) / d, np.nan
                         ).astype(np.float32)
        r_vc, t = self.rig.rect_to_vehicle(rectified_here)
        r = r_vc.astype(np.float32)
        out = np.empty((h, w, 3), np.float32)
        for i in range(3):
            out[..., i] = (r[i, 0] * rx + r[i, 1] * ry + r[i, 2]) * z + np.float32(t[i])
        return out

    def points(self, disp: np.ndarray, rectified_here: bool
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vehicle-frame points of the valid disparities: ``(p (N, 3) float64, rows (N,),
        cols (N,))``, rows / columns indexing ``disp``."""
        g = self.point_grid(disp, rectified_here)
        rr, cc = np.nonzero(np.isfinite(g[..., 2]))
        return g[rr, cc].astype(np.float64), rr, cc

    def _in_box(self, p: np.ndarray) -> np.ndarray:
        """Bool ``(...)``: vehicle-frame points ``(..., >=2)`` inside the range box."""
        return self._in_box_xy(p[..., 0], p[..., 1])

    def _in_box_xy(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bool: vehicle-frame ``x``, ``y`` (m, any shape) inside the range box."""
        t = self.rig.t_vehicle_cam
        ahead = x - np.float32(t[0])
        with np.errstate(invalid='ignore'):
            return ((ahead >= self.cfg.min_range_m) & (ahead <= self.cfg.max_range_m)
                    & (np.abs(y - np.float32(t[1])) <= self.cfg.max_lateral_m))

    def ground_plane(self, p: np.ndarray) -> tuple[Plane, bool]:
        """Road plane of one pair's vehicle-frame points (nominal plane on failure)."""
        cfg = self.cfg
        nominal = Plane.nominal()
        if not cfg.plane_fit:
            return nominal, False
        near = self._in_box(p) & (np.abs(p[:, 2]) < cfg.plane_max_offset_m + cfg.ransac_tol_m)
        plane, _ = fit_ground_plane(p[near], cfg.ransac_iterations, cfg.ransac_tol_m,
                                    cfg.ransac_max_points, cfg.plane_max_tilt_deg, self.rng)
        if plane is None or plane.tilt_deg > cfg.plane_max_tilt_deg \
                or abs(plane.c) > cfg.plane_max_offset_m:
            return nominal, False
        return plane, True

    def _stride_mask(self, h: int, w: int) -> np.ndarray:
        """Bool ``(h, w)`` (rows from ``first_row``): the pixels sampled for splatting.

        Near the car a cell holds hundreds of pixels (5 m ahead: 2 cm along x 6 mm across at
        the KAIST rig); a row whose ground footprint (nominal plane) is below ``cell_m / 4``
        keeps every ``s``-th row and column, ``s = floor(cell_m / (4 footprint))`` clipped to
        ``pixel_stride_max``: each cell still gets >= ~16 samples, for a quarter of the work.
        """
        key = (h, w)
        m = self._stride_cache.get(key)
        if m is None:
            rig, cfg = self.rig, self.cfg
            v = self.first_row + np.arange(h, dtype=np.float64)
            cam_h = max(float(rig.t_vehicle_cam[2]), 1e-3)
            with np.errstate(divide='ignore', invalid='ignore'):
                z = np.where(v > rig.cy + 1.0, rig.fy * cam_h / (v - rig.cy), np.inf)
                fp = np.maximum(z * z / (rig.fy * cam_h), z / rig.f)
                stride = np.where(np.isfinite(fp), np.floor(cfg.cell_m / (4.0 * fp)), 1.0)
            stride = np.clip(np.nan_to_num(stride, nan=1.0), 1, cfg.pixel_stride_max)
            stride = stride.astype(np.int64)
            rows = (np.arange(h) % stride) == 0
            cols = (np.arange(w)[None, :] % stride[:, None]) == 0
            m = rows[:, None] & cols
            self._stride_cache[key] = m
        return m

    def process(self, left: np.ndarray, right: np.ndarray,
                pose: Optional[np.ndarray] = None, encoding: str = 'bayer_rggb8',
                cells: Optional[tuple[np.ndarray, float]] = None) -> FrameResult:
        """One stereo pair -> coloured ground samples.

        Parameters
        ----------
        left, right : numpy.ndarray
            Raw images (``encoding``).
        pose : (3,), optional
            Vehicle pose ``(x, y, theta)`` (m, rad) in the world at the images' stamp;
            ``xy_world`` is empty without it.
        cells : (anchor_xy (2,), cell_m), optional
            The texture grid: with ``fill_gaps``, its cells in view that no ground pixel fell
            in get one sample at their centre (see :meth:`_fill`).
        """
        cfg, rig = self.cfg, self.rig
        t0 = time.perf_counter()
        lrgb, lg, rg, valid, tm = self.prepare(left, right, encoding)
        rect = bool(tm.pop('rectified_here'))
        t1 = time.perf_counter()
        disp = self.disparity(lg, rg)
        k = cfg.downscale
        if valid is not None:  # no disparity where the rectified left image has no data
            vk = valid[: disp.shape[0] * k: k, : disp.shape[1] * k: k]
            disp[~vk[: disp.shape[0], : disp.shape[1]]] = np.nan
        t2 = time.perf_counter()
        grid = self.point_grid(disp, rect)
        fin = np.isfinite(grid[..., 2])
        p = grid[fin].astype(np.float64)
        plane, fitted = self.ground_plane(p)
        n32 = plane.normal.astype(np.float32)
        t = rig.t_vehicle_cam.astype(np.float32)
        with np.errstate(invalid='ignore'):
            hgt = _dot3(grid, n32) + np.float32(plane.c)
            ground_ds = (np.abs(hgt) < cfg.height_tol_m) & self._in_box(grid)
            if cfg.obstacle_margin_px > 0:  # block matching fattens objects over the ground
                m = 2 * cfg.obstacle_margin_px + 1
                above = cv2.dilate((hgt > cfg.height_tol_m).astype(np.uint8),
                                   np.ones((m, m), np.uint8))
                ground_ds &= above == 0
        # full-resolution ground pixels
        hf, wf = lrgb.shape[:2]
        full = np.zeros((hf, wf), dtype=bool)
        up = np.repeat(np.repeat(ground_ds, k, axis=0), k, axis=1)
        full[: up.shape[0], : up.shape[1]] = up
        if valid is not None:
            full &= valid
        ground_full = full.copy()  # for gap filling
        full &= self._stride_mask(hf, wf)
        if cfg.snap_to_plane:  # ray-plane intersection, separable in rows and columns
            r_vc, _ = rig.rect_to_vehicle(rect)
            r = r_vc.astype(np.float32)
            ry, rx = self._grid_rays(self.first_row + np.arange(hf), np.arange(wf))
            q = [r[i, 0] * rx + r[i, 1] * ry + r[i, 2] for i in range(3)]  # vehicle rays
            nq = n32[0] * q[0] + n32[1] * q[1] + n32[2] * q[2]
            with np.errstate(divide='ignore', invalid='ignore'):
                sc = -np.float32(float(plane.normal @ rig.t_vehicle_cam) + plane.c) / nq
                full &= sc > 0
                px = t[0] + sc * q[0]
                py = t[1] + sc * q[1]
                full &= self._in_box_xy(px, py)
            xy_v = np.stack([px[full], py[full]], axis=-1).astype(np.float64)
        else:  # each full-resolution pixel takes the stereo point of its disparity pixel
            gu = np.repeat(np.repeat(grid[..., :2], k, axis=0), k, axis=1)
            g2 = np.zeros((hf, wf, 2), np.float32)
            g2[: gu.shape[0], : gu.shape[1]] = gu
            xy_v = g2[full].astype(np.float64)
        rgb = lrgb[full]
        n_fill = 0
        if pose is not None:
            x, y, th = (float(a) for a in np.asarray(pose, dtype=np.float64).reshape(3))
            c, s_ = math.cos(th), math.sin(th)
            xy_w = np.column_stack([x + c * xy_v[:, 0] - s_ * xy_v[:, 1],
                                    y + s_ * xy_v[:, 0] + c * xy_v[:, 1]])
            if cells is not None and cfg.fill_gaps:
                fxy, frgb = self._fill(np.array([x, y, th]), cells, xy_w, ground_full, lrgb,
                                        plane, rect)
                n_fill = len(fxy)
                if n_fill:
                    xy_w = np.concatenate([xy_w, fxy])
                    rgb = np.concatenate([rgb, frgb])
        else:
            xy_w = np.zeros((0, 2))
        t3 = time.perf_counter()
        tm.update(disparity=1e3 * (t2 - t1), ground=1e3 * (t3 - t2), total=1e3 * (t3 - t0))
        n_proc = disp.size if valid is None else max(int(valid[::k, ::k].sum()), 1)
        return FrameResult(xy_w, xy_v, rgb, plane, fitted, rect, disp, self.first_row,
                           float(np.isfinite(disp).sum() / max(n_proc, 1)), tm, n_fill)

    def _fill(self, pose: np.ndarray, cells: tuple[np.ndarray, float], xy_w: np.ndarray,
              ground: np.ndarray, lrgb: np.ndarray, plane: Plane, rect: bool,
              ) -> tuple[np.ndarray, np.ndarray]:
        """Gap filling: the cells of the frame's range box that no ground pixel fell in, whose
        centre projects onto a ground pixel, get the bilinear colour at that projection.

        Far away an image row spans more than a cell (0.33 m at 20 m for the KAIST rig), so
        pixel splatting alone leaves stripes; near, a cell holds many pixels and is left to
        them (area average). Returns ``(xy (M, 2) cell centres, rgb (M, 3))``.
        """
        cfg, rig = self.cfg, self.rig
        anchor, cm = np.asarray(cells[0], dtype=np.float64).reshape(2), float(cells[1])
        x, y, th = pose
        c, s = math.cos(th), math.sin(th)
        t = rig.t_vehicle_cam
        bx = t[0] + np.array([cfg.min_range_m, cfg.min_range_m, cfg.max_range_m, cfg.max_range_m])
        by = t[1] + np.array([-1.0, 1.0, -1.0, 1.0]) * cfg.max_lateral_m
        wx, wy = x + c * bx - s * by, y + s * bx + c * by
        i0, j0 = np.floor((np.array([wx.min(), wy.min()]) - anchor) / cm).astype(np.int64)
        i1, j1 = np.floor((np.array([wx.max(), wy.max()]) - anchor) / cm).astype(np.int64) + 1
        ni, nj = int(i1 - i0), int(j1 - j0)
        if ni <= 0 or nj <= 0 or ni * nj > 4_000_000:
            return np.zeros((0, 2)), np.zeros((0, 3), np.uint8)
        hit = np.zeros((nj, ni), dtype=bool)
        if len(xy_w):
            hc = np.floor((xy_w - anchor) / cm).astype(np.int64) - [i0, j0]
            ok = (hc[:, 0] >= 0) & (hc[:, 0] < ni) & (hc[:, 1] >= 0) & (hc[:, 1] < nj)
            hit[hc[ok, 1], hc[ok, 0]] = True
        gx = anchor[0] + (np.arange(i0, i1) + 0.5) * cm
        gy = anchor[1] + (np.arange(j0, j1) + 0.5) * cm
        dx, dy = gx[None, :] - x, gy[:, None] - y
        vx = (c * dx + s * dy).astype(np.float32)  # vehicle frame
        vy = (-s * dx + c * dy).astype(np.float32)
        cand = ~hit & self._in_box_xy(vx, vy)
        vx, vy = vx[cand], vy[cand]
        n = plane.normal
        vz = -(n[0] * vx + n[1] * vy + plane.c) / n[2]
        r_vc, _ = rig.rect_to_vehicle(rect)
        r = r_vc.astype(np.float32)
        px, py, pz = vx - np.float32(t[0]), vy - np.float32(t[1]), vz - np.float32(t[2])
        qx = r[0, 0] * px + r[1, 0] * py + r[2, 0] * pz  # camera frame: r^T p
        qy = r[0, 1] * px + r[1, 1] * py + r[2, 1] * pz
        qz = r[0, 2] * px + r[1, 2] * py + r[2, 2] * pz
        with np.errstate(divide='ignore', invalid='ignore'):
            u = rig.cx + rig.f * qx / qz
            v = rig.cy + rig.fy * qy / qz - self.first_row
        h, w = ground.shape
        ok = (qz > 0) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
        ui, vi = np.rint(u[ok]).astype(np.int64), np.rint(v[ok]).astype(np.int64)
        good = ground[vi, ui]
        idx = np.flatnonzero(cand.ravel())[np.flatnonzero(ok)[good]]
        if not idx.size:
            return np.zeros((0, 2)), np.zeros((0, 3), np.uint8)
        mu = u[ok][good].astype(np.float32).reshape(-1, 1)
        mv = v[ok][good].astype(np.float32).reshape(-1, 1)
        col = cv2.remap(lrgb, mu, mv, cv2.INTER_LINEAR).reshape(-1, 3)
        jj, ii = np.divmod(idx, ni)
        return np.column_stack([gx[ii], gy[jj]]), col

    def integrate(self, texmap: TextureMap, left: np.ndarray, right: np.ndarray,
                  pose: np.ndarray, encoding: str = 'bayer_rggb8') -> FrameResult:
        """:meth:`process` one pair at ``pose`` (gap filling on ``texmap``'s cells) and add
        its samples to ``texmap``."""
        res = self.process(left, right, pose, encoding, cells=(texmap.anchor, texmap.cell_m))
        texmap.add(res.xy_world, res.rgb)
        return res


# --------------------------------------------------------------------------------------------
# measurement on one real pair


def road_region_mask(rig: StereoRig, ahead_m: tuple[float, float] = (5.0, 15.0),
                     half_width_m: float = 1.75, rectified_here: bool = True) -> np.ndarray:
    """Bool ``(H, W)`` rectified-image mask of the ego-lane road region.

    The pixels whose ray meets the nominal ground (vehicle ``z = 0``) between ``ahead_m``
    metres ahead of the camera and within ``half_width_m`` of the camera's line (a 3.5 m
    lane), inside the valid rectified area.
    """
    r_vc, t = rig.rect_to_vehicle(rectified_here)
    vv, uu = np.mgrid[0:rig.height, 0:rig.width]
    ray = rig.pixel_rays(uu.ravel(), vv.ravel()) @ r_vc.T
    with np.errstate(divide='ignore', invalid='ignore'):
        s = -t[2] / ray[:, 2]
    gx = ray[:, 0] * s
    gy = ray[:, 1] * s
    m = (s > 0) & (gx >= ahead_m[0]) & (gx <= ahead_m[1]) & (np.abs(gy) <= half_width_m)
    m = m.reshape(rig.height, rig.width)
    if rectified_here:
        m &= rig.rectified_valid('left')
    return m


@dataclasses.dataclass
class PairMeasurement:
    """Disparity density and road plane of one stereo pair (:func:`measure_stereo_pair`).

    Attributes
    ----------
    road_density : float
        Valid-disparity fraction over the road region (:func:`road_region_mask`).
    road_inlier_fraction : float
        Fraction of the road region whose stereo point is within ``ransac_tol_m`` of the plane.
    processed_density : float
        Valid-disparity fraction over all processed rows.
    plane : Plane
        Fitted road plane (vehicle frame).
    plane_fitted : bool
    camera_height_m : float
        Distance of the left camera centre from the plane (m).
    normal_vehicle : (3,)
        Plane normal in the vehicle frame.
    normal_camera : (3,)
        The same in the rectified left camera frame (x right, y down, z forward).
    tilt_deg : float
        Angle between the normal and the vehicle z (deg).
    rectified_here : bool
    disparity_ms : float
        Time of the disparity step (ms).
    disparity_full : (H, W) float32
        Disparity at full resolution (nearest), NaN invalid / unprocessed.
    road_mask : (H, W) bool
    """

    road_density: float
    road_inlier_fraction: float
    processed_density: float
    plane: Plane
    plane_fitted: bool
    camera_height_m: float
    normal_vehicle: np.ndarray
    normal_camera: np.ndarray
    tilt_deg: float
    rectified_here: bool
    disparity_ms: float
    disparity_full: np.ndarray
    road_mask: np.ndarray

    def as_dict(self) -> dict:
        return {
            'road_density': round(self.road_density, 4),
            'road_inlier_fraction': round(self.road_inlier_fraction, 4),
            'processed_density': round(self.processed_density, 4),
            'plane_fitted': self.plane_fitted,
            'camera_height_m': round(self.camera_height_m, 4),
            'normal_vehicle': [round(float(v), 5) for v in self.normal_vehicle],
            'normal_camera': [round(float(v), 5) for v in self.normal_camera],
            'tilt_deg': round(self.tilt_deg, 3),
            'rectified_here': self.rectified_here,
            'disparity_ms': round(self.disparity_ms, 1),
        }


def measure_stereo_pair(left: np.ndarray, right: np.ndarray, rig: StereoRig,
                        cfg: Optional[TextureConfig] = None, encoding: str = 'bayer_rggb8',
                        ) -> PairMeasurement:
    """Disparity density on the ego-lane road region and the fitted road plane of one pair."""
    cfg = cfg or TextureConfig()
    tex = StereoTexturer(rig, cfg)
    res = tex.process(left, right, None, encoding)
    k = cfg.downscale
    full = np.full((rig.height, rig.width), np.nan, np.float32)
    up = np.repeat(np.repeat(res.disparity, k, axis=0), k, axis=1)
    full[res.first_row: res.first_row + up.shape[0], : up.shape[1]] = up
    road = road_region_mask(rig, rectified_here=res.rectified_here)
    valid = np.isfinite(full)
    dens = float(valid[road].mean()) if road.any() else 0.0
    # road inliers: stereo point of each road pixel within ransac_tol_m of the plane
    vv, uu = np.nonzero(road & valid)
    z = rig.f * rig.baseline_m / (full[vv, uu].astype(np.float64) - rig.cx_offset)
    r_vc, t = rig.rect_to_vehicle(res.rectified_here)
    p = (rig.pixel_rays(uu, vv) * z[:, None]) @ r_vc.T + t
    inl = float((np.abs(res.plane.height_of(p)) < cfg.ransac_tol_m).sum() / max(road.sum(), 1))
    n = res.plane.normal
    height = float(abs(n @ t + res.plane.c))
    return PairMeasurement(dens, inl, res.valid_fraction, res.plane, res.plane_fitted, height,
                           n.copy(), r_vc.T @ n, res.plane.tilt_deg, res.rectified_here,
                           res.timings_ms['disparity'], full, road)


# --------------------------------------------------------------------------------------------
# evaluation against a ground-truth floor texture


def read_floor_texture(png_path: str | os.PathLike, yaml_path: str | os.PathLike | None = None,
                       ) -> tuple[np.ndarray, float, np.ndarray]:
    """The simulator's ``floor_texture.png`` + ``.yaml`` -> ``(rgb, resolution, origin_xy)``.

    The PNG is north up (as ``cv2.imwrite`` wrote the RGB texture's rows reversed and its
    channels swapped); returned ``rgb`` is ``(H, W, 3)`` uint8 RGB in the ``OccupancyGrid``
    layout (row 0 = lowest y), ``origin_xy`` the world corner of cell (0, 0) (m).
    """
    png = Path(png_path)
    ym = Path(yaml_path) if yaml_path is not None else png.with_suffix('.yaml')
    img = cv2.imread(str(png), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f'{png}: cannot read')
    res, origin = None, None
    for line in ym.read_text(encoding='utf-8').splitlines():
        key, _, val = line.partition(':')
        if key.strip() == 'resolution':
            res = float(val)
        elif key.strip() == 'origin':
            origin = np.array([float(v) for v in val.strip().strip('[]').split(',')[:2]])
    if res is None or origin is None:
        raise ValueError(f'{ym}: needs resolution and origin')
    return np.ascontiguousarray(img[::-1, :, ::-1]), res, origin


def visible_ground_mask(poses: np.ndarray, rig: StereoRig, cfg: TextureConfig,
                        resolution: float, origin_xy: np.ndarray, shape: tuple[int, int],
                        rectified_here: bool = False) -> np.ndarray:
    """Cells (``OccupancyGrid`` layout) of the ground the left camera saw within the range box.

    A cell counts when its centre (on ``z = 0``) is inside the range box of
    :class:`TextureConfig` for one of ``poses`` (``(K, 3)``, the vehicle at each pair) and
    projects into the left image below ``first_row``. Occlusion is not modelled.
    """
    h, w = shape
    mask = np.zeros((h, w), dtype=bool)
    r_vc, t = rig.rect_to_vehicle(rectified_here)
    v_min = StereoTexturer(rig, cfg).first_row
    reach = math.hypot(cfg.max_range_m + abs(t[0]), cfg.max_lateral_m + abs(t[1]))
    for x, y, th in np.asarray(poses, dtype=np.float64).reshape(-1, 3):
        c0 = max(int((x - reach - origin_xy[0]) / resolution), 0)
        c1 = min(int((x + reach - origin_xy[0]) / resolution) + 1, w)
        r0 = max(int((y - reach - origin_xy[1]) / resolution), 0)
        r1 = min(int((y + reach - origin_xy[1]) / resolution) + 1, h)
        if c0 >= c1 or r0 >= r1:
            continue
        gx = origin_xy[0] + (np.arange(c0, c1) + 0.5) * resolution
        gy = origin_xy[1] + (np.arange(r0, r1) + 0.5) * resolution
        dx = gx[None, :] - x
        dy = gy[:, None] - y
        c, s = math.cos(th), math.sin(th)
        vx = c * dx + s * dy  # vehicle frame
        vy = -s * dx + c * dy
        ahead = vx - t[0]
        box = ((ahead >= cfg.min_range_m) & (ahead <= cfg.max_range_m)
               & (np.abs(vy - t[1]) <= cfg.max_lateral_m))
        pv = np.stack([vx, vy, np.zeros_like(vx)], axis=-1) - t
        q = pv @ r_vc  # camera frame (r_vc^T p)
        with np.errstate(divide='ignore', invalid='ignore'):
            u = rig.cx + rig.f * q[..., 0] / q[..., 2]
            v = rig.cy + rig.fy * q[..., 1] / q[..., 2]
        seen = box & (q[..., 2] > 0) & (u >= 0) & (u <= rig.width - 1) & (v >= v_min) \
            & (v <= rig.height - 1)
        mask[r0:r1, c0:c1] |= seen
    return mask


def colour_error(rgb: np.ndarray, covered: np.ndarray, gt_rgb: np.ndarray,
                 visible: Optional[np.ndarray] = None) -> dict:
    """Compare a texture with the ground truth in the same geometry.

    Returns ``mean_abs_rgb_error`` (mean over the cells both cover and the three channels,
    0..255), ``median_abs_rgb_error``, ``cells_coloured``, and when ``visible`` is given
    ``cells_visible`` and ``coverage`` (= coloured and visible / visible).
    """
    cov = np.asarray(covered, dtype=bool)
    err = np.abs(rgb[cov].astype(np.float64) - gt_rgb[cov].astype(np.float64)).mean(axis=1)
    out = {
        'cells_coloured': int(cov.sum()),
        'mean_abs_rgb_error': float(err.mean()) if err.size else float('nan'),
        'median_abs_rgb_error': float(np.median(err)) if err.size else float('nan'),
    }
    if visible is not None:
        vis = np.asarray(visible, dtype=bool)
        out['cells_visible'] = int(vis.sum())
        out['coverage'] = float((cov & vis).sum() / max(int(vis.sum()), 1))
    return out


# --------------------------------------------------------------------------------------------
# output images


def north_up_bgr(rgb: np.ndarray) -> np.ndarray:
    """``OccupancyGrid``-layout RGB (row 0 = lowest y) -> BGR for ``cv2.imwrite``, north up."""
    return np.ascontiguousarray(np.asarray(rgb)[::-1, :, ::-1])


def overlay_occupancy(rgb: np.ndarray, covered: np.ndarray, occupancy: np.ndarray,
                      occupied_threshold: int = 65, free_threshold: int = 25) -> np.ndarray:
    """Texture + occupancy in one RGB image (same geometry, ``OccupancyGrid`` layout).

    Occupied cells (``>= occupied_threshold``) are drawn red (255, 0, 0) over everything;
    textured cells show their colour; untextured free cells are light grey (200), unknown ones
    dark grey (90).
    """
    occ = np.asarray(occupancy)
    if occ.shape != rgb.shape[:2]:
        raise ValueError(f'occupancy {occ.shape} and texture {rgb.shape[:2]} differ')
    out = np.full(rgb.shape, 90, dtype=np.uint8)
    out[(occ >= 0) & (occ <= free_threshold)] = 200
    out[covered] = rgb[covered]
    out[occ >= occupied_threshold] = (255, 0, 0)
    return out


def write_texture_pngs(out_dir: str | os.PathLike, rgb: np.ndarray, covered: np.ndarray,
                       occupancy: Optional[np.ndarray] = None, name: str = 'texture',
                       ) -> list[Path]:
    """Write ``<name>.png`` (north up) and, with ``occupancy`` (same geometry),
    ``<name>_overlay.png`` into ``out_dir``; returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f'{name}.png']
    cv2.imwrite(str(paths[0]), north_up_bgr(rgb))
    if occupancy is not None:
        paths.append(out / f'{name}_overlay.png')
        cv2.imwrite(str(paths[1]), north_up_bgr(overlay_occupancy(rgb, covered, occupancy)))
    return paths
