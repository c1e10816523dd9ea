"""Bad input to the converters and to `pf-slam run`: every fault is named (file:line, topic),
recoverable ones are skipped and counted in the summary, fatal ones exit 1 with one line on
stderr and no traceback. The CLI cases run the real `pf-slam` command of the venv."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import DATA as SHARED_DATA
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pf_slam_nodes.io import skips
from pf_slam_nodes.io.bag import (
    TYPESTORE,
    BagError,
    BagReadError,
    bag_info,
    check_run_inputs,
    laser_scan,
    odometry,
    open_writer,
    read_bag,
)
from pf_slam_nodes.io.carmen import read_carmen
from pf_slam_nodes.io.mines import read_mines
from pf_slam_nodes.io.skips import SkipLog

PF_SLAM = str(Path(sys.executable).with_name("pf-slam"))
PARAM = SHARED_DATA / "kaist_sample" / "param"
needs_kaist = pytest.mark.skipif(not PARAM.is_dir(), reason=f"{PARAM} not available")


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([PF_SLAM, *map(str, args)], capture_output=True, text=True, timeout=120)


def assert_fatal(res: subprocess.CompletedProcess, command: str, *needles: str) -> str:
    """Exit 1, exactly one stderr line `pf-slam COMMAND: error: ...` holding every needle."""
    assert res.returncode == 1, (res.returncode, res.stdout, res.stderr)
    assert "Traceback" not in res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith(f"pf-slam {command}: error: "), lines[0]
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


def _flaser(ranges, t, n=None):
    n = len(ranges) if n is None else n
    return f"FLASER {n} {' '.join(map(str, ranges))} 0 0 0 0 0 0 {t} host {t}\n"


def _mines_line(t_us, left, right, mm=1000):
    return " ".join([str(t_us), "0", str(left), str(right)] + ["0"] * 20 + [str(mm)] * 682 + ["0"]) + "\n"


# ------------------------------------------------------------------------ the shared mechanism
def test_skiplog_counts_names_and_caps(monkeypatch):
    monkeypatch.setattr(skips, "MAX_LINE_WARNINGS", 2)
    counts, warnings = {"old": 1}, []
    log = SkipLog(counts, warnings)
    for line in (3, 5, 9):
        log.skip("a.csv", line, "NaN value", key="a.csv: NaN value", what="row")
    log.skip("b.csv", 4, "short row")
    log.skip("img.png", None, "truncated", key="bad image", what="image")
    log.finish()
    assert counts == {"old": 1, "a.csv: NaN value": 3, "short row": 1, "bad image": 1}
    assert warnings == [
        "a.csv:3: NaN value; row skipped",
        "a.csv:5: NaN value; row skipped",
        "b.csv:4: short row; line skipped",
        "img.png: truncated; image skipped",
        "a.csv: 1 more skipped not listed",
    ]


# ------------------------------------------------------------------------ CARMEN / Mines readers
def test_carmen_unknown_type_and_beam_count_against_header(tmp_path):
    rl = "ROBOTLASER1 0 -1.5 3.0 0.75 50.0 0.01 0 {n} " + "{r}" + " 0 0 0 0 0 0 0 0 0 0 0 0 {t} host 1.0\n"
    text = (
        _flaser([1, 2, 3, 4], "10.0")
        + "WIDGET 1 2 3\n"  # line 2: unknown type
        + rl.format(n=4, r="1 2 3 4", t="10.1")  # line 3: 4 x 0.75 = fov
        + rl.format(n=8, r="1 2 3 4 5 6 7 8", t="10.2")  # line 4: 8 beams, fov 3.0
        + "WIDGET 4\n"
    )  # line 5
    p = tmp_path / "x.clf"
    p.write_text(text)
    log = read_carmen(p)
    assert [s.line_no for s in log.scans] == [3]  # FLASER dropped: ROBOTLASER1 present
    assert log.skipped["WIDGET"] == 2 and log.skipped["malformed ROBOTLASER1"] == 1
    assert (
        "x.clf:2: message type WIDGET is not read (only FLASER, ROBOTLASER1, ODOM); its 2 lines skipped"
    ) in log.warnings
    assert (
        "x.clf:4: ROBOTLASER1: 8 beams at angular_res 0.75 do not cover the header fov 3.0; line skipped"
    ) in log.warnings


def test_mines_stamp_faults_name_the_first_line(tmp_path):
    p = tmp_path / "m.dat"
    p.write_text(
        _mines_line(1000, 0, 0)
        + _mines_line(2000, 1, 1)
        + _mines_line(2000, 2, 2)
        + _mines_line(1500, 3, 3)
        + _mines_line(3000, 4, 4)
    )
    log = read_mines(p)
    assert list(log.stamps_us) == [1000, 2000, 2000, 1500, 3000]  # kept, in file order
    assert log.warnings == ["m.dat: 1 timestamps repeat and 1 step back (first at line 3); kept in file order"]


# ------------------------------------------------------------------------ converters via the CLI
def test_cli_convert_carmen_skips_and_counts(tmp_path):
    good = [1.0, 2.0, 3.0, 81.9]
    lines = [
        _flaser(good, "1.0"),
        _flaser([1, 2, 3], "1.1", n=4),  # 2: short for its beam count
        _flaser([1, "x", 3, 4], "1.2"),  # 3: non-numeric
        _flaser([1, "nan", 3, 4], "1.3"),  # 4: NaN
        "GARBAGE\x00\x01 7\n",  # 5: unknown type
        _flaser(good, "2.0"),  # 6
        _flaser(good, "2.0"),  # 7: repeats line 6's stamp
        _flaser(good, "1.5"),
    ]  # 8: steps back
    clf = tmp_path / "bad.clf"
    clf.write_text("".join(lines))
    res = cli("convert", "carmen", clf, tmp_path / "bag")
    assert res.returncode == 0, res.stderr
    out = res.stdout
    assert "/scan: 4" in out
    assert "skipped 4: " in out and "malformed FLASER 3" in out
    for needle in (
        "bad.clf:2: FLASER: expected 15 fields for 4 beams, got 14; line skipped",
        "bad.clf:3: FLASER: non-numeric range 'x'; line skipped",
        "bad.clf:4: FLASER: NaN or inf in range; line skipped",
        "bad.clf:5: message type 'GARBAGE\\x00\\x01' is not read",
        "bad.clf: 1 scan timestamps repeat the previous one and 1 step back "
        "(by up to 0.500 s; first at line 7); kept in file order",
        "record time moved forward for 2 log lines' messages",
    ):
        assert needle in out, (needle, out)
    assert bag_info(tmp_path / "bag")["topics"]["/scan"][1] == 4


def test_cli_convert_fatal_errors_are_one_line(tmp_path):
    assert_fatal(cli("convert", "carmen", tmp_path / "nope.clf", tmp_path / "b"), "convert", "nope.clf", "No such file")
    only_bad = tmp_path / "only_bad.clf"
    only_bad.write_text(_flaser([1, "x"], "1.0") + "PARAM a b\n")
    assert_fatal(
        cli("convert", "carmen", only_bad, tmp_path / "b"),
        "convert",
        "only_bad.clf: no usable laser scan",
        "'malformed FLASER': 1",
    )
    assert not (tmp_path / "b").exists()
    dat = tmp_path / "m.dat"
    dat.write_text(_mines_line(1000, 0, 0))
    (tmp_path / "exists").mkdir()
    assert_fatal(cli("convert", "mines", dat, tmp_path / "exists"), "convert", "exists: already exists")
    short = tmp_path / "short.dat"
    short.write_text("1 2 3\nabc\n")
    assert_fatal(
        cli("convert", "mines", short, tmp_path / "b"), "convert", "short.dat: no usable line", "'malformed': 2"
    )
    assert_fatal(cli("convert", "kaist", tmp_path / "nodir", tmp_path / "b"), "convert", "nodir: not a directory")


def _kaist_dir(root: Path, n: int = 5) -> dict:
    """Real param/ files, tiny CSVs, one stereo pair per scan (Bayer PNGs of the YAML's size)."""
    import cv2

    shutil.copytree(PARAM, root / "param")
    sd = root / "sensor_data"
    sd.mkdir()
    t = 1544582648735466220 + np.arange(n, dtype=np.int64) * 10_000_000
    (sd / "encoder.csv").write_text("".join(f"{s},{i},{i}\n" for i, s in enumerate(t)))
    (sd / "fog.csv").write_text("".join(f"{s},0,0,0.001\n" for s in t))
    (sd / "lidar.csv").write_text("".join(f"{s}," + ",".join(["5.0"] * 286) + "\n" for s in t))
    fs = cv2.FileStorage(str(PARAM / "left_camera.yaml"), cv2.FILE_STORAGE_READ)
    w, h = int(fs.getNode("image_width").real()), int(fs.getNode("image_height").real())
    fs.release()
    pngs = []
    for cam in ("left", "right"):
        d = root / "stereo_images" / f"stereo_{cam}"
        d.mkdir(parents=True)
        for s in t:
            cv2.imwrite(str(d / f"{s}.png"), np.full((h, w), 128, np.uint8))
            pngs.append(d / f"{s}.png")
    return {"t": t, "pngs": pngs}


@needs_kaist
def test_cli_convert_kaist_faults(tmp_path):
    root = tmp_path / "kaist"
    ds = _kaist_dir(root)
    t = ds["t"]
    lidar = root / "sensor_data" / "lidar.csv"
    rows = lidar.read_text().splitlines(keepends=True)
    rows[1] = f"{t[1]}," + ",".join(["5.0"] * 200) + "\n"  # line 2: beams != lidar_param
    rows[3] = rows[2]  # line 4: repeats line 3's stamp
    lidar.write_text("".join(rows))
    enc = root / "sensor_data" / "encoder.csv"
    enc.write_text(enc.read_text() + f"{t[-1] + 1},1,nan\n")  # line 6: NaN
    bad_png = ds["pngs"][0]
    bad_png.write_bytes(bad_png.read_bytes()[:100])  # truncated PNG
    res = cli("convert", "kaist", root, tmp_path / "bag")
    assert res.returncode == 0, res.stderr
    out = res.stdout
    assert "/scan: 3" in out and "/encoders: 5" in out and "/stereo/left/image_raw: 4" in out
    for needle in (
        f"{lidar}:2: expected 287 columns, got 201; row skipped",
        f"{lidar}:4: timestamp repeats; row skipped",
        f"{enc}:6: NaN or inf value; row skipped",
        f"{bad_png}: not a readable PNG (truncated or corrupt); image skipped",
        "skipped 4: ",
        "lidar.csv: expected 287 columns, got 201 1",
        "stereo_left: bad image 1",
    ):
        assert needle in out, (needle, out)

    (root / "param" / "stereo_param.txt").unlink()
    assert_fatal(cli("convert", "kaist", root, tmp_path / "bag2"), "convert", "param/stereo_param.txt: missing")
    shutil.copy(PARAM / "stereo_param.txt", root / "param")
    yaml = root / "param" / "left_camera.yaml"
    yaml.write_text(yaml.read_text()[:150])  # truncated camera YAML
    assert_fatal(cli("convert", "kaist", root, tmp_path / "bag3"), "convert", "left_camera.yaml")
    (root / "param" / "Vehicle2Lidar.txt").write_text("RPY: 0 0 0\nR: 1 0 0 0 1 0 0 0 1\n")
    assert_fatal(cli("convert", "kaist", root, tmp_path / "bag4"), "convert", 'Vehicle2Lidar.txt: no "t:" line')


# ------------------------------------------------------------------------ bags for `pf-slam run`
def _run_bag(path: Path, storage: str = "mcap", n: int = 50, scan_type: bool = True) -> Path:
    with open_writer(path, storage=storage) as bag:
        bag.add_connection("/odom", "nav_msgs/msg/Odometry")
        bag.add_connection("/scan", "sensor_msgs/msg/LaserScan" if scan_type else "std_msgs/msg/String")
        string = TYPESTORE.types["std_msgs/msg/String"]
        for i in range(n):
            t = 1_000_000_000 + i * 100_000_000
            bag.write("/odom", t, odometry(t, pose=(0.01 * i, 0.0, 0.0)))
            bag.write(
                "/scan",
                t,
                laser_scan(t, "laser", -1.5, 0.01, np.full(300, 4.0), 0.0, 30.0)
                if scan_type
                else string(data="not a scan"),
            )
    return path


def _bag_with_unknown_type(path: Path) -> Path:
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg("int32 x", "acme_msgs/msg/Widget"))
    w = Writer(path, version=9)
    w.open()
    conn = w.add_connection("/widget", "acme_msgs/msg/Widget", typestore=store)
    w.write(conn, 1, store.serialize_cdr(store.types["acme_msgs/msg/Widget"](x=1), "acme_msgs/msg/Widget"))
    w.close()
    return path


def test_check_run_inputs_names_found_and_needed(tmp_path):
    ok = bag_info(_run_bag(tmp_path / "ok"))
    check_run_inputs(ok)  # no exception
    wrong = bag_info(_run_bag(tmp_path / "wrong", scan_type=False))
    with pytest.raises(BagError) as e:
        check_run_inputs(wrong)
    msg = str(e.value)
    assert "\n" not in msg
    assert "wrong: cannot run: /scan is std_msgs/msg/String, expected sensor_msgs/msg/LaserScan." in msg
    assert "Found: /odom [nav_msgs/msg/Odometry] (50), /scan [std_msgs/msg/String] (50)." in msg
    assert msg.endswith(
        "Needs: /scan [sensor_msgs/msg/LaserScan] with messages, and /odom "
        "[nav_msgs/msg/Odometry] or /encoders [sensor_msgs/msg/JointState]"
    )
    with pytest.raises(BagError, match=r"cannot run: /scan has no messages\. Found: /odom .*\(0\)"):
        check_run_inputs(bag_info(_run_bag(tmp_path / "empty", n=0)))
    with pytest.raises(
        BagError,
        match=(
            r"cannot run: no /scan topic; no /odom or /encoders topic; "
            r"message types unknown to this ROS install: "
            r"acme_msgs/msg/Widget\. Found: /widget "
            r"\[acme_msgs/msg/Widget\] \(1\)"
        ),
    ):
        check_run_inputs(bag_info(_bag_with_unknown_type(tmp_path / "widget")))
    fog = dict(ok, topics=dict(ok["topics"], **{"/fog": ("sensor_msgs/msg/Imu", 3)}))
    with pytest.raises(
        BagError,
        match="/fog is sensor_msgs/msg/Imu, expected "
        "pf_slam_interfaces/msg/FogBatch or geometry_msgs/msg/Vector3Stamped",
    ):
        check_run_inputs(fog)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_cli_run_refuses_bad_bags(tmp_path, storage, ros_domain):
    out = tmp_path / "run"
    wrong = _run_bag(tmp_path / "wrong", storage, scan_type=False)
    assert_fatal(
        cli("run", wrong, "--out", out), "run", "wrong: cannot run: /scan is std_msgs/msg/String", "Found: ", "Needs: "
    )
    assert not out.exists()  # nothing written for a bag that cannot run
    bag = _run_bag(tmp_path / "trunc", storage, n=400)
    data = next(f for f in bag.iterdir() if f.suffix in (".mcap", ".db3"))
    data.write_bytes(data.read_bytes()[: len(data.read_bytes()) // 3])
    assert_fatal(cli("run", bag, "--out", out), "run", str(bag))
    data.write_bytes(b"\x00garbage" * 100)
    assert_fatal(cli("run", bag, "--out", out), "run", str(bag))
    assert_fatal(cli("run", tmp_path / "missing", "--out", out), "run", "missing: no such file")
    assert not out.exists()


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_corrupt_bytes_inside_a_bag_raise_bag_error(tmp_path, storage):
    """Damage in the middle of the data file (the end intact): BagError naming the bag, at open
    (sqlite3) or when the reader reaches the damaged chunk (MCAP) -- never a raw exception."""
    bag = _run_bag(tmp_path / "mid", storage, n=2000)
    data = next(f for f in bag.iterdir() if f.suffix in (".mcap", ".db3"))
    b = bytearray(data.read_bytes())
    b[len(b) // 2 : len(b) // 2 + 5000] = b"\xff" * 5000
    data.write_bytes(bytes(b))
    n = 0
    with pytest.raises(BagError, match=f"{bag}: cannot (open bag|read messages)"):
        for _ in read_bag(bag):
            n += 1
    assert n < 4000  # stopped at the damage


# ------------------------------------------------------------------------ pf-slam run: bad parameters
@pytest.mark.parametrize(
    "args, yaml_text, needles",
    [
        (
            ["--particles", "0"],
            None,
            ["the command line (--particles): parameter 'filter.num_particles'", "num_particles must be >= 1, got 0"],
        ),
        (
            [],
            "/**:\n  ros__parameters:\n    num_partcles: 500\n",
            ["section '/**': unknown parameter 'num_partcles'", "nearest known: 'filter.num_particles'"],
        ),
        (
            [],
            "/**:\n  ros__parameters:\n    filter: {num_particles: 0}\n",
            ["p.yaml, section '/**': parameter 'filter.num_particles'", "must be >= 1, got 0"],
        ),
        (
            [],
            "correlator:\n  ros__parameters:\n    correlation.search_x_m: fast\n",
            ["p.yaml, section 'correlator': parameter 'correlation.search_x_m'"],
        ),
        (
            [],
            "/**:\n  ros__parameters:\n    filter: {num_particles: 5\n",
            ["p.yaml:4:1: cannot read parameter file: not valid YAML: "],
        ),
        (["--rate", "fast"], None, ["the command line (--rate): parameter 'rate'"]),
    ],
)
def test_cli_run_bad_parameters_one_line_nothing_written(tmp_path, args, yaml_text, needles):
    """Checked before anything is created: one line naming the flag or file+section and the
    parameter; --out is not created, and a pre-existing --out keeps exactly what it had."""
    bag = _run_bag(tmp_path / "bag")
    if yaml_text is not None:
        (tmp_path / "p.yaml").write_text(yaml_text)
        args = args + ["--params", tmp_path / "p.yaml"]
    out = tmp_path / "new" / "run"
    assert_fatal(cli("run", bag, "--out", out, *args), "run", *needles)
    assert not (tmp_path / "new").exists()
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    assert_fatal(cli("run", bag, "--out", mine, *args), "run", *needles)
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]


@pytest.mark.parametrize("processes", ["single", "multi"])
def test_cli_run_node_refusing_a_parameter_leaves_no_out(tmp_path, processes, ros_domain):
    """A value only the node itself checks (odometry_source 'gps') fails when the node is built
    (in this process, or in its own with --processes multi): the last line names the node and
    the parameter, exit 1, and what the run had created is removed."""
    bag = _run_bag(tmp_path / "bag")
    (tmp_path / "p.yaml").write_text("predictor:\n  ros__parameters:\n    odometry_source: gps\n")
    out = tmp_path / "run"
    res = cli("run", bag, "--out", out, "--params", tmp_path / "p.yaml", "--processes", processes)
    assert res.returncode == 1, (res.stdout, res.stderr)
    assert "Traceback" not in res.stderr
    last = res.stderr.strip().splitlines()[-1]
    assert last.startswith("pf-slam run: error: node predictor"), last
    assert "parameter 'odometry_source' must be 'odom', 'encoders' or 'tf', got 'gps'" in last
    assert not out.exists()


# ------------------------------------------------------------------------ pf-slam run: bag damaged mid-file
def _damaged_mid_bag(path: Path, n: int = 1500) -> tuple[Path, int, int]:
    """An MCAP bag of `n` scans + odometry (~3 MB: rosbags closes a chunk at 1 MiB, so several
    chunks) with 5000 bytes overwritten in the middle chunk; returns it, the messages and the
    scans readable before the damage (read from the damaged bag until the reader stops)."""
    bag = _run_bag(path, "mcap", n=n)
    data = next(f for f in bag.iterdir() if f.suffix == ".mcap")
    b = bytearray(data.read_bytes())
    b[len(b) // 2 : len(b) // 2 + 5000] = b"\xff" * 5000
    data.write_bytes(bytes(b))
    msgs = scans = 0
    with pytest.raises(BagReadError):
        for topic, *_ in read_bag(bag):
            msgs += 1
            scans += topic == "/scan"
    return bag, msgs, scans


def test_read_bag_damage_mid_file_yields_everything_before_it(tmp_path):
    """Damage in one MCAP chunk: every message of the chunks before it comes out (the same bytes
    as from an intact copy), then BagReadError with the position: message index and record time."""
    intact = [m for m in read_bag(_run_bag(tmp_path / "intact", "mcap", n=1500))]
    bag, msgs, scans = _damaged_mid_bag(tmp_path / "mid")
    assert 0.25 * len(intact) < msgs < 0.75 * len(intact)  # the middle chunk, not the start or the end
    got = []
    with pytest.raises(BagReadError) as e:
        for m in read_bag(bag):
            got.append(m)
    assert got == intact[:msgs]
    err = e.value
    assert err.messages == msgs and err.last_stamp_ns == intact[msgs - 1][2]
    assert str(err).startswith(
        f"{bag}: cannot read messages: damaged at message {msgs + 1} ({msgs} read, "
        f"the last at record time {intact[msgs - 1][2] / 1e9:.9f} s): "
    )
    assert err.damage.startswith(f"damaged at message {msgs + 1} of {bag} (")


@pytest.mark.parametrize("processes", ["single", "multi"])
def test_cli_run_bag_damaged_mid_file_keeps_what_came_before(tmp_path, processes, ros_domain):
    """A bag damaged mid-file: the replay publishes what it read and reports the damage; the run
    finishes those scans (not the 60 s idle stop), writes their outputs with "complete": false
    and the position in "stopped_by", ends with one line naming the bag and the position, exit 1."""
    import json

    bag, msgs, scans = _damaged_mid_bag(tmp_path / "mid")
    out = tmp_path / "run"
    res = cli("run", bag, "--out", out, "--processes", processes)
    assert res.returncode == 1, (res.stdout, res.stderr[-3000:])
    assert "Traceback" not in res.stderr and "Exception in" not in res.stderr
    last = res.stdout.strip().splitlines()[-1]
    assert last.startswith(
        f"run incomplete: stopped by BAG: damaged at message {msgs + 1} of {bag} ({msgs} read, the last at record time "
    ), last
    s = json.loads((out / "summary.json").read_text())
    assert s["complete"] is False
    assert s["stopped_by"].startswith(f"BAG: damaged at message {msgs + 1} of {bag} ")
    assert s["scans_in_bag"] == 1500 and s["scans_published"] == s["scans_processed"] == scans
    tum = [ln for ln in (out / "trajectory.tum").read_text().splitlines() if ln and not ln.startswith("#")]
    assert len(tum) == scans  # every scan before the damaged chunk
    stamps = [float(ln.split()[0]) for ln in tum]
    assert stamps == [1.0 + 0.1 * i for i in range(scans)] or np.allclose(stamps, 1.0 + 0.1 * np.arange(scans))
    assert (out / "map.pgm").is_file() and (out / "map.yaml").is_file()
