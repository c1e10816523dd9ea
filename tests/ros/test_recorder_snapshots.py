"""`pf-slam run`'s snapshots: one that comes due before the first /map (the mapper publishes it on a
wall-clock period, and a short bag in --rate max can be 30 s of bag time in before it) is written
with the first pose after the map comes, not lost."""

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import OccupancyGrid
from rclpy.serialization import serialize_message

from pf_slam_nodes.runner.recorder import _Recorder


def _pose(t_s: int, x: float) -> bytes:
    m = PoseStamped()
    m.header.frame_id = "map"
    m.header.stamp.sec = t_s
    m.pose.position.x = x
    m.pose.orientation.w = 1.0
    return serialize_message(m)


def _map() -> OccupancyGrid:
    g = OccupancyGrid()
    g.header.frame_id = "map"
    g.info.resolution = 0.1
    g.info.width = g.info.height = 20
    g.info.origin.orientation.w = 1.0
    g.data = [0] * 400
    return g


def test_a_snapshot_due_before_the_first_map_is_written_when_the_map_comes(ros_context, tmp_path):
    import rclpy

    node = rclpy.create_node("recorder_snapshots", context=ros_context)
    try:
        (tmp_path / "snapshots").mkdir()
        rec = _Recorder(node, tmp_path, 100, 60.0, "30s", False)
        for k in range(40):  # bag time 0-39 s: one snapshot due at 30 s, no map yet
            rec._on_pose(_pose(100 + k, 0.1 * k))
        assert not list((tmp_path / "snapshots").glob("scan_*.png"))
        rec._on_map(_map())
        rec._on_pose(_pose(140, 4.0))  # the first pose with a map: the waiting snapshot
        rec._on_pose(_pose(141, 4.1))  # nothing more is due until 60 s
        rec.snapshot("final.png", wait=True)  # waits for the writer
        assert sorted(p.name for p in (tmp_path / "snapshots").glob("*.png")) == ["final.png", "scan_000041.png"]
        assert rec.snapshots_written == 2 and rec.snapshots_skipped == 0
    finally:
        node.destroy_node()
