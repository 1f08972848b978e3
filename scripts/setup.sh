#!/usr/bin/env bash
# Create .venv and install C2D2 with everything it needs (idempotent).
set -euo pipefail
cd "$(dirname "$0")/.."

# Open3D needs the Debian library libusb-1.0-0.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  if [ "$(id -u)" = "0" ]; then
    echo "[setup] installing Debian package libusb-1.0-0 (needed by Open3D)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
  else
    echo "[setup] Open3D needs the Debian library libusb-1.0-0. Run: sudo apt-get install -y libusb-1.0-0" >&2
    exit 1
  fi
fi

PY=${PYTHON:-python3}
if [ -x .venv/bin/python ] && ! .venv/bin/python -m pip --version >/dev/null 2>&1; then
  echo "[setup] .venv has no pip (made without python3-venv?): creating it again"
  rm -rf .venv
fi
if [ ! -x .venv/bin/python ]; then
  if ! $PY -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
    echo "[setup] C2D2 needs Python 3.11 or newer as $PY (set PYTHON=/path/to/python3.11+)" >&2
    exit 1
  fi
  # Debian's pythons create virtual environments only with their -venv package (ensurepip).
  if ! $PY -c 'import ensurepip, venv' 2>/dev/null; then
    pkg="python$($PY -c 'import sys; print("%d.%d" % sys.version_info[:2])')-venv"
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
      echo "[setup] installing Debian package $pkg (needed to create .venv)"
      apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$pkg" >/dev/null
    fi
    if ! $PY -c 'import ensurepip, venv' 2>/dev/null; then
      echo "[setup] $PY cannot create a virtual environment. On Debian: sudo apt-get install -y $pkg" >&2
      exit 1
    fi
  fi
  echo "[setup] creating .venv with $($PY --version)"
  $PY -m venv .venv
fi
stamp=.venv/.c2d2-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "[setup] installing c2d2 and its dependencies into .venv (first time: several minutes)"
  .venv/bin/python -m pip install -q --upgrade pip
  # torch first, pinned: this takes the CPU build that lies on this machine.
  .venv/bin/python -m pip install -q torch==2.13.0
  .venv/bin/python -m pip install -q -e ".[dev]"
  touch "$stamp"
fi
