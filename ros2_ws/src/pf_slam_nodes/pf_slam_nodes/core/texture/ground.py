"""Stage 5: the road plane (:class:`Plane`, RANSAC + least squares :func:`fit_ground_plane`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

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


def fit_ground_plane(
    points: np.ndarray,
    iterations: int = 64,
    tol_m: float = 0.05,
    max_points: int = 4000,
    max_tilt_deg: float = 10.0,
    rng: np.random.Generator | None = None,
) -> tuple[Plane | None, np.ndarray]:
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
    off = -np.einsum("ij,ij->i", nrm, a)
    score = (np.abs(np.einsum("nj,hj->nh", sub, nrm) + off) < tol_m).sum(axis=0)
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
        _, vecs = np.linalg.eigh(np.einsum("ni,nj->ij", d, d) / len(d))
        normal = vecs[:, 0] * (1.0 if vecs[2, 0] >= 0 else -1.0)
        c0 = -float(mean @ normal)
    return Plane(normal, c0), np.abs(_dot3(p, normal) + c0) < tol_m


def _dot3(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``p @ n`` for ``(..., 3)`` points, as three multiply-adds (no BLAS)."""
    return p[..., 0] * n[0] + p[..., 1] * n[1] + p[..., 2] * n[2]
