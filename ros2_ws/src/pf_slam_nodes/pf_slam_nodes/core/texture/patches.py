"""Stage 8: the texture placed again on a corrected trajectory (:class:`PairPatches`).

Each pair is placed with the pose the filter published at its stamp (``/pose``). A loop closure
corrects the trajectory afterwards (the mapper's final ``pf_slam/trajectory``); the filter's own
poses are the worse of the two on most drives (the car's worlds: 0.30 m against 0.15 m median,
SE(2)-aligned). So every pair's samples are also kept in the vehicle frame, binned, and the
texture can be built again from them at the corrected poses.

Storage per pair: the samples binned at ``bin_m`` (0.05 m: half a texture cell; a bin's
position error is at most 3.5 cm) in the vehicle frame, each bin's mean colour (uint8), its
sample count (uint16) and its index (int16 x, int16 y): 9 bytes a bin, ~45 000 bins (0.4 MB)
for a KAIST pair. At most ``budget_bytes``: beyond it the oldest pairs are placed for good
(``frozen``, at the pose they were last placed with) and their samples dropped.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..scan import transform_points
from .map import TextureMap
from .texturer import interpolate_poses


@dataclass
class _Patch:
    stamp: float
    pose: np.ndarray  # (3,) where it is placed now
    qx: np.ndarray  # (N,) int16 bin indices (vehicle frame)
    qy: np.ndarray
    rgb: np.ndarray  # (N, 3) uint8
    n: np.ndarray  # (N,) uint16 samples per bin

    @property
    def nbytes(self) -> int:
        return self.qx.nbytes + self.qy.nbytes + self.rgb.nbytes + self.n.nbytes


class PairPatches:
    """The textured pairs' samples in their vehicle frames (see the module docstring).

    Parameters
    ----------
    bin_m : float
        Bin size in the vehicle frame (m).
    budget_bytes : int
        Bytes of kept samples at most (0: keep none; every pair is placed for good).
    """

    def __init__(self, bin_m: float = 0.05, budget_bytes: int = 256 << 20) -> None:
        if not bin_m > 0 or budget_bytes < 0:
            raise ValueError(f"bad kept-pair geometry: bin {bin_m} m, budget {budget_bytes} bytes")
        self.bin_m = float(bin_m)
        self.budget_bytes = int(budget_bytes)
        self.patches: deque[_Patch] = deque()
        self.nbytes = 0
        self.frozen: TextureMap | None = None  # pairs no longer kept, at their last pose
        self.pairs_frozen = 0

    def keep(self, stamp: float, pose: np.ndarray, xy_world: np.ndarray, rgb: np.ndarray, texmap: TextureMap) -> None:
        """Keep one pair's samples (as placed at ``pose``); ``texmap``'s geometry makes the frozen
        map when the budget is exceeded."""
        pose = np.asarray(pose, dtype=np.float64).reshape(3)
        xy = np.asarray(xy_world, dtype=np.float64).reshape(-1, 2)
        col = np.asarray(rgb).reshape(-1, 3)
        if not len(xy) or not np.all(np.isfinite(pose)):
            return
        # per axis: numpy's reductions and picks over (N, 2) arrays are slow
        x, y, th = (float(v) for v in pose)
        c, s = math.cos(th), math.sin(th)
        dx, dy = xy[:, 0] - x, xy[:, 1] - y
        with np.errstate(invalid="ignore"):
            fx, fy = np.floor((c * dx + s * dy) / self.bin_m), np.floor((-s * dx + c * dy) / self.bin_m)
            lim = np.iinfo(np.int16).max  # 1.6 km from the vehicle at 0.05 m: never for a camera
            ok = (np.abs(fx) < lim) & (np.abs(fy) < lim)  # False for NaN
        if not ok.all():
            fx, fy, col = fx[ok], fy[ok], col[ok]
        if not len(fx):
            return
        qx, qy = fx.astype(np.int64), fy.astype(np.int64)
        x0, y0 = int(qx.min()), int(qy.min())
        h, w = int(qx.max()) - x0 + 1, int(qy.max()) - y0 + 1
        flat = (qx - x0) * w + (qy - y0)
        chans = [np.ascontiguousarray(col[:, ch], dtype=np.float64) for ch in range(3)]
        if h * w <= 8 * len(flat) + (1 << 20):  # a camera's footprint: counts over its bounding box
            cnt = np.bincount(flat, minlength=h * w)
            uniq = np.flatnonzero(cnt)
            sums = np.stack([np.bincount(flat, weights=ch, minlength=h * w)[uniq] for ch in chans], axis=-1)
            cnt = cnt[uniq]
        else:  # scattered samples
            uniq, inv, cnt = np.unique(flat, return_inverse=True, return_counts=True)
            sums = np.stack([np.bincount(inv, weights=ch, minlength=len(uniq)) for ch in chans], axis=-1)
        patch = _Patch(
            float(stamp),
            pose.copy(),
            (uniq // w + x0).astype(np.int16),
            (uniq % w + y0).astype(np.int16),
            np.clip(np.rint(sums / cnt[:, None]), 0, 255).astype(np.uint8),
            np.minimum(cnt, np.iinfo(np.uint16).max).astype(np.uint16),
        )
        self.patches.append(patch)
        self.nbytes += patch.nbytes
        while self.patches and self.nbytes > self.budget_bytes:
            old = self.patches.popleft()
            self.nbytes -= old.nbytes
            if self.frozen is None:
                self.frozen = texmap.empty_like()
            self._place(self.frozen, old, old.pose)
            self.pairs_frozen += 1

    def _place(self, texmap: TextureMap, p: _Patch, pose: np.ndarray) -> None:
        centres = np.column_stack([(p.qx + 0.5) * self.bin_m, (p.qy + 0.5) * self.bin_m])  # vehicle frame
        texmap.add(transform_points(centres, pose), p.rgb, p.n)

    def replace(self, stamps: np.ndarray, poses: np.ndarray, like: TextureMap) -> tuple[TextureMap, dict]:
        """A new texture map (``like``'s geometry): the frozen pairs as they are, every kept pair
        at the trajectory ``(stamps (K,) s, poses (K, 3))`` interpolated at its stamp (a pair
        outside the trajectory stays where it is). Returns the map and ``{"pairs_moved",
        "pairs_frozen", "shift_median_m", "shift_max_m"}`` (the kept pairs' moves)."""
        out = self.frozen.copy() if self.frozen is not None else like.empty_like()
        st = np.array([p.stamp for p in self.patches])
        new = interpolate_poses(np.asarray(stamps, dtype=np.float64), poses, st) if len(st) else np.zeros((0, 3))
        shifts = []
        for p, pose in zip(self.patches, new):
            if np.all(np.isfinite(pose)):
                shifts.append(float(np.hypot(*(pose[:2] - p.pose[:2]))))
                p.pose = pose
            self._place(out, p, p.pose)
        sh = np.array(shifts) if shifts else np.zeros(1)
        return out, {
            "pairs_moved": len(shifts),
            "pairs_frozen": self.pairs_frozen,
            "shift_median_m": round(float(np.median(sh)), 3),
            "shift_max_m": round(float(sh.max()), 3),
        }
