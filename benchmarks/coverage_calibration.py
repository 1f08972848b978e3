"""Ways of calibrating the segment coverage, compared by cross-fitting on a run's folds.

For each fold of a `c2d2 train-coverage` run, its model's uncalibrated predictions on its
held-out procedures and their windows (learned.coverage_train.fold_predictions); each fold's
segments are then calibrated by a map fitted on the other folds' windows, in four ways: none,
the isotonic regression as it is (flat steps), the centred isotonic regression that
`learned.calibration` ships, and a straight line (least squares, clipped to [0, 1]). Prints
per way the segment MAE, bias, 3-class accuracy, deficient segments (true coverage < 0.4)
found and falsely flagged, and the bias of the segments below 0.4 and of those from 0.8; then
the count of windows and the shipped map, fitted on all the folds' windows, at outputs 0, 0.1,
..., 1.

    python benchmarks/coverage_calibration.py --run data/runs/coverage-cal
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from learned.calibration import KNOTS, cross_fitted, fit_table, pooled_isotonic
from learned.coverage_eval import CLASS_EDGES, three_class
from learned.coverage_nets import load_coverage_model
from learned.coverage_train import fold_predictions, load_run

GRID = np.linspace(0.0, 1.0, KNOTS)


def plain_isotonic(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """The isotonic regression read at GRID, with its flat steps."""
    outputs, _, fitted = pooled_isotonic(pred, true)
    return np.interp(GRID, outputs, fitted)


def straight_line(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    slope, offset = np.polyfit(pred, true, 1)
    return np.clip(slope * GRID + offset, 0.0, 1.0)


WAYS = {"none": lambda p, t: GRID, "isotonic": plain_isotonic, "centred isotonic": fit_table,
        "straight line": straight_line}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)
    _, _, samples, folds = load_run(args.run)
    held = [fold_predictions(load_coverage_model(args.run / f"fold-{k}.safetensors"),
                             [samples[i] for i in f], progress=True) for k, f in enumerate(folds)]
    raw = [np.concatenate(h.predictions.segment_pred) for h in held]
    true = np.concatenate([np.concatenate(h.predictions.segment_true) for h in held])
    labelled, low = np.isfinite(true), true < CLASS_EDGES[0]
    for name, fit in WAYS.items():
        pred = np.concatenate(cross_fitted(raw, [(h.window_pred, h.window_true) for h in held],
                                           fit))
        error, flagged = pred - true, pred < CLASS_EDGES[0]
        false = (flagged & ~low & labelled).sum()
        print(f"{name:17s} segment MAE {np.abs(error[labelled]).mean():.4f}  bias "
              f"{error[labelled].mean():+.4f}  3-class "
              f"{(three_class(pred) == three_class(true))[labelled].mean():.3f}  deficient "
              f"found {(flagged & low).sum()} of {low.sum()}, false {false}"
              f"  bias below 0.4 {error[low].mean():+.3f}, from 0.8 "
              f"{error[true >= CLASS_EDGES[1]].mean():+.3f}")
    windows = [np.concatenate([h.window_pred for h in held]),
               np.concatenate([h.window_true for h in held])]
    print(f"{len(windows[0])} windows; the shipped map at outputs 0, 0.1, ..., 1:",
          np.round(np.interp(np.linspace(0, 1, 11), GRID, fit_table(*windows)), 3))


if __name__ == "__main__":
    main()
