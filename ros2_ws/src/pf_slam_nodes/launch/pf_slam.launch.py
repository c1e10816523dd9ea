"""Launch the pf_slam graph on a real ROS 2 Jazzy install (colcon workspace).

    ros2 launch pf_slam_nodes pf_slam.launch.py [bag:=/path/to/bag] [params_file:=<file>] [profile:=auto]

Without bag:= the graph runs on live topics (a robot, or `ros2 bag play --clock` in another
terminal): predictor, correlator and mapper, no bag_replay; use_sim_time:=auto (the default) lets
each node switch to /clock when one is published; odometry_source:=tf takes odometry from the
robot's odom -> base_link transform. The map: the mapper's pf_slam/save_map service
(pf_slam_interfaces/srv/SaveMap), pf_slam/pause_mapping (std_srvs/SetBool), pf_slam/reset
(std_srvs/Trigger). What is started with which parameters: pf_slam_nodes.launch_plan.

Parameters, as `pf-slam run`: profile:=auto (the default) reads the bag's metadata and sensors and
picks the profile of config/ that fits (pf_slam_nodes.profiles: converter metadata pf_slam.format,
else a tilted lidar -> kaist, a planar one -> indoor = carmen_indoor.yaml); if the bag cannot be
read there (or without a bag), the indoor profile. The chosen profile is printed. A params_file:= is the whole tuning
(no profile under it, as `pf-slam run --params`) unless profile:=NAME is given, which layers that
profile under it; profile:=none uses the nodes' built-in defaults.

Bring your own bag: scan_topic:=/front/scan odom_topic:=/wheel/odom (the nodes' relative topics are
remapped; bag_replay publishes the bag's own names). texture:=true adds the stereo texture node.
map:=/path/map.yaml localizes on that saved map instead of building one (mode localization).
The pip-only install has no `launch` package; use `pf-slam run` there (same nodes, same files).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, LogInfo, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

NODES = ("bag_replay", "predictor", "correlator", "mapper", "texture")  # console scripts (setup.py)
DEFAULT_PARAMS = "carmen_indoor.yaml"  # in the package's share/config: the indoor profile (fallback of auto)


def _parameter_files(context):
    """[profile file?, params_file?] for the nodes (later wins), and the line saying which profile."""
    share = get_package_share_directory("pf_slam_nodes")
    bag = LaunchConfiguration("bag").perform(context)
    params_file = LaunchConfiguration("params_file").perform(context)
    profile = LaunchConfiguration("profile").perform(context) or "auto"
    from pf_slam_nodes import profiles

    if params_file and profile == "auto":
        files, line = [], f"[pf-slam] profile: none (params_file {params_file} is the whole tuning)"
    elif not bag and profile == "auto":
        prof = profiles.Profile("indoor", "no bag (live topics): indoor by default", profiles.profile_file("indoor"))
        path = os.path.join(share, "config", prof.file.name)
        files, line = [path], prof.line()
    else:
        try:
            prof = profiles.profile_for_bag(bag, forced=profile)
        except Exception as e:  # an unreadable bag: the indoor profile (documented above)
            if profile not in ("auto", ""):
                raise
            prof = profiles.Profile(
                "indoor", f"the bag could not be read ({e}): indoor by default", profiles.profile_file("indoor")
            )
        path = os.path.join(share, "config", prof.file.name) if prof.file else None
        files = [path] if path else []
        line = prof.line()
    return files + ([params_file] if params_file else []), line


def _nodes(context):
    from pf_slam_nodes.launch_plan import graph_nodes

    arg = LaunchConfiguration
    files, line = _parameter_files(context)
    remaps = [
        ("scan", arg("scan_topic")),
        ("odom", arg("odom_topic")),
        ("encoders", arg("encoders_topic")),
        ("fog", arg("fog_topic")),
        ("imu", arg("imu_topic")),
    ]
    plan = graph_nodes(
        **{
            k: arg(k).perform(context)
            for k in (
                "bag",
                "use_sim_time",
                "texture",
                "odometry_source",
                "publish_sensor_tf",
                "scan_topic",
                "map",
                "sensor_qos",
            )
        }
    )
    return [LogInfo(msg=line)] + [
        Node(
            package="pf_slam_nodes",
            executable=name,
            name=name,
            output="screen",
            parameters=files + [extra],
            remappings=remaps,
        )
        for name, extra in plan.items()
    ]


def generate_launch_description():
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "bag", default_value="", description="rosbag2 to replay (mcap or sqlite3); empty: live topics"
            ),
            DeclareLaunchArgument(
                "profile",
                default_value="auto",
                description="auto (from the bag; indoor if it cannot be read), indoor, kaist, "
                "mines, sim_indoor or none",
            ),
            DeclareLaunchArgument(
                "params_file",
                default_value="",
                description="ROS 2 parameter YAML; the whole tuning unless profile:=NAME",
            ),
            DeclareLaunchArgument(
                "use_sim_time", default_value="auto", description="auto (follow /clock once published), true or false"
            ),
            DeclareLaunchArgument(
                "odometry_source",
                default_value="",
                description="odom, encoders or tf (odom -> base_link on /tf); empty: the parameters'",
            ),
            DeclareLaunchArgument(
                "publish_sensor_tf",
                default_value="auto",
                description="mapper: base_link -> lidar on /tf_static from the parameters; auto: "
                "only with a bag (a robot's TF tree has it)",
            ),
            DeclareLaunchArgument("texture", default_value="false", description="run the stereo texture node"),
            DeclareLaunchArgument(
                "sensor_qos",
                default_value="",
                description="reliable or best_effort (drivers publishing with the sensor-data QoS); "
                "empty: the parameters'",
            ),
            DeclareLaunchArgument(
                "map",
                default_value="",
                description="localization only: track the pose on this saved map (map_server .yaml)",
            ),
            DeclareLaunchArgument("scan_topic", default_value="/scan", description="sensor_msgs/LaserScan"),
            DeclareLaunchArgument("odom_topic", default_value="/odom", description="nav_msgs/Odometry"),
            DeclareLaunchArgument("encoders_topic", default_value="/encoders", description="sensor_msgs/JointState"),
            DeclareLaunchArgument("fog_topic", default_value="/fog", description="FogBatch or Vector3Stamped"),
            DeclareLaunchArgument("imu_topic", default_value="/imu", description="sensor_msgs/Imu (fog_format: imu)"),
            OpaqueFunction(function=_nodes),
        ]
    )
