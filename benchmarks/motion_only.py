"""Learn motion and intrinsics alone, with the true depth given: does K converge?

Whole-image procedures only (others are refused): it feeds their frames to the networks as
they are, where c2d2 fills the black corners of ones simulated with `--octagon`
(FrameSequence.network_frame).

Trains a fresh MotionNet (fast preset) with the training loss on simulated procedures whose
true depth replaces the depth network, and prints the focal length it predicts on held-out
procedures relative to their true one, and the ratio of predicted to true rotation angle over
held-out pairs turning more than 2 degrees. If K converges here, the focal drift of full
training comes from depth absorbing the error.

Focal length is observable only through rotation (the flow of a translation scales with f/Z,
and depth absorbs f). `--weighting rotation` draws target frames with probability proportional
to the true rotation angle between their two source frames (clipped to 20 degrees, plus 2):
an upper bound on what sampling turning triplets more often can do.

    .venv/bin/python benchmarks/motion_only.py --data data/train-pink data/train-dusk \
        --val data/val --steps 600 [--weighting rotation]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from hybrid.dataset import Procedure, list_procedures
from learned.config import DepthConfig
from learned.map_triplets import relative_motion
from learned.model import DepthModel, to_tensor


def triplet(proc: Procedure, t: int, gap: int) -> tuple[torch.Tensor, torch.Tensor]:
    ids = (t - gap, t, t + gap)
    frames = torch.stack([to_tensor(proc.rgb(i)) for i in ids])
    depths = torch.stack([torch.from_numpy(proc.depth(i))[None].clamp(min=0.01) for i in ids])
    return frames, depths


def turn_deg(proc: Procedure, a: int, b: int) -> float:
    """True rotation angle between frames a and b, degrees."""
    return np.degrees(float(relative_motion(proc.poses, a, b)[0].norm()))


def held_out_ratios(model: DepthModel, procs: list[Procedure], gap: int) -> tuple[float, float]:
    """Predicted / true fx (mean over procedures) and rotation angle (median over pairs
    turning more than 2 degrees), from pairs `gap` apart every 10 frames."""
    focal, rotation = [], []
    with torch.no_grad():
        for proc in procs:
            ts = np.arange(gap, proc.num_frames, 10)
            a = torch.stack([to_tensor(proc.rgb(t - gap)) for t in ts])
            b = torch.stack([to_tensor(proc.rgb(t)) for t in ts])
            predicted, *_, K = model.pair_motion(a, b)
            focal.append(float(K.mean(0)[0, 0]) / proc.camera.fx)
            true = np.array([turn_deg(proc, t - gap, t) for t in ts])
            angle = np.degrees(predicted.norm(dim=1).numpy())
            rotation += list(angle[true > 2] / true[true > 2])
    return float(np.mean(focal)), float(np.median(rotation))


def target_weights(proc: Procedure, gap: int, weighting: str) -> np.ndarray:
    """Sampling weight of each target frame gap .. num_frames - gap - 1."""
    targets = range(gap, proc.num_frames - gap)
    if weighting == "uniform":
        return np.ones(len(targets))
    return np.array([min(turn_deg(proc, t - gap, t + gap), 20.0) + 2.0 for t in targets])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--val", type=Path, required=True)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--weighting", choices=["uniform", "rotation"], default="uniform")
    args = parser.parse_args()
    config = DepthConfig()
    procs = [p for d in args.data for p in list_procedures(d, whole_images=True)]
    val = list_procedures(args.val, whole_images=True)
    gap = max(1, round(procs[0].camera.fps * config.pair_gap_s))
    torch.manual_seed(args.seed)
    model = DepthModel(config)
    optimizer = torch.optim.Adam(model.motion.parameters(), lr=config.learning_rate)
    rng = np.random.default_rng(args.seed)
    weights = [target_weights(p, gap, args.weighting) for p in procs]
    candidates = [(proc, t) for proc, w in zip(procs, weights, strict=True)
                  for t in range(gap, gap + len(w))]
    chance = np.concatenate(weights) / np.concatenate(weights).sum()
    print(f"step 0: held-out predicted / true fx {held_out_ratios(model, val, gap)[0]:.3f}")
    for step in range(1, args.steps + 1):
        picks = [candidates[k] for k in rng.choice(len(candidates), config.batch_size, p=chance)]
        frames, depths = map(torch.stack, zip(*(triplet(p, t, gap) for p, t in picks),
                                              strict=True))
        region = torch.ones(len(picks), 1, *frames.shape[-2:])
        loss = model.loss(frames, region, depths).total
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if step % 100 == 0:
            focal, rotation = held_out_ratios(model, val, gap)
            print(f"step {step}: loss {float(loss.detach()):.4f}, held-out predicted / true "
                  f"fx {focal:.3f}, rotation {rotation:.3f}", flush=True)


if __name__ == "__main__":
    main()
