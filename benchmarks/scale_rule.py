"""The geometric branch's scale rule and lumen ends on a finished `c2d2 eval` of simulated
procedures.

Per procedure: the whole video's scale (reconstruction.json, cm per network unit) against the
truth's, taken as the median over every 60th frame of the median ratio of true to predicted
depth. Prints the median ratio of rule to truth and the median |log| error over the
procedures, and the segments whose camera positions start at ℓ = 0 of their lumen (the last
cameras projected onto the centreline's end: geometric.json's ell_min).

    python benchmarks/scale_rule.py --eval data/eval-heldout-shipped data/eval-heldout-lumen
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from hybrid import workdir as W
from hybrid.dataset import Procedure
from hybrid.npyio import NpyRows


def true_scale(procedure: Procedure, work: Path, stride: int = 60) -> float:
    """Median over frames of the median true / predicted depth, over pixels with both."""
    predicted = NpyRows(work / W.DEPTH)
    ratios = []
    for i in range(0, procedure.num_frames, stride):
        truth, guess = procedure.depth(i), np.asarray(predicted[i], dtype=float)
        valid = (truth > 0) & (guess > 0)
        ratios.append(np.median(truth[valid] / guess[valid]))
    return float(np.median(ratios))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--eval", type=Path, nargs="+", required=True,
                        help="output folders of c2d2 eval")
    args = parser.parse_args()
    for folder in args.eval:
        procedures = dict.fromkeys(r["procedure"] for r in
                                   json.loads((folder / "eval.json").read_text())["segments"])
        errors, clamped, segments = [], 0, 0
        for source in procedures:
            work = folder / f"{Path(source).parent.name}-{Path(source).name}"
            rule = json.loads((work / W.RECONSTRUCTION).read_text())["scale_cm_per_unit"]
            errors.append(np.log(rule / true_scale(Procedure.open(Path(source)), work)))
            ells = [s["ell_min"] for s in json.loads((work / W.GEOMETRIC).read_text())["segments"]
                    if s["ell_min"] is not None]
            clamped += sum(e <= 0 for e in ells)
            segments += len(ells)
        errors = np.array(errors)
        print(f"{folder}: scale rule / truth, median {np.exp(np.median(errors)):.2f}, median "
              f"|log| {np.median(np.abs(errors)):.3f} over {len(errors)} videos; segments "
              f"starting at ℓ = 0: {clamped} of {segments}")


if __name__ == "__main__":
    main()
