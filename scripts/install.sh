#!/usr/bin/env bash
# Installs l2calib and its two plugin distributions into ./.venv from this repository's files.
#
#   scripts/install.sh            # core + backends + policies + test tools + Ray (optional extra)
#
# Environment:
#   PYTHON       interpreter to build the venv from (default: python3, needs >= 3.10)
#   VENV         venv directory (default: .venv)
#   TORCH_SPEC   torch requirement installed first (default: torch==2.13.0, the CPU build these
#                machines carry; on other machines pass e.g. TORCH_SPEC="torch==2.13.0
#                --index-url https://download.pytorch.org/whl/cpu" to avoid a CUDA download)
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
VENV=${VENV:-.venv}
TORCH_SPEC=${TORCH_SPEC:-torch==2.13.0}

say() { printf '\033[1m[install]\033[0m %s\n' "$*"; }
die() { printf 'error: %s\n' "$*" >&2; exit 1; }

# 1. System library open3d needs (libusb-1.0). Install it with apt where we can.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  if command -v apt-get >/dev/null 2>&1; then
    SUDO=""
    [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
    if [ "$(id -u)" -eq 0 ] || [ -n "$SUDO" ]; then
      say "installing system library libusb-1.0-0 (needed by open3d)"
      $SUDO apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 || {
        $SUDO apt-get update -q >/dev/null 2>&1 && $SUDO apt-get install -y -q libusb-1.0-0 >/dev/null
      } || die "apt-get could not install libusb-1.0-0 — fix: run 'sudo apt-get install libusb-1.0-0' and retry"
    else
      die "open3d needs the system library libusb-1.0 — fix: run 'sudo apt-get install libusb-1.0-0' and retry"
    fi
  else
    die "open3d needs the system library libusb-1.0 — fix: install it with your package manager (Debian/Ubuntu: libusb-1.0-0; Fedora: libusb1; macOS: brew install libusb)"
  fi
fi

# 2. Virtual environment.
"$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 10))' \
  || die "$PYTHON is older than 3.10 — fix: set PYTHON=python3.11 (or newer)"
if [ ! -x "$VENV/bin/python" ]; then
  say "creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
PIP=("$VENV/bin/python" -m pip --disable-pip-version-check -q)

# 3. torch first, so the range in pyproject.toml is already satisfied by the CPU build.
if ! "$VENV/bin/python" -c 'import torch' >/dev/null 2>&1; then
  say "installing $TORCH_SPEC"
  # shellcheck disable=SC2086
  "${PIP[@]}" install $TORCH_SPEC
fi

# 4. The three distributions (editable) and the test tools.
say "installing l2calib (with the ray extra), l2calib-backends, l2calib-policies"
"${PIP[@]}" install -e ".[test,ray]" -e ./backends -e ./policies
"$VENV/bin/python" -c 'import open3d, torchrl, gtsam, kiss_icp, rosbags, ray' \
  || die "a dependency failed to import — fix: see the message above"
touch "$VENV/.installed"
say "done: $VENV/bin/l2calib"
