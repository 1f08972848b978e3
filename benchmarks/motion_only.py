"""Learn motion and intrinsics alone, with the true depth given: does K converge?

Trains a fresh MotionNet (fast preset) with the training loss on simulated procedures whose
true depth replaces the depth network, and prints the focal length it predicts on held-out
procedures relative to their true one. If K converges here, the focal drift of full training
comes from depth absorbing the error.

    .venv/bin/python benchmarks/motion_only.py --data data/train-pink data/train-dusk \
        --val data/val --steps 600
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from hybrid.dataset import Procedure, list_procedures
from learned.config import DepthConfig
from learned.model import DepthModel, to_tensor


def triplet(proc: Procedure, t: int, gap: int) -> tuple[torch.Tensor, torch.Tensor]:
    ids = (t - gap, t, t + gap)
    frames = torch.stack([to_tensor(proc.rgb(i)) for i in ids])
    depths = torch.stack([torch.from_numpy(proc.depth(i))[None].clamp(min=0.01) for i in ids])
    return frames, depths


def focal_ratio(model: DepthModel, procs: list[Procedure], gap: int) -> float:
    ratios = []
    with torch.no_grad():
        for proc in procs:
            ts = np.linspace(gap, proc.num_frames - 1, 8).astype(int)
            a = torch.stack([to_tensor(proc.rgb(t - gap)) for t in ts])
            b = torch.stack([to_tensor(proc.rgb(t)) for t in ts])
            K = model.pair_motion(a, b)[-1].mean(0)
            ratios.append(float(K[0, 0]) / proc.camera.fx)
    return float(np.mean(ratios))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--val", type=Path, required=True)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    config = DepthConfig()
    procs = [p for d in args.data for p in list_procedures(d)]
    val = list_procedures(args.val)
    gap = max(1, round(procs[0].camera.fps * config.pair_gap_s))
    torch.manual_seed(args.seed)
    model = DepthModel(config)
    optimizer = torch.optim.Adam(model.motion.parameters(), lr=config.learning_rate)
    rng = np.random.default_rng(args.seed)
    print(f"step 0: predicted fx / true fx on held-out = {focal_ratio(model, val, gap):.3f}")
    for step in range(1, args.steps + 1):
        picks = [(procs[k], int(rng.integers(gap, procs[k].num_frames - gap)))
                 for k in rng.integers(0, len(procs), config.batch_size)]
        frames, depths = map(torch.stack, zip(*(triplet(p, t, gap) for p, t in picks),
                                              strict=True))
        region = torch.ones(len(picks), 1, *frames.shape[-2:])
        loss = model.loss(frames, region, depths).total
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if step % 100 == 0:
            ratio = focal_ratio(model, val, gap)
            print(f"step {step}: loss {float(loss.detach()):.4f}, predicted fx / true fx on "
                  f"held-out = {ratio:.3f}")


if __name__ == "__main__":
    main()
