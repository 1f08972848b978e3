"""A rule on which videos to adapt to, scored: adapt (read the blend `--adapt-steps` gives)
only where the shipped model's starting photometric error is at or above --at-least, else read
the shipped model.

Reads `c2d2 eval-depth` JSONs of the same procedures: the shipped model's (all of them), and
one or more `--adapt-steps` runs (the procedures adapted to, each with its starting
`photometric_error`). Prints per adapted procedure its error and the two models' MRE, DOM and
fx error, then over those at or above the bound and over those below it: the means, and on
how many the blend's MRE is the lower.

    python benchmarks/adapt_rule.py --shipped docs/adapt/rule/shipped-eval.json \\
        --adapted docs/adapt/rule/blended-eval.json --at-least 0.058
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

FIGURES = ("mre", "dom", "fx_rel")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shipped", type=Path, required=True)
    parser.add_argument("--adapted", type=Path, nargs="+", required=True)
    parser.add_argument("--at-least", type=float, required=True)
    args = parser.parse_args()
    shipped = json.loads(args.shipped.read_text())["procedures"]
    adapted = {name: row for path in args.adapted
               for name, row in json.loads(path.read_text())["procedures"].items()
               if row.get("adapted")}
    if missing := sorted(set(adapted) - set(shipped)):
        raise SystemExit(f"not in {args.shipped}: {', '.join(missing)}")
    print(f"{'procedure':24s} {'error':>6s}   shipped MRE / DOM / fx     blend MRE / DOM / fx")
    for name in sorted(adapted, key=lambda n: adapted[n]["photometric_error"]):
        a, s = adapted[name], shipped[name]
        print(f"{name:24s} {a['photometric_error']:6.4f}   {_row(s)}   {_row(a)}")
    for label, keep in ((f"at or above {args.at_least:g}", True),
                        (f"below {args.at_least:g}", False)):
        names = [n for n in adapted if (adapted[n]["photometric_error"] >= args.at_least) == keep]
        if not names:
            print(f"{label}: none")
            continue
        means = [{k: np.mean([rows[n][k] for n in names]) for k in FIGURES}
                 for rows in (shipped, adapted)]
        lower = sum(adapted[n]["mre"] < shipped[n]["mre"] for n in names)
        print(f"{label}: {len(names)} procedures; shipped {_row(means[0])}, blend "
              f"{_row(means[1])}; the blend's MRE lower on {lower}")


def _row(figures: dict) -> str:
    return f"{figures['mre']:.3f} / {figures['dom']:.3f} / {100 * figures['fx_rel']:4.1f}%"


if __name__ == "__main__":
    main()
