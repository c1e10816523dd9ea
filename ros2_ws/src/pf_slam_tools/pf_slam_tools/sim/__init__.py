"""Seeded simulators that write the project's own sample bags (numpy + rosbags, no rclpy).

``pf_slam_tools.sim.indoor``: the office-floor drive behind ``bags/sample_indoor``.
Names are loaded lazily so ``python -m pf_slam_tools.sim.indoor`` imports the module once.
"""

from __future__ import annotations

from typing import Any

__all__ = ["SimResult", "simulate_indoor"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from pf_slam_tools.sim import indoor

        return getattr(indoor, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
