"""Launch the pf_slam graph on a real ROS 2 Jazzy install (colcon workspace).

    ros2 launch pf_slam_nodes pf_slam.launch.py bag:=/path/to/bag params_file:=<file> use_sim_time:=true

Bring your own bag: scan_topic:=/front/scan odom_topic:=/wheel/odom (the nodes' relative topics are
remapped; bag_replay publishes the bag's own names). texture:=true adds the stereo texture node.
The pip-only install has no `launch` package; use `pf-slam run` there (same nodes, same files).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

NODES = ("bag_replay", "predictor", "correlator", "mapper", "texture")  # console scripts (setup.py)
DEFAULT_PARAMS = "carmen_indoor.yaml"  # in the package's share/config


def generate_launch_description():
    share = get_package_share_directory("pf_slam_nodes")
    arg = LaunchConfiguration
    common = [arg("params_file"), {"use_sim_time": arg("use_sim_time")}]
    remaps = [("scan", arg("scan_topic")), ("odom", arg("odom_topic")), ("encoders", arg("encoders_topic")),
              ("fog", arg("fog_topic")), ("imu", arg("imu_topic"))]
    extra = {"bag_replay": [{"bag": arg("bag"), "scan_topic": arg("scan_topic")}]}
    nodes = [Node(package="pf_slam_nodes", executable=name, name=name, output="screen",
                  parameters=common + extra.get(name, []), remappings=remaps,
                  condition=IfCondition(arg("texture")) if name == "texture" else None)
             for name in NODES]
    return LaunchDescription([
        DeclareLaunchArgument("bag", description="rosbag2 to replay (mcap or sqlite3)"),
        DeclareLaunchArgument("params_file", default_value=os.path.join(share, "config", DEFAULT_PARAMS)),
        DeclareLaunchArgument("use_sim_time", default_value="true"),
        DeclareLaunchArgument("texture", default_value="false", description="run the stereo texture node"),
        DeclareLaunchArgument("scan_topic", default_value="/scan", description="sensor_msgs/LaserScan"),
        DeclareLaunchArgument("odom_topic", default_value="/odom", description="nav_msgs/Odometry"),
        DeclareLaunchArgument("encoders_topic", default_value="/encoders", description="sensor_msgs/JointState"),
        DeclareLaunchArgument("fog_topic", default_value="/fog", description="FogBatch or Vector3Stamped"),
        DeclareLaunchArgument("imu_topic", default_value="/imu", description="sensor_msgs/Imu (fog_format: imu)"),
        *nodes,
    ])
