"""Texture mapping settings (:class:`TextureConfig`) and the OpenCV codes it chooses between."""

from __future__ import annotations

import dataclasses

import cv2

from ..configbase import _check_finite, _check_int, _check_nonneg, _check_pos, _ConfigBase

#: ROS image encoding -> OpenCV conversion to RGB (OpenCV names a Bayer pattern by the colours
#: of the second row's second and third pixels: ``rggb`` is OpenCV's ``BayerBG``).
BAYER_CODES = {
    "bayer_rggb8": cv2.COLOR_BAYER_BG2RGB,
    "bayer_bggr8": cv2.COLOR_BAYER_RG2RGB,
    "bayer_gbrg8": cv2.COLOR_BAYER_GR2RGB,
    "bayer_grbg8": cv2.COLOR_BAYER_GB2RGB,
}
_BAYER_CV = {"bayer_rggb8": "BG", "bayer_bggr8": "RG", "bayer_gbrg8": "GR", "bayer_grbg8": "GB"}
_DEMOSAIC = {"bilinear": "", "ea": "_EA", "vng": "_VNG"}
_PREFILTERS = ("none", "clahe", "equalize")
_SGBM_MODES = {
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
}
_RECTIFY = ("auto", "yes", "no")


# --------------------------------------------------------------------------------------------
# configuration


@dataclasses.dataclass(frozen=True)
class TextureConfig(_ConfigBase):
    """Stereo texture mapping (:class:`StereoTexturer`, :class:`TextureMap`).

    Stereo matching is OpenCV ``StereoSGBM``. The defaults come from
    ``python -m pf_slam_tools.bench.texture {real,sim} ... --sweep`` (``docs/texture.md``):

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
    cell_samples : int
        Pixels splatted per cell along each image axis where the image has more: a row keeps
        every ``floor(cell_m / (cell_samples * footprint))``-th row and column (clipped to
        ``1 .. pixel_stride_max``), rows by their along-track footprint, columns by their
        across-track one (``StereoTexturer._stride_mask``).
    fill_gaps : bool
        Cells in view that no ground pixel fell in (far away, where image rows are sparser
        than cells) get the colour at their centre's projection (one sample).
    cell_m : float
        Texture cell size (m).
    tile_cells : int
        Texture tile edge (cells).
    max_tiles : int
        Tiles allocated at most (``16 * tile_cells**2`` bytes each).
    replace_budget_mb : float
        Every pair's samples are also kept in the vehicle frame (binned at ``replace_bin_m``,
        ~0.4 MB a KAIST pair, :class:`PairPatches`) so that the texture can be placed again on
        the loop closure's corrected trajectory; at most this much (MiB; beyond it the oldest
        pairs stay where they were placed). 0 keeps nothing.
    replace_bin_m : float
        Bin size of the kept samples (m).
    seed : int
        RANSAC random seed.
    depth_stride : int
        Depth mode (an RGB-D camera, :mod:`.depth`): every ``depth_stride``-th depth pixel of
        each row and column is used (4: 128 x 106 of the Kinect v2's 512 x 424).
    depth_min_m, depth_max_m : float
        Depth mode: valid depth (m); the Kinect v2 measures 0.4 .. 4.5 m.
    """

    rectify: str = "auto"
    demosaic: str = "vng"
    sgbm_mode: str = "hh4"
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
    prefilter: str = "none"
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
    cell_samples: int = 4
    fill_gaps: bool = True
    cell_m: float = 0.1
    tile_cells: int = 128
    max_tiles: int = 1024
    replace_budget_mb: float = 256.0
    replace_bin_m: float = 0.05
    seed: int = 0
    depth_stride: int = 4
    depth_min_m: float = 0.4
    depth_max_m: float = 4.5

    def __post_init__(self) -> None:
        if self.rectify not in _RECTIFY:
            raise ValueError(f"rectify must be one of {_RECTIFY}, got {self.rectify!r}")
        if self.demosaic not in _DEMOSAIC:
            raise ValueError(f"demosaic must be one of {tuple(_DEMOSAIC)}, got {self.demosaic!r}")
        if self.sgbm_mode not in _SGBM_MODES:
            raise ValueError(f"sgbm_mode must be one of {tuple(_SGBM_MODES)}, got {self.sgbm_mode!r}")
        if self.prefilter not in _PREFILTERS:
            raise ValueError(f"prefilter must be one of {_PREFILTERS}, got {self.prefilter!r}")
        _check_int("downscale", self.downscale, 1)
        if self.downscale not in (1, 2, 4):
            raise ValueError(f"downscale must be 1, 2 or 4, got {self.downscale!r}")
        _check_int("num_disparities", self.num_disparities, 16)
        if self.num_disparities % (16 * self.downscale):
            raise ValueError(
                f"num_disparities must be a multiple of 16 * downscale = "
                f"{16 * self.downscale}, got {self.num_disparities!r}"
            )
        _check_int("block_size", self.block_size, 1)
        if self.block_size % 2 == 0:
            raise ValueError(f"block_size must be odd, got {self.block_size!r}")
        _check_pos("p1", self.p1)
        _check_pos("p2", self.p2)
        if self.p2 <= self.p1:
            raise ValueError(f"p2 must be > p1, got p1={self.p1!r}, p2={self.p2!r}")
        _check_int("uniqueness_ratio", self.uniqueness_ratio, 0)
        _check_int("disp12_max_diff", self.disp12_max_diff, -1)
        _check_int("speckle_window", self.speckle_window, 0)
        _check_int("speckle_range", self.speckle_range, 0)
        _check_int("pre_filter_cap", self.pre_filter_cap, 1)
        if self.pre_filter_cap > 63:
            raise ValueError(f"pre_filter_cap must be <= 63, got {self.pre_filter_cap!r}")
        _check_nonneg("min_range_m", self.min_range_m)
        _check_pos("max_range_m", self.max_range_m)
        if self.max_range_m <= self.min_range_m:
            raise ValueError(f"max_range_m must be > min_range_m, got {self.max_range_m!r}")
        _check_pos("max_lateral_m", self.max_lateral_m)
        _check_int("row_margin_px", self.row_margin_px, 0)
        _check_pos("height_tol_m", self.height_tol_m)
        _check_int("obstacle_margin_px", self.obstacle_margin_px, 0)
        if not isinstance(self.plane_fit, bool):
            raise ValueError(f"plane_fit must be a bool, got {self.plane_fit!r}")
        if not isinstance(self.fill_gaps, bool):
            raise ValueError(f"fill_gaps must be a bool, got {self.fill_gaps!r}")
        if not isinstance(self.snap_to_plane, bool):
            raise ValueError(f"snap_to_plane must be a bool, got {self.snap_to_plane!r}")
        _check_int("ransac_iterations", self.ransac_iterations, 1)
        _check_pos("ransac_tol_m", self.ransac_tol_m)
        _check_int("ransac_max_points", self.ransac_max_points, 3)
        _check_pos("plane_max_tilt_deg", self.plane_max_tilt_deg)
        _check_pos("plane_max_offset_m", self.plane_max_offset_m)
        _check_int("pixel_stride_max", self.pixel_stride_max, 1)
        _check_int("cell_samples", self.cell_samples, 1)
        _check_pos("cell_m", self.cell_m)
        _check_int("tile_cells", self.tile_cells, 8)
        _check_int("max_tiles", self.max_tiles, 1)
        _check_nonneg("replace_budget_mb", self.replace_budget_mb)
        _check_pos("replace_bin_m", self.replace_bin_m)
        _check_int("seed", self.seed, 0)
        _check_finite("cell_m", self.cell_m)
        _check_int("depth_stride", self.depth_stride, 1)
        _check_nonneg("depth_min_m", self.depth_min_m)
        _check_pos("depth_max_m", self.depth_max_m)
        if self.depth_max_m <= self.depth_min_m:
            raise ValueError(f"depth_max_m must be > depth_min_m, got {self.depth_max_m!r}")
