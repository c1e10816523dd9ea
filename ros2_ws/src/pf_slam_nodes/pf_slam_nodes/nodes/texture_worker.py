"""The texture node's per-pair work, in a thread of the node's process or in a worker process
(the texture node's ``worker`` parameter; nodes/worker.py). No rclpy here: a spawned worker
process imports only this module, numpy, OpenCV and core/texture.

:class:`TextureEngine` owns the texturer (:class:`StereoTexturer` / :class:`DepthTexturer`) and the
accumulated :class:`TextureMap`; the node calls its methods through a backend: in a thread,
direct calls under a lock (beside the SLAM nodes' executor thread every numpy / OpenCV call waits
for the GIL again); in a process, one request at a time, answered in order: the texture is the
same bit for bit.
"""

from __future__ import annotations

import time

import numpy as np

from ..core.texture import (
    DepthCamera,
    DepthTexturer,
    IncrementalRender,
    PairPatches,
    StereoRig,
    StereoTexturer,
    TextureConfig,
    TextureMap,
)
from .worker import ProcessBackend, ThreadBackend, WorkerDied
from .worker import make_backend as worker_backend

__all__ = ["TextureEngine", "WorkerDied", "make_backend"]


class TextureEngine:
    """Texturer + texture map; every method returns plain data (picklable)."""

    def __init__(self, cfg: TextureConfig) -> None:
        self.cfg = cfg
        self.texmap = TextureMap.from_config(cfg)
        self.renderer = IncrementalRender()  # the periodic image: only changed tiles drawn again
        self.texturer: StereoTexturer | DepthTexturer | None = None
        budget = int(cfg.replace_budget_mb * 2**20)
        self.kept = PairPatches(cfg.replace_bin_m, budget) if budget > 0 else None

    def ready(self) -> bool:
        return True

    def set_anchor(self, xy: tuple[float, float]) -> None:
        """Align the texture cells with the map's origin (only while nothing is coloured)."""
        if not self.texmap.tiles:
            self.texmap.anchor = np.array([float(xy[0]), float(xy[1])])

    def setup_stereo(self, rig: StereoRig) -> None:
        self.texturer = StereoTexturer(rig, self.cfg)

    def setup_depth(self, camera: DepthCamera, floor_height_m: float) -> None:
        self.texturer = DepthTexturer(camera, self.cfg, floor_height_m)

    def stereo(
        self, left: np.ndarray, right: np.ndarray, pose: np.ndarray, encoding: str, stamp_s: float | None = None
    ) -> dict:
        assert isinstance(self.texturer, StereoTexturer)
        cells = (self.texmap.anchor.copy(), self.texmap.cell_m)
        res = self.texturer.process(left, right, pose, encoding, cells=cells)
        t1 = time.perf_counter()
        self.texmap.add(res.xy_world, res.rgb)
        t2 = time.perf_counter()
        self._keep(stamp_s, pose, res.xy_world, res.rgb)
        ms = {k: float(v) for k, v in res.timings_ms.items() if k != "total"}
        ms["accumulate"] = 1e3 * (t2 - t1)
        ms["keep"] = 1e3 * (time.perf_counter() - t2)
        return {"ms_stages": ms, "plane_fitted": bool(res.plane_fitted), **self.stats()}

    def _keep(self, stamp_s: float | None, pose: np.ndarray, xy: np.ndarray, rgb: np.ndarray) -> None:
        if self.kept is not None and stamp_s is not None:
            self.kept.keep(stamp_s, pose, xy, rgb, self.texmap)

    def replace(self, stamps_s: np.ndarray, poses: np.ndarray) -> dict:
        """The texture rebuilt with every kept pair at the trajectory ``(stamps_s, poses)``
        (the loop closure's corrected one); see :class:`PairPatches`."""
        if self.kept is None:
            return {"pairs_moved": 0, **self.stats()}
        self.texmap, info = self.kept.replace(stamps_s, poses, self.texmap)
        return {**info, **self.stats()}

    def depth(
        self,
        depth_mm: np.ndarray,
        rgb: np.ndarray,
        mount: tuple[np.ndarray, np.ndarray],
        pose: np.ndarray,
        rgb_from_depth: tuple[np.ndarray, np.ndarray] | None,
        stamp_s: float | None = None,
    ) -> dict:
        assert isinstance(self.texturer, DepthTexturer)
        res = self.texturer.process(depth_mm, rgb, mount, pose, rgb_from_depth)
        self.texmap.add(res.xy_world, res.rgb)
        self._keep(stamp_s, pose, res.xy_world, res.rgb)
        return {"ms_stages": {}, "plane_fitted": bool(res.plane_fitted), **self.stats()}

    def render(self, origin: tuple[float, float], resolution: float, width: int, height: int):
        return self.renderer.render(self.texmap, origin, resolution, width, height)

    def render_native(self):
        return self.texmap.render_native()

    def stats(self) -> dict:
        kept = self.kept
        return {
            "cells": int(self.texmap.cell_count()),
            "memory_bytes": int(self.texmap.memory_bytes),
            "kept_bytes": 0 if kept is None else int(kept.nbytes) + (kept.frozen.memory_bytes if kept.frozen else 0),
        }


def make_backend(kind: str, cfg: TextureConfig, nice: int = 0) -> ThreadBackend | ProcessBackend:
    """The texture engine in a ``'process'`` or a ``'thread'`` (the texture node's ``worker``
    parameter; nodes/worker.py)."""
    return worker_backend(kind, TextureEngine, (cfg,), nice, "texture worker")
