"""Launch the pf_slam graph on a real ROS 2 Jazzy install (colcon workspace).

    ros2 launch pf_slam_nodes pf_slam.launch.py bag:=/path/to/bag params_file:=<file> use_sim_time:=true

The pip-only install has no `launch` package; use `pf-slam run` there (same nodes).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    share = get_package_share_directory("pf_slam_nodes")
    bag = LaunchConfiguration("bag")
    params = LaunchConfiguration("params_file")
    sim_time = LaunchConfiguration("use_sim_time")
    common = [params, {"use_sim_time": sim_time}]
    nodes = [Node(package="pf_slam_nodes", executable=name, name=name, output="screen",
                  parameters=common + ([{"bag": bag}] if name == "bag_replay" else []))
             for name in ("bag_replay", "predictor", "correlator", "mapper")]
    return LaunchDescription([
        DeclareLaunchArgument("bag", description="rosbag2 to replay (mcap or sqlite3)"),
        DeclareLaunchArgument("params_file",
                              default_value=os.path.join(share, "config", "carmen_indoor.yaml")),
        DeclareLaunchArgument("use_sim_time", default_value="true"),
        *nodes,
    ])
