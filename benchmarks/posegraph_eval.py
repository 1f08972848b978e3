"""Trajectory error of the network's chained poses against pose-graph smoothing (batch, windowed).

For each simulated procedure: relative poses of the shipped depth model for gaps (1, 2, 4, 8)
over the first N frames, the chain of the gap-1 poses, and the pose graph smoothed in one batch
and in windows; ATE and RPE (after Sim(3) alignment, in cm and degrees) against the true poses.
The chain's seconds are the network's (relative poses for all gaps); the others, the smoothing's.

    .venv/bin/python benchmarks/posegraph_eval.py --data data/test --frames 300
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from fusion.posegraph import PoseGraphConfig, smooth_trajectory
from hybrid.dataset import list_procedures
from learned.checkpoints import SHIPPED_DEPTH
from learned.frames import open_sequence
from learned.infer import infer_sequence
from learned.metrics import trajectory_errors
from learned.model import DepthModel, load_depth_model

SIZE = (128, 160)
METRICS = ("ate", "rpe_translation", "rpe_rotation_deg")


def network_relative(model: DepthModel, path: Path, frames: int, gaps: tuple[int, ...]
                     ) -> tuple[dict[int, np.ndarray], np.ndarray, float]:
    """Relative poses over the first frames, the true poses there, and the seconds taken."""
    seq = open_sequence(path, SIZE)
    count = min(frames, seq.num_frames)
    start = time.perf_counter()
    relative = infer_sequence(model, seq, gaps, depth=False, frames=range(count)).relative
    return relative, seq.poses[:count], time.perf_counter() - start


def evaluate(relative: dict[int, np.ndarray], truth: np.ndarray,
             configs: dict[str, PoseGraphConfig]) -> dict[str, dict[str, float]]:
    """Errors of the gap-1 chain, and errors and seconds of each named smoothing."""
    rows = {}
    for name, config in configs.items():
        result = smooth_trajectory(relative, config)
        rows.setdefault("chain", trajectory_errors(result.chained, truth))
        rows[name] = trajectory_errors(result.poses, truth) | {"seconds": result.seconds}
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("data/test"),
                        help="folder of simulated procedures")
    parser.add_argument("--frames", type=int, default=300, help="first N frames of each")
    parser.add_argument("--window", type=int, default=100, help="frames per window (windowed)")
    parser.add_argument("--checkpoint", type=Path, default=SHIPPED_DEPTH,
                        help="depth model (default: the shipped one)")
    defaults = PoseGraphConfig()
    for field in ("rotation_sigma", "translation_sigma", "gap_exponent", "velocity_weight"):
        parser.add_argument("--" + field.replace("_", "-"), type=float,
                            default=getattr(defaults, field), help="see PoseGraphConfig")
    args = parser.parse_args()
    torch.set_num_threads(1)
    batch = PoseGraphConfig(rotation_sigma=args.rotation_sigma,
                            translation_sigma=args.translation_sigma,
                            gap_exponent=args.gap_exponent, velocity_weight=args.velocity_weight)
    configs = {"batch": batch, f"window {args.window}": replace(batch, window=args.window)}
    model = load_depth_model(args.checkpoint)
    print(f"{batch}\n")
    print("| procedure | poses | ATE (cm) | RPE (cm) | RPE (deg) | seconds | frames/s |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    table: dict[str, list[dict[str, float]]] = {}
    for proc in list_procedures(args.data):
        relative, truth, seconds = network_relative(model, proc.path, args.frames, batch.skips)
        rows = evaluate(relative, truth, configs)
        rows["chain"]["seconds"] = seconds  # the network's relative poses, all gaps
        for name, row in rows.items():
            table.setdefault(name, []).append(row)
            print(f"| {proc.path.name} | {name} | " + _cells(row, len(truth)))
    for name, rows in table.items():
        mean = {k: float(np.mean([r[k] for r in rows])) for k in (*METRICS, "seconds")}
        print(f"| **mean** | {name} | " + _cells(mean, args.frames))


def _cells(row: dict[str, float], frames: int) -> str:
    return (" | ".join(f"{row[k]:.3f}" for k in METRICS)
            + f" | {row['seconds']:.2f} | {frames / max(row['seconds'], 1e-9):.0f} |")


if __name__ == "__main__":
    main()
