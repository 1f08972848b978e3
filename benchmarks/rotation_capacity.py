"""Can the motion network learn the rotation at all? Trained with the truth as its target.

A fresh MotionNet (of the fast preset, or with `--set` changes such as a wider encoder; or a
trained checkpoint's with `--init`) is trained on simulated procedures with the true motion
between triplet frames as its target (the rotation's L1, radians, summed over the axes, as
`train-depth --maps` pulls it; plus 1 - cos of the translations' angle), no view synthesis.
It prints the rotation's L1 distance from the truth (degrees) and the slope of the predicted
on the true rotation about each camera axis, on fixed triplets of the held-out procedures and
of the training ones, beside the distance of a network that never turns; first for the
motion networks of trained depth checkpoints given with `--model`. A network that stays far
from the truth even when trained on it is held back by its design or its training (rate,
batch, steps), not by its training signal. `--memorise` trains on the scored training
triplets themselves, to see whether it can fit them at all; `--mirror` mirrors the training
pairs at random, to see whether it then learns a rule rather than the procedures. `--set
motion_net=correlation` trains the network that correlates the two frames' features over
shifts (`learned.nets.PairCorrelation`), to see whether it reads the rotation better. A
diagnostic: training on true poses is not a recipe.

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
from tqdm import tqdm

from learned.config import DEPTH_PRESETS, parse_overrides
from learned.frames import FrameSequence, open_sequence
from learned.map_triplets import relative_motion
from learned.model import DepthModel, load_depth_model, to_tensor
from learned.train import TripletSampler, expand_inputs, mirror_flips, mirror_images


def pairs(sampler: TripletSampler, drawn: list[tuple[int, int, int]]
          ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Target frames, source frames (both (2B, 3, H, W)) and the true motion target -> source
    (2B, 6: axis-angle, translation) of each triplet's two pairs."""
    targets, sources, motions = [], [], []
    for k, t, gap in drawn:
        seq = sampler.sequences[k]
        target = seq.network_frame(t)
        for s in (t - gap, t + gap):
            targets.append(target)
            sources.append(seq.network_frame(s))
            rotation, translation = relative_motion(seq.poses, t, s)[:2]
            motions.append(torch.cat([rotation[0], translation[0]]))
    return to_tensor(np.stack(targets)), to_tensor(np.stack(sources)), torch.stack(motions)


# Mirroring the image left-right (x -> -x) maps an axis-angle rotation (x, y, z) to
# (x, -y, -z) and a translation to (-x, y, z); up-down (y -> -y) maps them to (-x, y, -z)
# and (x, -y, z).
MIRROR_SIGNS = torch.tensor([[1.0, -1, -1, -1, 1, 1], [-1.0, 1, -1, 1, -1, 1]])


def mirrored_pairs(target: torch.Tensor, source: torch.Tensor, truth: torch.Tensor,
                   rng: np.random.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each pair mirrored left-right and up-down, each with chance 1/2, its motion with it
    (each pair drawn alone, where `train-depth --set mirror=true` mirrors a whole triplet; the
    flips come from the batches' generator, so a `--mirror` run also draws other batches)."""
    flips = mirror_flips(len(target), rng)
    for axis, signs in enumerate(MIRROR_SIGNS):
        truth = torch.where(flips[:, axis, None], truth * signs, truth)
    return mirror_images(target, flips), mirror_images(source, flips), truth


def motion_loss(model: DepthModel, target: torch.Tensor, source: torch.Tensor,
                truth: torch.Tensor) -> torch.Tensor:
    rotation, translation = model.pair_motion(target, source)[:2]
    return ((rotation - truth[:, :3]).abs().sum(1).mean()
            + (1 - F.cosine_similarity(translation, truth[:, 3:], dim=1)).mean())


def true_rotations(pairs_of_set: list[tuple[torch.Tensor, ...]]) -> np.ndarray:
    """(N, 3) axis-angle rotations of a set's pairs, as `pairs` gives them."""
    return torch.cat([m[:, :3] for *_, m in pairs_of_set]).numpy()


def report(label: str, model: DepthModel, sets: dict[str, list[tuple[torch.Tensor, ...]]]
           ) -> None:
    """Per set of pairs: the rotation's L1 from the truth (degrees) and per-axis slopes."""
    model.eval()
    parts = []
    for name, pairs_of_set in sets.items():
        with torch.no_grad():
            predicted = torch.cat([model.pair_motion(t, s)[0] for t, s, _ in pairs_of_set])
        true = true_rotations(pairs_of_set)
        predicted = predicted.numpy()
        distance = np.degrees(np.abs(predicted - true).sum(1).mean())
        slopes = [float(p @ q / (q @ q)) for p, q in zip(predicted.T, true.T, strict=True)]
        parts.append(f"{name} {distance:.2f}° (slope x / y / z {slopes[0]:.2f} / "
                     f"{slopes[1]:.2f} / {slopes[2]:.2f})")
    scale = float(model.motion.rotation_scale)
    print(f"{label}: rotation from the truth, " + "; ".join(parts)
          + f"; rotation scale {scale:.4f}", flush=True)


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
    parser.add_argument("--memorise", action="store_true",
                        help="train on the scored training triplets themselves, in batches of "
                             "8: can the network fit them at all?")
    parser.add_argument("--mirror", action="store_true",
                        help="mirror each training pair left-right and up-down at random, "
                             "its true motion with it")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.manual_seed(args.seed)
    if args.init is not None and args.set:
        raise SystemExit("--init keeps its checkpoint's config; drop --set")
    model = DepthModel(replace(DEPTH_PRESETS["fast"], **parse_overrides(args.set))) \
        if args.init is None else load_depth_model(args.init)
    config = model.config
    size = (config.height, config.width)

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
        still = np.degrees(np.abs(true_rotations(pairs_of_set)).sum(1).mean())
        print(f"{name} rotation's own size (a network that never turns): {still:.2f}°")
    for path in args.model:
        report(str(path), load_depth_model(path), sets)
    print(f"motion network: {sum(p.numel() for p in model.motion.parameters()):,} parameters")
    optimiser = torch.optim.Adam(model.motion.parameters(), lr=config.learning_rate)
    tic, rng = time.time(), np.random.default_rng([args.seed, 2])
    for step in tqdm(range(1, args.steps + 1), desc="motion on the truth", unit="step"):
        model.train()
        drawn = sets["training"][rng.integers(len(sets["training"]))] if args.memorise \
            else pairs(train, train.draw(config.batch_size, rng))
        if args.mirror:
            drawn = mirrored_pairs(*drawn, rng)
        loss = motion_loss(model, *drawn)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        if step % args.every == 0 or step == args.steps:
            report(f"trained on the truth, step {step} ({time.time() - tic:.0f} s, last loss "
                   f"{loss.item():.4f})", model, sets)


if __name__ == "__main__":
    main()
