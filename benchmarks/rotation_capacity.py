"""Can the motion network learn the rotation at all? Trained with the truth as its target.

A fresh MotionNet (of the fast preset, or with `--set` changes such as a wider encoder; or a
trained checkpoint's with `--init`) is trained on simulated procedures with the true motion
between triplet frames as its target (the rotation's L1, radians, summed over the axes, as
`train-depth --maps` pulls it; plus 1 - cos of the translations' angle), no view synthesis.
It prints the rotation's L1 distance from the truth (degrees) and the slope of the predicted
on the true rotation about each camera axis, on fixed triplets of the held-out procedures and
of the training ones (whether it fits them at all), beside the distance of a network that
never turns; first for the motion networks of trained depth checkpoints given with `--model`.
If a network trained on the truth stays far from it, the motion network, not its training
signal, holds the rotation back. `--correlation` trains instead a network that correlates
the two frames' features over shifts (CorrelationMotion below), to see whether such a
network reads the rotation better. A diagnostic: training on true poses is not a recipe.

    python benchmarks/rotation_capacity.py --data data/train-pink data/train-dusk \
        --val data/val data/test --steps 1500 --model learned/checkpoints/depth-fast.safetensors
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from tqdm import tqdm

from learned.config import DEPTH_PRESETS, parse_overrides
from learned.frames import FrameSequence, open_sequence
from learned.map_triplets import relative_motion
from learned.model import DepthModel, load_depth_model, to_tensor
from learned.nets import ResNetEncoder
from learned.train import TripletSampler, expand_inputs


class CorrelationMotion(nn.Module):
    """A motion network that compares the two frames' features rather than stacking their
    pixels: one encoder shared by both frames (the fast motion encoder's first two stages,
    stride 4),
    their correlation over shifts of up to `reach` feature pixels each way (±16 image pixels
    at reach 4), with the pixel's place in the image beside it, then strided convolutions and
    a mean to the 6-DoF motion (scaled as MotionNet's). Its K is a constant: this benchmark
    scores the rotation only."""

    def __init__(self, channels: tuple[int, ...], reach: int = 4):
        super().__init__()
        self.reach = reach
        self.encoder = ResNetEncoder(3, channels[:2], (1,))
        shifts = (2 * reach + 1) ** 2
        layers, width = [], shifts + 2
        for out in (64, 96, 128):
            layers += [nn.Conv2d(width, out, 3, 2, 1), nn.BatchNorm2d(out), nn.ReLU(inplace=True)]
            width = out
        self.head = nn.Sequential(*layers)
        self.motion = nn.Conv2d(width, 6, 1)
        self.rotation_scale = nn.Parameter(torch.tensor(0.01))
        self.translation_scale = nn.Parameter(torch.tensor(0.01))

    def forward(self, pair: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        a, b = (self.encoder((frame - 0.45) / 0.225)[-1] for frame in pair.split(3, dim=1))
        a, b = F.normalize(a, dim=1), F.normalize(b, dim=1)
        r = self.reach
        padded = F.pad(b, (r, r, r, r))
        height, width = a.shape[-2:]
        volume = torch.stack([(a * padded[..., dy:dy + height, dx:dx + width]).sum(1)
                              for dy in range(2 * r + 1) for dx in range(2 * r + 1)], 1)
        y, x = torch.meshgrid(torch.linspace(-1, 1, height), torch.linspace(-1, 1, width),
                              indexing="ij")
        place = torch.stack([x, y]).expand(len(pair), 2, height, width)
        motion = self.motion(self.head(torch.cat([volume, place], 1)).mean((2, 3), keepdim=True))
        motion = motion.flatten(1)
        K = torch.eye(3).expand(len(pair), 3, 3)
        return motion[:, :3] * self.rotation_scale, motion[:, 3:] * self.translation_scale, K


def pairs(sampler: TripletSampler, drawn: list[tuple[int, int, int]]
          ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Target frames, source frames (both (2B, 3, H, W)) and the true motion target -> source
    (2B, 6: axis-angle, translation) of each triplet's two pairs."""
    targets, sources, motions = [], [], []
    for k, t, gap in drawn:
        seq = sampler.sequences[k]
        for s in (t - gap, t + gap):
            targets.append(seq.frame(t))
            sources.append(seq.frame(s))
            rotation, translation = relative_motion(seq.poses, t, s)[:2]
            motions.append(torch.cat([rotation[0], translation[0]]))
    return to_tensor(np.stack(targets)), to_tensor(np.stack(sources)), torch.stack(motions)


def motion_loss(model: DepthModel, target: torch.Tensor, source: torch.Tensor,
                truth: torch.Tensor) -> torch.Tensor:
    rotation, translation = model.pair_motion(target, source)[:2]
    return ((rotation - truth[:, :3]).abs().sum(1).mean()
            + (1 - F.cosine_similarity(translation, truth[:, 3:], dim=1)).mean())


def report(label: str, model: DepthModel, sets: dict[str, list[tuple[torch.Tensor, ...]]]
           ) -> None:
    """Per set of pairs: the rotation's L1 from the truth (degrees) and per-axis slopes."""
    model.eval()
    parts = []
    for name, pairs_of_set in sets.items():
        with torch.no_grad():
            predicted = torch.cat([model.pair_motion(t, s)[0] for t, s, _ in pairs_of_set])
        true = torch.cat([m[:, :3] for *_, m in pairs_of_set]).numpy()
        predicted = predicted.numpy()
        distance = np.degrees(np.abs(predicted - true).sum(1).mean())
        slopes = [float(p @ q / (q @ q)) for p, q in zip(predicted.T, true.T, strict=True)]
        parts.append(f"{name} {distance:.2f}° (slope x / y / z {slopes[0]:.2f} / "
                     f"{slopes[1]:.2f} / {slopes[2]:.2f})")
    print(f"{label}: rotation from the truth, " + "; ".join(parts), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True,
                        help="simulated training procedures (or folders of them)")
    parser.add_argument("--val", type=Path, nargs="+", required=True,
                        help="held-out simulated procedures (or folders of them)")
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--every", type=int, default=500, help="report every N steps")
    parser.add_argument("--held-out-triplets", type=int, default=160,
                        help="triplets drawn to score, from --val and from --data each")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="change the fast preset's config (e.g. motion_channels=...)")
    parser.add_argument("--model", type=Path, action="append", default=[],
                        help="also report a trained depth checkpoint's motion network")
    parser.add_argument("--init", type=Path,
                        help="start from this depth checkpoint's motion network (its preset)")
    parser.add_argument("--correlation", action="store_true",
                        help="train CorrelationMotion (this file) in place of MotionNet")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.manual_seed(args.seed)
    if args.init is not None and args.set:
        raise SystemExit("--init keeps its checkpoint's config; drop --set")
    model = DepthModel(replace(DEPTH_PRESETS["fast"], **parse_overrides(args.set))) \
        if args.init is None else load_depth_model(args.init)
    config = model.config
    size = (config.height, config.width)
    if args.correlation:
        if args.init is not None:
            raise SystemExit("--correlation trains a fresh network; drop --init")
        model.motion = CorrelationMotion(config.motion_channels)

    def sampler_of(paths: list[Path]) -> TripletSampler:
        sequences: list[FrameSequence] = [open_sequence(p, size) for p in expand_inputs(paths)]
        if any(s.poses is None for s in sequences):
            raise SystemExit("every input must be a simulated procedure with its true poses")
        return TripletSampler(sequences, config.pair_gap_s, 0)

    train, val = sampler_of(args.data), sampler_of(args.val)
    rng = np.random.default_rng([args.seed, 1])
    sets = {name: [pairs(sampler, sampler.draw(8, rng))
                   for _ in range(args.held_out_triplets // 8)]
            for name, sampler in (("held out", val), ("training", train))}
    for name, pairs_of_set in sets.items():
        still = np.degrees(torch.cat([m[:, :3] for *_, m in pairs_of_set]).abs().sum(1).mean())
        print(f"{name} rotation's own size (a network that never turns): {still:.2f}°")
    for path in args.model:
        report(str(path), load_depth_model(path), sets)
    print(f"motion network: {sum(p.numel() for p in model.motion.parameters()):,} parameters")
    optimiser = torch.optim.Adam(model.motion.parameters(), lr=config.learning_rate)
    tic, rng = time.time(), np.random.default_rng([args.seed, 2])
    for step in tqdm(range(1, args.steps + 1), desc="motion on the truth", unit="step"):
        model.train()
        loss = motion_loss(model, *pairs(train, train.draw(config.batch_size, rng)))
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        if step % args.every == 0 or step == args.steps:
            report(f"trained on the truth, step {step} ({time.time() - tic:.0f} s, last loss "
                   f"{float(loss):.4f})", model, sets)


if __name__ == "__main__":
    main()
