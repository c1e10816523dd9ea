"""Choosing the bag's topics for the graph's inputs (no rclpy, no bag files: bag_info's shape)."""

import pytest

from pf_slam_nodes.graph import RunError, params_topics, select_inputs, topic_remaps

SCAN, ODOM, JS, IMG = (
    "sensor_msgs/msg/LaserScan",
    "nav_msgs/msg/Odometry",
    "sensor_msgs/msg/JointState",
    "sensor_msgs/msg/Image",
)


def info(**topics):
    return {"path": "bag", "topics": {"/" + k.replace("__", "/"): (v, 10) for k, v in topics.items()}}


def test_defaults_then_the_only_topic_of_a_type():
    assert select_inputs("b", info(scan=SCAN, odom=ODOM)) == {"scan": "/scan", "odom": "/odom"}
    got = select_inputs("b", info(front__scan=SCAN, wheel__odom=ODOM, joint_states=JS))
    assert got == {"scan": "/front/scan", "odom": "/wheel/odom"}  # odometry wins over a JointState
    got = select_inputs("b", info(lidar=SCAN, joint_states=JS, fog="geometry_msgs/msg/Vector3Stamped"))
    assert got == {"scan": "/lidar", "encoders": "/joint_states", "fog": "/fog"}
    assert select_inputs("b", info(scan=SCAN, odom=ODOM, fog="pf_slam_interfaces/msg/FogBatch")) == {
        "scan": "/scan",
        "odom": "/odom",
    }  # a gyro only with encoders
    both = info(scan=SCAN, odom=ODOM, enc=JS, stereo__left__image_raw=IMG, stereo__right__image_raw=IMG)
    assert select_inputs("b", both, {"encoders": "/enc"}) == {
        "scan": "/scan",
        "encoders": "/enc",
        "stereo_left": "/stereo/left/image_raw",
        "stereo_right": "/stereo/right/image_raw",
    }


def test_requested_topics_and_errors_name_what_was_found():
    i = info(a=SCAN, b=SCAN, odo=ODOM)
    with pytest.raises(RunError, match=r"several LaserScan topics \(/a, /b\).*--scan-topic"):
        select_inputs("bag", i)
    assert select_inputs("bag", i, {"scan": "/b"}) == {"scan": "/b", "odom": "/odo"}
    with pytest.raises(RunError, match=r"scan topic /c is not in the bag; found: /a \[sensor_msgs"):
        select_inputs("bag", i, {"scan": "/c"})
    with pytest.raises(RunError, match="/odo is nav_msgs/msg/Odometry; scan needs sensor_msgs/msg/LaserScan"):
        select_inputs("bag", i, {"scan": "/odo"})
    # nothing usable: the standard names' diagnosis (check_run_inputs) and the flags to name others
    with pytest.raises(RunError, match=r"cannot run: no /odom or /encoders topic.*--odom-topic"):
        select_inputs("bag", info(scan=SCAN))
    with pytest.raises(RunError, match=r"cannot run: no /scan topic.*--scan-topic"):
        select_inputs("bag", info(odom=ODOM))
    with pytest.raises(RunError, match=r"cannot run: /scan is std_msgs/msg/String, expected sensor_msgs/msg/LaserScan"):
        select_inputs("bag", info(scan="std_msgs/msg/String", odom=ODOM))


def test_remaps_and_topics_from_a_parameter_file():
    assert topic_remaps({"scan": "/front/scan", "odom": "/odom", "stereo_left": "/x"}) == {"scan": "/front/scan"}
    layer = {"/**": {"topics.scan": "/front/scan", "filter.seed": 1}}
    assert params_topics(layer) == {"scan": "/front/scan"} and layer == {"/**": {"filter.seed": 1}}


def test_an_imu_is_the_gyro_of_wheel_encoders_only():
    IMU = "sensor_msgs/msg/Imu"
    assert select_inputs("b", info(scan=SCAN, encoders=JS, imu__data=IMU)) == {
        "scan": "/scan",
        "encoders": "/encoders",
        "imu": "/imu/data",
    }
    assert select_inputs("b", info(scan=SCAN, odom=ODOM, imu__data=IMU)) == {"scan": "/scan", "odom": "/odom"}
    assert select_inputs("b", info(scan=SCAN, encoders=JS, imu=IMU, fog="pf_slam_interfaces/msg/FogBatch")) == {
        "scan": "/scan",
        "encoders": "/encoders",
        "fog": "/fog",
    }  # the FOG, when there is one
    assert topic_remaps({"scan": "/scan", "imu": "/imu/data"}) == {"imu": "/imu/data"}
