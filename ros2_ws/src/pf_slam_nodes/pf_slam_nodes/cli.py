"""The `pf-slam` command: convert logs to bags, run the graph on a bag, evaluate, benchmark."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .graph import DEFAULT_INPUTS, RunError
from .io.bag import BagError


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="pf-slam",
        description="Online particle-filter SLAM as a ROS 2 node graph (rclpy).",
        epilog="Example: pf-slam convert carmen intel.clf intel_bag && "
        "pf-slam run intel_bag --out runs/intel && "
        "pf-slam eval --est runs/intel/trajectory.tum --gt intel.relations",
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    conv = sub.add_parser("convert", help="convert a dataset log to a rosbag2 (MCAP)")
    csub = conv.add_subparsers(dest="format", required=True, metavar="FORMAT")
    c = csub.add_parser("carmen", help="CARMEN log (FLASER/ROBOTLASER1/ODOM) -> /scan + /odom")
    c.add_argument("log")
    c.add_argument("out_bag")
    c.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    k = csub.add_parser("kaist", help="KAIST-layout car dataset (encoders, FOG, lidar, stereo, param/)")
    k.add_argument("dataset_dir")
    k.add_argument("out_bag")
    k.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    k.add_argument("--fog-batch", type=int, default=10, help="FOG samples per FogBatch message")
    k.add_argument(
        "--fog-format",
        choices=["batch", "vector3"],
        default="batch",
        help="FogBatch messages (default) or one Vector3Stamped per sample",
    )
    k.add_argument("--no-images", action="store_true", help="leave the stereo images out")
    m = csub.add_parser("mines", help="Mines wheel-encoder + URG log -> /encoders + /scan")
    m.add_argument("dat")
    m.add_argument("out_bag")
    m.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    th = csub.add_parser(
        "thor",
        help="THOR humanoid .mat files (lidar, joint[, RGB, depth]) -> /scan /odom "
        "/joint_states /tf (moving head) /tf_static [/kinect/*] (docs/thor.md)",
    )
    th.add_argument("--lidar", required=True, metavar="LIDAR.mat")
    th.add_argument("--joint", required=True, metavar="JOINT.mat")
    th.add_argument("--rgb", metavar="RGB.mat", help="Kinect RGB frames (with --depth)")
    th.add_argument("--depth", metavar="DEPTH.mat", help="Kinect depth frames (with --rgb)")
    th.add_argument("out_bag")
    th.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    th.add_argument(
        "--rgb-scale",
        type=float,
        default=1.0,
        metavar="S",
        help="shrink the 1920x1080 RGB images (and their CameraInfo) by S in (0, 1] (default 1)",
    )

    r = sub.add_parser("run", help="replay a bag through the SLAM graph and write map/trajectory")
    r.add_argument("bag")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--params", help="ROS 2 parameter YAML (see config/), layered on top of the profile")
    r.add_argument(
        "--profile",
        default="auto",
        metavar="NAME",
        help="parameter profile: auto (default: from the bag's converter metadata, else its "
        "sensors, printed; none when --params is given), indoor (config/carmen_indoor.yaml), "
        "kaist, mines, sim_indoor (forced, also under --params), or none (the built-in defaults)",
    )
    r.add_argument("--rate", default="max", help="'max' (lossless, paced on the pipeline), 1 (real time) or N")
    r.add_argument(
        "--processes",
        choices=["single", "multi"],
        default="single",
        help="one process with one executor, or one process per node over DDS",
    )
    r.add_argument("--particles", type=int, help="number of particles (filter.num_particles)")
    r.add_argument("--seed", type=int, help="random seed (filter.seed)")
    r.add_argument(
        "--localize",
        metavar="MAP_YAML",
        help="localization only: track the pose on this saved map (map_server .yaml), never change it",
    )
    r.add_argument(
        "--initial-pose",
        metavar="X,Y,YAW",
        help="with --localize: start around this pose (map frame; m, m, rad) instead of a global initialisation",
    )
    r.add_argument(
        "--executor",
        choices=["single", "events"],
        default="events",
        help="executor of the single-process graph: SingleThreadedExecutor or rclpy's "
        "experimental C++ EventsExecutor (same result)",
    )
    r.add_argument(
        "--no-texture",
        action="store_true",
        help="do not run the texture node (stereo topics in the bag are then ignored)",
    )
    r.add_argument(
        "--snapshot-every",
        type=_snapshot_every,
        default="30s",
        metavar="N|Ns",
        help="snapshot PNG every N scans, or every N seconds of bag time (default 30s; 0: none)",
    )
    for role, what in (
        ("scan", "sensor_msgs/LaserScan"),
        ("odom", "nav_msgs/Odometry"),
        ("encoders", "sensor_msgs/JointState wheel angles (rad)"),
        ("fog", "gyro yaw increments with encoders: FogBatch or Vector3Stamped"),
        ("imu", "sensor_msgs/Imu, its yaw rate as the gyro with encoders"),
        ("stereo-left", "sensor_msgs/Image (texture)"),
        ("stereo-right", "sensor_msgs/Image (texture)"),
    ):
        default = DEFAULT_INPUTS[role.replace("-", "_")]
        r.add_argument(
            f"--{role}-topic",
            metavar="TOPIC",
            help=f"the bag's {what} topic (default: {default}"
            + (", or the bag's only one of that type)" if role in ("scan", "odom", "encoders", "imu") else ")"),
        )
    r.add_argument(
        "--domain",
        type=int,
        metavar="N",
        help="run on ROS domain N with the normal discovery, so rviz2 or Foxglove can watch "
        "(so does a set ROS_DOMAIN_ID); default: isolated on a free domain held by the run",
    )
    r.add_argument("--no-record", action="store_true", help="do not write OUT/result.mcap")
    r.add_argument(
        "--delay",
        type=float,
        metavar="S",
        default=0.0,
        help="start the replay S seconds after the graph is up (time for rviz2/Foxglove on --domain "
        "to discover the run; results unchanged)",
    )
    r.add_argument(
        "--record-map-every",
        type=float,
        metavar="S",
        help="result.mcap: a /map and a texture image every S seconds of bag time (default: bag duration / 20; "
        "the final ones always)",
    )

    _add_live_parsers(sub)

    e = sub.add_parser("eval", help="ATE/RPE against a reference trajectory; Kümmerle relations error")
    e.add_argument("--est", help="estimated trajectory (TUM)")
    e.add_argument("--gt", help="reference trajectory (TUM or 't x y theta'), or a .relations file")
    e.add_argument("--relations", help="Kümmerle et al. 2009 relations file")
    e.add_argument("--map", help="estimated map (map_server yaml, e.g. RUN/map.yaml)")
    e.add_argument("--gt-map", help="ground-truth map (map_server yaml): occupied-cell F1")
    e.add_argument("--map-tolerance", type=float, default=0.3, help="F1 match distance (m)")
    e.add_argument("--json", action="store_true", help="print JSON")

    si = sub.add_parser("simulate-indoor", help="write the seeded indoor sample bag with ground truth")
    sc = sub.add_parser(
        "simulate",
        help="write a seeded KAIST-layout car dataset with ground truth "
        "('pf-slam simulate thor ...': the THOR humanoid, see simulate-thor)",
    )
    st = sub.add_parser(
        "simulate-thor",
        help="write a seeded THOR humanoid walk (.mat files) with ground truth; also spelled 'pf-slam simulate thor'",
    )
    try:  # simulators and benches are the development package pf_slam_tools (installed by make setup)
        from pf_slam_tools.sim.car import add_arguments as add_car_arguments
        from pf_slam_tools.sim.indoor import add_arguments
        from pf_slam_tools.sim.thor import add_arguments as add_thor_arguments
    except ModuleNotFoundError:
        for p in (si, sc, st):
            p.add_argument("args", nargs=argparse.REMAINDER)
    else:
        add_arguments(si)
        add_car_arguments(sc)
        add_thor_arguments(st)

    t = sub.add_parser(
        "texture",
        add_help=False,
        help="texture map offline: a simulated drive vs its floor truth, or the real stereo pair "
        "(pf-slam texture {sim DATASET | real KAIST_DIR} --out OUT; --help for more)",
    )
    t.add_argument("args", nargs=argparse.REMAINDER)

    pr = sub.add_parser(
        "params",
        help="the parameter reference generated from the nodes' declarations "
        "(markdown table; --write updates docs/parameters.md)",
    )
    pr.add_argument("--write", metavar="FILE", help="replace the generated table in FILE (docs/parameters.md)")
    pr.add_argument("--bag", help="a bag for bag_replay to open (default: bags/sample_indoor)")

    b = sub.add_parser(
        "bench",
        help="benchmarks: ParticleArray layout; the graph on the CARMEN logs "
        "and on simulated car drives; the replay-only ceiling of a bag; scaling with "
        "particles and grid size",
    )
    b.add_argument("what", choices=["messages", "carmen", "car", "ceiling", "scaling", "thor", "worlds"])
    b.add_argument("--bag", help="ceiling: the bag to replay")
    b.add_argument("--duration", type=float, help="car, thor: simulated drive / walk length (s; default 300 / 60)")
    b.add_argument("--particles", type=int, help="car: filter.num_particles (default: kaist.yaml)")
    b.add_argument(
        "--data",
        help="carmen, scaling, worlds: the datasets folder (carmen/, carmen_corrected/ inside); required for them",
    )
    b.add_argument("--out", default="runs/bench", help="where bags, runs and tables go")
    b.add_argument(
        "--datasets",
        nargs="*",
        help="subset of intel_910 intel_2726 mit-csail (carmen), or of the "
        "corrected-pose buildings and simulated worlds (worlds)",
    )
    b.add_argument("--seeds", type=int, nargs="*", default=[0])
    b.add_argument(
        "--filter-seeds",
        type=int,
        nargs="*",
        default=[0],
        help="car: the filter's random streams (filter.seed) to run on each drive",
    )
    b.add_argument("--processes", choices=["single", "multi"], default="single")
    b.add_argument(
        "--no-images",
        action="store_true",
        help="car: bags without the stereo images (no texture node); default: stereo at 1 Hz",
    )
    b.add_argument(
        "--worlds",
        type=int,
        nargs="*",
        help="car: simulate each seed in these worlds (pf-slam simulate --world N: layouts and "
        "error levels not tuned on); default: the standard world",
    )
    b.add_argument(
        "--range-noise",
        type=float,
        metavar="M",
        help="worlds: the simulated worlds' laser range noise std (m; default: the simulator's 0.01); "
        "their own results section; refused with the corrected-pose buildings (real scans)",
    )
    b.add_argument(
        "--laser",
        metavar="BEAMS,FOV_DEG,RANGE_M",
        help="worlds: the simulated worlds' laser (e.g. 1081,270,30: a 0.25 deg scanner; default the "
        "simulator's 181,180,20); their own results section; refused with the corrected-pose buildings",
    )
    b.add_argument(
        "--sweep-particles",
        type=int,
        nargs="*",
        help="scaling: particle counts on intel_2726 (default 10 30 100 300 1000)",
    )
    b.add_argument(
        "--sweep-grid",
        type=int,
        nargs="*",
        help="scaling: grid cells per side on intel_910 (default 500 1000 2000 4000)",
    )
    b.add_argument("--plot-dir", help="scaling: where the PNG plots go (default: OUT/plots)")
    b.add_argument(
        "--results",
        metavar="FILE",
        help="also write the table into its section of FILE (docs/results.md), with the machine, "
        "the command and the commit",
    )
    return p


def _snapshot_every(text: str) -> str:
    """argparse type of --snapshot-every: checked here, kept as written (N or Ns)."""
    from .runner.common import snapshot_cadence

    try:
        snapshot_cadence(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def _add_live_parsers(sub) -> None:
    """`pf-slam live` (the graph on live topics) and `pf-slam play` (a bag onto live topics)."""
    lv = sub.add_parser(
        "live",
        help="run the SLAM graph on live topics (a robot, or a bag played elsewhere) "
        "until Ctrl-C; the map via the pf_slam/save_map service or --out",
    )
    lv.add_argument("--params", help="ROS 2 parameter YAML (the whole tuning unless --profile NAME)")
    lv.add_argument(
        "--profile",
        default="auto",
        metavar="NAME",
        help="auto (default: indoor, or none under --params), indoor, kaist, mines, sim_indoor or none",
    )
    lv.add_argument("--out", help="save map.pgm, map.yaml and trajectory.tum here when stopped")
    lv.add_argument("--processes", choices=["single", "multi"], default="single")
    lv.add_argument(
        "--odometry",
        choices=["odom", "encoders", "tf"],
        help="odometry from nav_msgs/Odometry, wheel encoders, or the odom -> base_link transform on "
        "/tf (default: the parameters', else odom)",
    )
    lv.add_argument(
        "--sim-time",
        choices=["auto", "true", "false"],
        default="auto",
        help="use_sim_time: auto follows /clock once one is published (default)",
    )
    lv.add_argument(
        "--sensor-qos",
        choices=["reliable", "best_effort"],
        default=None,
        help="QoS reliability of the sensor subscriptions (default reliable; best_effort for drivers "
        "that publish with the sensor-data QoS)",
    )
    lv.add_argument(
        "--mount-wait",
        type=float,
        default=5.0,
        metavar="S",
        help="after the first scan, wait up to S s for its frame on /tf_static or /tf (the lidar mount)",
    )
    lv.add_argument("--texture", action="store_true", help="also run the stereo texture node")
    lv.add_argument("--particles", type=int, help="number of particles (filter.num_particles)")
    lv.add_argument("--seed", type=int, help="random seed (filter.seed)")
    lv.add_argument("--domain", type=int, metavar="N", help="ROS domain (default: ROS_DOMAIN_ID, else 0)")
    for role in DEFAULT_INPUTS:
        lv.add_argument(
            f"--{role.replace('_', '-')}-topic",
            dest=f"{role}_topic",
            metavar="TOPIC",
            help=f"default {DEFAULT_INPUTS[role]}",
        )
    pl = sub.add_parser(
        "play",
        help="publish a bag's topics in real time (or N x) with /clock, as `ros2 bag play --clock`, for a live graph",
    )
    pl.add_argument("bag")
    pl.add_argument("--rate", default="1", help="1 (real time, default), N (N x faster) or max")
    pl.add_argument("--clock", action="store_true", help="publish /clock from the bag's record times")
    pl.add_argument("--delay", type=float, default=0.0, metavar="S", help="wait S s before the first message")
    pl.add_argument("--topics", nargs="*", help="only these topics (default: all)")
    pl.add_argument(
        "--wait-for",
        nargs="*",
        metavar="TOPIC",
        help="first wait (up to 30 s) until each of these topics has a subscriber (discovery)",
    )


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:2] == ["simulate", "thor"]:  # `pf-slam simulate thor ...` = `pf-slam simulate-thor ...`
        argv = ["simulate-thor"] + argv[2:]
    args = build_parser().parse_args(argv)
    try:
        return _dispatch(args)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except ModuleNotFoundError as e:
        if not (e.name or "").startswith("pf_slam_tools"):
            raise
        print(
            f"pf-slam {args.command}: error: needs the development package pf_slam_tools "
            "(simulators, benches): pip install -e ros2_ws/src/pf_slam_tools, or make setup",
            file=sys.stderr,
        )
        return 1
    except (RunError, BagError, ValueError, OSError) as e:  # known failures: one line, no traceback
        print(f"pf-slam {args.command}: error: {e}", file=sys.stderr)
        return 1


def _dispatch(args: argparse.Namespace) -> int:
    if args.command == "convert":
        from .io import convert

        if args.format == "carmen":
            rep = convert.convert_carmen(args.log, args.out_bag, storage=args.storage)
        elif args.format == "kaist":
            from .io.kaist import convert_kaist

            rep = convert_kaist(
                args.dataset_dir,
                args.out_bag,
                storage=args.storage,
                fog_batch=args.fog_batch,
                fog_format=args.fog_format,
                images=not args.no_images,
            )
        elif args.format == "thor":
            from .io.thor import convert_thor

            rep = convert_thor(
                args.lidar,
                args.joint,
                args.out_bag,
                rgb_path=args.rgb,
                depth_path=args.depth,
                storage=args.storage,
                rgb_scale=args.rgb_scale,
            )
        else:
            rep = convert.convert_mines(args.dat, args.out_bag, storage=args.storage)
        print(rep.summary())
        return 0
    if args.command == "texture":
        from pf_slam_tools.bench.texture import main as texture_main

        return texture_main(args.args)
    if args.command == "run":
        from .graph import run_cli

        return run_cli(args)
    if args.command == "live":
        from .runner.live import live_cli

        return live_cli(args)
    if args.command == "play":
        from .player import play_cli

        return play_cli(args)
    if args.command == "eval":
        from .core.metrics import format_evaluation
        from .io.evaluation import evaluate

        if not args.gt and not args.relations and not args.map:
            raise ValueError("eval needs --est with --gt and/or --relations, or --map with --gt-map")
        if (args.gt or args.relations) and not args.est:
            raise ValueError("eval: --gt/--relations need --est (the estimated trajectory)")
        res = evaluate(
            args.est,
            args.gt,
            relations_path=args.relations,
            map_path=args.map,
            gt_map_path=args.gt_map,
            map_tolerance_m=args.map_tolerance,
        )
        print(json.dumps(res, indent=2) if args.json else format_evaluation(res))
        return 0
    if args.command == "simulate-indoor":
        from pf_slam_tools.sim.indoor import run_args

        return run_args(args)
    if args.command == "simulate":
        from pf_slam_tools.sim.car import run_args as run_car

        return run_car(args)
    if args.command == "simulate-thor":
        from pf_slam_tools.sim.thor import run_args as run_thor

        return run_thor(args)
    if args.command == "params":
        from . import paramdoc

        table = paramdoc.markdown_table(paramdoc.declared_parameters(args.bag or paramdoc.SAMPLE_BAG))
        if args.write:
            paramdoc.write(args.write, table)
        else:
            print(table)
        return 0
    if args.command == "bench":
        rev = None
        if args.results:
            from pf_slam_tools.bench import results

            # the checkout as the bench starts: its own outputs (plots, an earlier bench's table)
            # and edits made while it runs do not mark the code it measured as dirty
            rev = results.commit(outputs=(args.results, getattr(args, "plot_dir", None)))
        name, title, table = _bench(args)
        print(table)
        if args.results and name:
            results.update(args.results, name, results.section(name, title, table, rev=rev))
        return 0
    raise AssertionError(args.command)


def _bench(args) -> tuple[str | None, str, str]:
    """Run `pf-slam bench WHAT`: (results section name or None, its title, the printed table)."""
    if args.what == "messages":
        from pf_slam_tools.bench import messages

        fog = messages.measure_fog(10.0)
        table = (
            messages.format_table(messages.run())
            + "\n\nFOG at 1 kHz, publish + receive, wall s per s of data (one executor):\n\n"
            + "| per-sample Vector3Stamped | FogBatch of 10 |\n|---:|---:|\n"
            + f"| {fog['vector3']:.3f} | {fog['batch']:.3f} |"
        )
        return "messages", "Messages: ParticleArray layout, FOG stream", table
    if args.what == "thor":
        from pf_slam_tools.bench import thor

        table = thor.main(args.out, tuple(args.seeds), args.duration or 60.0, tuple(args.filter_seeds), args.particles)
        return "thor", "THOR humanoid: simulated walks (moving head, RGB-D texture)", table
    if args.what == "car":
        from pf_slam_tools.bench import car

        worlds = tuple(args.worlds) if args.worlds else (None,)
        table = car.main(
            args.out,
            tuple(args.seeds),
            args.duration or 300.0,
            args.processes,
            args.particles,
            tuple(args.filter_seeds),
            images=not args.no_images,
            worlds=worlds,
        )
        name = f"car_{args.processes}" + ("_noimages" if args.no_images else "") + ("_worlds" if args.worlds else "")
        return (
            name,
            (
                f"The car: simulated drives ({args.processes} process, "
                f"{'no images' if args.no_images else 'stereo at 1 Hz, texture node on'}"
                f"{', worlds not tuned on' if args.worlds else ''})"
            ),
            table,
        )
    if args.what == "ceiling":
        from pf_slam_tools.bench.ceiling import replay_ceiling

        if not args.bag:
            raise ValueError("bench ceiling needs --bag BAG")
        return None, "", json.dumps(replay_ceiling(args.bag), indent=2)
    if args.what in ("carmen", "scaling", "worlds") and not args.data:
        raise ValueError(f"bench {args.what} needs --data DIR (the datasets folder, with carmen/ inside)")
    if args.what == "scaling":
        from pf_slam_tools.bench import scaling

        args.plot_dir = args.plot_dir or str(Path(args.out) / "plots")
        table = scaling.main(
            args.data,
            args.out,
            args.sweep_particles,
            args.sweep_grid,
            args.plot_dir,
            args.seeds[0] if args.seeds else 0,
        )
        return "scaling", "Scaling with particles and grid size", table
    if args.what == "worlds":
        from pf_slam_tools.bench import worlds

        laser = worlds.parse_laser(args.laser)
        table = worlds.main(
            args.data, args.out, args.datasets, tuple(args.seeds), range_sigma_m=args.range_noise, laser=laser
        )
        part, title = worlds.section(args.datasets, args.range_noise, laser)
        return part, f"Seeds and worlds: {title} (the indoor profile, ROS-free loop)", table
    from pf_slam_tools.bench import carmen

    table = carmen.main(args.data, args.out, args.datasets, tuple(args.seeds), args.processes)
    return (
        f"carmen_{args.processes}",
        f"CARMEN logs, no parameter file (the indoor profile), "
        f"{'one process' if args.processes == 'single' else 'one process per node'}",
        table,
    )


if __name__ == "__main__":
    sys.exit(main())
