"""The intrinsics head's focal length with the motion network's batch-norm running statistics
recomputed from ordinary training pairs.

The zoom term's batches pass through the motion network in training mode, so its running
statistics, which inference uses, average them in (docs/depth.md, "The shading prior on K and
the zoom term in the maps' run from scratch"). This resets those statistics, recomputes them
as a cumulative average over --batches batches of train-depth's own triplets (TripletSampler,
batch 8, read as DepthModel.loss reads them; no zoom crops, no map batches), then reads the
head on each procedure of --data as eval-depth does (the median K over all consecutive
pairs). It writes a JSON of fx_true and fx_head per procedure, which
benchmarks/focal_by_style.py reads like an eval-depth JSON:

    .venv/bin/python benchmarks/bn_statistics.py \\
        --model data/runs/maps-scratch-zoom/model.safetensors \\
        --train data/train-pink data/train-dusk --data data/heldout --out /tmp/zoom-bn.json
    .venv/bin/python benchmarks/focal_by_style.py --train data/train-pink data/train-dusk \\
        --eval /tmp/zoom-bn.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from torch import nn

from hybrid.dataset import list_procedures
from learned.frames import open_sequence
from learned.infer import infer_sequence
from learned.model import DepthModel, load_depth_model
from learned.train import TripletSampler


def recompute_statistics(model: DepthModel, sampler: TripletSampler, batches: int) -> None:
    """Reset the motion network's batch-norm running statistics and average them anew over
    `batches` batches of 8 triplets (seeded by the batch's index)."""
    for norm in model.motion.modules():
        if isinstance(norm, nn.BatchNorm2d):
            norm.reset_running_stats()
            norm.momentum = None  # a cumulative average
    model.motion.train()
    with torch.no_grad():
        for index in range(batches):
            frames, _ = sampler.batch(8, np.random.default_rng([0, index]), "cpu")
            model.triplet_motion(frames)
    model.eval()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, required=True, help="a train-depth model")
    parser.add_argument("--train", type=Path, nargs="+", required=True,
                        help="the training datasets the statistics are recomputed on")
    parser.add_argument("--data", type=Path, required=True, help="simulated procedures to read")
    parser.add_argument("--out", type=Path, required=True, help="JSON to write")
    parser.add_argument("--batches", type=int, default=150)
    args = parser.parse_args()
    model = load_depth_model(args.model)
    size = (model.config.height, model.config.width)
    training = [open_sequence(p.path, size) for root in args.train for p in list_procedures(root)]
    recompute_statistics(model, TripletSampler(training, model.config.pair_gap_s), args.batches)
    procedures = {}
    for procedure in list_procedures(args.data):
        seq = open_sequence(procedure.path, size)
        head = np.median(infer_sequence(model, seq, depth=False).K_pairs, axis=0)
        procedures[f"{args.data.name}/{procedure.path.name}"] = {"fx_true": float(seq.camera.fx),
                                                       "fx_head": float(head[0, 0])}
    args.out.write_text(json.dumps({"procedures": procedures}, indent=1))


if __name__ == "__main__":
    main()
