"""An object's work in a worker process, or in the caller's: the homes of core/deferred.py's
calls. No rclpy here: a spawned worker imports this module, numpy, OpenCV and the core module
of the object it builds.

* :class:`ProcessBackend`: ``(method, args)`` messages over a pipe to one worker process
  (multiprocessing ``spawn``: no fork of a process with DDS threads) that builds the object
  (``factory(*args)``) and answers in order; started when the node is built, so that its imports
  overlap the start of the run. :meth:`~ProcessBackend.submit` sends and returns,
  :meth:`~ProcessBackend.collect` waits for the oldest answer, :meth:`~ProcessBackend.call` is
  both. The answers are the same bit for bit as in the caller's process. The process ignores
  SIGINT (the node shuts it down), ends when its pipe closes (the node's process is gone), and
  its death is a :class:`WorkerDied` on the next call.
* :class:`ThreadBackend`: the object in the caller's process (:class:`~..core.deferred.Inline`),
  its calls under a lock (a node's worker thread and its executor may both call).
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

from ..core.deferred import Inline


class WorkerDied(RuntimeError):
    """The worker process is gone (its exit status in the message)."""


class ThreadBackend(Inline):
    """The object in the caller's process."""

    kind = "thread"

    def __init__(self, factory, args: tuple = ()) -> None:
        super().__init__(factory(*args))
        self._lock = threading.Lock()

    def submit(self, method: str, *args) -> None:
        with self._lock:
            super().submit(method, *args)

    def call(self, method: str, *args):
        with self._lock:
            return getattr(self.obj, method)(*args)


def _serve(conn, factory, args: tuple, nice: int) -> None:
    """The worker process: answer ``(method, args)`` requests with ``(True, result)`` or
    ``(False, error text)`` until ``None`` or the pipe closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the node, which stops us
    if nice > 0:
        try:
            os.setpriority(os.PRIO_PROCESS, 0, min(os.getpriority(os.PRIO_PROCESS, 0) + nice, 19))
        except OSError:
            pass
    obj = factory(*args)
    while True:
        try:
            req = conn.recv()
        except (EOFError, OSError):
            return
        if req is None:
            return
        method, margs = req
        try:
            out = (True, getattr(obj, method)(*margs))
        except Exception as e:  # noqa: BLE001  (one bad request must not end the worker)
            out = (False, f"{type(e).__name__}: {e}")
        try:
            conn.send(out)
        except (BrokenPipeError, OSError):
            return


class ProcessBackend:
    """``factory(*args)`` in a worker process (see the module docstring); ``name`` names the
    process and its errors."""

    kind = "process"

    def __init__(self, factory, args: tuple = (), nice: int = 0, name: str = "worker") -> None:
        self.name = name
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_serve, args=(child, factory, args, nice), name=name, daemon=True)
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
        self._waiting = 0  # requests sent, answers not yet collected

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
            self._dead = f"{self.name} process (pid {self.process.pid}) died ({how})"
        return WorkerDied(self._dead)

    def _send(self, method: str, args: tuple) -> None:
        if self._dead is not None:
            raise WorkerDied(self._dead)
        try:
            self._conn.send((method, args))
        except (EOFError, OSError):  # the pipe broke under the worker
            raise self._died() from None
        self._waiting += 1

    def _receive(self):
        try:
            while True:  # wait for the answer or the worker's end, whichever comes first
                ready = wait([self._conn, self.process.sentinel], timeout=5.0)
                if self._conn in ready:
                    ok, out = self._conn.recv()
                    break
                if self.process.sentinel in ready:
                    raise self._died()
        except (EOFError, OSError):
            raise self._died() from None
        self._waiting -= 1
        if not ok:
            raise RuntimeError(f"{self.name}: {out}")
        return out

    def submit(self, method: str, *args) -> None:
        """Send ``method(*args)`` to the worker; its answer waits for :meth:`collect`."""
        with self._lock:
            self._send(method, args)

    def collect(self):
        """The oldest answer not yet collected (waits for it); raises :class:`WorkerDied` once
        the worker is gone, a ``RuntimeError`` with the worker's error for a failed call."""
        with self._lock:
            return self._receive()

    def ready(self) -> bool:
        """:meth:`collect` would not wait: an answer is here (or the worker is gone)."""
        try:
            return self._dead is not None or self._conn.poll(0) or not self.process.is_alive()
        except (EOFError, OSError):
            return True

    def call(self, method: str, *args):
        """``method(*args)`` in the worker, waiting for its answer (nothing may be waiting to be
        collected)."""
        with self._lock:
            assert self._dead is not None or self._waiting == 0, "call() with answers not collected"
            self._send(method, args)  # once the worker is gone: WorkerDied
            return self._receive()

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
                self._dead = f"{self.name} process stopped"
        finally:
            if got:
                self._conn.close()
                self._lock.release()


def make_backend(kind: str, factory, args: tuple = (), nice: int = 0, name: str = "worker"):
    """``'process'`` (:class:`ProcessBackend`) or ``'thread'`` (:class:`ThreadBackend`)."""
    if kind == "process":
        return ProcessBackend(factory, args, nice, name)
    if kind == "thread":
        return ThreadBackend(factory, args)
    raise ValueError(f"{name} must be 'process' or 'thread', got {kind!r}")


class ProcessOrInline:
    """``factory(*args)`` in a worker process while it lives; once it is gone, ``on_death(text)``
    is told once and the work goes on in the caller's process with a new object: the answers
    the dead worker still owed are None (lost, not wrong). For side work a node can lose a
    little of (its state starts again) but must not stop for."""

    kind = "process"

    def __init__(self, factory, args: tuple, on_death, nice: int = 0, name: str = "worker") -> None:
        self._make = lambda: Inline(factory(*args))
        self._on_death = on_death
        self.backend: ProcessBackend | Inline = ProcessBackend(factory, args, nice, name)
        self._lost = 0  # answers the dead worker owed

    def _fall_back(self, e: WorkerDied) -> None:
        self._lost += self.backend._waiting
        self.backend.close(1.0)
        self.backend = self._make()
        self.kind = "inline"
        self._on_death(str(e))

    def submit(self, method: str, *args) -> None:
        try:
            self.backend.submit(method, *args)
        except WorkerDied as e:
            self._fall_back(e)
            self.backend.submit(method, *args)

    def collect(self):
        if self._lost:
            self._lost -= 1
            return None
        try:
            return self.backend.collect()
        except WorkerDied as e:
            self._fall_back(e)
            return self.collect()

    def ready(self) -> bool:
        return self._lost > 0 or self.backend.ready()

    def close(self, timeout_s: float = 5.0) -> None:
        self.backend.close(timeout_s)
