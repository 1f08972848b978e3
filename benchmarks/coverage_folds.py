"""Held-out coverage errors of each fold model a `c2d2 train-coverage` run has written so far.

A run writes `fold-K.safetensors` as each fold finishes, and its pooled cross-validation only
after the last; this prints each finished fold's metrics on its own held-out procedures (the
run's data, config and fold split), so that a variant stopped after a fold or two can be
compared fold by fold with another run. Then, pooled over the finished folds, the default
(1, 4) cm pair's error by kind of frame: true coverage 0 or not, and the sign of the travel
input's z (z > 0: moving along the view, as a camera looking back during a withdrawal does);
with --training, the same over each fold's training procedures, for the fold models' fit.

    python benchmarks/coverage_folds.py --run data/runs/coverage-base0 --run data/runs/coverage-hops
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from learned.coverage_eval import Predictions, coverage_metrics, format_table
from learned.coverage_nets import load_coverage_model
from learned.coverage_train import load_run, predict


def by_kind(pred: np.ndarray, true: np.ndarray, z: np.ndarray) -> str:
    """Lines of share, mean prediction and MAE of the (1, 4) pair per kind of frame."""
    ok = np.isfinite(true)
    pred, true, z = pred[ok], true[ok], z[ok]
    kinds = {"coverage 0, z > 0": (true == 0) & (z > 0),
             "coverage 0, z <= 0": (true == 0) & (z <= 0),
             "coverage > 0, z > 0": (true > 0) & (z > 0),
             "coverage > 0, z <= 0": (true > 0) & (z <= 0)}
    return "\n".join(f"  {name:22s} share {m.mean():.2f}  mean prediction {pred[m].mean():.3f}  "
                     f"MAE {np.abs(pred[m] - true[m]).mean():.3f}  (of the whole MAE: "
                     f"{np.abs(pred[m] - true[m]).sum() / len(true):.3f})"
                     for name, m in kinds.items() if m.any())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, action="append", required=True)
    parser.add_argument("--training", action="store_true",
                        help="also the error by kind on each fold's training procedures")
    args = parser.parse_args()
    torch.set_num_threads(1)
    for run in args.run:
        rows, pooled, trained = {}, [], []
        _, config, samples, folds = load_run(run)
        for k, held in enumerate(folds):
            path = run / f"fold-{k}.safetensors"
            if not path.is_file():
                continue
            model, predictions = load_coverage_model(path), Predictions()
            for i in held:
                frame, segment = predict(model, samples[i])
                predictions.add(frame, samples[i].frame_labels, segment,
                                samples[i].segment_labels)
                pooled.append((frame[:, 1], samples[i].frame_labels[:, 1],
                               samples[i].travel[:, 2]))
            rows[f"fold {k}"] = coverage_metrics(predictions)
            for i in sorted(set(range(len(samples))) - set(held)) if args.training else []:
                trained.append((predict(model, samples[i])[0][:, 1],
                                samples[i].frame_labels[:, 1], samples[i].travel[:, 2]))
        print(f"{run}:\n{format_table(rows)}")
        if pooled and config.travel_gap:
            print("(1, 4) cm per kind of frame, the finished folds pooled:")
            print(by_kind(*(np.concatenate(column) for column in zip(*pooled, strict=True))))
        if trained:
            print("the same on the folds' training procedures:")
            print(by_kind(*(np.concatenate(column) for column in zip(*trained, strict=True))))


if __name__ == "__main__":
    main()
