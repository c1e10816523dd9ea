"""The texture engine's worker process (nodes/texture_worker.py) without ROS: answers in order,
reports a failed call, and a stuck worker neither hangs close() nor the call waiting on it."""

import os
import signal
import threading
import time

import pytest

from pf_slam_nodes.core.texture import TextureConfig
from pf_slam_nodes.nodes.texture_worker import ProcessBackend, WorkerDied, make_backend


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


def test_close_ends_a_stuck_worker_and_the_call_waiting_on_it():
    b = ProcessBackend(TextureConfig())
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
