"""The odometry scale estimate (core/odometry.py OdomScaleEstimator, correlation.odom_scale): it
converges to a known wheel-scale error on synthetic measurements; a scan pair (core/scanpair.py)
measures the true travel where the street has along-track structure and nothing where it has
none; the correction stage learns the scale of odometry that under-reports the travel in a room,
the same with the pairs measured in a worker process."""

import math

import numpy as np
import pytest
from conftest import box_ranges

from pf_slam_nodes.core import config as cfg
from pf_slam_nodes.core.odometry import OdomScaleEstimator
from pf_slam_nodes.core.scanpair import ScalePairs, pair_scan, pair_travel
from pf_slam_nodes.core.slam import ParticleFilterSlam
from pf_slam_nodes.core.stages import scaled_increment
from pf_slam_nodes.nodes.worker import ProcessBackend


def _closed_loop(true_scale, steps=600, observed=1.0, noise_m=0.02, outliers=0.05, seed=0, **kw):
    """Pairs over 1.5-2.5 m: a fraction ``observed`` of them measures ``true * d`` plus noise (the
    others nothing: a pair without along-track structure), and a fraction ``outliers`` a bad
    match (+-0.5 m). Returns the estimator."""
    rng = np.random.default_rng(seed)
    est = OdomScaleEstimator(**kw)
    for _ in range(steps):
        d = rng.uniform(1.5, 2.5)
        if rng.random() >= observed:
            continue
        m = true_scale * d + rng.normal(0, noise_m)
        if rng.random() < outliers:
            m += rng.choice([-0.5, 0.5])
        est.add(d, m)
    return est


@pytest.mark.parametrize("true_scale", [0.99, 0.995, 1.0, 1.008])
def test_estimate_converges_to_the_wheel_scale(true_scale):
    est = _closed_loop(true_scale)
    assert est.travel_m > 1100
    assert abs(est.scale - true_scale) < 0.0015, est.scale


def test_few_measuring_pairs_still_converge():
    # 70 % of the pairs measure nothing (streets without along-track structure)
    est = _closed_loop(0.992, steps=1500, observed=0.3)
    assert abs(est.scale - 0.992) < 0.0015, est.scale


def test_phased_in_over_the_ramp_and_clamped():
    est = OdomScaleEstimator(window_m=1000.0, ramp_m=100.0, max_error=0.01)
    assert est.scale == 1.0  # nothing measured
    for _ in range(20):
        est.add(2.0, 2.0 * 0.95)
    # clamped to 1 - 0.01, then 40 of the 100 m ramp of it applied
    assert est.travel_m == 40.0 and est.scale == pytest.approx(1.0 - 0.4 * 0.01)
    for _ in range(200):
        est.add(2.0, 2.0 * 0.95)
    assert est.raw < 0.99 and est.scale == pytest.approx(0.99)
    est.add(0.0, 1.0)  # no travel: nothing
    est.add(2.0, math.nan)
    assert est.steps == 220


def test_bad_parameters():
    with pytest.raises(ValueError, match="window_m"):
        OdomScaleEstimator(window_m=0.0)
    with pytest.raises(ValueError, match="ramp_m"):
        OdomScaleEstimator(ramp_m=-1.0)
    with pytest.raises(ValueError, match="odom_scale_baseline_m"):
        cfg.CorrelationConfig(odom_scale_baseline_m=0.0)
    with pytest.raises(ValueError, match="odom_scale_min_curvature"):
        cfg.CorrelationConfig(odom_scale_min_curvature=-1.0)


def test_scaled_increment_moves_along_the_particles_increment():
    parts = np.array([[0.0, 0.0, 0.5], [1.0, 2.0, -1.0]])
    delta = np.array([2.0, 0.0, 0.5])
    out = scaled_increment(parts, delta, 1.01)
    phi = parts[:, 2] - 0.5
    np.testing.assert_allclose(out[:, :2] - parts[:, :2], 0.02 * np.stack([np.cos(phi), np.sin(phi)], 1))
    assert np.array_equal(out[:, 2], parts[:, 2])


def _room_scan(pose, n=360):
    """Ranges from ``pose`` in a 12 m x 6 m room (walls on cell centres of the 0.1 m grid)."""
    ang = np.linspace(-np.pi, np.pi, n, endpoint=False)
    return box_ranges(pose, ang, (-5.95, 6.05), (-2.95, 3.05)), ang


def test_correction_stage_learns_the_scale_of_odometry_that_under_reports():
    """Back and forth along the room; the odometry's travel is the true one / 1.02 (wheels 2 %
    too small). The estimate reaches 1.02 (the room's end walls show the travel; the trajectory
    is as good as without it: the matches correct every step here)."""

    def drive(on: bool, worker: bool = False):
        corr = cfg.CorrelationConfig(
            search_x_m=0.0,
            search_y_m=0.0,
            search_yaw_rad=0.0,
            sigma_m=0.1,
            max_distance_m=0.5,
            prior_sigma_xy_m=0.02,
            odom_scale=on,
            odom_scale_ramp_m=5.0,
            odom_scale_baseline_m=3.0,
            odom_scale_window_m=200.0,
            odom_scale_max=0.05,
        )
        slam = ParticleFilterSlam(
            cfg.FilterConfig(num_particles=20, min_travel_m=0.5, min_rotation_rad=1.0, seed=0),
            cfg.OdometryMotionConfig(
                sigma_xy_per_m=0.002,
                sigma_theta_per_m=0.0,
                sigma_theta_per_rad=0.0,
                sigma_xy_min_m=0.001,
                sigma_theta_min_rad=0.0,
                sigma_xy_per_rad=0.0,
            ),
            cfg.GridConfig(resolution_m=0.1, size_x_m=20.0, size_y_m=20.0),
            corr,
            cfg.ResampleConfig(),
        )
        if worker:  # the scan pairs measured in a worker process (the correlator node's default)
            slam.corrector.pairs = ProcessBackend(ScalePairs, (0.1, corr), name="test worker")
        truth = []
        for lap in range(10):
            xs = np.arange(-4.0, 4.01, 0.25)
            truth += list(xs if lap % 2 == 0 else xs[::-1])
        # odometry: the signed travel along x, 1/1.02 of the true one (heading kept, driving back)
        odom_x = -4.0 + np.concatenate([[0.0], np.cumsum(np.diff(truth))]) / 1.02
        out = []
        for x, ox in zip(truth, odom_x):
            r, a = _room_scan(np.array([x, 0.0, 0.0]))
            out.append(slam.process_odometry_scan(0.0, np.array([ox, 0.0, 0.0]), r, a, 0.0, 20.0)[0] - x)
        slam.corrector.close()
        return slam, float(np.sqrt(np.mean(np.square(out)))), out

    on, err_on, out_on = drive(True)
    off, err_off, _ = drive(False)
    in_worker, _, out_worker = drive(True, worker=True)
    assert out_worker == out_on  # bit for bit: the measurements are taken at the same corrections
    assert in_worker.corrector.odom_scale.scale == on.corrector.odom_scale.scale
    est = on.corrector.odom_scale
    print(f"scale {est.scale:.4f} over {est.steps} steps; x error rms {err_on:.3f} m (without: {err_off:.3f} m)")
    assert est.steps > 40 and on.corrector.scale_measurements == est.steps
    assert abs(est.scale - 1.02) < 0.004, est.scale
    assert err_on < 0.02 and err_on <= err_off + 0.002, (err_on, err_off)
    assert off.corrector.odom_scale is None
    # what summary.json and the run's last lines report (correlator status "odom_scale")
    st = on.corrector.scale_status()
    assert st["pairs"] == est.steps and st["scale"] == round(est.scale, 5)
    assert abs(st["measured"] - 1.02) < 0.004 and 0 < st["std_error"] < 0.004
    assert st["travel_m"] == round(est.travel_m, 1) and st["travel_m"] > 100.0
    assert off.corrector.scale_status() is None
    from pf_slam_nodes.runner.outputs import odom_scale_line

    line = odom_scale_line(st)
    assert f"{st['pairs']} scan pairs" in line and f"{100 * (st['measured'] - 1):+.2f} %" in line, line
    assert "no scan pair" in odom_scale_line({**st, "pairs": 0})


def _street(posts: bool, seed: int = 0) -> np.ndarray:
    """World points of a street: walls at y = +-8 m from x = -100 to 200 m, every 5 cm, and
    (``posts``) 0.4 m square posts at irregular x along y = +-6 m."""
    xs = np.arange(-100.0, 200.0, 0.05)
    pts = [np.stack([xs, np.full_like(xs, y)], 1) for y in (-8.0, 8.0)]
    if posts:
        rng = np.random.default_rng(seed)
        for x in np.cumsum(rng.uniform(6.0, 14.0, 14)) - 10.0:
            for y in (-6.0, 6.0):
                e = np.linspace(-0.2, 0.2, 5)
                pts.append(
                    np.stack(
                        [
                            x + np.r_[e, e, np.full(5, -0.2), np.full(5, 0.2)],
                            y + np.r_[np.full(5, -0.2), np.full(5, 0.2), e, e],
                        ],
                        1,
                    )
                )
    return np.concatenate(pts)


def _scan_from(world: np.ndarray, pose, rng, reach=75.0) -> np.ndarray:
    """The world points within ``reach`` of ``pose`` (x, y, yaw) in its frame, with 1 cm noise."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = world - np.asarray(pose[:2])
    local = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1)
    local = local[np.hypot(local[:, 0], local[:, 1]) <= reach]
    return local + rng.normal(0.0, 0.01, local.shape)


@pytest.mark.parametrize("true_scale", [0.99, 1.0, 1.01])
def test_scan_pair_measures_the_true_travel(true_scale):
    """Two scans 10 m apart by the truth; the odometry says 10 / true_scale. The pair measures
    the true 10 m (within 2 cm: 0.2 % of the travel) where posts give along-track structure."""
    c = cfg.CorrelationConfig(sigma_m=0.2, max_distance_m=1.0, range_max_m=75.0)
    rng = np.random.default_rng(1)
    world = _street(posts=True)
    truth = [np.array([5.0, 0.3, 0.02]), np.array([15.0, 0.3, 0.02])]
    odom_b = np.array([5.0 + 10.0 / true_scale, 0.3, 0.02])
    old = pair_scan(truth[0], _scan_from(world, truth[0], rng), 0.2, c)
    new = pair_scan(odom_b, _scan_from(world, truth[1], rng), 0.2, c)
    got = pair_travel(old, new, 0.03, 1000.0, 75.0)
    assert got is not None
    d, m = got
    assert d == pytest.approx(10.0 / true_scale, abs=1e-6)
    assert abs(m - 10.0) < 0.02, m


def test_scan_pair_without_along_track_structure_measures_nothing():
    c = cfg.CorrelationConfig(sigma_m=0.2, max_distance_m=1.0, range_max_m=75.0)
    rng = np.random.default_rng(2)
    world = _street(posts=False)
    a, b = np.array([5.0, 0.0, 0.0]), np.array([15.0, 0.0, 0.0])
    old = pair_scan(a, _scan_from(world, a, rng), 0.2, c)
    new = pair_scan(np.array([14.9, 0.0, 0.0]), _scan_from(world, b, rng), 0.2, c)
    assert pair_travel(old, new, 0.03, 1000.0, 75.0) is None
    assert pair_scan(a, np.zeros((5, 2)), 0.2, c) is None  # too few points: no scan to pair
