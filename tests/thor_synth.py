"""A small synthetic THOR bag written exactly as docs/THOR contract says (tests only).

A room with boxes, a humanoid walking a loop while its head nods (head pitch) and turns (neck
yaw); the Hokuyo's 1081 beams are cast in 3-D from the head's pose at each scan's stamp against
the walls (2.5 m high) and the floor, so a nod puts floor returns in the scan. Joints at 100 Hz on
their own stamps, scans at 20 Hz, odometry (drifting) with each scan, an optional RGB-D stream of
the coloured floor. Ground truth: base_link's poses, the wall segments, the floor colour.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from pf_slam_nodes.core.geometry import matrix_to_quat
from pf_slam_nodes.io import bag as B

HEAD_Z = 0.93 + 0.33
LIDAR_UP = 0.15
KINECT_UP = 0.07
WALL_H = 2.5
ANGLES = -2.35619449 + 0.00436332313 * np.arange(1081)
K_IR = np.array([[364.457, 0, 258.422], [0, 364.543, 202.487], [0, 0, 1]])
T_RGB_DEPTH = np.array([0.05227, 0.00152, -0.00061])
OPTICAL = np.array([[0, 0, 1.0], [-1, 0, 0], [0, -1, 0]])


def rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def room_segments() -> np.ndarray:
    """(S, 4) wall segments x0 y0 x1 y1: a 12 x 8 m room with three boxes."""

    def box(x0, y0, x1, y1):
        return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]

    segs = (
        box(-2.0, -4.0, 10.0, 4.0)
        + box(2.0, -0.8, 3.0, 0.6)
        + box(7.8, 2.4, 8.6, 3.2)
        + box(8.0, -3.3, 8.8, -2.5)
        + [(-2.0, 2.0, -0.8, 2.0), (9.0, -1.0, 10.0, -1.0)]
    )
    return np.array(segs, dtype=np.float64)


def floor_colour(x, y):
    return np.stack(
        [128 + 100 * np.sin(1.3 * x), 128 + 100 * np.cos(0.9 * y), 80 + 60 * np.sin(0.7 * (x + y))], axis=-1
    )


def path_pose(t: float) -> np.ndarray:
    """base_link in the world at t: a loop around the central box (0.35 m/s)."""
    w = 2 * math.pi / 45.0
    a = w * t
    x, y = 4.0 + 3.2 * math.sin(a), 0.0 - 2.4 * math.cos(a) + 0.0
    dx, dy = 3.2 * w * math.cos(a), 2.4 * w * math.sin(a)
    return np.array([x, y, math.atan2(dy, dx)])


def joints(t: float, look_down: tuple[float, float] | None) -> tuple[float, float]:
    """(neck yaw, head pitch) rad at t: a slow turn and a nod; ``look_down`` (t0, t1): the head
    pitched 1.2 rad down (mostly floor)."""
    neck = 0.35 * math.sin(2 * math.pi * t / 7.0)
    pitch = 0.22 + 0.2 * math.sin(2 * math.pi * t / 3.0)
    if look_down is not None and look_down[0] <= t <= look_down[1]:
        pitch = 1.2
    return neck, pitch


def cast(origin: np.ndarray, dirs: np.ndarray, segs: np.ndarray, max_range: float = 30.0) -> np.ndarray:
    """Ranges (B,) of 3-D rays from ``origin`` against the walls (height WALL_H) and the floor."""
    best = np.full(dirs.shape[0], np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        sf = np.where(dirs[:, 2] < -1e-9, -origin[2] / dirs[:, 2], np.inf)
        best = np.minimum(best, sf)
        p0, p1 = segs[:, :2], segs[:, 2:]
        e = p1 - p0  # (S, 2)
        dx, dy = dirs[:, 0:1], dirs[:, 1:2]  # (B, 1)
        den = dx * e[None, :, 1] - dy * e[None, :, 0]  # (B, S)
        wx, wy = p0[None, :, 0] - origin[0], p0[None, :, 1] - origin[1]
        s = (wx * e[None, :, 1] - wy * e[None, :, 0]) / den
        u = (wx * dy - wy * dx) / den
        z = origin[2] + s * dirs[:, 2:3]
        ok = (np.abs(den) > 1e-12) & (s > 0) & (u >= 0) & (u <= 1) & (z >= 0) & (z <= WALL_H)
        sw = np.where(ok, s, np.inf).min(axis=1)
    best = np.minimum(best, sw)
    return np.where(best <= max_range, best, np.inf)


@dataclasses.dataclass
class ThorSynth:
    bag: Path
    ground_truth: np.ndarray  # (N, 4) t x y theta at each scan
    segments: np.ndarray
    scans: int
    look_down_scans: int


def write_thor_bag(
    out: Path,
    duration_s: float = 30.0,
    seed: int = 0,
    scan_hz: float = 20.0,
    look_down: tuple[float, float] | None = (12.0, 13.5),
    rgbd_hz: float = 0.0,
    rgb_size: tuple[int, int] = (960, 540),
) -> ThorSynth:
    rng = np.random.default_rng(seed)
    segs = room_segments()
    t0 = 1_700_000_000 * 10**9
    ns = lambda t: t0 + int(round(t * 1e9))  # noqa: E731
    f_rgb = (1049.33 * rgb_size[0] / 1920, 1051.32 * rgb_size[1] / 1080)
    k_rgb = np.array(
        [[f_rgb[0], 0, 956.91 * rgb_size[0] / 1920], [0, f_rgb[1], 533.45 * rgb_size[1] / 1080], [0, 0, 1]]
    )
    events = []  # (t, topic, msg)
    # joints at 100 Hz, offset 3 ms from the scans
    for k in range(int(duration_s * 100) + 2):
        t = 0.003 + k * 0.01
        neck, pitch = joints(t, look_down)
        q = matrix_to_quat(rz(neck) @ ry(pitch))
        events.append((t, "/tf", B.tf_static(ns(t), [("base_link", "head", (0, 0, HEAD_Z), q)])))
        js = B._T["sensor_msgs/msg/JointState"](
            header=B.make_header(ns(t), ""),
            name=["neck", "head"],
            position=np.array([neck, pitch]),
            velocity=np.zeros(0),
            effort=np.zeros(0),
        )
        events.append((t, "/joint_states", js))
    # scans + odometry (drifting: 2 % scale, yaw noise)
    gt, odo = [], None
    prev = None
    look_down_scans = 0
    for k in range(int(duration_s * scan_hz)):
        t = k / scan_hz
        pose = path_pose(t)
        neck, pitch = joints(t, look_down)
        look_down_scans += int(look_down is not None and look_down[0] <= t <= look_down[1])
        r_bh = rz(neck) @ ry(pitch)
        r_w = rz(pose[2]) @ r_bh
        origin = np.array([pose[0], pose[1], 0.0]) + rz(pose[2]) @ (np.array([0, 0, HEAD_Z]) + r_bh @ [0, 0, LIDAR_UP])
        dirs = (r_w @ np.stack([np.cos(ANGLES), np.sin(ANGLES), np.zeros_like(ANGLES)])).T
        ranges = cast(origin, dirs, segs)
        ranges = np.where(np.isfinite(ranges), ranges + rng.normal(0, 0.01, ranges.size), ranges)
        events.append((t, "/scan", B.laser_scan(ns(t), "lidar", -2.35619449, 0.00436332313, ranges, 0.1, 30.0)))
        if prev is None:
            odo = pose.copy()
        else:
            c, s = math.cos(prev[2]), math.sin(prev[2])
            dx, dy = pose[0] - prev[0], pose[1] - prev[1]
            lx, ly = c * dx + s * dy, -s * dx + c * dy
            dth = math.atan2(math.sin(pose[2] - prev[2]), math.cos(pose[2] - prev[2]))
            lx, ly = lx * 1.02 + rng.normal(0, 0.003), ly + rng.normal(0, 0.003)
            dth = dth * 1.03 + rng.normal(0, 0.002)
            co, so = math.cos(odo[2]), math.sin(odo[2])
            odo = np.array([odo[0] + co * lx - so * ly, odo[1] + so * lx + co * ly, odo[2] + dth])
        prev = pose
        events.append((t, "/odom", B.odometry(ns(t), "odom", "base_link", odo)))
        gt.append((ns(t) / 1e9, *pose))
    if rgbd_hz > 0:
        for k in range(int(duration_s * rgbd_hz)):
            t = 0.5 + k / rgbd_hz
            depth, rgb = render_rgbd(t, look_down, k_rgb, rgb_size)
            rgb_msg = B.image(ns(t + 0.004), "kinect_rgb_optical", rgb, "rgb8")
            events.append((t + 0.004, "/kinect/rgb/image_raw", rgb_msg))
            m = B._T["sensor_msgs/msg/Image"](
                header=B.make_header(ns(t), "kinect_depth_optical"),
                height=424,
                width=512,
                encoding="16UC1",
                is_bigendian=0,
                step=1024,
                data=np.frombuffer(depth.astype("<u2").tobytes(), dtype=np.uint8),
            )
            events.append((t, "/kinect/depth/image_raw", m))
    events.sort(key=lambda e: e[0])
    with B.open_writer(out) as w:
        w.set_custom_data("pf_slam.format", "thor")
        for topic, typ in [
            ("/tf_static", "tf2_msgs/msg/TFMessage"),
            ("/tf", "tf2_msgs/msg/TFMessage"),
            ("/joint_states", "sensor_msgs/msg/JointState"),
            ("/scan", "sensor_msgs/msg/LaserScan"),
            ("/odom", "nav_msgs/msg/Odometry"),
        ]:
            w.add_connection(topic, typ)
        static = [
            ("head", "lidar", (0, 0, LIDAR_UP), (0, 0, 0, 1)),
            ("head", "kinect", (0, 0, KINECT_UP), (0, 0, 0, 1)),
            ("kinect", "kinect_rgb_optical", (0, 0, 0), matrix_to_quat(OPTICAL)),
            ("kinect_rgb_optical", "kinect_depth_optical", tuple(T_RGB_DEPTH), (0, 0, 0, 1)),
        ]
        w.write("/tf_static", ns(0), B.tf_static(ns(0), static))
        if rgbd_hz > 0:
            for topic in ("/kinect/rgb/image_raw", "/kinect/depth/image_raw"):
                w.add_connection(topic, "sensor_msgs/msg/Image")
            w.add_connection("/kinect/rgb/camera_info", "sensor_msgs/msg/CameraInfo")
            w.add_connection("/kinect/depth/camera_info", "sensor_msgs/msg/CameraInfo")
            w.write(
                "/kinect/rgb/camera_info",
                ns(0),
                B.camera_info(
                    ns(0),
                    "kinect_rgb_optical",
                    rgb_size[0],
                    rgb_size[1],
                    "plumb_bob",
                    np.zeros(5),
                    k_rgb,
                    np.eye(3),
                    np.hstack([k_rgb, np.zeros((3, 1))]),
                ),
            )
            w.write(
                "/kinect/depth/camera_info",
                ns(0),
                B.camera_info(
                    ns(0),
                    "kinect_depth_optical",
                    512,
                    424,
                    "plumb_bob",
                    np.zeros(5),
                    K_IR,
                    np.eye(3),
                    np.hstack([K_IR, np.zeros((3, 1))]),
                ),
            )
        for t, topic, msg in events:
            w.write(topic, ns(t), msg)
    return ThorSynth(Path(out), np.array(gt), segs, int(duration_s * scan_hz), look_down_scans)


def render_rgbd(t: float, look_down, k_rgb: np.ndarray, rgb_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The Kinect's depth (mm) and colour at t: the floor coloured by :func:`floor_colour` (the
    walls are not rendered: a room large enough that the camera sees floor)."""
    pose = path_pose(t)
    neck, pitch = joints(t, look_down)
    r_bh = rz(neck) @ ry(pitch)
    r_bc = r_bh @ OPTICAL
    t_bc = np.array([0, 0, HEAD_Z]) + r_bh @ [0, 0, KINECT_UP]
    r_bd, t_bd = r_bc, r_bc @ T_RGB_DEPTH + t_bc

    def hit(k, r, tt, w, h):
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        rays = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones_like(u)], axis=-1)
        d = rays @ r.T
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(d[..., 2] < -1e-6, -tt[2] / d[..., 2], np.nan)
        return s, tt + s[..., None] * d

    s, _ = hit(K_IR, r_bd, t_bd, 512, 424)
    depth = np.where(np.isfinite(s) & (s < 4.5) & (s > 0.4), np.rint(s * 1000), 0).astype(np.uint16)
    _, pts = hit(k_rgb, r_bc, t_bc, *rgb_size)
    c, sn = math.cos(pose[2]), math.sin(pose[2])
    wx = pose[0] + c * pts[..., 0] - sn * pts[..., 1]
    wy = pose[1] + sn * pts[..., 0] + c * pts[..., 1]
    col = np.nan_to_num(floor_colour(wx, wy), nan=0.0)
    return depth, np.clip(np.rint(col), 0, 255).astype(np.uint8)


def gt_grid(segs: np.ndarray, res: float = 0.05, margin: float = 1.0) -> tuple[np.ndarray, float, np.ndarray]:
    """The walls as an OccupancyGrid-layout int8 grid (100 on the walls, 0 elsewhere)."""
    lo = segs.reshape(-1, 2).min(axis=0) - margin
    hi = segs.reshape(-1, 2).max(axis=0) + margin
    w, h = (np.ceil((hi - lo) / res)).astype(int)
    occ = np.zeros((h, w), np.int8)
    for x0, y0, x1, y1 in segs:
        n = int(max(abs(x1 - x0), abs(y1 - y0)) / (res / 3)) + 2
        xs, ys = np.linspace(x0, x1, n), np.linspace(y0, y1, n)
        c = np.floor((xs - lo[0]) / res).astype(int)
        r = np.floor((ys - lo[1]) / res).astype(int)
        occ[r, c] = 100
    return occ, res, lo


def evaluate_run(out: Path, synth: ThorSynth) -> dict:
    """ATE (m, SE(2)-aligned), map F1 against the walls, and the occupied cells farther than
    0.3 m from any wall (floor returns that became walls)."""
    from pf_slam_nodes.core import metrics
    from pf_slam_nodes.io.mapfile import read_map
    from pf_slam_nodes.io.trajectory import read_trajectory

    t_e, p_e = read_trajectory(out / "trajectory.tum")
    g = synth.ground_truth
    pairs = metrics.associate(t_e, g[:, 0], max_dt=0.01)
    ate = metrics.ate(p_e[pairs[:, 0]], g[pairs[:, 1], 1:])
    occ, res, origin = read_map(out / "map.yaml")
    gocc, gres, gorigin = gt_grid(synth.segments)
    f1 = metrics.map_f1(occ, res, origin, gocc, gres, gorigin, tolerance_m=0.2)
    rows, cols = np.nonzero(occ >= 65)
    xy = np.column_stack([origin[0] + (cols + 0.5) * res, origin[1] + (rows + 0.5) * res])
    a, b = synth.segments[:, :2], synth.segments[:, 2:]
    e = b - a
    u = np.clip(((xy[:, None, :] - a[None]) * e[None]).sum(-1) / (e * e).sum(-1)[None], 0, 1)
    d = np.linalg.norm(xy[:, None, :] - (a[None] + u[..., None] * e[None]), axis=-1).min(axis=1)
    out_d = {
        "ate_m": ate["rmse"],
        "n": len(pairs),
        "map_f1": f1["f1"],
        "precision": f1["precision"],
        "recall": f1["recall"],
        "occupied": int(len(xy)),
        "false_walls": int((d > 0.3).sum()),
    }
    if (out / "texture.png").exists():
        from pf_slam_nodes.core.texture import colour_error
        from pf_slam_nodes.io.texture_files import read_floor_texture

        rgb, tres, torigin = read_floor_texture(out / "texture.png", out / "map.yaml")
        rr, cc = np.mgrid[0 : rgb.shape[0], 0 : rgb.shape[1]]
        gt = floor_colour(torigin[0] + (cc + 0.5) * tres, torigin[1] + (rr + 0.5) * tres)
        err = colour_error(rgb, rgb.any(axis=2), np.clip(np.rint(gt), 0, 255).astype(np.uint8))
        out_d.update(texture_error=err["mean_abs_rgb_error"], texture_cells=err["cells_coloured"])
    return out_d
