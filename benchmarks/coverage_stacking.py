"""Stage 2 trained on out-of-fold per-frame coverages (stacking), against stage 2 on the
per-frame network's own features.

Stage 2 is trained on features of procedures that stage 1 has nearly fitted, and meets noisier
ones on a new video, where its output shrinks towards the mean (docs/coverage.md, "Calibration
of the segment coverage"). Stacking trains it on inputs like those it meets: each procedure's
per-frame output from a per-frame network that never saw it. A fold model's features live in
its own space, so the stacked input is the per-frame coverage (three Δ pairs, per mirror view),
which every per-frame network gives in the same units.

For each fold K of a `c2d2 train-coverage` run, three segment networks are scored on the fold's
held-out procedures, each reading fold K's per-frame network there:
- `features`: the fold model's own segment network (on its in-sample features; as shipped);
- `cov in-sample`: a segment network on the fold model's per-frame coverages of its
  training procedures (the input changed, no stacking);
- `cov out-of-fold`: on each training procedure's coverages from the fold model that
  held it out (stacking). Those models were trained on procedures that include fold K's, so
  the cross-validation is not fully nested: fold K's labels never reach its segment network,
  but its procedures shaped the other folds' per-frame networks.
With --data, the same three segment networks of every fold are also scored on those
procedures, which no fold model saw (each fold's figures, then their mean), read through the
run's own depth model.

    python benchmarks/coverage_stacking.py --run data/runs/coverage-hops --data data/heldout \
        --out docs/coverage_stacking.json
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from hybrid.coverage import DELTA_PAIRS_CM
from learned.coverage_data import ProcedureSamples
from learned.coverage_eval import Predictions, bias_per_class, coverage_metrics, format_table
from learned.coverage_nets import CoverageModel, load_coverage_model
from learned.coverage_train import load_run, load_samples, train_segment_net

VARIANTS = ("features", "cov in-sample", "cov out-of-fold")


def frame_outputs(model: CoverageModel, samples: list[ProcedureSamples], desc: str
                  ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per procedure: per-frame coverage (N, 3), features (N, 4, F) and the per-view coverages
    (N, 4, 3) the head gives on them."""
    out = []
    for s in tqdm(samples, desc=desc):
        frame, features = model.frame_outputs(s.inputs, s.cues)
        with torch.no_grad():
            views = model.frame.coverage(torch.from_numpy(features)).numpy()
        out.append((frame, features, views))
    return out


def coverage_segment_net(model: CoverageModel, samples: list[ProcedureSamples],
                         views: list[np.ndarray]) -> CoverageModel:
    """A segment network of `model`'s design on per-view coverages (F = 3) of the samples.
    Only the returned model's `.segment` is trained and used; its frame network is unused."""
    config = replace(model.config, frame_channels=(*model.config.frame_channels[:-1],
                                                   len(DELTA_PAIRS_CM)))
    torch.manual_seed(config.seed)
    net = CoverageModel(config)
    train_segment_net(net, samples, views, lambda entry: None, progress=True)
    return net


def metrics(predictions: Predictions) -> dict:
    """`coverage_metrics`, with the segment bias per 3-class bin of the truth."""
    _, _, pred, true = predictions.arrays()
    ok = np.isfinite(true)
    return {**coverage_metrics(predictions), "segment_bias_per_class": bias_per_class(pred[ok],
                                                                                     true[ok])}


def scored(predictions: dict[str, Predictions], model: CoverageModel,
           nets: dict[str, CoverageModel], samples: list[ProcedureSamples], outputs) -> None:
    """Adds each variant's segment coverage of the samples to its predictions: the fold model's
    own segment network on the features, `nets` on the per-view coverages."""
    for s, (frame, features, views) in zip(samples, outputs, strict=True):
        starts = s.segment_starts.tolist()
        segments = {"features": model.segment_outputs(features, starts, calibrated=False),
                    **{v: n.segment_outputs(views, starts, calibrated=False)
                       for v, n in nets.items()}}
        for v in VARIANTS:
            predictions[v].add(frame, s.frame_labels, segments[v], s.segment_labels)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True)
    parser.add_argument("--data", type=Path, action="append", default=[],
                        help="procedures no fold model saw, or folders of them (repeat)")
    parser.add_argument("--out", type=Path, help="write every figure to this JSON file")
    args = parser.parse_args()
    record, config, samples, folds = load_run(args.run, progress=True)
    if not folds:
        parser.error(f"{args.run} has no cross-validation folds")
    models = [load_coverage_model(args.run / f"fold-{k}.safetensors") for k in range(len(folds))]
    fold_of = {int(i): k for k, held in enumerate(folds) for i in held}
    outputs = [frame_outputs(m, samples, f"fold {k}, all procedures")
               for k, m in enumerate(models)]
    extra = load_samples(args.data, config, Path(record["depth_checkpoint"]["path"]),
                         progress=True) if args.data else []
    cv = {v: Predictions() for v in VARIANTS}
    unseen = {v: [] for v in VARIANTS}
    for k, (model, held) in enumerate(zip(models, folds, strict=True)):
        train = [i for i in range(len(samples)) if fold_of[i] != k]
        nets = {"cov in-sample": coverage_segment_net(
                    model, [samples[i] for i in train], [outputs[k][i][2] for i in train]),
                "cov out-of-fold": coverage_segment_net(
                    model, [samples[i] for i in train], [outputs[fold_of[i]][i][2] for i in train])}

        scored(cv, model, nets, [samples[i] for i in held], [outputs[k][i] for i in held])
        if extra:
            mine = {v: Predictions() for v in VARIANTS}
            scored(mine, model, nets, extra, frame_outputs(model, extra, f"fold {k}, --data"))
            for v in VARIANTS:
                unseen[v].append(metrics(mine[v]))
                print(f"fold {k}, --data, {v}: segment MAE {unseen[v][-1]['segment_mae']:.4f}",
                      flush=True)
    results = {"cv": {v: metrics(cv[v]) for v in VARIANTS},
               "data_per_fold": unseen if extra else {}}
    print(f"{len(folds)}-fold cross-validation")
    print(format_table(results["cv"]))
    for v in VARIANTS:
        print(f"{v}: segment bias per class of the truth (below 0.4, 0.4-0.8, from 0.8): "
              + ", ".join(f"{b:+.3f}" for b in results["cv"][v]["segment_bias_per_class"]))
    if extra:
        results["data_fold_mean"] = {v: {key: np.mean([m[key] for m in unseen[v]], axis=0).tolist()
                                         for key in unseen[v][0] if unseen[v][0][key] is not None
                                         and all(m[key] is not None for m in unseen[v])}
                                     for v in VARIANTS}
        print(f"--data, mean over the {len(folds)} fold models")
        print(format_table({v: {k: results["data_fold_mean"][v].get(k) for k in unseen[v][0]}
                            for v in VARIANTS}))
        for v in VARIANTS:
            print(f"{v}: segment bias per class of the truth: " + ", ".join(
                f"{b:+.3f}" for b in results["data_fold_mean"][v]["segment_bias_per_class"]))
    if args.out:
        args.out.write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
