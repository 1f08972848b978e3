"""Calibration of the per-segment coverage: a monotone map from the network's output to
coverage, fitted on cross-validated (out-of-fold) predictions.

Stage 2 trains on the features of procedures that stage 1 has fitted closely, and sees noisier
features on a new procedure; its outputs there shrink towards the mean (segments of low
coverage come out too high, docs/coverage.md). A centred isotonic regression of the true
coverage on the network's output over held-out windows undoes part of that: the isotonic
regression (scipy), then one knot per block of equal fitted values, at the block's mean output,
joined by straight lines (Oron and Flournoy 2017), so that the map has no flat steps between
the first and the last block's mean output (a step across a class edge would send a whole
range of outputs to one side of it); below the first and above the last it is flat. The map
is kept as a table of its values at evenly spaced outputs in [0, 1], read by linear
interpolation.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from scipy.optimize import isotonic_regression

from hybrid.types import InputError

KNOTS = 101
"""Points of the calibration table (outputs 0, 0.01, ..., 1)."""


def identity_table(knots: int = KNOTS) -> np.ndarray:
    """The table of no calibration."""
    return np.linspace(0.0, 1.0, knots)


def pooled_isotonic(pred: np.ndarray, true: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The isotonic regression of `true` on `pred` (values in [0, 1]), equal outputs pooled:
    the distinct outputs, their counts and the fitted values (with flat steps)."""
    pred, true = np.asarray(pred, dtype=np.float64), np.asarray(true, dtype=np.float64)
    if pred.shape != true.shape or pred.ndim != 1 or len(pred) < 2 or \
            not (np.isfinite(pred).all() and np.isfinite(true).all()):
        raise InputError(f"calibration needs matching finite predictions and labels (at least "
                         f"2), got {pred.shape} and {true.shape}")
    outputs, which, counts = np.unique(pred, return_inverse=True, return_counts=True)
    means = np.bincount(which, weights=true) / counts  # equal outputs: one point, their mean
    return outputs, counts, np.clip(isotonic_regression(means, weights=counts).x, 0.0, 1.0)


def fit_table(pred: np.ndarray, true: np.ndarray, knots: int = KNOTS) -> np.ndarray:
    """(knots,) non-decreasing table of the centred isotonic regression of `true` on `pred`
    (values in [0, 1])."""
    outputs, counts, fitted = pooled_isotonic(pred, true)
    blocks = np.split(np.arange(len(fitted)), np.flatnonzero(np.diff(fitted)) + 1)
    centres = [np.average(outputs[b], weights=counts[b]) for b in blocks]
    return np.interp(np.linspace(0.0, 1.0, knots), centres, [fitted[b[0]] for b in blocks])


def apply_table(table: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """The calibrated coverage (float64) of network outputs in [0, 1]: linear interpolation in
    the table; NaN stays NaN."""
    table, values = table.double(), values.double()
    position = values.nan_to_num(0.0).clamp(0.0, 1.0) * (len(table) - 1)
    low = position.floor().long().clamp(max=len(table) - 2)
    frac = position - low
    calibrated = table[low] * (1.0 - frac) + table[low + 1] * frac
    return torch.where(values.isnan(), values, calibrated)


def cross_fitted(pred_by_fold: list[np.ndarray],
                 windows_by_fold: list[tuple[np.ndarray, np.ndarray]],
                 fit: Callable[[np.ndarray, np.ndarray], np.ndarray] = fit_table
                 ) -> list[np.ndarray]:
    """Each fold's held-out segment predictions calibrated by a table (`fit`: predictions,
    labels -> KNOTS values) fitted on the other folds' held-out windows (predictions, labels),
    so that no fold is calibrated on itself."""
    out = []
    for k, pred in enumerate(pred_by_fold):
        others = [w for j, w in enumerate(windows_by_fold) if j != k]
        table = fit(np.concatenate([p for p, _ in others]), np.concatenate([t for _, t in others]))
        out.append(apply_table(torch.from_numpy(table), torch.from_numpy(pred)).numpy())
    return out
