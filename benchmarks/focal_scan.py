"""Training loss against the focal length, with true depth and true motion.

Whole-image procedures only (others are refused): it feeds their frames to the networks as
they are, where c2d2 fills the black corners of ones simulated with `--octagon`
(FrameSequence.network_frame).

Runs the training loss (`learned.losses.view_synthesis_loss`, default config) on triplets of
simulated procedures with their true depth and poses, scaling the true K's focal lengths. If the
minimum sits at scale 1, the loss itself is unbiased in K and any drift of the learned focal
length comes from the joint fit of depth, motion and K.

    .venv/bin/python benchmarks/focal_scan.py --data data/val
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from hybrid.dataset import list_procedures
from learned.config import DepthConfig
from learned.losses import view_synthesis_loss
from learned.map_triplets import relative_motion
from learned.model import to_tensor


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--scales", type=float, nargs="+",
                        default=[0.6, 0.8, 0.9, 1.0, 1.1, 1.25, 1.5])
    parser.add_argument("--every", type=int, default=60, help="frames between targets")
    args = parser.parse_args()
    config = DepthConfig()
    losses: dict[float, list[float]] = {s: [] for s in args.scales}
    for proc in list_procedures(args.data, whole_images=True):
        gap = max(1, round(proc.camera.fps * config.pair_gap_s))
        K_true = torch.tensor(proc.camera.K, dtype=torch.float32)[None]
        for t in range(gap, proc.num_frames - gap, args.every):
            ids = (t - gap, t, t + gap)
            frames = [to_tensor(proc.rgb(i))[None] for i in ids]
            # Pixels without a surface get a tiny depth; they project nowhere useful either way.
            depths = [torch.from_numpy(proc.depth(i))[None, None].clamp(min=0.01) for i in ids]
            motions = [relative_motion(proc.poses, t, s) for s in (ids[0], ids[2])]
            region = torch.ones(1, 1, *frames[1].shape[-2:])
            for scale in args.scales:
                K = K_true.clone()
                K[:, 0, 0] *= scale
                K[:, 1, 1] *= scale
                torch.manual_seed(0)  # the same auto-mask tie-breaking for every scale
                terms = view_synthesis_loss(frames[1], [frames[0], frames[2]], depths[1],
                                            [depths[0], depths[2]], motions, K, region, config)
                losses[scale].append(float(terms.photometric))
    for scale in args.scales:
        print(f"focal x{scale:<5g} photometric loss {np.mean(losses[scale]):.5f}")


if __name__ == "__main__":
    main()
