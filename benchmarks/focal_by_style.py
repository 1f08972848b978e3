"""The intrinsics head's focal length by appearance style, against the training cameras.

Reads eval-depth JSONs (per procedure: fx_true and the head's fx_head; in JSONs written
before fx_head existed, fx_pred is the head's) and the simulated procedures they scored, and
prints per style and over all: the true and the head's mean fx, the slope of the head's fx on
the true one and their correlation, the head's error, and the mean fx of the training
procedures of that style. It shows whether the head reads a camera or the style's usual
camera. The last column is the error left once the head's fx is multiplied by the one
factor that puts its level on the truth's (the geometric mean of true / head over the
row's procedures; it zeroes their mean log ratio): about what a head with this spread but
the right level would err. It uses the truth, so it is a figure to read, not a correction to
apply.

    .venv/bin/python benchmarks/focal_by_style.py --train data/train-pink data/train-dusk \\
        --eval docs/zoom/shipped-heldout.json docs/zoom/shipped-selfcal-fresh.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from hybrid.dataset import Procedure, list_procedures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval", type=Path, nargs="+", required=True,
                        help="eval-depth --out JSONs")
    parser.add_argument("--data-root", type=Path, default=Path("data"),
                        help="folder holding the datasets the JSON's names refer to")
    parser.add_argument("--train", type=Path, nargs="+", required=True,
                        help="the training datasets, for their cameras")
    args = parser.parse_args()
    rows: dict[str, list[tuple[float, float]]] = {}
    for path in args.eval:
        for name, m in json.loads(path.read_text())["procedures"].items():
            rows.setdefault(Procedure.open(args.data_root / name).style, []).append(
                (m["fx_true"], m["fx_head"] if "fx_head" in m else m["fx_pred"]))
    rows["all"] = [row for values in rows.values() for row in values]
    train: dict[str, list[float]] = {}
    for folder in args.train:
        for proc in list_procedures(folder):
            train.setdefault(proc.style, []).append(proc.camera.fx)
    train["all"] = [fx for values in train.values() for fx in values]
    print(f"{'style':6s} {'n':>3s} {'true fx':>8s} {'head fx':>8s} {'slope':>6s} {'corr':>5s} "
          f"{'head error':>10s} {'training fx':>11s} {'at the true level':>17s}")
    for style, values in sorted(rows.items(), key=lambda item: (item[0] == "all", item[0])):
        true, head = np.array(values).T
        level = np.exp(np.mean(np.log(true / head)))  # puts the head's level on the truth's
        print(f"{style:6s} {len(true):3d} {true.mean():8.1f} {head.mean():8.1f} "
              f"{np.polyfit(true, head, 1)[0]:6.2f} {np.corrcoef(true, head)[0, 1]:5.2f} "
              f"{np.mean(abs(head / true - 1)):10.1%} "
              f"{np.mean(train.get(style, [np.nan])):11.1f} "
              f"{np.mean(abs(head * level / true - 1)):17.1%}")


if __name__ == "__main__":
    main()
