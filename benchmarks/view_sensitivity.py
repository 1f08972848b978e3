"""How exact must the field of view be for coverage networks that read it?

Networks trained with `field_of_view=true` see each simulated camera's field of view, which a
video does not carry. This scores such a model on simulated procedures with that input
replaced by:
- the true camera's (as trained);
- the intrinsics head's (the median K over consecutive pairs, as `c2d2 run` takes it);
- with `--self-calibration`, the focal length of `c2d2 eval-depth --self-calibrate` where at
  least `--min-agreeing` of its stretches agreed (2: the rule of `c2d2 depth
  --self-calibrate`), else the head's; or else, for those procedures, the predictions of
  `--without` (a model that does not read the field of view) or, for a model trained with
  `view_hidden`, its own with the field of view hidden; and the true field of view in place
  of the self-calibrated one (the most that rule could give);
- with `--sweep`, how exact the input must be: the true focal length off by a fixed factor
  for every procedure (a biased estimate); off by a random factor per procedure, log-normal
  with the given spreads (an unbiased but noisy estimate; the mean over `--draws` seeded
  draws); one field of view for every procedure, the mean true one of the procedures scored
  (what the input gives when it reads nothing of the camera).
For each it prints the input's mean relative focal-length error (of fx and fy; column "fx
error") over the procedures given it, the per-frame MAE of the three Δ pairs and the
per-segment MAE (calibrated, as `c2d2 eval-coverage`).

    python benchmarks/view_sensitivity.py --data data/heldout \
        --model data/runs/cov72-fold0-bf16-log-fov.safetensors [--sweep] \
        [--self-calibration docs/self_calibration/heldout-contrast.json \
         --without data/runs/cov72-fold0-bf16-log.safetensors --min-agreeing 2 3]
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from fusion.self_calibration import eval_records
from hybrid.coverage import DELTA_PAIRS_CM, pair_key
from hybrid.dataset import Procedure
from learned.checkpoints import SHIPPED_DEPTH
from learned.coverage_data import ProcedureSamples
from learned.coverage_eval import Predictions, coverage_metrics
from learned.coverage_nets import load_coverage_model
from learned.coverage_train import evaluate, load_samples
from learned.train import expand_inputs, input_name
from learned.view import VIEW_SIZE, hidden_view, known_view, view_values

FACTORS = (0.8, 0.9, 0.95, 1.05, 1.1, 1.2)
SPREADS = (0.03, 0.05, 0.1, 0.2)


def fx_error(view: np.ndarray, true: np.ndarray) -> float:
    """Mean relative focal-length error (fx and fy) of field-of-view values (log(W / 2 fx),
    log(H / 2 fy) per procedure)."""
    return float(np.mean(np.abs(np.exp(true - view) - 1)))


def self_calibrated(paths: list[Path], procedures: list[Path], head: np.ndarray,
                    min_agreeing: int) -> tuple[np.ndarray, np.ndarray]:
    """(P, 2) field-of-view values, self-calibration's K where at least `min_agreeing` of its
    stretches agreed, else the head's; (P,) bool where they did."""
    runs = eval_records(paths)
    values, agreed = head.copy(), np.zeros(len(procedures), bool)
    for k, proc in enumerate(procedures):
        name = input_name(proc)
        if name not in runs:
            raise SystemExit(f"{name}: not in the self-calibration JSONs "
                             f"{', '.join(map(str, paths))}; self-calibrate it first")
        run = runs[name]
        if run["K"] is not None and len(run["agreeing"]) >= min_agreeing:
            (height, width) = run["size"]
            values[k], agreed[k] = view_values(np.asarray(run["K"]), width, height, 1)[0], True
    return values, agreed


def pooled(each: list[Predictions]) -> Predictions:
    """Predictions on several procedures, pooled."""
    out = Predictions()
    for predictions in each:
        out.extend(predictions)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--depth-checkpoint", type=Path, default=SHIPPED_DEPTH)
    parser.add_argument("--self-calibration", type=Path, nargs="+",
                        help="JSONs of c2d2 eval-depth --self-calibrate on the procedures")
    parser.add_argument("--without", type=Path,
                        help="a model that does not read the field of view, for the procedures "
                             "whose self-calibration did not agree (besides the model itself "
                             "with the field of view hidden, if trained with view_hidden)")
    parser.add_argument("--min-agreeing", type=int, nargs="+", default=[2],
                        help="stretches that must agree for the self-calibrated K to be used "
                             "(2: the rule of c2d2 depth --self-calibrate)")
    parser.add_argument("--sweep", action="store_true",
                        help="also the fixed factors, the log-normal spreads and one field of "
                             "view for all")
    parser.add_argument("--draws", type=int, default=5)
    args = parser.parse_args()
    model = load_coverage_model(args.model)
    if model.config.field_of_view != "true":
        parser.error(f"{args.model}: trained with field_of_view "
                     f"{model.config.field_of_view!r}, not 'true'")
    paths = expand_inputs(args.data)
    samples = load_samples(paths, model.config, args.depth_checkpoint, progress=True)
    head_samples = load_samples(paths, replace(model.config, field_of_view="predicted",
                                               view_hidden=0.0),
                                args.depth_checkpoint, progress=True)
    true = np.stack([s.view[0, :VIEW_SIZE] for s in samples])
    head = np.stack([s.view[0] for s in head_samples])
    fovs = [Procedure.open(p).camera.hfov_deg for p in paths]
    print(f"{len(paths)} procedures, field of view {min(fovs):.0f}-{max(fovs):.0f} deg; "
          f"model {args.model}")
    keys = [f"frame_mae_{pair_key(p)}" for p in DELTA_PAIRS_CM]
    print(f"{'field of view input':44} {'fx error':>8}  " + "  ".join(
        f"{k.removeprefix('frame_mae_'):>7}" for k in keys) + "  segment", flush=True)

    def given(s: ProcedureSamples, values: np.ndarray | None) -> ProcedureSamples:
        """s with the field-of-view values (2,) as the model takes them, or hidden (None)."""
        if values is None:
            return replace(s, view=hidden_view(len(s.view)))
        view = np.tile(values, (len(s.view), 1)).astype(np.float32)
        return replace(s, view=known_view(view) if model.config.view_hidden else view)

    def each(view: np.ndarray) -> list[Predictions]:
        """The model's predictions on each procedure given its field-of-view values (P, 2)."""
        return [evaluate(model, [given(s, v)]) for s, v in zip(samples, view, strict=True)]

    def row(name: str, draws: list[tuple[float, list[Predictions]]]) -> None:
        """Print the input's focal-length error and the metrics of per-procedure predictions,
        each the mean over the draws."""
        metrics = [coverage_metrics(pooled(d)) for _, d in draws]
        print(f"{name:44} {np.mean([e for e, _ in draws]):8.3f}  " + "  ".join(
            f"{np.mean([m[k] for m in metrics]):7.4f}" for k in keys)
            + f"  {np.mean([m['segment_mae'] for m in metrics]):7.4f}", flush=True)

    def mixed(use: np.ndarray, chosen: list[Predictions], rest: list[Predictions]
              ) -> list[Predictions]:
        """chosen's predictions on the procedures in `use`, rest's on the others."""
        return [c if u else r for c, r, u in zip(chosen, rest, use, strict=True)]

    true_each = each(true)
    row("true", [(0.0, true_each)])
    row("intrinsics head", [(fx_error(head, true), each(head))])
    # What the procedures without an agreed self-calibration get instead of the head's.
    fallbacks = {}
    if args.without:
        other = load_coverage_model(args.without)
        if other.config.field_of_view != "none":
            parser.error(f"--without {args.without}: it reads the field of view")
        fallbacks["without"] = [evaluate(other, [s]) for s in load_samples(
            paths, other.config, args.depth_checkpoint)]
    if model.config.view_hidden:
        fallbacks["hidden"] = [evaluate(model, [given(s, None)]) for s in samples]
    for label, rest in fallbacks.items():
        row(f"{label}, all", [(np.nan, rest)])
    for least in args.min_agreeing if args.self_calibration else ():
        chosen, agreed = self_calibrated(args.self_calibration, paths, head, least)
        used = f"{agreed.sum()} with >= {least} agreeing"
        chosen_each = each(chosen)
        row(f"self-calibrated ({used}), else head", [(fx_error(chosen, true), chosen_each)])
        error = fx_error(chosen[agreed], true[agreed]) if agreed.any() else np.nan
        for label, rest in fallbacks.items():
            row(f"self-calibrated ({used}), else {label}",
                [(error, mixed(agreed, chosen_each, rest))])
            row(f"true ({used}), else {label}", [(0.0, mixed(agreed, true_each, rest))])
    if not args.sweep:
        return
    for factor in FACTORS:
        row(f"fx x {factor:g}", [(fx_error(true - np.log(factor), true),
                                   each(true - np.log(factor)))])
    rng = np.random.default_rng(0)
    for spread in SPREADS:
        draws = [true - rng.normal(0, spread, (len(true), 1)) for _ in range(args.draws)]
        row(f"log-normal {spread:g} ({args.draws} draws)",
            [(fx_error(d, true), each(d)) for d in draws])
    constant = np.tile(true.mean(axis=0), (len(true), 1))
    row("one for all (the mean)", [(fx_error(constant, true), each(constant))])

if __name__ == "__main__":
    main()
