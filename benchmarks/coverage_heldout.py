"""Train the coverage networks on other procedures and test them on a run's held-out folds.

Fits both stages (the run's config, changed by any --set) on the procedures under --train, then
prints their metrics on the procedures that fold --fold of `c2d2 train-coverage` run --run held
out, beside that fold model's; without --fold, on every fold's held-out procedures pooled,
beside the run's fold models. Both are uncalibrated (learned.calibration; the run's
`cv_metrics.json` gives them as its `uncalibrated` entry). A like-for-like test of a change of
training data (say, more and shorter procedures for as many frames), which the run's own
cross-validation cannot make.
With --fold and --plus-fold-training, the model is fitted on that fold's training procedures
as well as on --train: the fold model's data and more, a point on the learning curve. With
--data, both models are also scored on those procedures (which neither saw).
With --frame-train, more procedures train the per-frame network alone (stage 1), e.g. ones
simulated with `--frame-step 4` (docs/coverage.md, "Sparse procedures for the per-frame
network").
The --train procedures must not include any of the run's (checked by name), nor the
--frame-train ones any colon of the run, --train or --data. With --plus-fold-training the
run's own per-frame procedures (`train-coverage --frame-data`) train the new model too.

    python benchmarks/coverage_heldout.py --run data/runs/coverage-hops --fold 0 \
        --train data/cov-pink-short --train data/cov-dusk-short --count 38 \
        --out data/runs/coverage-short76.safetensors
    python benchmarks/coverage_heldout.py --run data/runs/coverage-hops --fold 0 \
        --plus-fold-training --train data/cov-pink-more --train data/cov-dusk-more \
        --data data/heldout --out data/runs/coverage-fold0-more.safetensors

The model is kept at --out, with the names of its training procedures beside it (.json), and
reused when they match.
"""

from __future__ import annotations

import argparse
import functools
import json
import time
from dataclasses import replace
from pathlib import Path

from learned.config import parse_overrides
from learned.coverage_eval import Predictions, coverage_metrics, format_table
from learned.coverage_nets import load_coverage_model
from learned.coverage_train import (
    check_no_shared_colon,
    evaluate,
    fit_model,
    load_run,
    load_samples,
    run_samples,
)
from learned.train import expand_inputs, input_name


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True)
    parser.add_argument("--fold", type=int, default=None, help="one fold (default: all)")
    parser.add_argument("--train", type=Path, action="append", default=[],
                        help="a folder of simulated procedures (repeat)")
    parser.add_argument("--frame-train", type=Path, action="append", default=[],
                        help="a folder of procedures for the per-frame network alone (repeat)")
    parser.add_argument("--count", type=int, default=None,
                        help="take the first COUNT procedures of each --train folder")
    parser.add_argument("--plus-fold-training", action="store_true",
                        help="with --fold: also fit on that fold's training procedures")
    parser.add_argument("--data", type=Path, action="append", default=[],
                        help="also score both on these procedures (repeat)")
    parser.add_argument("--out", type=Path, required=True, help="where to save the model")
    parser.add_argument("--set", action="append", default=[], metavar="K=V",
                        help="fit the new model with this CoverageConfig field changed "
                             "(repeat), e.g. frame_epochs=7; a field of its inputs (e.g. "
                             "median_normalise=false) changes them for the new model alone")
    args = parser.parse_args()
    if args.plus_fold_training and args.fold is None:
        parser.error("--plus-fold-training needs --fold")
    record, config, samples, folds = load_run(args.run, progress=True)
    try:
        fit_config = replace(config, **parse_overrides(args.set, config))
    except ValueError as err:
        parser.error(str(err))
    if args.fold is not None and not 0 <= args.fold < len(folds):
        raise SystemExit(f"error: --fold must be 0-{len(folds) - 1} for {args.run}")
    paths = [p for folder in args.train for p in expand_inputs([folder])[:args.count]]
    names = [input_name(p) for p in paths]
    if clash := sorted(set(names) & set(record["procedures"])):
        raise SystemExit(f"error: --train holds procedures of {args.run}: {clash}")
    fold_training = (sorted(set(range(len(samples))) - set(folds[args.fold].tolist()))
                     if args.plus_fold_training else [])
    names = [record["procedures"][i] for i in fold_training] + names
    if clash := sorted({input_name(p) for p in expand_inputs(args.data)}
                       & (set(names) | set(record["procedures"]))):
        raise SystemExit(f"error: --data holds procedures of {args.run} or --train: {clash}")
    # the fold model's per-frame procedures belong to its training data
    run_frames = [Path(p) for p in record.get("frame_data", [])] if args.plus_fold_training else []
    check_no_shared_colon([Path(p) for p in record["data"]] + paths + args.data,
                          run_frames + args.frame_train)
    frame_paths = expand_inputs(run_frames + args.frame_train)
    names += [f"frames only: {input_name(p)}" for p in frame_paths] + [f"--set {item}"
                                                                        for item in args.set]
    if not (paths or frame_paths or fold_training):
        parser.error("nothing to train on: give --train, --frame-train or --plus-fold-training")
    depth = Path(record["depth_checkpoint"]["path"])
    # the new model's inputs follow its own config (a --set may change them, e.g.
    # median_normalise); the run's samples serve it when nothing changed
    fit_samples = functools.cache(lambda: samples if fit_config == config
                                  else run_samples(args.run, record, fit_config, progress=True))
    sidecar = args.out.with_suffix(".json")
    if args.out.is_file():
        trained_on = json.loads(sidecar.read_text())["procedures"] if sidecar.is_file() else None
        if trained_on != names:
            raise SystemExit(f"error: {args.out} was not trained on these procedures; remove "
                             f"it or choose another --out")
        model = load_coverage_model(args.out)
    else:
        train = [fit_samples()[i] for i in fold_training] + load_samples(
            paths, fit_config, depth, progress=True)
        frames = (load_samples(frame_paths, fit_config, depth, progress=True, frames_only=True)
                  if frame_paths else [])
        tic = time.time()
        model = fit_model(train, fit_config, lambda entry: None, progress=True,
                          frame_samples=frames)
        model.depth_tag = record["depth_checkpoint"]["sha256_12"]
        model.save(args.out)
        sidecar.write_text(json.dumps({"procedures": names}, indent=1) + "\n")
        alone = (f" and {len(frames)} for the per-frame network alone "
                 f"({sum(len(s.inputs) for s in frames)} frames)" if frames else "")
        print(f"fitted on {len(train)} procedures ({sum(len(s.inputs) for s in train)} "
              f"frames){alone} in {time.time() - tic:.0f} s")
    fold_models = {k: load_coverage_model(args.run / f"fold-{k}.safetensors")
                   for k in (range(len(folds)) if args.fold is None else [args.fold])}
    ours, theirs = Predictions(), Predictions()
    for k, fold_model in fold_models.items():
        held = [samples[i] for i in folds[k]]
        evaluate(fold_model, held, theirs)
        evaluate(model, [fit_samples()[i] for i in folds[k]], ours)
    which = "all folds" if args.fold is None else f"fold {args.fold}"
    ours_name = "trained on " + " + ".join(
        part for part, given in (("--train", paths),
                                 (f"fold {args.fold}'s training", args.plus_fold_training),
                                 ("per-frame procedures", frame_paths)) if given) + "".join(
        f", {item}" for item in args.set)
    rows = {f"the run's fold models, {which}": coverage_metrics(theirs),
            f"{ours_name}, {which}": coverage_metrics(ours)}
    if args.data:
        extra = load_samples(args.data, config, depth, progress=True)
        for k, fold_model in fold_models.items():
            rows[f"fold model {k}, --data"] = coverage_metrics(evaluate(fold_model, extra))
        ours_extra = (extra if fit_config == config
                      else load_samples(args.data, fit_config, depth, progress=True))
        rows[f"{ours_name}, --data"] = coverage_metrics(evaluate(model, ours_extra))
    print(format_table(rows))


if __name__ == "__main__":
    main()
