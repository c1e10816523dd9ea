"""The QoS profiles of the graph, built in one place."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


def pipeline(depth: int = 1000) -> QoSProfile:
    """Reliable, deep queue: sensor data and particle sets inside the graph must not be lost."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


#: what the predictor's sensor subscriptions may ask for (parameter sensor_qos)
SENSOR_QOS = ("reliable", "best_effort")


def sensor(depth: int, reliability: str = "reliable") -> QoSProfile:
    """The predictor's sensor inputs (scan, odometry, encoders, gyro). ``reliable`` (the replay's,
    lossless in --rate max); ``best_effort`` for drivers that publish with the sensor-data QoS
    (a reliable subscription never matches a best-effort publisher; a best-effort one matches both)."""
    if reliability not in SENSOR_QOS:
        raise ValueError(f"parameter 'sensor_qos' must be one of {', '.join(SENSOR_QOS)}, got {reliability!r}")
    if reliability == "reliable":
        return pipeline(depth)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


def latched(depth: int = 1) -> QoSProfile:
    """RELIABLE + TRANSIENT_LOCAL, depth 1: /map, /map_metadata, /tf_static, the internal grid.

    A late subscriber (map_saver, rviz2, Foxglove) still receives the last message.
    """
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )


def outputs(depth: int = 100) -> QoSProfile:
    """User-facing streams (/pose, /path, /tf): reliable, volatile."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )
