"""Calibration of the segment coverage: the isotonic table, its interpolation, the cross-fit,
checkpoints from before it; and the coverage metrics on a hand case."""

import numpy as np
import pytest
import torch
from safetensors import safe_open
from safetensors.torch import save_file

from hybrid.types import InputError
from learned.calibration import apply_table, cross_fitted, fit_table, identity_table
from learned.config import COVERAGE_PRESETS
from learned.coverage_eval import Predictions, bias_per_class, coverage_metrics
from learned.coverage_nets import CoverageModel, load_coverage_model


def test_fit_table_recovers_a_monotone_distortion():
    # A network that reports the square root of the coverage: the table must square it.
    true = np.random.default_rng(0).random(2000)
    table = fit_table(np.sqrt(true), true)
    grid = np.linspace(0, 1, len(table))
    assert np.abs(table - grid**2).max() < 0.01
    assert np.all(np.diff(table) >= 0)


def test_fit_table_is_flat_beyond_the_outputs_seen_and_refuses_bad_input():
    table = fit_table(np.array([0.3, 0.5, 0.7]), np.array([0.1, 0.2, 0.9]))
    assert table[0] == pytest.approx(0.1) and table[-1] == pytest.approx(0.9)
    assert table[50] == pytest.approx(0.2)
    for pred, true in ((np.array([0.5]), np.array([0.5])),
                       (np.array([0.5, np.nan]), np.array([0.5, 0.5])),
                       (np.array([0.1, 0.2]), np.array([0.1, 0.2, 0.3]))):
        with pytest.raises(InputError, match="calibration"):
            fit_table(pred, true)


def test_fit_table_joins_the_centres_of_the_isotonic_blocks():
    # Isotonic: 0.1, then 0.5 and 0.3 pooled to 0.4, then 0.9; the pooled block's knot sits at
    # its mean output 0.5, so there is no flat step from 0.4 to 0.6.
    table = fit_table(np.array([0.2, 0.4, 0.6, 0.8]), np.array([0.1, 0.5, 0.3, 0.9]))
    grid = np.linspace(0, 1, len(table))
    np.testing.assert_allclose(np.interp([0.1, 0.35, 0.5, 0.65, 0.9], grid, table),
                               [0.1, 0.25, 0.4, 0.65, 0.9], atol=1e-9)


def test_apply_table_interpolates_linearly():
    table = torch.tensor([0.0, 0.2, 1.0])  # knots at outputs 0, 0.5, 1
    values = torch.tensor([0.0, 0.25, 0.5, 0.75, 1.0, 1.5, -0.5, float("nan")])
    expected = torch.tensor([0.0, 0.1, 0.2, 0.6, 1.0, 1.0, 0.0, float("nan")], dtype=torch.float64)
    assert torch.allclose(apply_table(table, values), expected, equal_nan=True)
    identity = torch.from_numpy(identity_table())  # float64, as the model holds it
    values = torch.rand(1000)
    assert (apply_table(identity, values) - values.double()).abs().max() < 1e-12


def test_cross_fit_never_calibrates_a_fold_on_itself():
    pred = np.linspace(0.05, 0.95, 19)
    # Folds 1 and 2 say the outputs are right; fold 0's windows say every window is 0.
    windows = [(pred, np.zeros_like(pred)), (pred, pred), (pred, pred)]
    calibrated = cross_fitted([pred, pred, pred], windows)
    np.testing.assert_allclose(calibrated[0], pred, atol=1e-9)  # from folds 1 and 2 only
    # Folds 1 and 2 are calibrated on fold 0's zeros and one fold's truth, tie for tie: half.
    np.testing.assert_allclose(calibrated[1], pred / 2, atol=1e-9)
    np.testing.assert_allclose(calibrated[2], pred / 2, atol=1e-9)


def test_checkpoint_from_before_the_calibration_loads_uncalibrated(tmp_path):
    model = CoverageModel(COVERAGE_PRESETS["fast"])
    path = tmp_path / "model.safetensors"
    model.save(path)
    with safe_open(str(path), "pt") as f:
        names = f.keys()
        tensors = {k: f.get_tensor(k) for k in names if k != "segment.calibration"}
        metadata = f.metadata()
    save_file(tensors, str(path), metadata=metadata)  # as saved before the calibration
    loaded = load_coverage_model(path)
    np.testing.assert_allclose(loaded.segment.calibration.numpy(), identity_table(), atol=1e-7)
    assert torch.equal(loaded.segment.fc.weight, model.segment.fc.weight)


def test_coverage_metrics_hand_case():
    # Segments: true 0.1, 0.3, 0.5, 0.9; predicted 0.2, 0.6, 0.3, 0.9.
    predictions = Predictions()
    predictions.add(np.array([[0.5, 0.5, 0.5]]), np.array([[0.4, 0.6, 0.7]]),
                    np.array([0.2, 0.6, 0.3, 0.9]), np.array([0.1, 0.3, 0.5, 0.9]))
    m = coverage_metrics(predictions)
    assert [m[f"frame_mae_{k}"] for k in ("1-3", "1-4", "1-6")] == pytest.approx([0.1, 0.1, 0.2])
    assert m["segment_mae"] == pytest.approx((0.1 + 0.3 + 0.2 + 0) / 4)
    assert m["segment_bias"] == pytest.approx((0.1 + 0.3 - 0.2 + 0) / 4)
    assert m["segment_3class_accuracy"] == pytest.approx(2 / 4)  # 0.1 and 0.9 right
    # Deficient (< 0.4): 0.1 and 0.3; flagged: 0.2 and 0.3 (the segment of true 0.5).
    assert m["deficient_recall"] == pytest.approx(1 / 2)
    assert m["deficient_precision"] == pytest.approx(1 / 2)


def test_bias_per_class_of_the_truth():
    # Truth 0.2 (class 0) read 0.3 and 0.5; truth 0.9 (class 2) read 0.8; no class-1 truth.
    bias = bias_per_class([0.3, 0.5, 0.8], [0.2, 0.2, 0.9])
    assert bias[0] == pytest.approx(0.2) and np.isnan(bias[1])
    assert bias[2] == pytest.approx(-0.1)
