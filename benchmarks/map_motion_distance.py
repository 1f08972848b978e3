"""How far each depth model's motion network and K head lie from the structure-from-motion
maps, on the maps' training triplets: the terms `train-depth --maps` pulls on with
`w_map_motion` (learned.map_triplets.map_motion_errors), the same batches for every model.

Prints the maps' own rotation (its L1 size: how far a network that never turns would lie),
then per model the rotation's L1 distance (axis-angle, summed over the axes, mean over the
two pairs of a triplet, in radians and degrees), 1 - cos of the angle between the
translations, and |log| of the focal lengths' ratio. Where the inputs are simulated, the
same distances from the true motion too: the maps' own (how far the target lies from the
truth) and each model's; and whether the model's own view-synthesis loss (its depth, on the
same triplets) prefers the true rotation: the loss at its own motion and K, with the true
rotation in place of its own, with the true motion (translations at its own lengths), and
with the true K as well; and the share of pairs whose negative gradient on the rotation
points towards the truth (cosine > 0), with the median cosine.

    python benchmarks/map_motion_distance.py --data data/train-pink data/train-dusk \
        --maps data/sfm-maps --model learned/checkpoints/depth-fast.safetensors \
        --model data/runs/maps-scratch/model.safetensors
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from learned.flow import flows_to_sources
from learned.frames import open_sequence
from learned.losses import view_synthesis_loss
from learned.map_triplets import (
    MapBatch,
    MapTriplets,
    Motion,
    map_motion_errors,
    relative_motion,
    stack_motions,
)
from learned.model import DepthModel, load_depth_model
from learned.train import TripletSampler, expand_inputs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True,
                        help="the training inputs the maps were made of")
    parser.add_argument("--maps", type=Path, required=True, help="`c2d2 sfm-maps` output")
    parser.add_argument("--model", type=Path, action="append", required=True,
                        help="a depth checkpoint (repeat to compare)")
    parser.add_argument("--batches", type=int, default=25)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--min-points", type=int, default=20,
                        help="DepthConfig.map_min_points")
    args = parser.parse_args()
    torch.set_num_threads(1)
    models = [load_depth_model(path) for path in args.model]
    config = models[0].config
    size = (config.height, config.width)
    sampler = TripletSampler([open_sequence(p, size) for p in expand_inputs(args.data)],
                             config.pair_gap_s, 0)
    maps = MapTriplets(sampler.sequences, sampler.gaps, args.maps, args.min_points)
    batches = [maps.batch(args.batch_size, np.random.default_rng([args.seed, i]))
               for i in range(args.batches)]
    truths = [true_batch(maps, batch) for batch in batches]
    known = all(truth is not None for truth in truths)
    still = rotation_size(batches)
    print(f"the maps' own rotation, as far as a motion network that never turns would lie: "
          f"{still:.4f} rad ({np.degrees(still):.2f}°)")
    if known:
        errors = distances([(truth.motions, truth.K) for truth in truths], batches)
        still = rotation_size(truths)
        print(f"the true rotation's own size {still:.4f} rad ({np.degrees(still):.2f}°); the "
              f"truth from the maps: rotation {errors[0]:.4f} rad ({np.degrees(errors[0]):.2f}°)"
              f", direction {errors[1]:.4f}, focal {errors[2]:.4f}")
    for path, model in zip(args.model, models, strict=True):
        if (model.config.height, model.config.width) != size:
            raise SystemExit(f"{path}: another preset's size than {args.model[0]}")
        model.eval()
        with torch.no_grad():
            estimates = [model.triplet_motion(batch.frames) for batch in batches]
        errors = distances(estimates, batches)
        print(f"{path}: rotation {errors[0]:.4f} rad ({np.degrees(errors[0]):.2f}°), "
              f"direction {errors[1]:.4f}, focal {errors[2]:.4f}")
        if known:
            errors = distances(estimates, truths)
            print(f"    from the truth: rotation {errors[0]:.4f} rad "
                  f"({np.degrees(errors[0]):.2f}°), direction {errors[1]:.4f}, "
                  f"focal {errors[2]:.4f}")
            checks = [loss_towards_truth(model, batch, truth, estimate)
                      for batch, truth, estimate in zip(batches, truths, estimates, strict=True)]
            own, true_rotation, true_motion, true_K = np.mean([c[0] for c in checks], axis=0)
            cosines = np.concatenate([c[1] for c in checks])
            print(f"    its loss: own motion {own:.4f}, true rotation {true_rotation:.4f}, true "
                  f"motion {true_motion:.4f}, and true K {true_K:.4f}; gradient towards the "
                  f"true rotation in {(cosines > 0).mean():.0%} of pairs (median cosine "
                  f"{np.median(cosines):.2f})")


def rotation_size(batches: list[MapBatch]) -> float:
    """The mean L1 size of the batches' rotations (radians, summed over the axes)."""
    return float(np.mean([float(torch.stack([side[0].abs().sum(1).mean()
                                             for side in batch.motions]).mean())
                          for batch in batches]))


def distances(estimates: list[tuple[list[Motion], torch.Tensor]], references: list[MapBatch]
              ) -> np.ndarray:
    """Rotation, direction and focal distance (map_motion_errors) of per-batch estimates
    (motions, K) from the references' motion and K, averaged over the batches."""
    return np.mean([[float(e) for e in map_motion_errors(*estimate, reference.motions,
                                                         reference.K)]
                    for estimate, reference in zip(estimates, references, strict=True)], axis=0)


def loss_towards_truth(model: DepthModel, batch: MapBatch, truth: MapBatch,
                       estimate: tuple[list[Motion], torch.Tensor]
                       ) -> tuple[list[float], np.ndarray]:
    """The model's view-synthesis loss on the batch (its own depth) at its own motion and K,
    at the true rotation, at the true motion (translations kept at the model's lengths) and
    with the true K too; and per pair the cosine between the loss's negative gradient on the
    rotation and the way from the model's rotation to the true one. estimate: the model's
    triplet_motion of the batch."""
    frames, config = batch.frames, model.config.ordinary_view()  # the loss it trained on
    motions, K = estimate
    with torch.no_grad():
        depths = model.depth(frames.flatten(0, 1)).unflatten(0, frames.shape[:2])
    target, sources = frames[:, 1], [frames[:, 0], frames[:, 2]]
    flows = flows_to_sources(target, sources, config)

    def loss(chosen: list[Motion], intrinsics: torch.Tensor) -> torch.Tensor:
        return view_synthesis_loss(target, sources, depths[:, 1], [depths[:, 0], depths[:, 2]],
                                   chosen, intrinsics, batch.regions, config, flows).total

    def lengths_of(own: torch.Tensor, true: torch.Tensor) -> torch.Tensor:
        return true / true.norm(dim=1, keepdim=True) * own.norm(dim=1, keepdim=True)

    true_rotation = [(t[0], m[1], t[2], m[3]) for m, t in zip(motions, truth.motions, strict=True)]
    true_motion = [(t[0], lengths_of(m[1], t[1]), t[2], lengths_of(m[3], t[3]))
                   for m, t in zip(motions, truth.motions, strict=True)]
    with torch.no_grad():
        losses = [float(loss(motions, K)), float(loss(true_rotation, K)),
                  float(loss(true_motion, K)), float(loss(true_motion, truth.K))]
    leaves = [tuple(part.clone().requires_grad_(True) for part in m) for m in motions]
    loss(leaves, K).backward()
    cosines = [F.cosine_similarity(-mine[0].grad, true[0] - mine[0].detach(), dim=1)
               for mine, true in zip(leaves, truth.motions, strict=True)]
    return losses, torch.cat(cosines).numpy()


def true_batch(maps: MapTriplets, batch: MapBatch) -> MapBatch | None:
    """The batch with the true motion and K of its triplets in place of the maps', or None
    where an input has no true poses."""
    sides, Ks = [], []
    for k, t in batch.triplets:
        seq, gap = maps.sequences[k], maps.gaps[k]
        if seq.poses is None or seq.camera is None:
            return None
        sides.append([relative_motion(seq.poses, t, s) for s in (t - gap, t + gap)])
        Ks.append(seq.camera.K)
    return replace(batch, K=torch.tensor(np.stack(Ks), dtype=torch.float32),
                   motions=stack_motions(sides))


if __name__ == "__main__":
    main()
