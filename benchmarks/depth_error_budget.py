"""What a depth model's MRE and DOM are made of, on simulated procedures.

For the frames `c2d2 eval-depth` scores (24 per procedure, evenly spaced), per procedure and
pooled:
  - MRE, and MRE after the best power of the prediction per frame (pred^p, p searched from
    0.5 to 3): what is left once the depth map's compression is undone;
  - DOM, and its error split by how far apart the two pixels' true depths are (ratio of the
    larger to the smaller): the share of the sampled pairs in each band, the share of them
    ordered right, and what the band adds to 1 - DOM.

    .venv/bin/python benchmarks/depth_error_budget.py \
        --model learned/checkpoints/depth-fast.safetensors --data data/test data/val
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from learned.evaluate import scored_depths
from learned.frames import open_sequence
from learned.metrics import mre, order_agreement
from learned.model import load_depth_model
from learned.train import expand_inputs

POWERS = np.arange(0.5, 3.001, 0.05)
RATIO_EDGES = (1.0, 1.02, 1.05, 1.1, 1.25, 1.5, 2.0, np.inf)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--frames", type=int, default=24, help="frames per procedure")
    args = parser.parse_args()
    model = load_depth_model(args.model)  # in eval mode
    size = (model.config.height, model.config.width)
    ratios, agreements, plain, powered, best = [], [], [], [], []
    for path in expand_inputs(args.data):
        seq = open_sequence(path, size)
        picks, depths = scored_depths(model, seq, args.frames)
        rows = []
        for pred, t in zip(depths.astype(np.float64), picks, strict=True):
            gt = seq.depth(int(t))
            errors = [mre(pred ** p, gt, seq.region) for p in POWERS]
            ratio, agree = order_agreement(pred, gt, seq.region)
            ratios.append(ratio)
            agreements.append(agree)
            rows.append((mre(pred, gt, seq.region), min(errors), POWERS[int(np.argmin(errors))],
                         agree.mean()))
        rows = np.array(rows)
        plain += list(rows[:, 0])
        powered += list(rows[:, 1])
        best += list(rows[:, 2])
        print(f"{seq.name}: MRE {rows[:, 0].mean():.3f}, at the best power {rows[:, 1].mean():.3f} "
              f"(median power {np.median(rows[:, 2]):.2f}), DOM {rows[:, 3].mean():.3f}")
    print(f"all: MRE {np.mean(plain):.3f}, at the best power per frame {np.mean(powered):.3f} "
          f"(median power {np.median(best):.2f}; {np.isin(best, POWERS[[0, -1]]).sum()} of "
          f"{len(best)} frames at an end of the searched powers)")
    ratio, agree = np.concatenate(ratios), np.concatenate(agreements)
    print(f"DOM (pooled pairs) {agree.mean():.3f}; by true depth ratio of the pair:")
    for lo, hi in zip(RATIO_EDGES[:-1], RATIO_EDGES[1:], strict=True):
        band = (ratio >= lo) & (ratio < hi)
        if band.any():
            print(f"  {lo:.2f}-{hi:.2f}: share {band.mean():.3f}, ordered right "
                  f"{agree[band].mean():.3f}, adds {(~agree[band]).sum() / agree.size:.4f} "
                  "to 1 - DOM")


if __name__ == "__main__":
    main()
