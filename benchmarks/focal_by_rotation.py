"""Does the intrinsics head read the focal length better on the pairs that turn?

The focal length is observable only through rotation (docs/depth.md, "Why the signal is
weak"), so the head's K on pairs where the camera turns might be nearer the truth than its
median over all consecutive pairs, which `c2d2 depth` writes. For each folder of simulated
procedures this prints the mean relative fx error of the median over all pairs and over the
pairs whose rotation (the motion network's own estimate, gap 1) lies in the top 50 / 25 / 10 /
3% of the procedure's, the mean correlation of the per-pair fx with that rotation, and how the
head's fx follows the true one across procedures (correlation, slope, means). Last, the error
of one constant fx for every procedure, the mean true fx of the other folders (with two or
more): what a head that read nothing of the camera would score.

    python benchmarks/focal_by_rotation.py --data data/heldout data/heldout2
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from hybrid.dataset import list_procedures
from learned.checkpoints import SHIPPED_DEPTH
from learned.frames import open_sequence
from learned.infer import infer_sequence
from learned.model import load_depth_model

TOP = (0.5, 0.25, 0.1, 0.03)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--model", type=Path, default=SHIPPED_DEPTH)
    args = parser.parse_args()
    model = load_depth_model(args.model)
    size = (model.config.height, model.config.width)
    truth, head = {}, {}
    for folder in args.data:
        errors, correlations, truth[folder], head[folder] = [], [], [], []
        for procedure in list_procedures(folder):
            seq = open_sequence(procedure.path, size)
            result = infer_sequence(model, seq, depth=False)
            fx, true = result.K_pairs[:, 0, 0], seq.camera.fx
            angle = Rotation.from_matrix(result.relative[1][:, :3, :3]).magnitude()
            picks = [np.median(fx)] + [np.median(fx[angle >= np.quantile(angle, 1 - q)])
                                       for q in TOP]
            errors.append(np.abs(np.array(picks) - true) / true)
            correlations.append(np.corrcoef(fx, angle)[0, 1])
            truth[folder].append(true)
            head[folder].append(picks[0])
        t, h = np.array(truth[folder]), np.array(head[folder])
        mean = np.mean(errors, axis=0)
        print(f"{folder} ({len(t)} procedures): fx error, median over all pairs {mean[0]:.1%}; "
              + ", ".join(f"top {q:.0%} by rotation {e:.1%}" for q, e in zip(TOP, mean[1:],
                                                                             strict=True)))
        print(f"    per-pair fx against rotation: mean correlation {np.mean(correlations):+.3f}; "
              f"head against true fx: correlation {np.corrcoef(t, h)[0, 1]:.2f}, slope "
              f"{np.polyfit(t, h, 1)[0]:.2f}, mean {h.mean():.1f} against {t.mean():.1f} px")
    if len(args.data) < 2:
        return
    for folder in args.data:
        others = np.concatenate([truth[f] for f in args.data if f != folder])
        t = np.array(truth[folder])
        print(f"{folder}: one fx for all, {others.mean():.1f} px (the other folders' mean "
              f"true fx): error {np.mean(np.abs(others.mean() - t) / t):.1%}")


if __name__ == "__main__":
    main()
