"""Does the depth network keep the true depth's scale from frame to frame, and across videos?

The per-frame coverage of a band 1-3 cm ahead depends on how far the wall is in centimetres,
which the median-normalised input of the per-frame network hides (the simulated colons' radius
varies 1.5-3.5 cm along the lumen). The `depth_scale` cue gives the network each frame's median
depth against its video's. This prints, per simulated procedure, how the log of the depth
network's per-frame median depth follows that of the simulator's: their correlation, the slope
of the fit, the spread of the true log median (how much the scale varies within a procedure),
the spread left after the best affine fit, and the mean log ratio (predicted over true: its
spread across procedures says how far the network's absolute scale drifts between videos).

Reads the predicted medians cached by `c2d2 train-coverage --set depth_scale=true` (run it
first, with the same depth model).

    .venv/bin/python benchmarks/depth_scale.py --data data/cov-pink data/cov-dusk
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from hybrid.dataset import Procedure
from learned.checkpoint import file_tag
from learned.checkpoints import SHIPPED_DEPTH
from learned.coverage_data import true_depth
from learned.coverage_nets import region_medians
from learned.train import expand_inputs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--depth-checkpoint", type=Path, default=SHIPPED_DEPTH)
    args = parser.parse_args()
    tag = file_tag(args.depth_checkpoint)
    rows = []
    print("procedure            corr   slope  sd(log true)  sd(residual)  mean log(pred/true)")
    for path in expand_inputs(args.data):
        cached = path / "cache" / f"medians-{tag}.npy"
        if not cached.is_file():
            raise SystemExit(f"{cached} is missing: run c2d2 train-coverage --set "
                             f"depth_scale=true on {path} first")
        pred = np.log(np.load(cached))
        true = np.log(region_medians(*true_depth(Procedure.open(path))))
        slope, intercept = np.polyfit(true, pred, 1)
        row = (np.corrcoef(pred, true)[0, 1], slope, true.std(),
               np.std(pred - (slope * true + intercept)), np.mean(pred - true))
        rows.append(row)
        print(f"{path.parent.name}/{path.name:10s}  {row[0]:.3f}  {row[1]:.2f}   "
              f"{row[2]:.3f}         {row[3]:.3f}         {row[4]:+.3f}")
    rows = np.array(rows)
    print(f"median over {len(rows)} procedures: corr {np.median(rows[:, 0]):.3f}, slope "
          f"{np.median(rows[:, 1]):.2f}, sd(log true) {np.median(rows[:, 2]):.3f}; mean log "
          f"ratio {rows[:, 4].mean():+.3f} with spread {rows[:, 4].std():.3f} across procedures")


if __name__ == "__main__":
    main()
