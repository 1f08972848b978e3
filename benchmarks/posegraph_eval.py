"""Trajectory error of the network's chained poses, of the RGB-D odometry's, and of pose-graph
smoothing (batch, windowed).

For each simulated procedure, over the first N frames: the shipped depth model's depth, K and
relative poses for gaps (1, 2, 4, 8); their gap-1 chain and their pose graph with those four
gaps (the pipeline before 2026-11-23); the same relative poses refined by RGB-D odometry
(fusion.odometry), their gap-1 chain, and the pose graph of the configured gaps (default: the
pipeline's) in one batch and in windows. ATE and RPE (after Sim(3) alignment, in cm and
degrees) against the true poses. Seconds: the network's (depth and all gaps) in the network
chain's row, the odometry's in the odometry chain's, the smoothing's in the others.

    .venv/bin/python benchmarks/posegraph_eval.py --data data/test --frames 300
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from fusion.odometry import refine_relative_poses
from fusion.posegraph import PoseGraphConfig, smooth_trajectory
from hybrid.dataset import list_procedures
from learned.checkpoints import SHIPPED_DEPTH
from learned.frames import open_sequence
from learned.infer import infer_sequence
from learned.metrics import trajectory_errors
from learned.model import DepthModel, load_depth_model

SIZE = (128, 160)
METRICS = ("ate", "rpe_translation", "rpe_rotation_deg")


NETWORK_GAPS = (1, 2, 4, 8)


def relative_poses(model: DepthModel, path: Path, frames: int, refine: tuple[int, ...]
                   ) -> tuple[dict[str, dict[int, np.ndarray]], np.ndarray, dict[str, float]]:
    """The network's relative poses and those of the gaps `refine` refined by odometry, over
    the first frames; the true poses there; the seconds each took."""
    seq = open_sequence(path, SIZE)
    count = min(frames, seq.num_frames)
    start = time.perf_counter()
    inferred = infer_sequence(model, seq, NETWORK_GAPS, frames=range(count))
    network_s = time.perf_counter() - start
    start = time.perf_counter()
    refined = refine_relative_poses({g: inferred.relative[g] for g in refine}, inferred.depth,
                                    [seq.frame(i) for i in range(count)],
                                    np.median(inferred.K_pairs, axis=0), seq.region,
                                    name=path.name)
    odometry_s = time.perf_counter() - start
    return ({"network": inferred.relative, "odometry": refined.relative}, seq.poses[:count],
            {"network": network_s, "odometry": odometry_s})


def evaluate(relative: dict[str, dict[int, np.ndarray]], truth: np.ndarray,
             configs: dict[str, tuple[str, PoseGraphConfig]]) -> dict[str, dict[str, float]]:
    """Errors of each source's gap-1 chain, and errors and seconds of each named smoothing of
    the (source, config) it names."""
    rows = {}
    for name, (source, config) in configs.items():
        result = smooth_trajectory(relative[source], config)
        rows.setdefault(f"{source} chain", trajectory_errors(result.chained, truth))
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
    configs = {"network, batch, gaps 1-8": ("network", replace(batch, skips=NETWORK_GAPS)),
               "odometry, batch": ("odometry", batch),
               f"odometry, window {args.window}": ("odometry",
                                                    replace(batch, window=args.window))}
    model = load_depth_model(args.checkpoint)
    print(f"{batch}\n")
    print("| procedure | poses | ATE (cm) | RPE (cm) | RPE (deg) | seconds | frames/s |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    table: dict[str, list[dict[str, float]]] = {}
    for proc in list_procedures(args.data):
        relative, truth, seconds = relative_poses(model, proc.path, args.frames, batch.skips)
        rows = evaluate(relative, truth, configs)
        for source, taken in seconds.items():  # the network's (all gaps), the odometry's
            rows[f"{source} chain"]["seconds"] = taken
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
