"""Shared fixtures. ROS fixtures import rclpy lazily so tests/unit never needs it."""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("PF_SLAM_DATA", ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def data_dir() -> Path:
    if not DATA.is_dir():
        pytest.skip(f"shared datasets not found at {DATA} (set PF_SLAM_DATA)")
    return DATA


@contextlib.contextmanager
def claim_domain() -> Iterator[int]:
    """A ROS_DOMAIN_ID no other test or `pf-slam run` (in this or a parallel process) holds and
    no ROS 2 node of this host uses right now: the product's own claim (pf_slam_nodes.ros.domain,
    domains 1..100, an exclusive file lock held while the context is open). ROS_DOMAIN_ID and
    ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST are set for child processes.
    """
    from pf_slam_nodes.ros.domain import _environ
    from pf_slam_nodes.ros.domain import claim_domain as claim

    with claim() as (domain, _lock), _environ(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"):
        yield domain


@pytest.fixture
def ros_domain() -> Iterator[int]:
    with claim_domain() as d:
        yield d


@pytest.fixture(scope="module")
def module_ros_domain() -> Iterator[int]:
    with claim_domain() as d:
        yield d


@pytest.fixture
def ros_context(ros_domain: int):
    """An isolated rclpy Context on the test's own domain, shut down afterwards."""
    import rclpy

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    try:
        yield ctx
    finally:
        if ctx.ok():
            rclpy.shutdown(context=ctx)


def spin_until(executor, predicate: Callable[[], bool], timeout_s: float, step_s: float = 0.01) -> bool:
    """Spin `executor` until `predicate()` is true or `timeout_s` passes; returns the predicate."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return predicate()
        executor.spin_once(timeout_sec=step_s)
    return True


def box_ranges(pose, angles, x_walls: tuple[float, float], y_walls: tuple[float, float]):
    """Ranges from ``pose`` ``[x, y, theta]`` along the beam ``angles`` (robot frame) to the
    walls of an axis-aligned box ``x_walls[0] <= x <= x_walls[1]``, ``y_walls[0] <= y <= y_walls[1]``."""
    import numpy as np

    th = pose[2] + angles
    c, s = np.cos(th), np.sin(th)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (x_walls[1] - pose[0]) / c, (x_walls[0] - pose[0]) / c)
        ty = np.where(s > 0, (y_walls[1] - pose[1]) / s, (y_walls[0] - pose[1]) / s)
    return np.minimum(np.abs(tx), np.abs(ty))


def config_section(cls, params: dict, prefix: str):
    """The config `cls` from a node's flat parameters (`prefix.field`), as declare_config builds it
    (for the ROS-free loop next to the graph in the tests)."""
    import dataclasses

    from pf_slam_nodes.nodes.declared import as_default_type

    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    vals = {}
    for k, v in params.items():
        if k.startswith(prefix + "."):
            name = k[len(prefix) + 1 :]
            d = defaults[name]
            vals[name] = tuple(float(x) for x in v) if isinstance(d, tuple) else as_default_type(d, v)
    return cls.from_dict(vals)
