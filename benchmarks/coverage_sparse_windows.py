"""Stage 2 with the sparse procedures' windows too, on a fixed per-frame network.

Takes a model fitted by `coverage_heldout.py --fold K --plus-fold-training --frame-train ...`
(its per-frame network saw the sparse procedures), keeps its per-frame network and fits the
per-segment network again, for each --seed, on fold K's training windows alone and on those
plus the windows of the --frame-train procedures (`c2d2 simulate --frame-step k`): windows of
300 / k of their frames every round(30 / k), labelled with the exact coverage of the frames
they keep, their per-frame features brought to 30 fps by each --upsample (nearest frame, as
`c2d2 run` does for other frame rates, or linear between kept frames, the last three frames
of a window then blending towards the next kept frame). Prints each model's metrics on the
fold's held-out procedures and on --data (docs/coverage.md, "Sparse procedures: a
shorter stage 1, and their windows in stage 2").

    python benchmarks/coverage_sparse_windows.py --run data/runs/cov48 --fold 0 \
        --model data/runs/cov48-fold0-sparse96.safetensors \
        --frame-train data/cov-pink-sparse --frame-train data/cov-dusk-sparse \
        --data data/heldout --upsample nearest --upsample linear --seed 0 --seed 1
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from hybrid.dataset import Procedure
from learned.coverage_data import window_labels
from learned.coverage_eval import coverage_metrics, format_table
from learned.coverage_nets import CoverageModel, load_coverage_model, resample_features
from learned.coverage_train import evaluate, load_run, load_samples, train_segment_net
from learned.train import expand_inputs


def upsampled(features: np.ndarray, step: int, window: int, how: str) -> np.ndarray:
    """(N * step, ...) features of every step-th frame brought to the full frame rate: as
    `c2d2 run` resamples them (nearest frame) or linearly between kept frames."""
    if how == "nearest":
        return resample_features(features, window // step, window)
    t = np.arange(len(features) * step) / step
    i = np.minimum(t.astype(int), len(features) - 2)
    w = np.minimum(t - i, 1.0)[:, None, None]
    return ((1 - w) * features[i] + w * features[i + 1]).astype(features.dtype)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True)
    parser.add_argument("--fold", type=int, required=True)
    parser.add_argument("--model", type=Path, required=True,
                        help="whose per-frame network is kept (coverage_heldout.py --out)")
    parser.add_argument("--frame-train", type=Path, action="append", required=True,
                        help="a folder of sparse procedures (repeat)")
    parser.add_argument("--data", type=Path, action="append", default=[],
                        help="also score on these procedures (repeat)")
    parser.add_argument("--upsample", choices=("nearest", "linear"), action="append",
                        required=True, help="how the sparse features reach 30 fps (repeat)")
    parser.add_argument("--seed", type=int, action="append", required=True,
                        help="the per-segment network's seed (repeat)")
    args = parser.parse_args()
    record, config, samples, folds = load_run(args.run, progress=True)
    depth = Path(record["depth_checkpoint"]["path"])
    held = [samples[i] for i in folds[args.fold]]
    train = [samples[i] for i in sorted(set(range(len(samples))) - set(folds[args.fold]))]
    extra = load_samples(args.data, config, depth, progress=True) if args.data else []
    paths = expand_inputs(args.frame_train)
    sparse = load_samples(paths, config, depth, progress=True, frames_only=True)
    kept = load_coverage_model(args.model)
    if replace(kept.config, frame_epochs=config.frame_epochs) != config:
        raise SystemExit(f"error: {args.model} was not fitted with {args.run}'s config (up to "
                         f"the stage-1 epochs)")
    T, stride = config.segment_frames, config.segment_stride
    tic = time.time()
    steps, windowed = [], []
    for path, s in zip(tqdm(paths, desc="sparse window labels"), sparse, strict=True):
        proc = Procedure.open(path)
        step = round(config.frame_rate / proc.camera.fps)
        if T % step:
            raise SystemExit(f"error: {path}: a step of {step} frames does not divide the "
                             f"{T}-frame window")
        labels = window_labels(proc, T // step, round(stride / step))
        steps.append(step)
        windowed.append(replace(s, window_starts=labels[:, 0].astype(int) * step,
                                window_labels=labels[:, 1]))
    print(f"sparse window labels in {time.time() - tic:.0f} s")
    features = [kept.frame_outputs(s.inputs, s.cues)[1] for s in train]
    sparse_features = [kept.frame_outputs(s.inputs, s.cues)[1] for s in windowed]
    variants = [("fold windows", train, features)] + [
        (f"+ sparse windows ({how})", train + windowed,
         features + [upsampled(f, step, T, how)
                    for f, step in zip(sparse_features, steps, strict=True)])
        for how in args.upsample]
    print("training windows: fold {}, sparse {}".format(
        *(sum(int(np.isfinite(s.window_labels).sum()) for s in ss) for ss in (train, windowed))))
    rows = {}
    for seed in args.seed:
        for name, ss, ff in variants:
            torch.manual_seed(seed)
            model = CoverageModel(replace(config, seed=seed))
            model.frame.load_state_dict(kept.frame.state_dict())
            model.frame.eval()
            tic = time.time()
            train_segment_net(model, ss, ff, lambda entry: None, progress=True)
            print(f"seed {seed}, {name}: stage 2 in {time.time() - tic:.0f} s")
            rows[f"seed {seed}, {name}, fold {args.fold}"] = coverage_metrics(
                evaluate(model, held))
            if extra:
                rows[f"seed {seed}, {name}, --data"] = coverage_metrics(evaluate(model, extra))
        print(format_table(rows), flush=True)  # so far


if __name__ == "__main__":
    main()
