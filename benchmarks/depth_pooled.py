"""The mean of each depth figure over the procedures of several `c2d2 eval-depth` JSONs, as
the docs' "52 held-out procedures" rows pool `data/heldout`, `data/test`,
`data/selfcal-test` and `data/selfcal-fresh` (each procedure counts once, whatever its set).

    python benchmarks/depth_pooled.py docs/swap/swap-{heldout,test,selfcal-test,selfcal-fresh}.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

FIGURES = ("mre", "dom", "fx_rel", "rpe_rotation_deg", "ate")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("evals", type=Path, nargs="+", help="eval-depth JSONs")
    args = parser.parse_args()
    rows = [row for path in args.evals
            for row in json.loads(path.read_text())["procedures"].values()]
    print(f"{len(rows)} procedures: " + ", ".join(
        f"{name} {np.mean([row[name] for row in rows]):.4f}" for name in FIGURES))


if __name__ == "__main__":
    main()
