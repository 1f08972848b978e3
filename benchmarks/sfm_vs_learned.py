"""Classical SfM (fusion.sfm_baseline) against the learned branch, on simulated procedures.

For each procedure under --data, on its first --frames frames at the fast preset's 128x160:

- SfM: pycolmap on every --step-th frame (a wider baseline per pair), one shared
  SIMPLE_PINHOLE camera, the image region as its mask.
- Learned: the shipped depth checkpoint on all consecutive frames (as it was trained); its
  chained poses are taken at the same frames as SfM's; K is the median over frame pairs.

Reported against the truth (camera.json resized to 128x160, poses.npy): frames registered by
SfM, relative focal error |f - f_true| / f_true (mean over fx, fy), ATE and RPE after a Sim(3)
alignment (learned.metrics.trajectory_errors, RPE between consecutive compared frames) for both
on the frames SfM registered, when at least MIN_SCORED (identical frames; SfM's gaps make some
"consecutive" pairs wider), the learned ATE also on all compared frames, and wall seconds (SfM's
include writing the PNGs). Torch uses one thread.

Run from the repository root:

    .venv/bin/python benchmarks/sfm_vs_learned.py --data data/test --frames 300 --step 2
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import pycolmap
import torch

from fusion.sfm_baseline import run_sfm
from hybrid.dataset import list_procedures
from hybrid.types import PRESET_IMAGE_SIZE, InputError
from learned.checkpoints import SHIPPED_DEPTH
from learned.frames import open_sequence
from learned.infer import infer_sequence
from learned.metrics import intrinsics_error, trajectory_errors
from learned.model import load_depth_model

MIN_SCORED = 10
"""Fewest registered frames for which trajectory errors are reported (fewer say nothing)."""


def focal_error(K: np.ndarray, K_true: np.ndarray, width: int, height: int) -> float:
    """Mean of the relative fx and fy errors."""
    errors = intrinsics_error(K, K_true, width, height)
    return (errors["fx_rel"] + errors["fy_rel"]) / 2


def compare(path: Path, model, frames: int, step: int) -> dict:
    """SfM and learned K and poses on one procedure, each scored against the truth."""
    height, width = PRESET_IMAGE_SIZE["fast"]
    seq = open_sequence(path, (height, width))
    count = min(frames, seq.num_frames)
    picks = np.arange(0, count, step)
    K_true = seq.camera.K
    true_poses = seq.poses[picks]

    start = time.perf_counter()
    learned = infer_sequence(model, seq, frames=range(count))
    learned_s = time.perf_counter() - start
    learned_poses = learned.poses[picks]

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as work:
        try:
            sfm = run_sfm([seq.frame(i) for i in picks], seq.region, Path(work), name=path.name)
        except InputError:  # no model at all
            sfm = None
    sfm_s = time.perf_counter() - start
    reg = np.zeros(len(picks), bool) if sfm is None else sfm.registered
    scored = reg.sum() >= MIN_SCORED
    return {
        "procedure": path.name, "frames": len(picks), "registered": int(reg.sum()),
        "path_cm": float(np.linalg.norm(np.diff(true_poses[:, :3, 3], axis=0), axis=1).sum()),
        "sfm_f": None if sfm is None else focal_error(sfm.K, K_true, width, height),
        "learned_f": focal_error(np.median(learned.K_pairs, axis=0), K_true, width, height),
        "sfm": trajectory_errors(sfm.poses[reg], true_poses[reg]) if scored else None,
        "learned": trajectory_errors(learned_poses[reg], true_poses[reg]) if scored else None,
        "learned_all": trajectory_errors(learned_poses, true_poses),
        "sfm_s": sfm_s, "learned_s": learned_s,
    }


def cells(errors: dict | None) -> str:
    if errors is None:
        return "- | - | -"
    return (f"{errors['ate']:.3f} | {errors['rpe_translation']:.4f} "
            f"| {errors['rpe_rotation_deg']:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("data/test"))
    parser.add_argument("--frames", type=int, default=300, help="first frames of each procedure")
    parser.add_argument("--step", type=int, default=2, help="SfM and scoring use every k-th")
    parser.add_argument("--checkpoint", type=Path, default=SHIPPED_DEPTH)
    args = parser.parse_args()
    torch.set_num_threads(1)
    pycolmap.logging.minloglevel = 2
    model = load_depth_model(args.checkpoint)
    print(f"pycolmap {pycolmap.__version__}, torch {torch.__version__}, checkpoint "
          f"{args.checkpoint.name}, first {args.frames} frames, every {args.step}")
    print("| procedure | frames | path (cm) | SfM registered | focal err SfM | focal err learned "
          "| ATE SfM (cm) | RPE-t SfM (cm) | RPE-r SfM (°) | ATE learned (cm) "
          "| RPE-t learned (cm) | RPE-r learned (°) | ATE learned, all frames (cm) | SfM s "
          "| learned s |")
    print("|" + " --- |" * 15)
    for proc in list_procedures(args.data):
        r = compare(proc.path, model, args.frames, args.step)
        sfm_f = "-" if r["sfm_f"] is None else f"{r['sfm_f']:.3f}"
        print(f"| {r['procedure']} | {r['frames']} | {r['path_cm']:.1f} | {r['registered']} "
              f"| {sfm_f} | {r['learned_f']:.3f} | {cells(r['sfm'])} | {cells(r['learned'])} "
              f"| {r['learned_all']['ate']:.3f} | {r['sfm_s']:.1f} | {r['learned_s']:.1f} |",
              flush=True)


if __name__ == "__main__":
    main()
