"""Scans travel serialized between the nodes: the stamp is read from the CDR bytes, and only
the scans that are corrected are deserialized."""

import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Image, LaserScan

from pf_slam_nodes.nodes.common import ScanQueue
from pf_slam_nodes.ros import convert


def _scan(stamp_ns: int, n: int = 5) -> LaserScan:
    m = LaserScan()
    m.header.stamp = convert.ns_to_stamp(stamp_ns)
    m.header.frame_id = "laser"
    m.ranges = [float(i) for i in range(n)]
    return m


@pytest.mark.parametrize("stamp", [0, 1, 1_318_000_000_123_456_789, 2**31 * 1_000_000_000 - 1])
def test_stamp_from_cdr_equals_deserialized_stamp(stamp):
    assert convert.stamp_ns_from_cdr(serialize_message(_scan(stamp))) == stamp
    img = Image()
    img.header.stamp = convert.ns_to_stamp(stamp)
    assert convert.stamp_ns_from_cdr(serialize_message(img)) == stamp


def test_stamp_from_cdr_rejects_garbage():
    with pytest.raises(ValueError, match="CDR"):
        convert.stamp_ns_from_cdr(b"\x07\x07\x00\x00" + bytes(8))
    with pytest.raises(ValueError):
        convert.stamp_ns_from_cdr(b"\x00\x01")


def test_scan_queue_takes_by_index_and_forgets_older_scans():
    q = ScanQueue()
    for k in range(10):
        q.append(serialize_message(_scan(1000 + k, n=k + 1)))
    assert q.has(9, 1009) and not q.has(10, 1010)
    s = q.take(3, 1003)
    assert convert.stamp_to_ns(s.header.stamp) == 1003 and len(s.ranges) == 4
    assert convert.stamp_to_ns(q.take(7, 1007).header.stamp) == 1007
    with pytest.raises(IndexError):
        q.take(10, 1010)  # not here yet
    q.append(serialize_message(_scan(2000)))
    assert convert.stamp_to_ns(q.take(10, 2000).header.stamp) == 2000
    assert q.lost == 0


def test_scan_queue_after_losses_finds_the_scan_by_stamp_or_reports_it_lost():
    """A replay faster than the graph: this node lost scans 2 and 3, the predictor (whose
    numbering the sets carry) lost scan 6. A set must get its own scan, or none."""
    q = ScanQueue()
    for k in (0, 1, 4, 5, 6, 7, 8, 9):
        q.append(serialize_message(_scan(1000 + k)))
    # the predictor's numbering skips 6: its 6 is stamp 1007, its 7 is 1008
    assert convert.stamp_to_ns(q.take(1, 1001).header.stamp) == 1001
    assert q.has(2, 1002) and q.take(2, 1002) is None  # lost here: a later scan has arrived
    assert convert.stamp_to_ns(q.take(4, 1004).header.stamp) == 1004  # found where it is
    assert convert.stamp_to_ns(q.take(6, 1007).header.stamp) == 1007  # numbering re-based
    assert convert.stamp_to_ns(q.take(7, 1008).header.stamp) == 1008
    assert not q.has(9, 1010)  # not here yet: no later scan has arrived
    q.append(serialize_message(_scan(1011)))
    assert q.take(9, 1010) is None and q.lost == 2
