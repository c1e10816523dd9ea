"""Worker processes (nodes/worker.py) without ROS: the texture engine's answers in order, a failed
call reported, a stuck worker neither hangs close() nor the call waiting on it; requests
submitted ahead and collected later in order; a worker that dies replaced by the caller's process."""

import os
import signal
import threading
import time

import pytest

from pf_slam_nodes.core.texture import TextureConfig
from pf_slam_nodes.nodes.texture_worker import TextureEngine, make_backend
from pf_slam_nodes.nodes.worker import ProcessBackend, ProcessOrInline, WorkerDied


def test_calls_answer_in_order_and_errors_come_back():
    b = make_backend("process", TextureConfig())
    try:
        assert b.call("ready") is True
        b.call("set_anchor", (1.5, -2.0))
        assert b.call("stats") == {"cells": 0, "memory_bytes": 0, "kept_bytes": 0}
        assert b.call("render_native") is None
        with pytest.raises(RuntimeError, match="AttributeError"):
            b.call("no_such_method")
        assert b.call("ready") is True  # a failed call does not end the worker
    finally:
        b.close()
    assert b.process.exitcode == 0
    with pytest.raises(WorkerDied):
        b.call("ready")


def test_calls_after_a_worker_died_mid_call_say_so():
    """A call whose worker is killed while it waits ends in WorkerDied, and so does every later
    call (not a complaint about the answer the dead worker still owed)."""
    b = ProcessBackend(_Counter, (0,), name="counter")
    try:
        assert b.call("add", 1) == 1
        os.kill(b.process.pid, signal.SIGSTOP)  # it takes the request but never answers
        t = threading.Timer(0.3, lambda: os.kill(b.process.pid, signal.SIGKILL))
        t.start()
        with pytest.raises(WorkerDied, match="counter process"):
            b.call("add", 1)
        t.join()
        for _ in range(2):
            with pytest.raises(WorkerDied, match="killed by signal 9"):
                b.call("add", 1)
    finally:
        b.close()


def test_close_ends_a_stuck_worker_and_the_call_waiting_on_it():
    b = ProcessBackend(TextureEngine, (TextureConfig(),), name="texture worker")
    assert b.call("ready") is True
    os.kill(b.process.pid, signal.SIGSTOP)  # alive but never answers
    errors: list[BaseException] = []

    def waiting_call():
        try:
            b.call("ready")
        except BaseException as e:  # noqa: BLE001
            errors.append(e)

    t = threading.Thread(target=waiting_call)
    t.start()
    time.sleep(0.2)
    t0 = time.monotonic()
    b.close(timeout_s=1.0)
    t.join(10.0)
    assert not t.is_alive() and time.monotonic() - t0 < 8.0
    assert len(errors) == 1 and isinstance(errors[0], WorkerDied) and "texture worker process" in str(errors[0])
    assert not b.process.is_alive()


def test_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="'process' or 'thread'"):
        make_backend("fork", TextureConfig())


class _Counter:
    """A worker's own state: the running sum of what it was sent."""

    def __init__(self, start: int) -> None:
        self.total = start

    def add(self, x: int) -> int:
        self.total += x
        return self.total


def test_submitted_requests_are_collected_in_order():
    b = ProcessBackend(_Counter, (10,), name="counter")
    try:
        for x in (1, 2, 3):
            b.submit("add", x)
        assert [b.collect() for _ in range(3)] == [11, 13, 16]
        b.submit("no_such_method")
        b.submit("add", 4)
        with pytest.raises(RuntimeError, match="counter: AttributeError"):
            b.collect()
        assert b.collect() == 20  # the failed request does not end the worker nor shift answers
        b.submit("add", 1)
        with pytest.raises(AssertionError):
            b.call("add", 1)  # an answer is still waiting
    finally:
        b.close()


def test_a_dead_worker_is_reported_once_and_the_work_goes_on_here():
    deaths: list[str] = []
    b = ProcessOrInline(_Counter, (0,), deaths.append, name="counter")
    try:
        b.submit("add", 5)
        assert b.collect() == 5
        b.submit("add", 1)  # owed by the worker when it dies
        assert b.backend._conn.poll(5.0)  # answered, not yet collected
        os.kill(b.backend.process.pid, signal.SIGKILL)
        b.backend.process.join(5.0)
        b.submit("add", 2)  # the dead worker's pipe: this goes to a new counter here
        assert b.collect() is None  # the answer the worker owed is lost, not wrong
        assert b.collect() == 2  # the new object starts again from its factory
        assert b.kind == "inline" and len(deaths) == 1 and "counter process" in deaths[0]
        assert "killed by signal 9" in deaths[0]
    finally:
        b.close()
