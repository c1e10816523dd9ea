"""Default topic names (relative, so a namespace or remapping applies)."""

SCAN = "scan"
ODOM = "odom"
ENCODERS = "encoders"
FOG = "fog"
IMU = "imu"
CLOCK = "/clock"
TF = "/tf"
TF_STATIC = "/tf_static"

PARTICLES_PREDICTED = "particles/predicted"
PARTICLES_UPDATED = "particles/updated"
POSE = "pose"
MAP = "map"
MAP_METADATA = "map_metadata"
PATH = "path"
# predictor -> correlator, mapper: the scans that are corrected, as received (the car's lidar
# runs at 100 Hz, corrections every ~2 m: they need 1 scan in 20)
SCAN_CORRECTED = "pf_slam/scan_corrected"
GRID = "pf_slam/grid"  # mapper -> correlator: the occupancy grid after every integration
# mapper -> recorder, users: every scan's pose in the final (loop-closed) frame, latched, at the end
TRAJECTORY = "pf_slam/trajectory"
# mapper -> texture, users: at every closed loop that re-renders the map, every scan's pose so far
# in the new frame (latched): the live texture is placed again on it
LOOP_TRAJECTORY = "pf_slam/loop_trajectory"
REPLAY_STATUS = "pf_slam/replay_status"  # bag_replay -> all: end of bag
REPLAY_STALL = "pf_slam/replay_stall"  # bag_replay -> predictor: stopped at max_in_flight, counts so far
READY = "pf_slam/ready"  # each stage, once its outputs are matched: the replay may start
LIDAR_MOUNT = "pf_slam/lidar_mount"  # predictor -> correlator, mapper: the mount from TF (mount_from_tf), latched
# texture -> bag_replay: [pairs finished (processed, skipped or dropped), pairs waiting for their
# pose]; in --rate max the replay holds the next stereo pair back while one is being worked on
TEXTURE_PROGRESS = "pf_slam/texture_progress"
STATUS = "pf_slam/status"  # nodes -> recorder: JSON (fault counters), latched
INITIAL_POSE = "initialpose"  # localization: rviz2's "2D Pose Estimate" (PoseWithCovarianceStamped)
PARTICLE_CLOUD = "particlecloud"  # correlator -> users: the particles after each correction (PoseArray)

# the mapper's services (live use)
SAVE_MAP = "pf_slam/save_map"  # pf_slam_interfaces/SaveMap: map.pgm + map.yaml + trajectory.tum into a folder
PAUSE_MAPPING = "pf_slam/pause_mapping"  # std_srvs/SetBool: true freezes the map, false resumes
RESET = "pf_slam/reset"  # std_srvs/Trigger: a new map from the next corrected scan
