#!/usr/bin/env bash
# Set up everything (first run only), then run the C2D2 demo on a built-in simulated video.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/c2d2 demo "$@"
