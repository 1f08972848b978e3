"""The intrinsics head's focal length by appearance style, against the training cameras.

Reads an eval-depth JSON (per procedure: fx_true and the head's fx_head; in JSONs written
before fx_head existed, fx_pred is the head's) and the simulated procedures it scored, and
prints per style: the true and the head's mean fx, the slope of the head's fx on the true
one, and the mean fx of the training procedures of that style. It shows whether the head
reads a camera or the style's usual camera.

    .venv/bin/python benchmarks/focal_by_style.py --eval docs/depth_eval_heldout.json \\
        --train data/train-pink data/train-dusk
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from hybrid.dataset import Procedure, list_procedures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval", type=Path, required=True, help="eval-depth --out JSON")
    parser.add_argument("--data-root", type=Path, default=Path("data"),
                        help="folder holding the datasets the JSON's names refer to")
    parser.add_argument("--train", type=Path, nargs="+", required=True,
                        help="the training datasets, for their cameras")
    args = parser.parse_args()
    scored = json.loads(args.eval.read_text())["procedures"]
    rows: dict[str, list[tuple[float, float]]] = {}
    for name, m in scored.items():
        rows.setdefault(Procedure.open(args.data_root / name).style, []).append(
            (m["fx_true"], m.get("fx_head", m["fx_pred"])))
    train: dict[str, list[float]] = {}
    for folder in args.train:
        for proc in list_procedures(folder):
            train.setdefault(proc.style, []).append(proc.camera.fx)
    print(f"{'style':6s} {'n':>3s} {'true fx':>8s} {'head fx':>8s} {'slope':>6s} "
          f"{'head error':>10s} {'training fx':>11s}")
    for style, values in sorted(rows.items()):
        true, head = np.array(values).T
        print(f"{style:6s} {len(true):3d} {true.mean():8.1f} {head.mean():8.1f} "
              f"{np.polyfit(true, head, 1)[0]:6.2f} {np.mean(abs(head / true - 1)):10.1%} "
              f"{np.mean(train.get(style, [np.nan])):11.1f}")


if __name__ == "__main__":
    main()
