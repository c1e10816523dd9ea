"""The RGB-D (depth mode) floor texturer on a synthetic Kinect v2 view of a coloured floor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pf_slam_nodes.core.texture import DepthCamera, DepthTexturer, TextureConfig, TextureMap, colour_error

# Kinect v2 (the numbers); the RGB image at half size (K halved) to keep the test fast
K_IR = np.array([[364.457, 0, 258.422], [0, 364.543, 202.487], [0, 0, 1]])
K_RGB = np.array([[1049.33 / 2, 0, 956.91 / 2], [0, 1051.32 / 2, 533.45 / 2], [0, 0, 1]])
T_RGB_DEPTH = np.array([0.05227, 0.00152, -0.00061])
OPTICAL = np.array([[0, 0, 1.0], [-1, 0, 0], [0, -1, 0]])  # optical axes in a body frame (x fwd, z up)


def ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def floor_colour(x, y):
    """The true floor colour at world (x, y): smooth stripes (0..255)."""
    return np.stack(
        [128 + 100 * np.sin(1.3 * x), 128 + 100 * np.cos(0.9 * y), 80 + 60 * np.sin(0.7 * (x + y))], axis=-1
    )


def render_rgbd(base_from_rgb, pose, floor_z=0.0, rgb_size=(960, 540)):
    """(depth (424, 512) uint16 mm, rgb (h, w, 3) uint8) of a flat floor at ``floor_z`` (base
    frame), coloured by :func:`floor_colour` in the world (base pose ``pose`` (x, y, theta))."""
    r_bc, t_bc = base_from_rgb
    r_bd, t_bd = r_bc, r_bc @ T_RGB_DEPTH + t_bc  # the depth camera (R = I) in the base frame

    def hit(k, r, t, w, h):
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        rays = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones_like(u)], axis=-1)
        d = rays @ r.T  # rays in the base frame (unit optical z)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (floor_z - t[2]) / d[..., 2]
        s = np.where(d[..., 2] < -1e-6, s, np.nan)
        return s, t + s[..., None] * d

    s, _ = hit(K_IR, r_bd, t_bd, 512, 424)
    depth = np.where(np.isfinite(s) & (s * 1000 < 65535), np.rint(s * 1000), 0).astype(np.uint16)
    _, pts = hit(K_RGB, r_bc, t_bc, *rgb_size)
    x, y, th = pose
    wx = x + math.cos(th) * pts[..., 0] - math.sin(th) * pts[..., 1]
    wy = y + math.sin(th) * pts[..., 0] + math.cos(th) * pts[..., 1]
    col = np.nan_to_num(floor_colour(wx, wy), nan=0.0)
    return depth, np.clip(np.rint(col), 0, 255).astype(np.uint8)


PITCH = math.radians(25)


def kinect_mount(neck=0.0, pitch=PITCH):
    """kinect_rgb_optical in base_link: head at 1.26 m, Rz(neck) Ry(pitch), kinect 0.07 above."""
    r_bh = rz(neck) @ ry(pitch)
    return r_bh @ OPTICAL, np.array([0, 0, 1.26]) + r_bh @ [0, 0, 0.07]


def camera():
    return DepthCamera(K_IR, K_RGB, np.eye(3), T_RGB_DEPTH, (960, 540))


def test_depth_texture_of_a_coloured_floor():
    cfg = TextureConfig(cell_m=0.05)
    tex = DepthTexturer(camera(), cfg)
    texmap = TextureMap.from_config(cfg)
    for pose, neck in [((0.0, 0.0, 0.0), 0.0), ((0.5, 0.2, 0.3), 0.4), ((1.0, -0.3, -0.5), -0.3)]:
        mount = kinect_mount(neck)
        depth, rgb = render_rgbd(mount, pose)
        res = tex.process(depth, rgb, mount, np.array(pose))
        assert res.plane_fitted
        assert abs(res.floor_offset_m) < 0.01  # the fitted floor is the kinematic floor
        assert res.plane.tilt_deg < 0.5
        assert len(res.xy_world) > 3000
        texmap.add(res.xy_world, res.rgb)
    rgb, cov = texmap.render((-2.0, -4.0), 0.05, 160, 160)
    yy, xx = np.mgrid[0:160, 0:160]
    gt = floor_colour(-2.0 + (xx + 0.5) * 0.05, -4.0 + (yy + 0.5) * 0.05)
    err = colour_error(rgb, cov, np.clip(np.rint(gt), 0, 255).astype(np.uint8))
    assert err["cells_coloured"] > 2000
    assert err["mean_abs_rgb_error"] < 6.0, err


def test_floor_offset_from_the_kinematics_is_caught():
    cfg = TextureConfig(plane_max_offset_m=0.1)
    tex = DepthTexturer(camera(), cfg)
    mount = kinect_mount()
    # the real floor 5 cm below the kinematic one: fitted, offset measured
    depth, rgb = render_rgbd(mount, (0, 0, 0), floor_z=-0.05)
    res = tex.process(depth, rgb, mount, np.zeros(3))
    assert res.plane_fitted and res.floor_offset_m == pytest.approx(-0.05, abs=0.01)
    # a box top 0.4 m above the kinematic floor filling the view: rejected, the kinematic floor used
    depth, rgb = render_rgbd(mount, (0, 0, 0), floor_z=0.4)
    res = tex.process(depth, rgb, mount, np.zeros(3))
    assert not res.plane_fitted
    assert len(res.xy_world) == 0  # nothing lies on the kinematic floor


def test_depth_camera_checks():
    with pytest.raises(ValueError, match="k_depth"):
        DepthCamera(np.zeros((3, 3)), K_RGB, np.eye(3), T_RGB_DEPTH, (960, 540))
    with pytest.raises(ValueError, match="orthonormal"):
        DepthCamera(K_IR, K_RGB, 2 * np.eye(3), T_RGB_DEPTH, (960, 540))
