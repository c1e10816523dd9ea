"""The texture node's per-pair work, in a thread of the node's process or in a worker process
(the texture node's ``worker`` parameter). No rclpy here: a spawned worker process imports only
this module, numpy, OpenCV and core/texture.

:class:`TextureEngine` owns the texturer (:class:`StereoTexturer` / :class:`DepthTexturer`) and the
accumulated :class:`TextureMap`; the node calls its methods through a backend:

* :class:`ThreadBackend`: direct calls (under a lock) in the node's worker thread; beside the
  SLAM nodes' executor thread every numpy / OpenCV call waits for the GIL again.
* :class:`ProcessBackend`: the same calls, as ``(method, args)`` messages over a pipe to one worker
  process (multiprocessing ``spawn``: no fork of a process with DDS threads), started when the
  node is built so that its imports overlap the start of the run. One request at a time, answered
  in order: the texture is the same bit for bit as in a thread. The process ignores SIGINT (the
  node shuts it down), ends when its pipe closes (the node's process is gone), and its death is a
  :class:`WorkerDied` on the next call.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import sys
import threading
import time
import types
from multiprocessing.connection import wait

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


class WorkerDied(RuntimeError):
    """The worker process is gone (its exit status in the message)."""


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


class ThreadBackend:
    """The engine in the caller's process."""

    kind = "thread"

    def __init__(self, cfg: TextureConfig, nice: int = 0) -> None:
        self._engine = TextureEngine(cfg)
        self._lock = threading.Lock()

    def call(self, method: str, *args):
        with self._lock:
            return getattr(self._engine, method)(*args)

    def close(self, timeout_s: float = 5.0) -> None:
        pass


def _serve(conn, cfg: TextureConfig, nice: int) -> None:
    """The worker process: answer ``(method, args)`` requests with ``(True, result)`` or
    ``(False, error text)`` until ``None`` or the pipe closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the node, which stops us
    if nice > 0:
        try:
            os.setpriority(os.PRIO_PROCESS, 0, min(os.getpriority(os.PRIO_PROCESS, 0) + nice, 19))
        except OSError:
            pass
    engine = TextureEngine(cfg)
    while True:
        try:
            req = conn.recv()
        except (EOFError, OSError):
            return
        if req is None:
            return
        method, args = req
        try:
            out = (True, getattr(engine, method)(*args))
        except Exception as e:  # noqa: BLE001  (a bad pair must not end the worker)
            out = (False, f"{type(e).__name__}: {e}")
        try:
            conn.send(out)
        except (BrokenPipeError, OSError):
            return


class ProcessBackend:
    """The engine in a worker process (see the module docstring)."""

    kind = "process"

    def __init__(self, cfg: TextureConfig, nice: int = 0) -> None:
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_serve, args=(child, cfg, nice), name="texture_worker", daemon=True)
        # the worker needs this module only: it does not re-import the caller's __main__ (a
        # script without a __main__ guard would run again there; the CLI would import rclpy)
        main = sys.modules.get("__main__")
        sys.modules["__main__"] = types.ModuleType("__main__")
        try:
            self.process.start()
        finally:
            if main is not None:
                sys.modules["__main__"] = main
        child.close()
        self._lock = threading.Lock()
        self._dead: str | None = None

    def _died(self) -> WorkerDied:
        if self._dead is None:
            self.process.join(timeout=1.0)
            code = self.process.exitcode
            for _ in range(10):  # another thread may be reaping it right now
                if code is not None:
                    break
                time.sleep(0.05)
                code = self.process.exitcode
            how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit code {code}"
            self._dead = f"texture worker process (pid {self.process.pid}) died ({how})"
        return WorkerDied(self._dead)

    def call(self, method: str, *args):
        """Run ``method(*args)`` in the worker; raises :class:`WorkerDied` once it is gone, a
        ``RuntimeError`` with the worker's error for a failed call."""
        with self._lock:
            if self._dead is not None:
                raise WorkerDied(self._dead)
            try:
                self._conn.send((method, args))
                while True:  # wait for the answer or the worker's end, whichever comes first
                    ready = wait([self._conn, self.process.sentinel], timeout=5.0)
                    if self._conn in ready:
                        ok, out = self._conn.recv()
                        break
                    if self.process.sentinel in ready:
                        raise self._died()
            except (EOFError, OSError):  # the pipe broke under the worker (WorkerDied passes through)
                raise self._died() from None
        if not ok:
            raise RuntimeError(out)
        return out

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the worker: ask, then terminate, then kill. A call still waiting on a worker that
        does not answer (the lock not free within ``timeout_s``) ends with :class:`WorkerDied`
        once the worker is terminated."""
        got = self._lock.acquire(timeout=timeout_s)
        try:
            if got and self.process.is_alive():
                try:
                    self._conn.send(None)
                except (BrokenPipeError, OSError):
                    pass
                self.process.join(timeout_s)
            if self.process.is_alive():
                self.process.terminate()
                self.process.join(1.0)
            if self.process.is_alive():
                self.process.kill()
                self.process.join(1.0)
            if self._dead is None:
                self._dead = "texture worker process stopped"
        finally:
            if got:
                self._conn.close()
                self._lock.release()


def make_backend(kind: str, cfg: TextureConfig, nice: int = 0) -> ThreadBackend | ProcessBackend:
    """``'thread'`` or ``'process'`` (the texture node's ``worker`` parameter)."""
    if kind == "process":
        return ProcessBackend(cfg, nice)
    if kind == "thread":
        return ThreadBackend(cfg, nice)
    raise ValueError(f"texture worker must be 'process' or 'thread', got {kind!r}")
