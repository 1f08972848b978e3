"""Would CORAL on the per-frame features help on a shifted style? An experiment, not a
feature: the per-frame network's features (each frame in each mirror view a sample) of the
target videos are mapped onto the source videos' mean and covariance (learned.coral's
transform), then read by the per-frame head and by the per-segment network unchanged (its own
CORAL left as it is in the model). Prints per-frame and segment MAE on the test procedures
without and with that transform.

    python benchmarks/coral_frames.py --source data/heldout --target data/cov-nbi/proc_0000 ... \
        --data data/cov-nbi/proc_0006 ...
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from learned.coral import coral_transform
from learned.coverage_eval import Predictions, coverage_metrics, format_table
from learned.coverage_nets import load_coverage_model
from learned.coverage_train import load_samples

SHIPPED = Path(__file__).resolve().parents[1] / "learned" / "checkpoints"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=SHIPPED / "coverage-fast.safetensors")
    parser.add_argument("--depth-checkpoint", type=Path,
                        default=SHIPPED / "depth-fast.safetensors")
    parser.add_argument("--source", type=Path, nargs="+", required=True,
                        help="synthetic procedures the model was not trained on")
    parser.add_argument("--target", type=Path, nargs="+", required=True,
                        help="procedures of the shifted style to fit on (labels unused)")
    parser.add_argument("--data", type=Path, nargs="+", required=True,
                        help="procedures of the shifted style to score")
    args = parser.parse_args()
    model = load_coverage_model(args.model)
    model.check_depth(args.depth_checkpoint, str(args.model))

    def features(paths: list[Path]) -> list:
        samples = load_samples(paths, model.config, args.depth_checkpoint, progress=True)
        return [(s, *model.frame_outputs(s.inputs, s.cues)) for s in samples]

    def rows(read: list) -> np.ndarray:
        return np.concatenate([f.reshape(-1, f.shape[-1]) for _, _, f in read])

    source = rows(features(args.source))
    target = rows(features(args.target))
    A, b = coral_transform(source.mean(0), np.cov(source, rowvar=False), target)
    test = features(args.data)
    results = {}
    for name, transform in (("as trained", None), ("frame CORAL", (A, b))):
        predictions = Predictions()
        for s, frame, f in test:
            if transform is not None:
                f = (f.astype(np.float64) @ A.T + b).astype(np.float32)
                with torch.no_grad():
                    frame = model.frame.coverage(torch.from_numpy(f)).mean(1).numpy()
            predictions.add(frame, s.frame_labels,
                            model.segment_outputs(f, s.segment_starts.tolist()),
                            s.segment_labels)
        results[name] = coverage_metrics(predictions)
    print(f"{len(source)} source and {len(target)} target samples of "
          f"{source.shape[1]} features")
    print(format_table(results))


if __name__ == "__main__":
    main()
