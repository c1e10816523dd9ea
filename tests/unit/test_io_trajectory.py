"""TUM / 't x y theta' trajectories and relation files."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import DATA as SHARED_DATA

from pf_slam_nodes.io.trajectory import read_relations, read_trajectory, write_tum

DATA = SHARED_DATA / "carmen"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"{DATA} not available")


def test_tum_round_trip(tmp_path):
    t = np.array([976052890.244111, 976052892.4424, 976052893.797315])
    p = np.array([[0.6, -0.03, -0.35], [1.0, 2.0, 3.1], [-5.0, 0.0, -3.1]])
    f = tmp_path / "traj.tum"
    write_tum(f, t, p)
    first = f.read_text().splitlines()[1].split()
    assert len(first) == 8 and first[0] == "976052890.244111000"
    t2, p2 = read_trajectory(f)
    np.testing.assert_array_equal(t2, t)
    np.testing.assert_allclose(p2, p, atol=1e-6)
    with pytest.raises(ValueError):
        write_tum(f, t[:2], p)


def test_four_columns_and_errors(tmp_path):
    f = tmp_path / "a.txt"
    f.write_text("# t x y theta\n1.0 2 3 0.5\n\n2.0,3,4,0.6\n")
    t, p = read_trajectory(f)
    np.testing.assert_array_equal(t, [1.0, 2.0])
    np.testing.assert_array_equal(p, [[2, 3, 0.5], [3, 4, 0.6]])
    f.write_text("1 2 3 4\n1 2 3\n")
    with pytest.raises(ValueError, match="a.txt:2: expected 8 or 4 columns, got 3"):
        read_trajectory(f)
    f.write_text("1 2 3 x\n")
    with pytest.raises(ValueError, match="a.txt:1: non-numeric"):
        read_trajectory(f)


@needs_data
def test_reference_and_relations():
    t, p = read_trajectory(DATA / "intel_910_gmapping_reference.txt")
    assert t.shape == (910,) and p.shape == (910, 3)
    np.testing.assert_allclose(p[0], [0.600266, -0.032033, -0.354665])
    st, d = read_relations(DATA / "intel_910.relations")
    assert st.shape == (90, 2) and d.shape == (90, 3)
    np.testing.assert_allclose(st[0], [976053556.625959, 976053557.746919])
    np.testing.assert_allclose(d[0], [-0.016980, 0.059550, 0.497670])
