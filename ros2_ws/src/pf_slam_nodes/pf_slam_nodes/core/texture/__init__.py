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
8. **Placed again** (:class:`PairPatches`): every pair's samples are also kept in the vehicle
   frame (binned), so that the texture can be rebuilt at the loop closure's corrected poses.

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

Depth mode (an RGB-D camera, THOR's Kinect v2): :mod:`.depth` (:class:`DepthTexturer`:
depth -> 3-D -> RGB pixel -> base frame -> floor plane checked against the kinematic floor ->
world), accumulated in the same :class:`TextureMap`.

Modules (by stage): :mod:`.config` (:class:`TextureConfig`), :mod:`.rig` (:class:`StereoRig`),
:mod:`.images` (stages 1-2: :func:`debayer`, :func:`grey`, :func:`detect_rectified`),
:mod:`.texturer` (stages 1-6 per pair: :class:`StereoTexturer`; :func:`interpolate_poses`),
:mod:`.ground` (stage 5: :class:`Plane`, :func:`fit_ground_plane`), :mod:`.map` (stage 7:
:class:`TextureMap`, :class:`IncrementalRender`; :func:`north_up_bgr`, :func:`overlay_occupancy`), :mod:`.patches` (stage 8:
:class:`PairPatches`), :mod:`.evaluation`
(:func:`measure_stereo_pair`, :func:`visible_ground_mask`, :func:`colour_error`). No file I/O
here: the rig from the KAIST ``param/`` files is :func:`pf_slam_nodes.io.calib.read_stereo_rig`,
the PNG reader / writer are in :mod:`pf_slam_nodes.io.texture_files`.
"""

from __future__ import annotations

from .config import BAYER_CODES, TextureConfig
from .depth import DepthCamera, DepthFrameResult, DepthTexturer
from .evaluation import PairMeasurement, colour_error, measure_stereo_pair, road_region_mask, visible_ground_mask
from .ground import Plane, fit_ground_plane
from .images import debayer, detect_rectified, grey
from .map import IncrementalRender, TextureMap, north_up_bgr, overlay_occupancy
from .patches import PairPatches
from .rig import StereoRig
from .texturer import FrameResult, StereoTexturer, interpolate_poses

__all__ = [
    "BAYER_CODES",
    "DepthCamera",
    "DepthFrameResult",
    "DepthTexturer",
    "FrameResult",
    "IncrementalRender",
    "PairMeasurement",
    "PairPatches",
    "Plane",
    "StereoRig",
    "StereoTexturer",
    "TextureConfig",
    "TextureMap",
    "colour_error",
    "debayer",
    "detect_rectified",
    "fit_ground_plane",
    "grey",
    "interpolate_poses",
    "measure_stereo_pair",
    "north_up_bgr",
    "overlay_occupancy",
    "road_region_mask",
    "visible_ground_mask",
]
