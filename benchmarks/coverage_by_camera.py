"""Per-procedure error of a coverage model against its camera's field of view.

Each simulated procedure has its own camera (horizontal field of view 90-130 degrees). Unless
trained with `field_of_view`, the per-frame network sees a depth image, not the field of view,
so a camera wider than it assumes sees more of the wall than it predicts. Prints, per
procedure (sorted by field of view), the per-frame bias and MAE for the default (1, 4) cm
pair, the per-segment bias, how often the sign of the travel input's z (moving along the view
or against it) agrees with the true motion's, and, for a model that reads the field of view of
the motion network's intrinsics, that field of view; then the correlations of field of view
with the per-frame bias and with the network's.

    .venv/bin/python benchmarks/coverage_by_camera.py \
        --data data/cov-pink/proc_0012 ... [--model MODEL]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from hybrid.coverage import DEFAULT_PAIR_CM, DELTA_PAIRS_CM
from hybrid.dataset import Procedure
from learned.checkpoints import SHIPPED_COVERAGE, SHIPPED_DEPTH
from learned.coverage_nets import load_coverage_model
from learned.coverage_train import load_samples, predict
from learned.train import expand_inputs
from learned.travel import travel_features


def travel_agreement(poses: np.ndarray, travel: np.ndarray, gap: int) -> float:
    """Share of frames whose travel z has the sign of the one the true poses (camera-to-world)
    give over `gap` frames; NaN without a travel input."""
    if not gap:
        return float("nan")
    true = travel_features(np.linalg.inv(poses[gap:]) @ poses[:-gap], len(poses))
    return float(np.mean((true[:-gap, 2] > 0) == (travel[:-gap, 2] > 0)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--model", type=Path, default=SHIPPED_COVERAGE)
    parser.add_argument("--depth-checkpoint", type=Path, default=SHIPPED_DEPTH)
    args = parser.parse_args()
    model = load_coverage_model(args.model)
    paths = expand_inputs(args.data)
    pair = DELTA_PAIRS_CM.index(DEFAULT_PAIR_CM)
    rows = []
    for path, samples in zip(paths, load_samples(paths, model.config, args.depth_checkpoint),
                             strict=True):
        proc = Procedure.open(path)
        camera = proc.camera
        fov = camera.hfov_deg
        frame, segment = predict(model, samples)
        labelled = np.isfinite(samples.frame_labels[:, pair])
        error = frame[labelled, pair] - samples.frame_labels[labelled, pair]
        network_fov = (2 * np.degrees(np.arctan(np.exp(samples.view[0, 0])))
                       if model.config.field_of_view == "predicted" else np.nan)
        rows.append((fov, error.mean(), np.abs(error).mean(),
                     np.nanmean(segment - samples.segment_labels),
                     travel_agreement(proc.poses, samples.travel,
                                      model.config.travel_frames(camera.fps)),
                     network_fov, samples.name))
    print("field of view (deg)  frame bias  frame MAE  segment bias  travel z sign  "
          "network's fov  procedure")
    for fov, bias, mae, segment_bias, agree, network_fov, name in sorted(rows):
        print(f"{fov:19.0f}  {bias:+10.3f}  {mae:9.3f}  {segment_bias:+12.3f}  {agree:13.2f}  "
              f"{network_fov:13.0f}  {name}")
    fovs, biases, network = (np.array([r[k] for r in rows]) for k in (0, 1, 5))
    print(f"correlation of field of view with frame bias: {np.corrcoef(fovs, biases)[0, 1]:.2f}"
          f"; mean |frame bias| {np.abs(biases).mean():.3f}")
    if np.isfinite(network).all():
        print(f"correlation of field of view with the network's: "
              f"{np.corrcoef(fovs, network)[0, 1]:.2f}; mean |difference| "
              f"{np.abs(network - fovs).mean():.1f} deg")


if __name__ == "__main__":
    main()
