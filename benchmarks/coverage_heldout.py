"""Train the coverage networks on other procedures and test them on a run's held-out folds.

Fits both stages (the run's config) on the procedures under --train, then prints their
metrics on the procedures that fold --fold of `c2d2 train-coverage` run --run held out,
beside that fold model's; without --fold, on every fold's held-out procedures pooled, beside
the run's cross-validation. A like-for-like test of a change of training data (say, more and
shorter procedures for as many frames), which the run's own cross-validation cannot make.
The --train procedures must not include any of the run's (checked by name).

    python benchmarks/coverage_heldout.py --run data/runs/coverage-hops --fold 0 \
        --train data/cov-pink-short --train data/cov-dusk-short --count 38 \
        --out data/runs/short-fold0.safetensors
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from learned.config import CoverageConfig
from learned.coverage_eval import Predictions, coverage_metrics, format_table
from learned.coverage_nets import load_coverage_model
from learned.coverage_train import evaluate, fit_model, fold_split, load_samples
from learned.train import expand_inputs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True)
    parser.add_argument("--fold", type=int, default=None, help="one fold (default: all)")
    parser.add_argument("--train", type=Path, action="append", required=True,
                        help="a folder of simulated procedures (repeat)")
    parser.add_argument("--count", type=int, default=None,
                        help="take the first COUNT procedures of each --train folder")
    parser.add_argument("--out", type=Path, required=True, help="where to save the model")
    args = parser.parse_args()
    record = json.loads((args.run / "record.json").read_text())
    config = CoverageConfig.from_dict(record["config"])
    depth = Path(record["depth_checkpoint"]["path"])
    samples = load_samples([Path(p) for p in record["data"]], config, depth, progress=True)
    folds = fold_split(len(samples), config.folds, config.seed)
    chosen = range(len(folds)) if args.fold is None else [args.fold]
    folders = [expand_inputs([folder])[:args.count] for folder in args.train]
    train = load_samples([p for paths in folders for p in paths], config, depth, progress=True)
    clash = {s.name for s in train} & {s.name for s in samples}
    if clash:
        raise SystemExit(f"error: --train holds held-out procedures: {sorted(clash)}")
    if args.out.is_file():
        model = load_coverage_model(args.out)
    else:
        tic = time.time()
        model = fit_model(train, config, lambda entry: None, progress=True)
        model.save(args.out)
        print(f"fitted on {len(train)} procedures ({sum(len(s.inputs) for s in train)} "
              f"frames) in {time.time() - tic:.0f} s")
    ours, theirs = Predictions(), Predictions()
    for k in chosen:
        held = [samples[i] for i in folds[k]]
        evaluate(load_coverage_model(args.run / f"fold-{k}.safetensors"), held, theirs)
        evaluate(model, held, ours)
    which = "all folds" if args.fold is None else f"fold {args.fold}"
    print(format_table({f"{args.run.name}, {which}": coverage_metrics(theirs),
                        f"{args.out.stem}, {which}": coverage_metrics(ours)}))


if __name__ == "__main__":
    main()
