"""How sharply the training loss tells the truth from the truth spoiled, with the images
blurred before the photometric comparison (`train-depth --set photo_blur=S`), by style.

For triplets every `--every` frames of simulated procedures, the photometric term of
learned.losses.view_synthesis_loss (default config but photo_blur: brightness match,
highlights, per-pixel minimum, auto-masking) at the true depth, motion and K, and its ratio
when they are spoiled as in depth_diagnosis.py (depth^0.63 and ^0.8 about the median, focal
x0.8, rotation x0.65). Larger ratios: a loss that singles out the truth more sharply; the
increase itself (in brackets) is what the gradients of the spoiled quantity scale with.

    .venv/bin/python benchmarks/loss_blur.py --data data/val --blur 0 1 1.5 2
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from depth_diagnosis import SPOILED, loss_of, triplets

from hybrid.dataset import list_procedures
from learned.config import DepthConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--blur", type=float, nargs="+", default=[0.0, 1.5])
    parser.add_argument("--every", type=int, default=25, help="frames between target frames")
    args = parser.parse_args()
    procs = [p for d in args.data for p in list_procedures(d)]
    for style in sorted({p.style for p in procs}):
        chosen = [p for p in procs if p.style == style]
        for blur in args.blur:
            config = DepthConfig(photo_blur=blur)
            rows: dict[str, list[float]] = {"truth": [], **{k: [] for k in SPOILED}}
            for _, frames, depths, motions, K in triplets(chosen, config.pair_gap_s, args.every):
                rows["truth"].append(loss_of(frames, depths, motions, K, config)["photometric"])
                for name, spoil in SPOILED.items():
                    rows[name].append(
                        loss_of(frames, depths, motions, K, config, **spoil)["photometric"])
            base = np.mean(rows["truth"])
            print(f"{style} ({len(chosen)} procedures), photo_blur {blur:g}: truth {base:.4f}  "
                  + "  ".join(f"{k} x{np.mean(v) / base:.3f} (+{np.mean(v) - base:.5f})"
                              for k, v in rows.items() if k != "truth"), flush=True)


if __name__ == "__main__":
    torch.set_num_threads(2)
    main()
