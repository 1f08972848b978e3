"""How much averaging a run's models helps on procedures none of them was trained on.

A `c2d2 train-coverage` run leaves five fold models (each trained on four fifths of its
procedures) and the final model (on all of them). This prints, on the --data procedures, the
metrics of each model alone, then of the mean of the fold models' predictions, and of all six:
per frame the mean of their per-frame coverages, per segment the mean of their segment
coverages (each model on its own per-frame features). Where the ensemble gains little per
frame, the per-frame error is not the spread between models (variance) but error they share.
The models as saved (the fold models uncalibrated; the final model as shipped).

    python benchmarks/coverage_ensemble.py --run data/runs/coverage-hops --data data/heldout
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from learned.checkpoints import SHIPPED_DEPTH
from learned.coverage_eval import Predictions, coverage_metrics, format_table
from learned.coverage_nets import load_coverage_model
from learned.coverage_train import load_samples, predict


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True)
    parser.add_argument("--data", type=Path, action="append", required=True,
                        help="simulated procedures or folders of them (repeat)")
    parser.add_argument("--depth-checkpoint", type=Path, default=SHIPPED_DEPTH)
    args = parser.parse_args()
    folds = sorted((p.stem for p in args.run.glob("fold-*.safetensors")),
                   key=lambda name: int(name.split("-")[1]))
    if not folds or not (args.run / "model.safetensors").is_file():
        parser.error(f"{args.run} holds no fold models or no final model.safetensors")
    names = [*folds, "model"]
    models = {n: load_coverage_model(args.run / f"{n}.safetensors") for n in names}
    samples = load_samples(args.data, models["model"].config, args.depth_checkpoint,
                           progress=True)
    outputs = {n: [predict(m, s) for s in samples] for n, m in models.items()}

    def averaged(members: list[str]) -> dict:
        predictions = Predictions()
        for i, s in enumerate(samples):
            frame, segment = (np.mean([outputs[n][i][k] for n in members], axis=0)
                              for k in (0, 1))
            predictions.add(frame, s.frame_labels, segment, s.segment_labels)
        return coverage_metrics(predictions)

    rows = {n: averaged([n]) for n in names}
    rows[f"{len(folds)} folds, mean"] = averaged(folds)
    rows[f"all {len(names)}, mean"] = averaged(names)
    print(format_table(rows))


if __name__ == "__main__":
    main()
