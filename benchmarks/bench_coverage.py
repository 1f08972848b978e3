"""Inference speed of the coverage networks at both presets, on this CPU or a GPU.

Per-frame network: frames/s on batches of normalised depth, each frame read in its four
mirror views (the depth network is not included). Per-segment network: segments/s on
T x 4 x F feature windows (the four mirrored sequences), and the equivalent frames/s when a
window is evaluated once per segment (T frames each). Weights are random:
speed does not depend on them.

    python benchmarks/bench_coverage.py --threads 2
    python benchmarks/bench_coverage.py --device cuda --batch 256 --paper-batch 64
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from learned.config import COVERAGE_PRESETS
from learned.coverage_nets import MIRRORS, CoverageModel, count_parameters
from learned.device import pick_device


def timed(fn, repeats: int) -> float:
    fn()  # warm-up
    tic = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - tic) / repeats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--batch", type=int, default=32, help="frames per call (fast preset)")
    parser.add_argument("--paper-batch", type=int, default=4, help="frames per call (paper)")
    parser.add_argument("--frame-batch", type=int, default=32,
                        help="frames per pass of the per-frame network within a call")
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    device = pick_device(args.device)
    print(f"device {device}, torch threads {args.threads}, "
          f"load average {os.getloadavg()[0]:.2f}")
    print(f"{'preset':8s} {'input':>9s} {'frame params':>13s} {'frames/s':>9s} "
          f"{'segment params':>15s} {'segments/s':>11s} {'frames/s (seg)':>15s}")
    for name, config in COVERAGE_PRESETS.items():
        model = CoverageModel(config).eval().to(device)
        batch = args.batch if name == "fast" else args.paper_batch
        depth = np.random.default_rng(0).normal(
            size=(batch, 1, config.height, config.width)).astype(np.float32)
        cues = np.zeros((batch, config.cue_size), np.float32)
        frame_s = timed(lambda d=depth, c=cues, m=model: m.frame_outputs(
            d, c, batch=args.frame_batch), 3)
        features = np.random.default_rng(1).normal(
            size=(config.segment_frames, len(MIRRORS), config.feature_size)).astype(np.float32)
        seg_s = timed(lambda f=features, m=model: m.segment_outputs(f, [0]), 20)
        print(f"{name:8s} {config.height:4d}x{config.width:<4d} "
              f"{count_parameters(model.frame):13,d} {batch / frame_s:9.1f} "
              f"{count_parameters(model.segment):15,d} {1 / seg_s:11.1f} "
              f"{config.segment_frames / seg_s:15.0f}")


if __name__ == "__main__":
    main()
