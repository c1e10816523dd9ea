"""laser.smooth_beams: a noisy laser's returns moved onto the surface through their neighbours.

The scan's own noise is estimated from its beams (each middle return against the chord of its
two neighbours); scans noisier than ``smooth_min_noise_m`` whose ranges are not rounded to a
coarse lattice have each return on a straight stretch moved onto the line fitted to it and its
neighbours, and nothing at corners, edges or gaps."""

import math

import numpy as np
import pytest

from pf_slam_nodes.core.config import LaserConfig
from pf_slam_nodes.core.scan import NoiseTally, range_noise, range_rounding, smooth_scan
from pf_slam_nodes.core.stages import scan_in_base

ANGLES = np.radians(np.arange(-90.0, 90.5, 1.0))  # 181 beams, 1 deg: a SICK LMS


def room(angles: np.ndarray) -> np.ndarray:
    """True ranges from (0, 0) in a 8 m x 6 m box centred at (2, 0): walls x = 6, y = +-3."""
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 1e-9, 6.0 / c, np.inf)
        ty = np.where(np.abs(s) > 1e-9, 3.0 / np.abs(s), np.inf)
    return np.minimum(tx, ty)


@pytest.mark.parametrize("sigma", [0.005, 0.01, 0.02, 0.03])
def test_the_noise_is_found_from_the_scan_itself(sigma):
    rng = np.random.default_rng(1)
    truth = room(ANGLES)
    est = [range_noise(truth + rng.normal(0.0, sigma, truth.shape), ANGLES) for _ in range(20)]
    assert np.median(est) == pytest.approx(sigma, rel=0.15)
    assert range_noise(truth, ANGLES) < 1e-6  # exact walls: no noise
    assert math.isnan(range_noise(np.full(5, 2.0), ANGLES[:5]))  # too few beams to tell


def test_a_noisy_scan_comes_closer_to_its_walls_and_its_corners_stay():
    rng = np.random.default_rng(2)
    truth = room(ANGLES)
    before, after = [], []
    corner = int(np.argmin(np.abs(ANGLES - math.atan2(3.0, 6.0))))  # the beam at the corner (6, 3)
    for _ in range(10):
        noisy = truth + rng.normal(0.0, 0.03, truth.shape)
        smooth = smooth_scan(noisy, ANGLES, 2, 0.015)[0]
        before.append(noisy - truth)
        after.append(smooth - truth)
        assert abs(smooth[corner] - noisy[corner]) <= 3 * range_noise(noisy, ANGLES) + 1e-9  # within the noise
    before, after = np.concatenate(before), np.concatenate(after)
    assert np.std(after) < 0.7 * np.std(before)
    assert abs(np.mean(after)) < 0.005  # no bias towards or away from the walls


def test_no_return_stays_no_return_and_gaps_are_not_bridged():
    rng = np.random.default_rng(3)
    noisy = room(ANGLES) + rng.normal(0.0, 0.03, ANGLES.shape)
    noisy[60:70] = np.inf
    noisy[100] = np.nan
    smooth = smooth_scan(noisy, ANGLES, 2, 0.015)[0]
    assert np.all(np.isinf(smooth[60:70])) and np.isnan(smooth[100])
    # the beams next to a gap have no full window of neighbours: unchanged
    for k in (58, 59, 70, 71, 98, 99, 101, 102):
        assert smooth[k] == noisy[k]


def test_precise_or_rounded_scans_are_left_as_they_are():
    rng = np.random.default_rng(4)
    truth = room(ANGLES)
    precise = truth + rng.normal(0.0, 0.006, truth.shape)  # a SICK at 6 mm: below 1.5 cm
    assert np.array_equal(smooth_scan(precise, ANGLES, 2, 0.015)[0], precise)
    noisy = truth + rng.normal(0.0, 0.03, truth.shape)
    rounded = np.round((noisy - 0.005) / 0.025) * 0.025 + 0.005  # a log that stored 2.5 cm steps
    assert range_rounding(rounded) == 0.025
    assert np.array_equal(smooth_scan(rounded, ANGLES, 2, 0.015)[0], rounded)
    assert range_rounding(np.round(noisy, 2)) == 0.0  # centimetres: as sensors report them
    assert range_rounding(noisy) == 0.0
    assert np.array_equal(smooth_scan(noisy, ANGLES, 0, 0.015)[0], noisy)  # off


def test_the_correlator_and_the_mapper_see_the_same_smoothed_scan():
    """Both take their planar scan from scan_in_base: smoothing there reaches both."""
    rng = np.random.default_rng(5)
    noisy = room(ANGLES) + rng.normal(0.0, 0.03, ANGLES.shape)
    r0, _, _ = scan_in_base(noisy, ANGLES, LaserConfig(), np.zeros(3), 0.0, 80.0)
    r2, a2, _ = scan_in_base(noisy, ANGLES, LaserConfig(smooth_beams=2), np.zeros(3), 0.0, 80.0)
    assert np.array_equal(r0, noisy)
    assert np.array_equal(r2, smooth_scan(noisy, a2, 2, 0.015)[0]) and not np.array_equal(r2, noisy)


def test_the_parameters_are_checked():
    with pytest.raises(ValueError, match="smooth_beams"):
        LaserConfig(smooth_beams=-1)
    with pytest.raises(ValueError, match="smooth_min_noise_m"):
        LaserConfig(smooth_min_noise_m=-0.01)


def test_the_tally_says_what_was_found():
    rng = np.random.default_rng(6)
    truth = room(ANGLES)
    tally = NoiseTally()
    noisy = truth + rng.normal(0.0, 0.03, truth.shape)
    for r in (noisy, truth + rng.normal(0.0, 0.006, truth.shape), np.round(noisy / 0.05) * 0.05, np.full(5, 2.0)):
        _, noise, verdict = smooth_scan(r, ANGLES[: r.size], 2, 0.015)
        tally.add(noise, verdict)
    status = tally.status()
    assert status["scans"] == {"smoothed": 1, "precise": 1, "rounded": 1, "unknown": 1}
    assert 0.006 < status["noise_m_median"] < 0.04
