"""How much averaging a run's models helps on procedures none of them was trained on.

A `c2d2 train-coverage` run leaves five fold models (each trained on four fifths of its
procedures) and the final model (on all of them). This prints, on the --data procedures, the
metrics of each model alone, then of the mean of the fold models' predictions, and of all six:
per frame the mean of their per-frame coverages, per segment the mean of their segment
coverages (each model on its own per-frame features). Where the ensemble gains little per
frame, the per-frame error is not the spread between models (variance) but error they share.
The models as saved (the fold models uncalibrated; the final model as shipped).

With --segment-seeds N --fold K instead: fold K's per-frame network kept, N - 1 more segment
networks trained on its features of the fold's training procedures (seeds 1 .. N - 1), and
the segment MAE on the fold's held-out procedures of each (seed 0: the fold model's own) and
of their mean: how much the segment network's seed alone moves a fold's error. --fold
repeats, and the errors are also pooled over the folds and seeds. With --set FIELD=VALUE
(stage 2's training settings only) each seed, 0 included, is trained twice on the same features, as
the run was and with that setting: a change of the segment network's training, paired by
seed, beside the seeds' spread.

    python benchmarks/coverage_ensemble.py --run data/runs/coverage-hops --data data/heldout
    python benchmarks/coverage_ensemble.py --run data/runs/coverage-hops --segment-seeds 4 --fold 0
    python benchmarks/coverage_ensemble.py --run data/runs/coverage-more96-l1 --segment-seeds 1 \
        --fold 0 --fold 1 --fold 2 --fold 3 --fold 4 --set segment_loss=l1
"""

from __future__ import annotations

import argparse
import copy
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from learned.checkpoints import SHIPPED_DEPTH
from learned.config import COVERAGE_PRESETS, parse_overrides
from learned.coverage_eval import Predictions, coverage_metrics, format_table
from learned.coverage_nets import SegmentNet, load_coverage_model
from learned.coverage_train import load_run, load_samples, predict, run_samples, train_segment_net

# Stage 2's training settings: what --set may change on the fold models' own features (the
# segment network's shape and windows are the fold model's).
SEGMENT_TRAINING = ("segment_loss", "segment_epochs", "segment_batch", "segment_lr")


def segment_seeds(run: Path, fold_ids: list[int], seeds: int, overrides: dict) -> None:
    """The segment MAE of each fold in `fold_ids` under `seeds` segment networks on its
    per-frame features; with `overrides`, each seed trained both as the run was and with them."""
    record, config, _, folds = load_run(run, with_samples=False)
    if bad := [k for k in fold_ids if k not in range(len(folds))]:
        raise SystemExit(f"error: {run} has no fold {bad[0]}"
                         + (f" (folds 0-{len(folds) - 1})" if folds else ""))
    samples = run_samples(run, record, config, progress=True)
    variants = {"as run": config}
    if overrides:
        variants[", ".join(f"{k}={v}" for k, v in overrides.items())] = replace(config, **overrides)
    pooled = {name: ([], []) for name in variants}  # (prediction, truth) per fold and seed
    for fold in fold_ids:
        held = sorted(folds[fold].tolist())
        fold_model = load_coverage_model(run / f"fold-{fold}.safetensors")
        features = [fold_model.frame_outputs(s.inputs, s.cues)[1] for s in samples]
        train = [i for i in range(len(samples)) if i not in held]
        true = np.concatenate([samples[i].segment_labels for i in held])
        ok = np.isfinite(true)
        for name, variant in variants.items():
            predictions = []
            for seed in range(seeds):
                model = fold_model
                if seed or overrides:
                    model = copy.deepcopy(fold_model)
                    model.config = replace(variant, seed=seed)
                    torch.manual_seed(seed)
                    model.segment.load_state_dict(SegmentNet(model.config).state_dict())
                    train_segment_net(model, [samples[i] for i in train],
                                      [features[i] for i in train], lambda entry: None,
                                      progress=True)
                predictions.append(np.concatenate([model.segment_outputs(
                    features[i], samples[i].segment_starts.tolist(), calibrated=False)
                    for i in held])[ok])
                pooled[name][0].append(predictions[-1])
                pooled[name][1].append(true[ok])
                print(f"fold {fold}, {name}, segment seed {seed}: segment MAE "
                      f"{np.abs(predictions[-1] - true[ok]).mean():.4f}", flush=True)
            print(f"fold {fold}, {name}, mean of {seeds} segment networks: segment MAE "
                  f"{np.abs(np.mean(predictions, axis=0) - true[ok]).mean():.4f}")
    for name, (predicted, truth) in pooled.items():
        error = np.concatenate(predicted) - np.concatenate(truth)
        print(f"folds {fold_ids}, {name}, every seed pooled: segment MAE "
              f"{np.abs(error).mean():.4f}, bias {error.mean():+.4f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True)
    parser.add_argument("--data", type=Path, action="append",
                        help="simulated procedures or folders of them (repeat)")
    parser.add_argument("--depth-checkpoint", type=Path, default=SHIPPED_DEPTH)
    parser.add_argument("--segment-seeds", type=int, default=0,
                        help="segment networks per fold (with --fold; instead of --data)")
    parser.add_argument("--fold", type=int, action="append",
                        help="with --segment-seeds: this fold (repeat; default: 0)")
    parser.add_argument("--set", action="append", default=[], dest="overrides",
                        help="with --segment-seeds: train each segment network also with this "
                             f"setting, one of {', '.join(SEGMENT_TRAINING)}, e.g. "
                             "segment_loss=l1 (repeat)")
    args = parser.parse_args()
    if any(item.partition("=")[0] not in SEGMENT_TRAINING for item in args.overrides):
        parser.error(f"--set takes {', '.join(SEGMENT_TRAINING)} only: the per-frame network "
                     f"and the segment network's shape are the fold model's")
    if args.fold and not args.segment_seeds:
        parser.error("--fold needs --segment-seeds")
    if args.segment_seeds:
        try:
            overrides = parse_overrides(args.overrides, COVERAGE_PRESETS["fast"])
            replace(COVERAGE_PRESETS["fast"], **overrides)  # the values' own checks
        except ValueError as err:
            parser.error(str(err))
        return segment_seeds(args.run, sorted(set(args.fold or [0])), args.segment_seeds,
                             overrides)
    if args.overrides:
        parser.error("--set needs --segment-seeds")
    if not args.data:
        parser.error("give --data, or --segment-seeds")
    folds = sorted((p.stem for p in args.run.glob("fold-*.safetensors")),
                   key=lambda name: int(name.split("-")[1]))
    if not folds or not (args.run / "model.safetensors").is_file():
        parser.error(f"{args.run} holds no fold models or no final model.safetensors")
    names = [*folds, "model"]
    models = {n: load_coverage_model(args.run / f"{n}.safetensors") for n in names}
    samples = load_samples(args.data, models["model"].config, args.depth_checkpoint,
                           progress=True)
    outputs = {n: [predict(m, s) for s in samples] for n, m in models.items()}

    def averaged(members: list[str]) -> dict:
        predictions = Predictions()
        for i, s in enumerate(samples):
            frame, segment = (np.mean([outputs[n][i][k] for n in members], axis=0)
                              for k in (0, 1))
            predictions.add(frame, s.frame_labels, segment, s.segment_labels)
        return coverage_metrics(predictions)

    rows = {n: averaged([n]) for n in names}
    rows[f"{len(folds)} folds, mean"] = averaged(folds)
    rows[f"all {len(names)}, mean"] = averaged(names)
    print(format_table(rows))


if __name__ == "__main__":
    main()
