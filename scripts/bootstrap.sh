#!/usr/bin/env bash
# Create or reuse .venv and install what the workspace needs, idempotently.
#
#   bash scripts/bootstrap.sh                     the runtime: nodes, `lightstage`, `make demo`
#   bash scripts/bootstrap.sh --with camera       + real cameras (pypylon; Aravis and PyGObject)
#   bash scripts/bootstrap.sh --with cluster      + the trainer on a Dask cluster
#   bash scripts/bootstrap.sh --with test         + the test suite: every extra above, the test
#                                                   tools, Debian's chromium, the AVR toolchain,
#                                                   simavr and the firmware build (`make test`)
# Extras combine (`--with camera,cluster`) and stay installed; LIGHTSTAGE_EXTRAS=test does the same.
#
# Steps run only when their inputs changed (a hash stamp per step in .venv/.stamps), so a
# second run finishes in seconds. Details go to .cache/bootstrap.log; the terminal gets one
# line per step. Set LIGHTSTAGE_PYTHON to choose the interpreter (Python 3.11: the ROS 2
# Jazzy wheels and the interface build are tied to it).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
VENV="$ROOT/.venv"
STAMPS="$VENV/.stamps"
LOG_DIR="$ROOT/.cache"
LOG="$LOG_DIR/bootstrap.log"
mkdir -p "$LOG_DIR"
: > "$LOG"

EXTRAS=",${LIGHTSTAGE_EXTRAS:-},"
while [ $# -gt 0 ]; do
  case "$1" in
    --with) [ $# -ge 2 ] || { echo "bootstrap.sh: --with needs camera, cluster or test" >&2; exit 2; }
            EXTRAS="$EXTRAS$2,"; shift 2 ;;
    --with=*) EXTRAS="$EXTRAS${1#--with=},"; shift ;;
    -h|--help) sed -n '2,10p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "bootstrap.sh: unknown argument $1 (--with camera|cluster|test)" >&2; exit 2 ;;
  esac
done
for extra in ${EXTRAS//,/ }; do
  case "$extra" in camera|cluster|test) ;; *) echo "bootstrap.sh: unknown extra '$extra' (camera, cluster, test)" >&2; exit 2 ;; esac
done
with() { case "$EXTRAS" in *",$1,"*) return 0 ;; esac; [ "$1" != test ] && case "$EXTRAS" in *",test,"*) return 0 ;; esac; return 1; }

# Debian packages. The runtime: the interface build (cmake, ninja, g++, pkg-config).
# camera: Aravis (GenICam cameras) and its GObject introspection data, and the headers
# PyGObject and pycairo are built against (libgirepository1.0-dev, libcairo2-dev).
# test: the AVR firmware build (gcc-avr, binutils-avr, avr-libc), the simavr harness it is
# tested in (libsimavr-dev, libelf-dev), strace, with which a test checks that ROS traffic
# stays on loopback, iproute2, with which scripts/run_tests.sh brings up loopback in the
# tests' network namespace, and Debian's chromium, in which the tests drive the operator's
# page headless (no browser download).
APT_PACKAGES=(cmake ninja-build gcc g++ make pkg-config)
with camera && APT_PACKAGES+=(libaravis-0.8-0 gir1.2-aravis-0.8 libgirepository1.0-dev libcairo2-dev)
with test && APT_PACKAGES+=(gcc-avr binutils-avr avr-libc libsimavr-dev libelf-dev strace iproute2 chromium)
PROJECT_PACKAGES=(lightstage_graph lightstage_physics lightstage_camera lightstage_driver mux_classifier mux_trainer lightstage_recording lightstage_bringup)

step() { printf '[bootstrap] %s\n' "$*"; echo "=== $* ($(date -u +%H:%M:%S))" >> "$LOG"; }
fail() {
  [ -z "${numba_pid:-}" ] || kill "$numba_pid" 2>/dev/null || true
  printf '[bootstrap] FAILED: %s\n[bootstrap] last lines of %s:\n' "$1" "$LOG" >&2
  tail -n 25 "$LOG" >&2
  exit 1
}
# Hash of the given files/dirs (contents and names), ignoring build products.
tree_hash() {
  find "$@" -type f -not -path '*/build/*' -not -path '*/__pycache__/*' \
       -not -name '*.pyc' -not -path '*.egg-info/*' -print0 2>/dev/null \
    | LC_ALL=C sort -z | xargs -0 sha256sum | sha256sum | cut -c1-16
}
stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
stamp_set() { mkdir -p "$STAMPS"; echo "$2" > "$STAMPS/$1"; }

# 1. Debian packages
missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  step "installing Debian packages: ${missing[*]}"
  SUDO=""
  if [ "$(id -u)" != 0 ]; then
    command -v sudo >/dev/null || fail "need root or sudo to install: ${missing[*]}"
    SUDO="sudo"
  fi
  { $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}"; } >> "$LOG" 2>&1 \
    || fail "apt-get install ${missing[*]}"
fi

# 2. the venv
if [ ! -x "$VENV/bin/python" ]; then
  PY="${LIGHTSTAGE_PYTHON:-}"
  if [ -z "$PY" ]; then
    for cand in python3.11 python3; do
      if command -v "$cand" >/dev/null && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
        PY="$cand"; break
      fi
    done
  fi
  [ -n "$PY" ] || fail "Python 3.11 not found (the ROS 2 Jazzy wheels need it); set LIGHTSTAGE_PYTHON"
  step "creating .venv with $("$PY" --version 2>&1)"
  "$PY" -m venv "$VENV" >> "$LOG" 2>&1 || fail "python -m venv"
fi
PIP=("$VENV/bin/python" -m pip --disable-pip-version-check)

# 3. pinned Python dependencies: the runtime set, then each extra asked for (one pin set,
#    constraints.txt, for all of them)
pip_requirements() {  # STAMP FILE WHAT
  local h; h=$(tree_hash requirements*.txt constraints.txt)
  if ! stamp_ok "$1" "$h"; then
    step "installing pinned Python dependencies: $3"
    "${PIP[@]}" install -q 'pip==26.3' 'setuptools==79.0.1' 'wheel==0.48.0' >> "$LOG" 2>&1 || fail "pip upgrade"
    "${PIP[@]}" install -q -r "$2" -c constraints.txt >> "$LOG" 2>&1 || fail "pip install -r $2"
    stamp_set "$1" "$h"
  fi
}
pip_requirements requirements requirements.txt "the runtime (ROS 2 Jazzy wheels, numpy, scikit-learn, jax, ...)"
with camera && pip_requirements requirements-camera requirements-camera.txt "cameras (pypylon, PyGObject)"
with cluster && pip_requirements requirements-cluster requirements-cluster.txt "Dask (distributed)"
with test && pip_requirements requirements-test requirements-test.txt "tests (pytest, hypothesis, rosbags, ...)"

# 4. the project's ament_python packages (regular installs: data files such as the
#    ament index markers and the lib/<pkg>/ executables for `ros2 run` land in the venv; they
#    install without the interface package, which the nodes import only when they run)
for pkg in "${PROJECT_PACKAGES[@]}"; do
  h=$(tree_hash "src/$pkg")
  if ! stamp_ok "$pkg" "$h"; then
    step "installing $pkg"
    "${PIP[@]}" install -q --no-build-isolation --no-deps --force-reinstall "./src/$pkg" >> "$LOG" 2>&1 \
      || fail "pip install ./src/$pkg"
    rm -rf "src/$pkg/build" "src/$pkg/"*.egg-info
    stamp_set "$pkg" "$h"
    reinstalled=1
  fi
done
# the numba kernels (HOG, noise, exact SVM) compile once into the installed packages' caches,
# so that no classify request or search pays the compile (seconds) later; on the second core
# while the interface package builds (the two took 38 s and 79 s one after the other)
numba_pid=""
if [ -n "${reinstalled:-}" ]; then
  step "compiling the numba kernels (beside the next step)"
  "$VENV/bin/python" -c 'from mux_trainer.rendering import compile_kernels; compile_kernels()' \
    > "$LOG.numba" 2>&1 &
  numba_pid=$!
fi

# 5. the interface package (rosidl, built with cmake against the wheels)
if [ -f src/lightstage_interfaces/pyproject.toml ]; then
  h=$(tree_hash src/lightstage_interfaces)
  if ! stamp_ok interfaces "$h"; then
    step "building lightstage_interfaces (rosidl; about a minute)"
    "${PIP[@]}" install -q --no-build-isolation --no-deps --force-reinstall ./src/lightstage_interfaces >> "$LOG" 2>&1 \
      || fail "building src/lightstage_interfaces"
    stamp_set interfaces "$h"
  fi
fi

# 6. the firmware (AVR) and its simavr harness: for the tests (the demo's stage runs the
#    Python firmware simulator)
if with test && [ -f src/lightstage_driver/firmware/Makefile ]; then
  h=$(tree_hash src/lightstage_driver/firmware)
  if ! stamp_ok firmware "$h" || [ ! -d src/lightstage_driver/firmware/build ]; then
    step "building the AVR firmware and the simavr harness"
    make -C src/lightstage_driver/firmware >> "$LOG" 2>&1 || fail "make -C src/lightstage_driver/firmware"
    stamp_set firmware "$h"
  fi
fi

# the numba kernels started beside the interface build: wait for them, their log into LOG
if [ -n "$numba_pid" ]; then
  numba_ok=0
  wait "$numba_pid" || numba_ok=$?
  numba_pid=""
  cat "$LOG.numba" >> "$LOG"; rm -f "$LOG.numba"
  [ "$numba_ok" = 0 ] || fail "compiling the numba kernels (mux_trainer.rendering.compile_kernels)"
fi

# 7. the venv's ROS setup file, and a path fix in the interface package's own setup file
#    (its configure-time prefix is scikit-build-core's temporary wheel folder, gone by now)
sed -i "s|^: \${AMENT_CURRENT_PREFIX:=\"[^\"]*\"}|: \${AMENT_CURRENT_PREFIX:=\"$VENV\"}|" \
  "$VENV/share/lightstage_interfaces/local_setup.sh"
cat > "$VENV/setup.bash" <<'SETUP'
# The ROS environment of this venv (written by scripts/bootstrap.sh): `source .venv/setup.bash`,
# as /opt/ros/jazzy/setup.bash on a full ROS 2 install. It puts the venv's bin/ first on PATH
# (python, lightstage) and applies the project's ROS environment (lightstage_graph.ros_env):
# the venv on AMENT_PREFIX_PATH (so `ros2 pkg` / `ros2 run` / ament_index_python find every
# package), LOCALHOST discovery, the Fast DDS profile. Paths come from this file's location.
_lightstage_venv="$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")" && pwd)"
export VIRTUAL_ENV="$_lightstage_venv"
case ":$PATH:" in *":$_lightstage_venv/bin:"*) ;; *) export PATH="$_lightstage_venv/bin:$PATH" ;; esac
eval "$("$_lightstage_venv/bin/python" -m lightstage_graph.ros_env)"
unset _lightstage_venv
SETUP
step "ready: $VENV (ROS environment: source .venv/setup.bash)"
