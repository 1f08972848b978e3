"""What CORAL does when fitted on too little target video (why learned.coral asks for more
segments' worth of video than the dimensions it aligns).

The shipped coverage networks, CORAL fitted (bypassing that minimum) on the windows every 30
frames of the first `seconds` of one simulated procedure, in-domain, where the transform
should stay near the identity; printed per target length: the windows, the largest stretch
of A (its largest singular value), and the segment MAE on every window of another procedure
before and after.

    python benchmarks/coral_small_target.py --target data/cov-dusk/proc_0005 \
        --other data/cov-pink/proc_0007 --seconds 14 20 60
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import numpy as np
import torch

from learned.checkpoint import file_tag
from learned.checkpoints import SHIPPED_COVERAGE, SHIPPED_DEPTH
from learned.coral import coral_transform
from learned.coverage_data import procedure_samples
from learned.coverage_nets import load_coverage_model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--target", type=Path, required=True)
    parser.add_argument("--other", type=Path, required=True)
    parser.add_argument("--seconds", type=float, nargs="+", default=[14, 20, 60])
    args = parser.parse_args()
    model = load_coverage_model(SHIPPED_COVERAGE)
    tag = file_tag(Path(SHIPPED_DEPTH))
    T, stride = model.config.segment_frames, model.config.segment_stride

    def features(path: Path):
        samples = procedure_samples(path, model.config, None, tag)
        return samples, model.frame_outputs(samples.inputs, samples.cues)[1]

    _, target = features(args.target)
    other, other_features = features(args.other)
    starts = list(range(0, len(other_features) - T + 1, stride))
    truth = other.window_labels[:len(starts)]
    before = np.abs(model.segment_outputs(other_features, starts) - truth).mean()
    net = model.segment
    for seconds in args.seconds:
        frames = target[:round(seconds * model.config.frame_rate)]
        windows = list(range(0, len(frames) - T + 1, stride))
        rows = model.segment_embeddings(frames, windows).double().numpy()
        A, b = coral_transform(net.source_mean.double().numpy(), net.source_cov.double().numpy(),
                               rows.reshape(-1, rows.shape[-1]))
        adapted = copy.deepcopy(model)
        adapted.segment.coral_matrix.copy_(torch.from_numpy(A).float())
        adapted.segment.coral_offset.copy_(torch.from_numpy(b).float())
        after = np.abs(adapted.segment_outputs(other_features, starts) - truth).mean()
        print(f"{seconds:5.1f} s of target: {len(windows)} windows, largest stretch of A "
              f"{np.linalg.svd(A, compute_uv=False)[0]:.1f}; other video's segment MAE "
              f"{before:.3f} -> {after:.3f}")


if __name__ == "__main__":
    main()
