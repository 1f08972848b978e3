"""Preview of a simulated procedure: sample frames with their depth, and segment coverage."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hybrid.coverage import pair_key  # noqa: E402
from hybrid.dataset import Procedure  # noqa: E402


def write_preview(procedure: Procedure, path: Path, frames: int = 6) -> Path:
    """PNG with `frames` evenly spaced RGB frames, their depth, and per-segment coverage."""
    cov = procedure.coverage
    picks = np.linspace(0, procedure.num_frames - 1, frames).round().astype(int)
    fig = plt.figure(figsize=(2.2 * frames, 7.5), layout="constrained")
    grid = fig.add_gridspec(3, frames, height_ratios=[1, 1, 1.3])
    for col, f in enumerate(picks):
        ax = fig.add_subplot(grid[0, col])
        ax.imshow(procedure.rgb(f))
        ax.set_title(f"frame {f}", fontsize=9)
        ax.axis("off")
        ax = fig.add_subplot(grid[1, col])
        depth = procedure.depth(f)
        shown = ax.imshow(np.where(depth > 0, depth, np.nan), cmap="viridis")
        fig.colorbar(shown, ax=ax, shrink=0.7, label="depth (cm)" if col == frames - 1 else None)
        ax.axis("off")
    ax = fig.add_subplot(grid[2, :])
    fps = procedure.camera.fps
    t = np.arange(procedure.num_frames) / fps
    default = pair_key(cov.default_pair)
    ax.plot(t, np.array(cov.per_frame[default], dtype=float), lw=0.6, color="0.6",
            label=f"per frame (Δ = {default} cm)")
    for pair in cov.delta_pairs:
        key = pair_key(pair)
        for s in cov.segments:
            value = s.coverage[key]
            ax.hlines(np.nan if value is None else value, s.start / fps, s.stop / fps,
                      lw=2.5 if key == default else 1.2,
                      color=f"C{cov.delta_pairs.index(pair)}",
                      label=f"segment (Δ = {key} cm)" if s.index == 0 else None)
    for edge in (0.4, 0.8):
        ax.axhline(edge, ls=":", color="k", lw=0.8)
    ax.set_ylim(0, 1)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("ground-truth coverage")
    ax.legend(fontsize=8, loc="lower left", ncols=2)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)
