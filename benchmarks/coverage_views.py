"""Cross-validated coverage errors of a run's fold models read in one view or in the four
mirror views, and of per-frame predictions smoothed over time.

For each fold model of a `c2d2 train-coverage` run, predicts its held-out procedures (the
run's own data, config and fold split, as `coverage_by_view.py`) three ways: from the frame as
it is only; from the four mirror views, a segment being the mean of the per-segment network's
outputs on the four sequences (what the networks do); and from the four views with a segment
taken from the mean of their features ("mean features"). Then the per-frame MAE of the
four-view predictions after a running mean and a running median over time, for each window of
--smooth frames.

    python benchmarks/coverage_views.py --run data/runs/coverage-base
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from scipy.ndimage import median_filter, uniform_filter1d

from learned.coverage_eval import Predictions, coverage_metrics, format_table
from learned.coverage_nets import MIRRORS, CoverageModel, load_coverage_model
from learned.coverage_train import load_run


def one_view_segments(model: CoverageModel, features: np.ndarray, starts: list[int]
                      ) -> np.ndarray:
    """Segment coverage from (N, F) features given as every view's."""
    return model.segment_outputs(np.repeat(features[:, None], len(MIRRORS), axis=1), starts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True)
    parser.add_argument("--smooth", type=int, nargs="*", default=[9, 31, 61])
    args = parser.parse_args()
    torch.set_num_threads(1)
    _, _, samples, folds = load_run(args.run)
    ways = {"one view": Predictions(), "four views": Predictions(),
            "mean features": Predictions()}
    smoothed: dict[tuple[str, int], list[np.ndarray]] = {}
    for k, held in enumerate(folds):
        model = load_coverage_model(args.run / f"fold-{k}.safetensors")
        for i in held:
            s = samples[i]
            coverage, features = model.frame_outputs(s.inputs, s.cues)
            starts = s.segment_starts.tolist()
            with torch.no_grad():
                one = model.frame.coverage(torch.from_numpy(features[:, 0])).numpy()
            ways["one view"].add(one, s.frame_labels,
                                 one_view_segments(model, features[:, 0], starts),
                                 s.segment_labels)
            ways["four views"].add(coverage, s.frame_labels,
                                   model.segment_outputs(features, starts), s.segment_labels)
            ways["mean features"].add(coverage, s.frame_labels,
                                      one_view_segments(model, features.mean(axis=1), starts),
                                      s.segment_labels)
            for size in args.smooth:
                for name, smooth in (("mean", uniform_filter1d(coverage, size, axis=0,
                                                               mode="nearest")),
                                     ("median", median_filter(coverage, size=(size, 1),
                                                              mode="nearest"))):
                    smoothed.setdefault((name, size), []).append(
                        np.abs(smooth - s.frame_labels))
    print(format_table({name: coverage_metrics(p) for name, p in ways.items()}))
    print("per-frame MAE (1,3) / (1,4) / (1,6) of the four-view predictions smoothed over time")
    for (name, size), errors in smoothed.items():
        mae = np.nanmean(np.concatenate(errors), axis=0)
        print(f"running {name:6s} over {size:3d} frames: " + " / ".join(f"{v:.3f}" for v in mae))


if __name__ == "__main__":
    main()
