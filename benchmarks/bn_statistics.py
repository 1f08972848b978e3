"""The intrinsics head's focal length with the motion network's batch-norm running statistics
recomputed from ordinary training pairs.

Training leaves an exponential average of the statistics of its last few batches of every
kind (map batches and zoom crops too) in the motion network's running statistics, which
inference uses (docs/depth.md, "The shading prior on K and the zoom term in the maps' run
from scratch", "Batch norm's statistics recomputed"). This resets them and recomputes them
as `train-depth --set bn_recompute_batches=N` does at the end of a run
(learned.train.recompute_motion_statistics: a plain average over --batches batches of
train-depth's own triplets; no zoom crops, no map batches), then reads the head on each
procedure of --data as eval-depth does (the median K over all consecutive pairs). It writes
a JSON of fx_true and fx_head per procedure, which benchmarks/focal_by_style.py reads like an
eval-depth JSON, and with --save the model with the new statistics, for eval-depth:

    .venv/bin/python benchmarks/bn_statistics.py \\
        --model data/runs/maps-scratch-zoom/model.safetensors \\
        --train data/train-pink data/train-dusk --data data/heldout --out /tmp/zoom-bn.json
    .venv/bin/python benchmarks/focal_by_style.py --train data/train-pink data/train-dusk \\
        --eval /tmp/zoom-bn.json
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

from hybrid.dataset import list_procedures
from learned.checkpoint import read_checkpoint, save_checkpoint
from learned.evaluate import head_focal_lengths
from learned.frames import open_sequence
from learned.model import load_depth_model
from learned.train import TripletSampler, recompute_motion_statistics


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, required=True, help="a train-depth model")
    parser.add_argument("--train", type=Path, nargs="+", required=True,
                        help="the training datasets the statistics are recomputed on")
    parser.add_argument("--data", type=Path, nargs="+", required=True,
                        help="folders of simulated procedures to read")
    parser.add_argument("--out", type=Path, required=True, help="JSON to write")
    parser.add_argument("--batches", type=int, default=150)
    parser.add_argument("--save", type=Path, help="write the model with the new statistics")
    args = parser.parse_args()
    model = load_depth_model(args.model)
    size = (model.config.height, model.config.width)
    training = [open_sequence(p.path, size) for root in args.train for p in list_procedures(root)]
    recompute_motion_statistics(model, TripletSampler(training, model.config.pair_gap_s),
                                args.batches, model.config.seed)
    if args.save:
        config = replace(model.config, bn_recompute_batches=args.batches)
        save_checkpoint(args.save, {"depth": model.depth, "motion": model.motion},
                        config.to_dict(), read_checkpoint(args.model)[1]["step"])
    procedures = head_focal_lengths(model, args.data)
    args.out.write_text(json.dumps({"procedures": procedures}, indent=1))


if __name__ == "__main__":
    main()
