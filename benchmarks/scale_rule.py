"""The geometric branch's scale rule and lumen ends on a finished `c2d2 eval` of simulated
procedures.

Per procedure: the whole video's scale (reconstruction.json, cm per network unit) against the
truth's, taken as the median over every 60th frame of the median ratio of true to predicted
depth. Prints the median ratio of rule to truth and the median |log| error over the
procedures, the segments whose camera positions start at ℓ = 0 of their lumen (the last
cameras projected onto the centreline's end: geometric.json's ell_min), and the median ratio
of each segment's estimated ℓ range (ell_max - ell_min) to the true one (the procedure's
coverage), by the segment's place in its video.

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
        ranges: dict[str, list[float]] = {"first": [], "middle": [], "last": []}
        for source in procedures:
            work = folder / f"{Path(source).parent.name}-{Path(source).name}"
            procedure = Procedure.open(Path(source))
            rule = json.loads((work / W.RECONSTRUCTION).read_text())["scale_cm_per_unit"]
            errors.append(np.log(rule / true_scale(procedure, work)))
            estimated = json.loads((work / W.GEOMETRIC).read_text())["segments"]
            true = procedure.coverage.segments
            for k, (guess, truth) in enumerate(zip(estimated, true, strict=True)):
                if guess["ell_min"] is None:
                    continue
                clamped += guess["ell_min"] <= 0
                segments += 1
                place = "first" if k == 0 else "last" if k == len(true) - 1 else "middle"
                ranges[place].append((guess["ell_max"] - guess["ell_min"])
                                     / (truth.ell_max - truth.ell_min))
        errors = np.array(errors)
        print(f"{folder}: scale rule / truth, median {np.exp(np.median(errors)):.2f}, median "
              f"|log| {np.median(np.abs(errors)):.3f} over {len(errors)} videos; segments "
              f"starting at ℓ = 0: {clamped} of {segments}; the segments' ℓ range, estimated "
              f"/ true, median by place in the video: " + ", ".join(
                  f"{name} {np.median(r):.2f} ({len(r)})" for name, r in ranges.items() if r))


if __name__ == "__main__":
    main()
