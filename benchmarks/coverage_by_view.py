"""Cross-validated coverage errors split by where the camera looks.

For each fold model of a `c2d2 train-coverage` run, predicts its held-out procedures and splits
the errors by the cosine between each camera's view axis and the lumen direction at its
position: looking down the lumen (> 0.5), sideways, or back towards the rectum (< -0.5) (with
the share of each group's frames whose travel input has z > 0, for a travel-aware run); and
segments by their share of backward-looking frames. The data, config and fold split are the
run's own (its record.json), so each fold model sees only the procedures it held out.

    python benchmarks/coverage_by_view.py --run data/runs/coverage-fast
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from hybrid.coverage import DEFAULT_PAIR_CM, DELTA_PAIRS_CM, Lumen
from hybrid.dataset import Procedure
from learned.config import CoverageConfig
from learned.coverage_nets import load_coverage_model
from learned.coverage_train import fold_split, load_samples, predict
from learned.train import expand_inputs


def view_cosine(proc: Procedure) -> np.ndarray:
    """(N,) cosine between each camera's z axis and the lumen tangent at its nearest point."""
    lumen = Lumen(proc.lumen)
    ell, _ = lumen.project(proc.poses[:, :3, 3])
    tangent = np.gradient(lumen.points, lumen.arclength, axis=0)
    along = np.stack([np.interp(ell, lumen.arclength, tangent[:, k]) for k in range(3)], 1)
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    return np.einsum("ij,ij->i", along, proc.poses[:, :3, 2])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=Path("data/runs/coverage-fast"))
    parser.add_argument("--backward-share", type=float, default=0.2)
    args = parser.parse_args()
    torch.set_num_threads(1)
    record = json.loads((args.run / "record.json").read_text())
    config = CoverageConfig.from_dict(record["config"])
    paths = expand_inputs([Path(p) for p in record["data"]])
    samples = load_samples(paths, config, Path(record["depth_checkpoint"]["path"]))
    if [s.name for s in samples] != record["procedures"]:
        raise SystemExit(f"the procedures under {record['data']} are not the run's own")
    pair = DELTA_PAIRS_CM.index(DEFAULT_PAIR_CM)
    groups = {"forward": [], "sideways": [], "backward": []}
    moving_along_view = {name: [] for name in groups}  # travel z > 0 (with a travel input)
    segments = []
    for k, held in enumerate(fold_split(len(samples), config.folds, config.seed)):
        model = load_coverage_model(args.run / f"fold-{k}.safetensors")
        for i in held:
            s = samples[i]
            cosine = view_cosine(Procedure.open(paths[i]))
            pred, values = predict(model, s)
            truth = s.frame_labels[:, pair]
            ok = np.isfinite(truth)
            error = np.abs(pred[:, pair] - truth)
            picks = {"forward": cosine > 0.5, "backward": cosine < -0.5,
                     "sideways": np.abs(cosine) <= 0.5}
            for name, pick in picks.items():
                groups[name] += error[ok & pick].tolist()
                if config.travel_size:
                    moving_along_view[name] += (s.travel[ok & pick, 2] > 0).tolist()
            T = config.segment_frames
            for start, value, label in zip(s.segment_starts, values, s.segment_labels,
                                           strict=True):
                segments.append((np.mean(cosine[start:start + T] < -0.5), value - label))
    total = sum(len(v) for v in groups.values())
    for name, errors in groups.items():
        along = (f"  travel z > 0 for {np.mean(moving_along_view[name]):.0%}"
                 if moving_along_view[name] else "")
        print(f"{name:9s} frames {len(errors):6d} ({len(errors) / total:.0%})  per-frame MAE "
              f"(1,4) {np.mean(errors):.3f}{along}")
    share, error = np.array(segments).T
    ok = np.isfinite(error)
    many = ok & (share > args.backward_share)
    for name, pick in ((f"segments with > {args.backward_share:.0%} backward frames", many),
                       ("the other segments", ok & ~many)):
        print(f"{name:38s} {pick.sum():4d}  segment MAE {np.abs(error[pick]).mean():.3f}")


if __name__ == "__main__":
    main()
