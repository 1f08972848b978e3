"""Shipped checkpoints (fast preset), trained by this project's own commands; see README.md."""

from pathlib import Path

SHIPPED_DEPTH = Path(__file__).with_name("depth-fast.safetensors")
"""Depth + motion + intrinsics, fast preset."""
SHIPPED_COVERAGE = Path(__file__).with_name("coverage-fast.safetensors")
"""Per-frame and per-segment coverage networks, fast preset (no CORAL adaptation)."""
