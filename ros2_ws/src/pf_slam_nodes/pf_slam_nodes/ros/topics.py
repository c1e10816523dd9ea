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
REPLAY_STATUS = "pf_slam/replay_status"  # bag_replay -> all: end of bag
REPLAY_STALL = "pf_slam/replay_stall"  # bag_replay -> predictor: stopped at max_in_flight, counts so far
READY = "pf_slam/ready"  # each stage, once its outputs are matched: the replay may start
# texture -> bag_replay: [pairs finished (processed, skipped or dropped), pairs waiting for their
# pose]; in --rate max the replay holds the next stereo pair back while one is being worked on
TEXTURE_PROGRESS = "pf_slam/texture_progress"
STATUS = "pf_slam/status"  # nodes -> recorder: JSON (fault counters), latched
