"""The mean of each depth figure over the procedures of several `c2d2 eval-depth` JSONs, as
the docs' "52 held-out procedures" rows pool `data/heldout`, `data/test`,
`data/selfcal-test` and `data/selfcal-fresh` (each procedure counts once, whatever its set);
with --by-style, also over each appearance style's procedures (read from the simulated
procedures the JSONs name, under --data-root).

    python benchmarks/depth_pooled.py docs/swap/swap-{heldout,test,selfcal-test,selfcal-fresh}.json
    python benchmarks/depth_pooled.py --by-style docs/sfm_depth/maps-scratch-heldout.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from hybrid.dataset import Procedure

FIGURES = ("mre", "dom", "fx_rel", "rpe_rotation_deg", "ate")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("evals", type=Path, nargs="+", help="eval-depth JSONs")
    parser.add_argument("--by-style", action="store_true",
                        help="also the means over each appearance style's procedures")
    parser.add_argument("--data-root", type=Path, default=Path("data"),
                        help="folder holding the datasets the JSONs' names refer to")
    args = parser.parse_args()
    named = [(name, row) for path in args.evals
             for name, row in json.loads(path.read_text())["procedures"].items()]
    groups = {"": [row for _, row in named]}
    if args.by_style:
        for name, row in named:
            groups.setdefault(f" ({Procedure.open(args.data_root / name).style})", []).append(row)
    for label, rows in groups.items():
        print(f"{len(rows)} procedures{label}: " + ", ".join(
            f"{name} {np.mean([row[name] for row in rows]):.4f}" for name in FIGURES))


if __name__ == "__main__":
    main()
