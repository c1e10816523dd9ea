"""Trajectory and ground-truth relation files.

* TUM (``t x y z qx qy qz qw``): written by ``pf-slam run`` (``trajectory.tum``), read back.
* ``timestamp x y theta`` (4 columns): the ``*_gmapping_reference.txt`` files.
* Relations (``t1 t2 x y z roll pitch yaw``): the Kümmerle et al. 2009 ground truth
  (``*.relations``), the true pose at ``t2`` expressed in the pose at ``t1``.

Lines starting with ``#`` and empty lines are ignored; commas are accepted as separators.
A line with another column count or a non-numeric value raises ``ValueError`` naming
``file:line``.
"""

from __future__ import annotations

import math
import os

import numpy as np

from ..core.geometry import quat_to_yaw

__all__ = ["format_stamp", "read_relations", "read_trajectory", "write_tum"]


def format_stamp(t: float) -> str:
    """Seconds with exactly 9 decimals, using the shortest digits that round-trip the float.

    ``976052890.244111`` -> ``'976052890.244111000'`` (plain ``'%.9f'`` would print the
    float's binary noise, ``'976052890.244110942'``).
    """
    text = np.format_float_positional(float(t), precision=9, unique=True, fractional=True, trim="k")
    whole, _, frac = text.partition(".")
    return f"{whole}.{frac:0<9}"


def write_tum(path: str | os.PathLike, stamps_s: np.ndarray, poses: np.ndarray) -> None:
    """Write planar poses as a TUM trajectory.

    Parameters
    ----------
    path : str or PathLike
        Output file (overwritten).
    stamps_s : np.ndarray
        ``(K,)`` times (s), written with 9 decimals.
    poses : np.ndarray
        ``(K, 3)`` ``[x, y, theta]`` (m, m, rad); written with ``z = 0`` and a yaw quaternion.
    """
    t = np.asarray(stamps_s, dtype=np.float64).ravel()
    p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    if len(t) != len(p):
        raise ValueError(f"stamps_s has {len(t)} entries but poses has {len(p)} rows")
    half = 0.5 * p[:, 2]
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("# timestamp x y z qx qy qz qw\n")
        for ti, (x, y, _), qz, qw in zip(t, p, np.sin(half), np.cos(half)):
            fh.write(f"{format_stamp(ti)} {x:.6f} {y:.6f} 0.000000 0.000000 0.000000 {qz:.9f} {qw:.9f}\n")


def _read_table(path: str | os.PathLike, allowed: tuple[int, ...]) -> np.ndarray:
    name = os.path.basename(str(path))
    rows: list[list[float]] = []
    ncols = None
    with open(path, encoding="utf-8") as fh:
        for line_no, line in enumerate(fh, start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            if line_no == 1 and s[0].isalpha():  # a CSV header row (the car simulator's poses.csv)
                continue
            tok = s.replace(",", " ").split()
            if len(tok) not in allowed:
                raise ValueError(f"{name}:{line_no}: expected {' or '.join(map(str, allowed))} columns, got {len(tok)}")
            if ncols is None:
                ncols = len(tok)
            elif len(tok) != ncols:
                raise ValueError(f"{name}:{line_no}: {len(tok)} columns after {ncols}-column lines")
            try:
                vals = [float(v) for v in tok]
            except ValueError:
                raise ValueError(f"{name}:{line_no}: non-numeric value in {s!r}") from None
            if not all(math.isfinite(v) for v in vals):
                raise ValueError(f"{name}:{line_no}: NaN or inf in {s!r}")
            rows.append(vals)
    if not rows:
        return np.zeros((0, allowed[0]))
    return np.array(rows, dtype=np.float64)


def read_trajectory(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM (8 columns) or ``timestamp x y theta`` (4 columns) trajectory.

    Commas work as separators and a first line starting with a letter is a header (the car
    simulator's ``ground_truth/poses.csv``); stamps above 1e14 are taken as nanoseconds.

    Returns
    -------
    stamps : np.ndarray
        ``(K,)`` times (s), in file order.
    poses : np.ndarray
        ``(K, 3)`` ``[x, y, theta]``; theta from the quaternion's yaw for TUM files.
    """
    a = _read_table(path, (8, 4))
    if a.size and np.abs(a[:, 0]).max() > 1e14:  # integer nanoseconds (KAIST layout) -> seconds
        a[:, 0] /= 1e9
    if a.shape[1] == 4:
        return a[:, 0].copy(), a[:, 1:4].copy()
    yaw = quat_to_yaw(a[:, 4], a[:, 5], a[:, 6], a[:, 7])
    return a[:, 0].copy(), np.column_stack([a[:, 1], a[:, 2], yaw])


def read_relations(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a relations file (``t1 t2 x y z roll pitch yaw``).

    Returns
    -------
    stamps : np.ndarray
        ``(K, 2)`` ``[t1, t2]`` (s).
    delta : np.ndarray
        ``(K, 3)`` ``[dx, dy, dyaw]``: the true pose at ``t2`` in the frame of the pose at
        ``t1`` (m, m, rad). ``z``, roll and pitch are ignored (zero in 2D data sets).
    """
    a = _read_table(path, (8,))
    return a[:, 0:2].copy(), a[:, [2, 3, 7]].copy()
