"""MRE and DOM of depth models read with 1, 2 and 4 mirror views (DepthModel.predict_depth
with depth_views set), and optionally of their ensemble, scored as `c2d2 eval-depth` scores
depth (24 evenly spaced frames a procedure; learned.evaluate.scored_depths), without
writing a model file for each setting (docs/depth.md, "Mirror views at inference").

The ensemble is the mean over the models of each one's log depth less its per-frame median
(each model has its own unit), read with the same views.

    python benchmarks/depth_views.py --models data/runs/maps-scratch/model.safetensors \\
        learned/checkpoints/depth-fast.safetensors \\
        --data data/heldout data/test data/selfcal-test data/selfcal-fresh --out /tmp/views.json
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from learned.evaluate import scored_depths
from learned.frames import open_sequence
from learned.metrics import dom, mre
from learned.model import load_depth_model
from learned.train import expand_inputs

VIEWS = (1, 2, 4)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=Path, nargs="+", required=True)
    parser.add_argument("--data", type=Path, nargs="+", required=True,
                        help="simulated procedures, or folders of them")
    parser.add_argument("--ensemble", action="store_true",
                        help="also score the models' ensemble at each number of views")
    parser.add_argument("--out", type=Path, required=True, help="JSON of the per-procedure figures")
    args = parser.parse_args()
    models = {str(path): load_depth_model(path) for path in args.models}
    sizes = {(m.config.height, m.config.width) for m in models.values()}
    if len(sizes) != 1:
        parser.error(f"the models take different frame sizes: {sorted(sizes)}")
    size = sizes.pop()
    procedures = expand_inputs(args.data)
    rows: dict[str, dict[str, dict[str, float]]] = {}
    for path in procedures:
        seq = open_sequence(path, size)
        truth = None
        for views in VIEWS:
            logs = {}
            for name, model in models.items():
                model.config = replace(model.config, depth_views=views)
                picks, depths = scored_depths(model, seq)
                logs[name] = np.log(depths)
            if args.ensemble:
                logs["ensemble"] = np.mean([lg - np.median(lg, axis=(1, 2), keepdims=True)
                                            for lg in logs.values()], axis=0)
            if truth is None:
                truth = [seq.depth(t) for t in picks]
            for name, lg in logs.items():
                pred = np.exp(lg)
                scores = [(mre(p, g, seq.region), dom(p, g, seq.region))
                          for p, g in zip(pred, truth, strict=True)]
                rows.setdefault(f"{name} views={views}", {})[f"{path.parent.name}/{path.name}"] = \
                    dict(zip(("mre", "dom"), map(float, np.mean(scores, axis=0)), strict=True))
    args.out.write_text(json.dumps(rows, indent=1) + "\n")
    for label, per in rows.items():
        print(f"{label}: {len(per)} procedures, MRE {np.mean([r['mre'] for r in per.values()]):.4f}"
              f", DOM {np.mean([r['dom'] for r in per.values()]):.4f}")


if __name__ == "__main__":
    main()
