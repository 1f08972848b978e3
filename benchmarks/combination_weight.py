"""The report's combined coverage with the geometric value weighted more or less.

`hybrid.crosscheck.combined_coverage` averages a segment's learned and geometric coverage with
weights 1 and `geometric_weight` times the geometric value's support. For each weight this
reads the per-segment values of `c2d2 eval` runs and prints, per eval.json, the combined
coverage's MAE, its 3-class accuracy and how many segments it puts below 0.4 (the deficient
rule's threshold; in brackets, how many of those truly lie below it), with the correlation of
the branches' errors and the number of segments whose truth lies below 0.4. Then, for
each file, the weight with the lowest mean of the other files' MAEs (chosen without it) and
its MAE on the file against that of the weight 1, with the paired difference's 95% interval
bootstrapped over procedures as `c2d2 eval` does. Only segments where both branches gave a
value count (elsewhere the weight changes nothing), so its MAE at weight 1 is eval.json's
combined MAE only where the geometric branch answered everywhere. A segment without a
recorded support (eval.json written before it was) has support 1, as in the report.

    python benchmarks/combination_weight.py data/eval-heldout-cov72/eval.json \\
        data/eval-heldout2-cov72/eval.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from hybrid.crosscheck import combined_coverage
from learned.coverage_eval import CLASS_EDGES, procedure_interval, three_class


def read(path: Path) -> dict[str, np.ndarray]:
    """Per-segment columns of an eval.json, over the segments where both branches ran."""
    rows = [r for r in json.loads(path.read_text())["segments"]
            if r["learned"] is not None and r["geometric"] is not None]
    if not rows:
        raise SystemExit(f"{path}: no segment with both branches")
    columns = {key: np.array([r[key] for r in rows], dtype=float)
               for key in ("truth", "learned", "geometric")}
    columns["support"] = np.array([r.get("geometric_support") for r in rows], dtype=object)
    columns["procedure"] = np.unique([r["procedure"] for r in rows], return_inverse=True)[1]
    return columns


def combined(data: dict[str, np.ndarray], weight: float) -> np.ndarray:
    return np.array([combined_coverage(lv, gv, sv, weight) for lv, gv, sv in zip(
        data["learned"], data["geometric"], data["support"], strict=True)])


def mae(data: dict[str, np.ndarray], weight: float) -> float:
    return float(np.abs(combined(data, weight) - data["truth"]).mean())


def cell(data: dict[str, np.ndarray], weight: float) -> str:
    """MAE / 3-class accuracy / segments below the deficient threshold (of them truly)."""
    value, truth = combined(data, weight), data["truth"]
    low = value < CLASS_EDGES[0]
    return (f"{mae(data, weight):.4f} / {np.mean(three_class(value) == three_class(truth)):.2f}"
            f" / {low.sum()} ({(low & (truth < CLASS_EDGES[0])).sum()})")


def paired_interval(data: dict[str, np.ndarray], weight: float) -> list[float] | None:
    """95% interval of MAE(weight) - MAE(1), procedures resampled whole."""
    gain = np.abs(combined(data, weight) - data["truth"]) - np.abs(combined(data, 1.0)
                                                                   - data["truth"])
    groups = [gain[data["procedure"] == p] for p in range(data["procedure"].max() + 1)]
    return procedure_interval(len(groups), lambda picks: float(np.concatenate(
        [groups[p] for p in picks]).mean()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("evals", type=Path, nargs="+", help="eval.json files of `c2d2 eval`")
    parser.add_argument("--weights", type=float, nargs="+",
                        default=[0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0])
    args = parser.parse_args()
    if not all(np.isfinite(w) and w >= 0 for w in args.weights):
        parser.error(f"--weights must be finite numbers, 0 or more: {args.weights}")
    sets = {path: read(path) for path in args.evals}
    print("weight  " + "  ".join(f"{'MAE / 3-class / below 0.4':>25s}" for _ in sets))
    for weight in args.weights:
        print(f"{weight:6.2f}  " + "  ".join(f"{cell(d, weight):>25s}" for d in sets.values()))
    for path, data in sets.items():
        error_l, error_g = data["learned"] - data["truth"], data["geometric"] - data["truth"]
        print(f"{path}: {len(data['truth'])} segments, {(data['truth'] < CLASS_EDGES[0]).sum()} "
              f"truly below 0.4; correlation of the branches' errors "
              f"{np.corrcoef(error_l, error_g)[0, 1]:.2f}")
    if len(sets) < 2:
        return
    for path, data in sets.items():
        others = [d for p, d in sets.items() if p != path]
        best = min(args.weights, key=lambda w: np.mean([mae(d, w) for d in others]))
        low, high = paired_interval(data, best) or (np.nan, np.nan)
        chosen, plain = mae(data, best), mae(data, 1.0)
        print(f"{path}: weight {best:g} chosen on the others: MAE {chosen:.4f} against "
              f"{plain:.4f} at weight 1, paired {chosen - plain:+.4f} [{low:+.4f}, {high:+.4f}]")


if __name__ == "__main__":
    main()
