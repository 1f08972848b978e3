"""Shipped checkpoints (fast preset), trained by this project's own commands; see README.md."""

from pathlib import Path

SHIPPED_DEPTH = Path(__file__).with_name("depth-fast.safetensors")
"""Depth + motion + intrinsics, fast preset."""
