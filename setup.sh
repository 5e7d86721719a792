#!/usr/bin/env bash
# Set up abyss on a fresh Debian/Ubuntu machine with Python 3.11:
# system libraries for offscreen rendering (Mesa EGL/OSMesa) and Open3D (libusb) from
# apt-packages.txt, Chromium, a Docker engine, docker-compose and debootstrap for the tests, then
# a virtual environment in .venv with the package and its test tools.
set -euo pipefail
cd "$(dirname "$0")"

APT_PACKAGES="$(grep -v '^#' apt-packages.txt | xargs)"  # what a station needs; the Dockerfile's too
# the web viewer's test loads it in Chromium; the deployment's tests validate compose.yaml and run
# it: Debian's engine (unless one is installed already, e.g. Docker's own docker-ce) and debootstrap
# for the base image, as no container registry may be reachable (deploy/base-image.sh); ping for
# the namespace lab's test; user-mode Linux and kmod's insmod for a kernel with sch_netem, where
# the host's has none (tests/linkemu/uml.py)
TEST_APT_PACKAGES="chromium chromium-driver docker-compose debootstrap iputils-ping user-mode-linux kmod"
# a C compiler for the physics in C (stations/simulation/native_physics.c; without it the physics
# steps in Python: the per-step terms alike bit for bit, the low level to rounding, slower)
TEST_APT_PACKAGES="$TEST_APT_PACKAGES gcc libc6-dev"
command -v dockerd >/dev/null || TEST_APT_PACKAGES="$TEST_APT_PACKAGES docker.io"
missing=""
for p in $APT_PACKAGES $TEST_APT_PACKAGES; do
  dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"
done
if [ -n "$missing" ]; then
  if [ "$(id -u)" = 0 ]; then
    echo "setup: installing system packages:$missing"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >/dev/null
  else
    needed=""
    for p in $missing; do case " $TEST_APT_PACKAGES " in *" $p "*) ;; *) needed="$needed $p";; esac; done
    echo "setup: missing system packages; run as root:" >&2
    echo "  sudo apt-get install -y$missing" >&2
    [ -z "$needed" ] || exit 1
  fi
fi

PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null || PYTHON=python3
"$PYTHON" -c 'import sys; assert sys.version_info[:2] >= (3, 11), sys.version' \
  || { echo "setup: abyss needs Python 3.11 or newer ($PYTHON is older)" >&2; exit 1; }
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
stamp=.venv/.abyss-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "setup: installing Python packages into .venv (first time: a few minutes)"
  # pip's and the build backend's chatter (setuptools says on every editable install that a folder
  # named like the package may shadow it) goes to a log, shown whole if the install fails
  log=.venv/pip-install.log
  { .venv/bin/python -m pip install -q --upgrade pip && .venv/bin/python -m pip install -q -e '.[test]'; } >"$log" 2>&1 \
    || { cat "$log" >&2; echo "setup: the Python packages did not install (log: $log)" >&2; exit 1; }
  touch "$stamp"
fi
# the physics in C (stations/simulation/native.py builds native_physics.c against the MuJoCo in
# .venv), when it is newer than the library or the packages are
native=.venv/lib/abyss/libabyss_physics.so  # stations/simulation/native.py loads it from there
if command -v cc >/dev/null \
  && { [ ! -f "$native" ] || [ stations/simulation/native_physics.c -nt "$native" ] || [ "$stamp" -nt "$native" ]; }; then
  .venv/bin/python -m abyss.stations.simulation.native
fi
