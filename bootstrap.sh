#!/usr/bin/env bash
# Set up weldcell on a fresh Debian machine (Python 3.11+) and run it.
#
#   bash bootstrap.sh demo   set up, then run the scan-and-plan job in the simulated cell
#   bash bootstrap.sh test   set up, then run the test suite (extra arguments go to pytest)
#   bash bootstrap.sh setup  set up only
#
# Set-up: the system libraries open3d needs (installed with apt-get when run as root, otherwise
# the exact command is printed), a virtual environment in .venv, and `pip install -e .[all,test]`.
# It is idempotent: a second run reinstalls only when pyproject.toml changed.
set -euo pipefail
cd "$(dirname "$0")"
ROOT=$(pwd)
VENV=${WELDCELL_VENV:-$ROOT/.venv}
PY=${PYTHON:-python3}

say() { printf '\033[1m[weldcell]\033[0m %s\n' "$*" >&2; }
die() { printf '\033[1;31m[weldcell] error:\033[0m %s\n' "$*" >&2; exit 1; }

command -v "$PY" >/dev/null || die "python3 not found; install Python 3.11+ (apt-get install python3)"
"$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))' \
  || die "weldcell needs Python 3.11 or newer; found $("$PY" --version 2>&1). Set PYTHON=/path/to/python3.11"

# System packages: open3d links libusb-1.0, libgomp, libGL, libEGL and libX11; venv needs python3-venv
# on Debian's own Python; xvfb gives the projector adapter's window tests a real X display; chromium lets
# the report tests open report.html in a real (headless) browser.
need=()
if command -v dpkg >/dev/null; then
  for pkg in libusb-1.0-0 libgomp1 libgl1 libegl1 libx11-6 xvfb chromium; do
    dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
  done
  if ! "$PY" -c 'import ensurepip, venv' >/dev/null 2>&1; then
    need+=("python3-venv")
  fi
fi
if ((${#need[@]})); then
  if [ "$(id -u)" = 0 ]; then
    say "installing system packages: ${need[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >/dev/null
    apt-get install -y -qq "${need[@]}" >/dev/null
  else
    die "missing system packages: ${need[*]}. Run: sudo apt-get install -y ${need[*]}"
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  say "creating the virtual environment $VENV"
  "$PY" -m venv "$VENV"
fi
stamp="$VENV/.weldcell-installed"
want=$(cat pyproject.toml setup.py | sha256sum | cut -c1-16)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  say "installing weldcell and its dependencies (first time: a few minutes)"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q -e ".[all,test]"
  echo "$want" > "$stamp"
fi

case "${1:-demo}" in
  demo)
    shift || true
    exec "$VENV/bin/weldcell" run profiles/cell1-scan-and-plan-sim.toml "$@"
    ;;
  test)
    shift || true
    # one pytest worker per core; a test file runs in one worker (module fixtures are built once)
    exec "$VENV/bin/python" -m pytest -q -n auto --dist loadfile "$@"
    ;;
  setup)
    say "ready: source $VENV/bin/activate, then run weldcell --help"
    ;;
  *)
    die "unknown command '$1'; use demo, test or setup"
    ;;
esac
