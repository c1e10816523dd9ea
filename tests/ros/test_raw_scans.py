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
    assert q.has(9) and not q.has(10)
    s = q.take(3)
    assert convert.stamp_to_ns(s.header.stamp) == 1003 and len(s.ranges) == 4
    assert convert.stamp_to_ns(q.take(7).header.stamp) == 1007
    with pytest.raises(IndexError):
        q.take(5)  # forgotten
    q.append(serialize_message(_scan(2000)))
    assert convert.stamp_to_ns(q.take(10).header.stamp) == 2000
