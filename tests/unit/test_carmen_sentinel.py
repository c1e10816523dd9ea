"""'No return' written as a range (one held-out log: exactly 50.0 m, 11 139 times): inferred from
the data, written as +inf, said in the convert summary with the count."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import DATA as SHARED_DATA

from pf_slam_nodes.io.bag import deserialize, read_bag
from pf_slam_nodes.io.carmen import infer_no_return, read_carmen
from pf_slam_nodes.io.convert import convert_carmen

DATA = SHARED_DATA / "carmen"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"{DATA} not available")


def _log(path, ranges):
    """FLASER lines (ranges (S, B) written with 2 decimals, as the CARMEN loggers do)."""
    lines = []
    for k, r in enumerate(ranges):
        vals = " ".join(f"{v:.2f}" for v in r)
        t = f"{100 + 0.1 * k:.3f}"
        lines.append(f"FLASER {len(r)} {vals} {0.05 * k} 0 0 {0.05 * k} 0 0 {t} host {t}\n")
    path.write_text("".join(lines))
    return path


def _ranges(rng, scans=300, beams=90, sentinel=50.0, frac=0.2, top=45.0):
    r = np.round(rng.uniform(0.3, top, (scans, beams)), 2)
    r[rng.random(r.shape) < frac] = sentinel
    return r


def test_a_50_m_sentinel_is_inferred_and_written_as_no_return(tmp_path):
    rng = np.random.default_rng(0)
    r = _ranges(rng)
    n = int(np.count_nonzero(r == 50.0))
    log = read_carmen(_log(tmp_path / "a.clf", r))
    assert (log.sentinel_m, log.sentinel_count) == (50.0, n)
    got = np.stack([s.ranges for s in log.scans])
    assert np.count_nonzero(np.isinf(got)) == n and np.isfinite(got[r != 50.0]).all()
    np.testing.assert_allclose(got[r != 50.0], r[r != 50.0], rtol=1e-6)
    assert all(s.range_max == 50.0 for s in log.scans)
    assert any(f"{n} beams read exactly 50 m" in w for w in log.warnings)
    rep = convert_carmen(tmp_path / "a.clf", tmp_path / "bag")
    assert f"no return: {n} beams at exactly 50 m" in rep.summary()
    msgs = [deserialize(raw, mt) for _, mt, _, raw in read_bag(tmp_path / "bag", topics=["/scan"])]
    ranges = np.stack([np.asarray(m.ranges) for m in msgs])
    assert np.count_nonzero(np.isinf(ranges)) == n and msgs[0].range_max == 50.0
    # without the inference (as before): 50.0 is a real range
    assert read_carmen(tmp_path / "a.clf", infer_sentinel=False).sentinel_m is None


def test_no_sentinel_where_the_longest_range_is_a_real_one(tmp_path):
    rng = np.random.default_rng(1)
    r = _ranges(rng, frac=0.0)  # the longest range occurs once or a few times
    log = read_carmen(_log(tmp_path / "b.clf", r))
    assert log.sentinel_m is None and log.warnings == []
    assert np.isfinite(np.stack([s.ranges for s in log.scans])).all()
    # rare repeats of the maximum (< 50 beams) are not a sentinel either
    r2 = r.copy()
    r2[:30, 0] = 46.0
    assert read_carmen(_log(tmp_path / "c.clf", r2)).sentinel_m is None
    # coarse ranges (0.5 m steps): every value repeats, the maximum no more than the others
    r3 = np.round(rng.uniform(0.3, 20.0, (300, 90)) * 2) / 2
    assert infer_no_return(r3) == (None, 0)
    assert infer_no_return(np.full(10, np.inf)) == (None, 0)


@needs_data
@pytest.mark.parametrize("name, inf", [("intel_2726", 13586), ("intel_910", 4172), ("mit-csail", 23711)])
def test_real_logs_keep_their_no_return_handling(name, inf):
    """Intel's 81.83 is 'no return' by the >= 80 m rule as before; nothing else is inferred."""
    log = read_carmen(DATA / f"{name}.clf")
    assert log.sentinel_m is None
    assert int(np.count_nonzero(np.isinf(np.concatenate([s.ranges for s in log.scans])))) == inf
