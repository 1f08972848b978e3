"""Held-out coverage errors of each fold model a `c2d2 train-coverage` run has written so far.

A run writes `fold-K.safetensors` as each fold finishes, and its pooled cross-validation only
after the last; this prints each finished fold's metrics on its own held-out procedures (the
run's data, config and fold split), so that a variant stopped after a fold or two can be
compared fold by fold with another run. Then, pooled over the finished folds, the default
(1, 4) cm pair's error by kind of frame: true coverage 0 or not, and the sign of the travel
input's z (z > 0: moving along the view, as a camera looking back during a withdrawal does);
with --training, the same over each fold's training procedures, for the fold models' fit, and
each fold model's metrics on its training procedures, their training windows (every 30
frames) standing for segments, with the bias of the windows of true coverage below 0.4.
With --data, each finished fold model's metrics on those procedures too (none of which it
saw): a second, paired comparison of two runs' fold models; --data-only skips the run's own
held-out folds (most of the time on a large run). With --by-position, the segment
error by the segment's place in its procedure (0: the first, from the start of the
withdrawal), pooled over the finished folds; with --data as well, the same of every finished
fold model on those procedures, pooled over the models.
The fold models are uncalibrated (learned.calibration).

    python benchmarks/coverage_folds.py --run data/runs/coverage-base0 --run data/runs/coverage-hops
    python benchmarks/coverage_folds.py --run data/runs/coverage-hops --fold 0 --training
    python benchmarks/coverage_folds.py --run data/runs/coverage-hops --fold 0 --data data/heldout
    python benchmarks/coverage_folds.py --run data/runs/coverage-more96-cv --data-only \
        --data data/cov-pink-more2 --data data/cov-dusk-more2
    python benchmarks/coverage_folds.py --run data/runs/coverage-hops --by-position \
        --data data/heldout
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from learned.coverage_eval import CLASS_EDGES, Predictions, coverage_metrics, format_table
from learned.coverage_nets import load_coverage_model
from learned.coverage_train import evaluate, fold_predictions, load_run, load_samples, predict


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


def by_position(segments: list[tuple[np.ndarray, np.ndarray]]) -> str:
    """Lines of count, mean truth, MAE and bias of the segments at each place in their
    procedure, from (predicted, true) segment coverages per procedure."""
    lines = []
    for place in range(max(len(true) for _, true in segments)):
        pairs = np.array([(pred[place], true[place]) for pred, true in segments
                          if place < len(true) and np.isfinite(true[place])])
        if len(pairs):
            error = pairs[:, 0] - pairs[:, 1]
            lines.append(f"  segment {place}: {len(pairs):3d} segments  mean truth "
                         f"{pairs[:, 1].mean():.3f}  MAE {np.abs(error).mean():.3f}  bias "
                         f"{error.mean():+.3f}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, action="append", required=True)
    parser.add_argument("--training", action="store_true",
                        help="also the fit to each fold's training procedures")
    parser.add_argument("--fold", type=int, action="append",
                        help="only this fold (repeatable; default: every finished fold)")
    parser.add_argument("--by-position", action="store_true",
                        help="also the segment error by the segment's place in its procedure")
    parser.add_argument("--data", type=Path, action="append", default=[],
                        help="procedures no fold model saw (repeatable)")
    parser.add_argument("--data-only", action="store_true",
                        help="with --data: skip the run's own held-out folds")
    args = parser.parse_args()
    if args.data_only and not args.data:
        parser.error("--data-only needs --data")
    if args.data_only and args.training:
        parser.error("--data-only skips the run's procedures, which --training scores")
    torch.set_num_threads(1)
    for run in args.run:
        rows, pooled, trained, placed, placed_data = {}, [], [], [], []
        record, config, samples, folds = load_run(run, with_samples=not args.data_only)
        extra = load_samples(args.data, config, Path(record["depth_checkpoint"]["path"])) \
            if args.data else []
        if args.fold and not set(args.fold) <= set(range(len(folds))):
            parser.error(f"--fold: {run} has folds 0-{len(folds) - 1}")
        for k, held in enumerate(folds):
            path = run / f"fold-{k}.safetensors"
            if not path.is_file() or (args.fold and k not in args.fold):
                continue
            model, predictions = load_coverage_model(path), Predictions()
            for i in [] if args.data_only else held:
                frame, segment = predict(model, samples[i])
                predictions.add(frame, samples[i].frame_labels, segment,
                                samples[i].segment_labels)
                pooled.append((frame[:, 1], samples[i].frame_labels[:, 1],
                               samples[i].travel[:, 2]))
                placed.append((segment, samples[i].segment_labels))
            if not args.data_only:
                rows[f"fold {k}"] = coverage_metrics(predictions)
            if extra:
                on_data = evaluate(model, extra)
                placed_data += zip(on_data.segment_pred, on_data.segment_true, strict=True)
                rows[f"fold {k}, --data"] = coverage_metrics(on_data)
            if args.training:
                training = [samples[i] for i in sorted(set(range(len(samples))) - set(held))]
                fit = fold_predictions(model, training)
                windows = Predictions(fit.predictions.frame_pred, fit.predictions.frame_true,
                                      [fit.window_pred], [fit.window_true])
                rows[f"fold {k}, training"] = coverage_metrics(windows)
                low = fit.window_true < CLASS_EDGES[0]
                if low.any():
                    rows[f"fold {k}, training"]["low_windows"] = (int(low.sum()), float(
                        (fit.window_pred - fit.window_true)[low].mean()))
                trained += [(frame[:, 1], s.frame_labels[:, 1], s.travel[:, 2]) for frame, s
                            in zip(fit.predictions.frame_pred, training, strict=True)]
        print(f"{run}:\n{format_table(rows)}")
        for name, row in rows.items():
            if "low_windows" in row:
                count, bias = row["low_windows"]
                print(f"{name}: {count} windows below 0.4, their bias {bias:+.3f}")
        if pooled and config.travel_gap:
            print("(1, 4) cm per kind of frame, the finished folds pooled:")
            print(by_kind(*(np.concatenate(column) for column in zip(*pooled, strict=True))))
        if trained:
            print("the same on the folds' training procedures:")
            print(by_kind(*(np.concatenate(column) for column in zip(*trained, strict=True))))
        if args.by_position and placed:
            print("segments by place in their procedure, the finished folds' held-out ones:")
            print(by_position(placed))
        if args.by_position and placed_data:
            print(f"the same on {', '.join(map(str, args.data))}, every finished fold "
                  f"model's, pooled:")
            print(by_position(placed_data))


if __name__ == "__main__":
    main()
