#!/usr/bin/env bash
# Install shapeviewer and what it needs on Debian/Ubuntu, as root or as a user with sudo.
#
#   bash tools/install.sh          # the app: libusb (Open3D needs it to import), torch (CPU), shapeviewer
#   bash tools/install.sh --test   # also the test extras (pytest, Playwright, Ray) and Chromium
#
# Python packages go into the interpreter that runs `python` (set PYTHON to choose another).
set -euo pipefail
cd "$(dirname "$0")/.."
export DEBIAN_FRONTEND=noninteractive PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_ROOT_USER_ACTION=ignore

test_extras=0
case "${1:-}" in
  --test) test_extras=1 ;;
  "") ;;
  *) echo "usage: bash tools/install.sh [--test]" >&2; exit 2 ;;
esac

# Root runs apt-get itself (containers and CI images often have no sudo); anyone else through sudo.
if [ "$(id -u)" -eq 0 ]; then
  as_root=()
elif command -v sudo >/dev/null 2>&1; then
  as_root=(sudo)
else
  echo "install.sh: system packages need root: run it as root or install sudo" >&2
  exit 1
fi

# libusb-1.0-0: Open3D needs it to import; chromium: the browser tests drive it with Playwright.
packages=(libusb-1.0-0)
[ "$test_extras" -eq 1 ] && packages+=(chromium)
if ! dpkg -s "${packages[@]}" >/dev/null 2>&1; then
  ${as_root[@]+"${as_root[@]}"} apt-get update -qq
  ${as_root[@]+"${as_root[@]}"} env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
    "${packages[@]}" >/dev/null
fi

python=${PYTHON:-python}
command -v "$python" >/dev/null 2>&1 || python=python3
if "$python" -c 'import sys, sysconfig, os; sys.exit(sys.prefix == sys.base_prefix and os.path.exists(os.path.join(sysconfig.get_path("stdlib"), "EXTERNALLY-MANAGED")))'; then
  :
else
  echo "install.sh: $python belongs to the system (PEP 668); make a virtual environment first:" >&2
  echo "  python3 -m venv .venv && . .venv/bin/activate && bash tools/install.sh $*" >&2
  exit 1
fi
# torch first, pinned, so that pip takes the CPU build instead of a CUDA one of several GB.
"$python" -m pip install -q torch==2.13.0
if [ "$test_extras" -eq 1 ]; then
  "$python" -m pip install -q -e ".[test]"
else
  "$python" -m pip install -q -e .
fi
