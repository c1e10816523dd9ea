"""result.mcap keeps the texture image at most once per map interval of bag time and always the
last one: the texture node publishes once a second of wall time, so at real time a 5 min car
drive would otherwise carry 300 images of several megabytes."""

from __future__ import annotations

import pytest

pytest.importorskip("rclpy")

from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from pf_slam_nodes.runner.recorder import ResultRecorder  # noqa: E402


class _Writer:
    """Stands in for the MCAP writer: what would be written, in order."""

    def __init__(self) -> None:
        self.rows: list[tuple[str, int, bytes]] = []

    def write_raw(self, topic: str, stamp: int, raw: bytes) -> None:
        self.rows.append((topic, stamp, raw))


def _image(stamp_s: float, value: int) -> bytes:
    m = Image()
    m.header.stamp.sec, m.header.stamp.nanosec = int(stamp_s), int(round((stamp_s % 1) * 1e9))
    m.height, m.width, m.encoding, m.step = 1, 1, "rgb8", 3
    m.data = bytes([value, value, value])
    return serialize_message(m)


def test_texture_images_are_thinned_by_bag_time_and_the_last_one_kept():
    rec = object.__new__(ResultRecorder)  # the writing logic only: no node, no file
    rec.bag = _Writer()
    rec.map_every_ns, rec.last_texture_ns, rec._held_texture = int(15e9), None, None
    rec.texture_topic = "/texture"
    for k in range(300):  # one a second of bag time (real time), the last one the final texture
        rec._on_texture(_image(1000.0 + k, k % 250))
    rec._on_texture(_image(1299.0, 251))  # placed again at the end: same stamp, other content
    assert len(rec.bag.rows) == 20  # at 0, 15, ..., 285 s
    rec.flush_texture()  # what close() does first
    assert len(rec.bag.rows) == 21 and rec.bag.rows[-1][2] == _image(1299.0, 251)
    assert [s for _, s, _ in rec.bag.rows[:3]] == [int(1000e9), int(1015e9), int(1030e9)]
