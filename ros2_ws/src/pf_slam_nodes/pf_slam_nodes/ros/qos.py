"""The QoS profiles of the graph, built in one place."""
from __future__ import annotations

from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile,
                       ReliabilityPolicy)


def pipeline(depth: int = 1000) -> QoSProfile:
    """Reliable, deep queue: sensor data and particle sets inside the graph must not be lost."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def latched(depth: int = 1) -> QoSProfile:
    """RELIABLE + TRANSIENT_LOCAL, depth 1: /map, /map_metadata, /tf_static, the internal grid.

    A late subscriber (map_saver, rviz2, Foxglove) still receives the last message.
    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def outputs(depth: int = 100) -> QoSProfile:
    """User-facing streams (/pose, /path, /tf): reliable, volatile."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
