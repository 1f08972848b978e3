"""A calibrated and an uncalibrated coverage model on held-out procedures, segment by segment.

For each group of `--data` folders: the segment MAE of both models, their difference with a
95% interval (learned.coverage_eval.procedure_interval, paired: both models resampled alike), and
each model's bias per class of true coverage.

    .venv/bin/python benchmarks/calibration_heldout.py --data data/heldout \
        --data data/test data/val --calibrated data/runs/coverage-cal/model.safetensors
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from learned.coverage_eval import bias_per_class, procedure_interval
from learned.coverage_nets import load_coverage_model
from learned.coverage_train import evaluate, load_samples

SHIPPED = Path("learned/checkpoints/coverage-fast.safetensors")
DEPTH = Path("learned/checkpoints/depth-fast.safetensors")


def mae_difference(errors: dict[str, list[np.ndarray]], picks: np.ndarray) -> float:
    """Calibrated minus uncalibrated segment MAE over the picked procedures' errors."""
    calibrated, uncalibrated = (np.concatenate([errors[k][i] for i in picks]).mean()
                                for k in ("calibrated", "uncalibrated"))
    return float(calibrated - uncalibrated)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", action="append", required=True,
                        help="A group of folders of simulated procedures (repeatable).")
    parser.add_argument("--calibrated", type=Path, required=True)
    parser.add_argument("--uncalibrated", type=Path, default=SHIPPED)
    parser.add_argument("--resamples", type=int, default=2000)
    args = parser.parse_args()
    models = {"calibrated": load_coverage_model(args.calibrated),
              "uncalibrated": load_coverage_model(args.uncalibrated)}
    for group in args.data:
        samples = load_samples(group, models["calibrated"].config, DEPTH)
        errors, bias = {}, {}
        for name, model in models.items():
            p = evaluate(model, samples)
            errors[name] = [np.abs(a - t) for a, t in zip(p.segment_pred, p.segment_true,
                                                         strict=True)]
            bias[name] = bias_per_class(np.concatenate(p.segment_pred),
                                        np.concatenate(p.segment_true))
        mae = {k: float(np.concatenate(v).mean()) for k, v in errors.items()}
        low, high = procedure_interval(
            len(samples), lambda picks, e=errors: mae_difference(e, picks), args.resamples)
        print(f"{' '.join(map(str, group))}: {len(samples)} procedures, "
              f"{sum(map(len, errors['calibrated']))} segments")
        print(f"  segment MAE calibrated {mae['calibrated']:.4f}, uncalibrated "
              f"{mae['uncalibrated']:.4f}, difference "
              f"{mae['calibrated'] - mae['uncalibrated']:+.4f} [{low:+.4f}, {high:+.4f}]")
        for name, values in bias.items():
            print(f"  {name} bias for true coverage < 0.4, 0.4-0.8, >= 0.8: "
                  + ", ".join(f"{b:+.3f}" for b in values))


if __name__ == "__main__":
    main()
