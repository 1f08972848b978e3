"""Evaluate depth, intrinsics and ego-motion on simulated procedures against their truth.

Per procedure: depth metrics over evenly spaced frames, the K aggregated over all its
consecutive pairs (as `c2d2 depth` writes it) against the true camera, and the chained
trajectory over a window against the true poses (Sim(3)-aligned).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from hybrid.dataset import list_procedures
from hybrid.types import InputError
from learned.device import device_of
from learned.frames import FrameSequence, open_sequence
from learned.infer import infer_sequence
from learned.metrics import (
    dom,
    dr_mre,
    intrinsics_error,
    median_scaled_metrics,
    mre,
    trajectory_errors,
)
from learned.model import DepthModel, to_tensor

DEPTH_KEYS = ("mre", "dr_mre", "dom", "abs_rel", "sq_rel", "rmse", "delta1")


Opener = Callable[[Path, tuple[int, int]], FrameSequence]


def head_focal_lengths(model: DepthModel, folders: list[Path],
                       open_procedure: Opener = open_sequence) -> dict[str, dict[str, float]]:
    """fx_true and the head's fx_head (the median K over all consecutive pairs, as eval-depth
    reads it) of each simulated procedure in `folders`, keyed "folder/procedure" as in
    eval-depth's JSON; open_procedure(path, size) opens each one."""
    size = (model.config.height, model.config.width)
    readings = {}
    for folder in folders:
        for procedure in list_procedures(folder):
            seq = open_procedure(procedure.path, size)
            head = np.median(infer_sequence(model, seq, depth=False).K_pairs, axis=0)
            readings[f"{folder.name}/{procedure.path.name}"] = {
                "fx_true": float(seq.camera.fx), "fx_head": float(head[0, 0])}
    return readings


def scored_depths(model: DepthModel, seq: FrameSequence, count: int = 24
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The frames whose depth eval-depth scores (`count`, evenly spaced) and the model's depth
    of each (count, H, W)."""
    picks = np.linspace(0, seq.num_frames - 1, count).round().astype(int)
    with torch.no_grad():
        depths = model.predict_depth(to_tensor(np.stack([seq.network_frame(t) for t in picks]),
                                                device_of(model)))[:, 0].cpu().numpy()
    return picks, depths


def evaluate_sequence(model: DepthModel, seq: FrameSequence, depth_frames: int = 24,
                      trajectory_frames: int = 150, K: np.ndarray | None = None) -> dict:
    """Metrics of one simulated procedure (seq must carry its true camera and depth). K (3, 3,
    at the network's size) is scored in place of the intrinsics head's median over all the
    consecutive pairs; the trajectory is scored over the first `trajectory_frames`. For a
    fisheye procedure (`c2d2 simulate --fisheye`) the true K is its lens's, whose f is the
    magnification at the image centre (1.3-1.9 times the pinhole twin's: hybrid.lens)."""
    if seq.camera is None or seq.poses is None:
        raise InputError(f"{seq.name}: no ground truth; eval-depth needs simulated procedures")
    if seq.num_frames < 3:
        raise InputError(f"{seq.name}: needs at least 3 frames for trajectory errors")
    result = infer_sequence(model, seq, depth=False)
    window = min(seq.num_frames, trajectory_frames)
    picks, depths = scored_depths(model, seq, depth_frames)
    per_frame = []
    for t, pred in zip(picks, depths, strict=True):
        gt = seq.depth(t)
        row = {"mre": mre(pred, gt, seq.region), "dr_mre": dr_mre(pred, gt, seq.region),
               "dom": dom(pred, gt, seq.region)}
        row.update(median_scaled_metrics(pred, gt, seq.region))
        per_frame.append(row)
    metrics = {k: float(np.mean([r[k] for r in per_frame])) for k in per_frame[0]}
    head = np.median(result.K_pairs, axis=0)
    K = head if K is None else K
    metrics.update(intrinsics_error(K, seq.camera.K, seq.camera.width, seq.camera.height))
    metrics["fx_pred"], metrics["fx_true"] = float(K[0, 0]), float(seq.camera.fx)
    metrics["fx_head"] = float(head[0, 0])
    metrics["fx_head_rel"] = abs(metrics["fx_head"] - metrics["fx_true"]) / metrics["fx_true"]
    metrics.update(trajectory_errors(result.poses[:window], seq.poses[:window]))
    return metrics


def summarise(per_sequence: dict[str, dict]) -> dict[str, float]:
    """Mean of each metric over sequences."""
    keys = next(iter(per_sequence.values())).keys()
    return {k: float(np.mean([m[k] for m in per_sequence.values()])) for k in keys}
