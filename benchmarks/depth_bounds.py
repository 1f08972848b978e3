"""Bounds on the depth network: trained with the simulator's truth, or with structure from motion.

The shipped depth network learns by view synthesis, without labels and with learned motion
and K (issue 3). Runs of the same DepthNet (fast preset, batch, learning rate, frames; from
train-depth's random start, or from `--init`) tell where its error comes from:

- `--signal labels`: trained on the true depth, with a scale-free loss, the mean absolute
  deviation of log(pred / true) from its median over each frame's pixels (depth is known
  only up to scale, and MRE's minimising scale is a median of ratios). What the network can
  do at its size and resolution.
- `--signal true-motion`: trained by view synthesis (learned.losses.view_synthesis_loss,
  train-depth's first-stage settings) with the true motion and K in place of the motion
  network's. What the loss can do for depth once motion and K are right. The depth's unit
  stays free, as in train-depth: the true translations are multiplied by one learned factor,
  which starts at the ratio of the network's median depth to the truth's on the first batch
  (that forward pass, in training mode, moves the batch-norm statistics once before step 1)
  (the network starts near its smallest depth; in a first try without the factor the true
  translations in cm asked for depths 10 times farther at once, and the depth collapsed to
  one value).
- `--signal sfm`: the same view synthesis with the motion and K of structure from motion in
  place of the true ones: no labels and no calibration (`learned.map_triplets`; the maps by
  `c2d2 sfm-maps`). Triplets come from frames placed in one stretch whose focal
  length agrees with the procedure's other stretches (the self-calibration's consensus,
  `fusion.self_calibration`), with at least `--min-points` mapped points seen in the target.
  Each model has its own unit, so each target's translations are multiplied by the median
  ratio of the network's depth to the map's at those points (not differentiated). With
  `--sparse-weight w`, w times the scale-free loss of the network's depth at those points
  against the map's (the `labels` loss on sparse depth) is added. With `--mixed`, each step
  also adds train-depth's first-stage loss on a batch drawn as train-depth draws it, with the
  `--motion-from` network's motion and K (frozen, in eval mode), so that video the maps miss
  still teaches the depth.

The motion network is copied from `--motion-from` so that `c2d2 eval-depth` can score the
result as it scores any checkpoint (its K and trajectory figures are that network's):

    .venv/bin/python benchmarks/depth_bounds.py --signal labels --data data/train-pink \
        data/train-dusk --val data/val --out data/runs/supervised --steps 6000
    c2d2 eval-depth --data data/heldout --checkpoint data/runs/supervised/model.safetensors

Every 500 steps it logs the training loss, the validation MRE (as train-depth logs it) and
the translation factor (`depth_unit`; it stays at its start with `labels`, which does not
use it) to `metrics.jsonl` and saves `checkpoint.safetensors` in --out (a run is not
resumed); `model.safetensors` when it completes.
"""

from __future__ import annotations

import argparse
import json
import time
from functools import partial
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from learned.checkpoint import export_weights, save_checkpoint
from learned.config import DepthConfig
from learned.frames import open_sequence
from learned.losses import view_synthesis_loss
from learned.map_triplets import (
    MapBatch,
    MapTriplets,
    map_view_loss,
    relative_motion,
    stack_motions,
)
from learned.model import load_depth_model, to_tensor
from learned.nets import DepthNet
from learned.train import TripletSampler, expand_inputs, validate


def scale_free_loss(pred: torch.Tensor, true: torch.Tensor) -> torch.Tensor:
    """Mean over frames of the mean |log(pred/true) - median| over valid pixels.
    pred, true (B, H, W); true <= 0 marks no depth."""
    losses = []
    for p, t in zip(pred, true, strict=True):
        valid = t > 0
        d = torch.log(p[valid]) - torch.log(t[valid])
        losses.append((d - d.median().detach()).abs().mean())
    return torch.stack(losses).mean()


def truth_batch(sampler: TripletSampler, size: int, rng: np.random.Generator) -> dict:
    """Triplets drawn as train-depth draws them: frames (B, 3, 3, H, W) of (previous, target,
    next), their true K (B, 3, 3), motions target -> previous and target -> next as
    view_synthesis_loss takes them, and true depths (B, 3, H, W)."""
    picks = [(sampler.sequences[k], (t - gap, t, t + gap)) for k, t, gap in sampler.draw(size, rng)]
    return {"frames": to_tensor(np.stack([np.stack([seq.network_frame(i) for i in ids])
                                          for seq, ids in picks])),
            "K": torch.tensor(np.stack([seq.camera.K for seq, _ in picks]), dtype=torch.float32),
            "motions": stack_motions([[relative_motion(seq.poses, ids[1], s)
                                       for s in ids[::2]] for seq, ids in picks]),
            "depths": torch.from_numpy(np.stack([np.stack([seq.depth(i) for i in ids])
                                                 for seq, ids in picks])).float()}


def motion_loss(depth_net: DepthNet, batch: dict | MapBatch, config: DepthConfig,
                log_unit: torch.Tensor | None = None, sparse_weight: float = 0.0
                ) -> torch.Tensor:
    """train-depth's view-synthesis loss with the batch's motion and K: a MapBatch's as
    learned.map_triplets.map_view_loss takes them (plus sparse_weight times its sparse
    depth's loss), the truth's with the translations multiplied by exp(log_unit)."""
    if isinstance(batch, MapBatch):
        frames = batch.frames
        depths = depth_net(frames.flatten(0, 1)).unflatten(0, frames.shape[:2])
        terms, sparse = map_view_loss(depths, batch, config)
        return terms.total + sparse_weight * sparse
    frames = batch["frames"]
    depths = depth_net(frames.flatten(0, 1)).unflatten(0, frames.shape[:2])
    region = torch.ones(frames.shape[0], 1, *frames.shape[-2:])
    unit = log_unit.exp()
    motions = [(r, t * unit, r_back, t_back * unit) for r, t, r_back, t_back in batch["motions"]]
    return view_synthesis_loss(frames[:, 1], [frames[:, 0], frames[:, 2]], depths[:, 1],
                               [depths[:, 0], depths[:, 2]], motions, batch["K"],
                               region, config).total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--signal", choices=["labels", "true-motion", "sfm"], required=True)
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--val", type=Path, nargs="+", required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--steps", type=int, default=6000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--init", type=Path, help="start from this model's depth network")
    parser.add_argument("--maps", type=Path, help="c2d2 sfm-maps's output (sfm)")
    parser.add_argument("--min-points", type=int, default=20,
                        help="sparse depth points a target needs (sfm)")
    parser.add_argument("--sparse-weight", type=float, default=0.0, help="(sfm)")
    parser.add_argument("--mixed", action="store_true",
                        help="add train-depth's loss with the frozen motion network (sfm)")
    parser.add_argument("--motion-from", type=Path,
                        default=Path("learned/checkpoints/depth-fast.safetensors"))
    parser.add_argument("--photo-blur", type=float, default=0.0,
                        help="train-depth's photo_blur (pixels) for the view-synthesis signals")
    args = parser.parse_args()
    if args.signal != "sfm" and (args.maps or args.sparse_weight or args.mixed):
        parser.error("--maps, --sparse-weight and --mixed are for --signal sfm")
    model = load_depth_model(args.motion_from, "fast")
    config = DepthConfig(seed=args.seed, steps=args.steps, photo_blur=args.photo_blur)
    torch.manual_seed(config.seed)
    model.depth = DepthNet(config)  # train-depth's random start
    if args.init:
        model.depth.load_state_dict(load_depth_model(args.init, "fast").depth.state_dict())
    size = (config.height, config.width)
    sampler = TripletSampler([open_sequence(p, size) for p in expand_inputs(args.data)],
                             config.pair_gap_s)
    val = [open_sequence(p, size) for p in expand_inputs(args.val)]
    parameters = list(model.depth.parameters())
    if args.signal == "sfm":
        if args.maps is None:
            parser.error("--signal sfm needs --maps")
        triplets = MapTriplets(sampler.sequences, sampler.gaps, args.maps, args.min_points)
        if not triplets.triplets:
            parser.error(f"no triplet of frames placed in an agreeing stretch in {args.maps}")
        tqdm.write(f"{len(triplets.triplets)} triplets in agreeing stretches")
        draw, log_unit = triplets.batch, None
    else:
        draw = partial(truth_batch, sampler)
        with torch.no_grad():  # the depth's unit against the truth's, on the first batch
            first = draw(config.batch_size, np.random.default_rng([config.seed, 1]))
            log_unit = torch.log(model.depth(first["frames"][:, 1]).median()
                                 / first["depths"][:, 1].median())
        if args.signal == "true-motion":
            parameters.append(log_unit.requires_grad_())
    optimizer = torch.optim.Adam(parameters, lr=config.learning_rate)
    args.out.mkdir(parents=True, exist_ok=True)
    log = (args.out / "metrics.jsonl").open("w")
    checkpoint = args.out / "checkpoint.safetensors"  # every 500 steps (no resuming)
    started, running = time.time(), 0.0
    model.train()
    model.motion.requires_grad_(False)  # only the depth network learns
    if args.mixed:
        model.config = config  # its loss with train-depth's first-stage settings
    for step in tqdm(range(1, args.steps + 1), desc=f"depth ({args.signal})", unit="step"):
        batch = draw(config.batch_size, np.random.default_rng([config.seed, step]))
        if args.signal == "labels":
            loss = scale_free_loss(model.depth(batch["frames"][:, 1])[:, 0],
                                   batch["depths"][:, 1])
        else:
            loss = motion_loss(model.depth, batch, config, log_unit, args.sparse_weight)
        if args.mixed:
            model.motion.eval()  # frozen as at inference (validate() leaves it in train mode)
            loss = loss + model.loss(*sampler.batch(config.batch_size, np.random.default_rng(
                [config.seed, step, 1]))).total
        if not torch.isfinite(loss):
            raise FloatingPointError(f"step {step}: the loss is {float(loss)}; the last "
                                     f"checkpoint in {args.out} is kept")
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.depth.parameters(), config.grad_clip)
        optimizer.step()
        running += float(loss.detach())
        if step % 500 == 0 or step == args.steps:
            record = {"step": step, "loss": running / (step % 500 or 500),
                      **({} if log_unit is None else {"depth_unit": float(log_unit.exp())}),
                      "val_mre": validate(model, val)["val_mre"],
                      "seconds": round(time.time() - started, 1)}
            running = 0.0
            log.write(json.dumps(record) + "\n")
            log.flush()
            tqdm.write(json.dumps(record))
            save_checkpoint(checkpoint, {"depth": model.depth, "motion": model.motion},
                            model.config.to_dict(), step)
    log.close()
    export_weights(checkpoint, args.out / "model.safetensors")


if __name__ == "__main__":
    main()
