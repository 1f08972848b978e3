"""Inference speed of the coverage networks at both presets, on this CPU or a GPU.

Per-frame network: frames/s on batches of normalised depth, each frame read in its four
mirror views (the depth network is not included). Per-segment network: segments/s on
T x 4 x F feature windows (the four mirrored sequences), and the equivalent frames/s when a
window is evaluated once per segment (T frames each). Stage-1 training: steps/s of
`train_frame_net` itself (batches of `frame_batch`, flips, loss, AdamW) on random frames, for
the presets named by --train-presets. Weights and data are random: speed does not depend on
them.

    python benchmarks/bench_coverage.py --threads 2
    python benchmarks/bench_coverage.py --train-steps 300 --set frame_precision=bfloat16
    python benchmarks/bench_coverage.py --device cuda --batch 256 --paper-batch 64
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

import numpy as np
import torch

from learned.config import COVERAGE_PRESETS, CoverageConfig, parse_overrides
from learned.coverage_data import ProcedureSamples
from learned.coverage_nets import MIRRORS, CoverageModel, count_parameters
from learned.coverage_train import train_frame_net
from learned.device import pick_device


def timed(fn, repeats: int) -> float:
    fn()  # warm-up
    tic = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - tic) / repeats


def training_rate(config: CoverageConfig, steps: int, device: torch.device) -> float:
    """Stage-1 training steps/s of `train_frame_net`, as `c2d2 train-coverage` runs it, over
    one epoch of `steps` batches of random frames (its set-up included)."""
    rng = np.random.default_rng(2)
    frames = config.frame_batch * steps
    none = np.zeros((frames, 0), np.float32)
    samples = ProcedureSamples(
        name="random",
        inputs=rng.normal(size=(frames, 1, config.height, config.width)).astype(np.float16),
        travel=rng.normal(size=(frames, config.travel_size)).astype(np.float32),
        view=none, scale=none, frame_labels=rng.random((frames, 3)).astype(np.float32),
        window_starts=np.zeros(0, int), window_labels=np.zeros(0),
        segment_starts=np.zeros(0, int), segment_labels=np.zeros(0))
    model = CoverageModel(replace(config, frame_epochs=1)).to(device)
    tic = time.perf_counter()
    train_frame_net(model, [samples], lambda entry: None)
    return steps / (time.perf_counter() - tic)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--batch", type=int, default=32, help="frames per call (fast preset)")
    parser.add_argument("--paper-batch", type=int, default=4, help="frames per call (paper)")
    parser.add_argument("--frame-batch", type=int, default=32,
                        help="frames per pass of the per-frame network within a call")
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    parser.add_argument("--train-steps", type=int, default=100,
                        help="stage-1 training steps to time (0: none)")
    parser.add_argument("--train-presets", nargs="*", default=["fast"],
                        choices=sorted(COVERAGE_PRESETS), help="presets whose training is timed")
    parser.add_argument("--set", action="append", default=[], metavar="K=V",
                        help="a CoverageConfig field changed in every preset (repeat), e.g. "
                             "frame_precision=bfloat16")
    args = parser.parse_args()
    try:
        presets = {name: replace(config, **parse_overrides(args.set, config))
                   for name, config in COVERAGE_PRESETS.items()}
    except ValueError as err:
        parser.error(str(err))
    torch.set_num_threads(args.threads)
    device = pick_device(args.device)
    print(f"device {device}, torch threads {args.threads}, "
          f"load average {os.getloadavg()[0]:.2f}")
    print(f"{'preset':8s} {'input':>9s} {'frame params':>13s} {'frames/s':>9s} "
          f"{'segment params':>15s} {'segments/s':>11s} {'frames/s (seg)':>15s} "
          f"{'train steps/s':>14s}")
    for name, config in presets.items():
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
        train = (f"{training_rate(config, args.train_steps, device):14.1f}"
                 if args.train_steps and name in args.train_presets else f"{'-':>14s}")
        print(f"{name:8s} {config.height:4d}x{config.width:<4d} "
              f"{count_parameters(model.frame):13,d} {batch / frame_s:9.1f} "
              f"{count_parameters(model.segment):15,d} {1 / seg_s:11.1f} "
              f"{config.segment_frames / seg_s:15.0f} {train}")


if __name__ == "__main__":
    main()
