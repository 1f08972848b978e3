"""How accurate both branches must be for their 3-class agreement to reach a bar.

Reads the per-segment truth, learned and geometric coverage of a `c2d2 eval` run. First, what
the disagreements are: which branch's class is wrong, how many have a value within 0.05 of a
class edge, the correlation of the branches' errors and each branch's bias per class of
truth. Then it shrinks each branch's error on every segment by the same factor (truth +
factor x (branch - truth)) and prints both MAEs and the branches' 3-class agreement at each
factor. A what-if on the run's own
segments: it keeps where their truths lie (how close to a class edge) and how the two branches'
errors go together, and asks only how large the errors may be.

    .venv/bin/python benchmarks/agreement_what_if.py --eval data/eval-heldout/eval.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from learned.coverage_eval import CLASS_EDGES, bias_per_class, three_class


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval", type=Path, required=True, help="eval.json of `c2d2 eval`.")
    parser.add_argument("--factors", type=float, nargs="+",
                        default=[1.0, 0.75, 0.5, 0.4, 0.3, 0.25, 0.2, 0.1])
    args = parser.parse_args()
    segments = [s for s in json.loads(args.eval.read_text())["segments"]
                if s["learned"] is not None and s["geometric"] is not None]
    truth, learned, geometric = (np.array([s[k] for s in segments], dtype=float)
                                 for k in ("truth", "learned", "geometric"))
    print(f"{len(segments)} segments; truth per class (< 0.4, 0.4-0.8, >= 0.8): "
          f"{np.bincount(three_class(truth), minlength=3).tolist()}")
    classes = {k: three_class(v) for k, v in
               (("truth", truth), ("learned", learned), ("geometric", geometric))}
    differ = classes["learned"] != classes["geometric"]
    edge_distance = np.min([np.abs(v[:, None] - np.asarray(CLASS_EDGES)).min(1)
                            for v in (learned, geometric)], axis=0)
    right = {k: classes[k] == classes["truth"] for k in ("learned", "geometric")}
    print(f"{differ.sum()} disagreements: only the learned class wrong in "
          f"{(differ & right['geometric']).sum()}, only the geometric in "
          f"{(differ & right['learned']).sum()}, both in "
          f"{(differ & ~right['learned'] & ~right['geometric']).sum()}; "
          f"{(differ & (edge_distance <= 0.05)).sum()} with a value within 0.05 of a class edge")
    print(f"correlation of the branches' errors: "
          f"{np.corrcoef(learned - truth, geometric - truth)[0, 1]:.2f}")
    for name, values in (("learned", learned), ("geometric", geometric)):
        print(f"{name} bias per class of truth: " + ", ".join(
            f"{b:+.3f}" for b in bias_per_class(values, truth)))
    print("factor  learned MAE  geometric MAE  agreement")
    for factor in args.factors:
        a, b = truth + factor * (learned - truth), truth + factor * (geometric - truth)
        agreement = np.mean(three_class(a) == three_class(b))
        print(f"{factor:6.2f}  {np.abs(a - truth).mean():11.3f}  "
              f"{np.abs(b - truth).mean():13.3f}  {agreement:9.2f}")


if __name__ == "__main__":
    main()
