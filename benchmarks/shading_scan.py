"""How sharply the inverse-square shading prior (learned.shading) tells the true depth's shape
and the true focal length apart, on simulated procedures.

Whole-image procedures only (others are refused): it feeds their frames to the networks as
they are, where c2d2 fills the black corners of ones simulated with `--octagon`
(FrameSequence.network_frame).

For frames every `--every` frames, the prior with the true depth and K, with the depth's shape
spoiled (gt^p, compressed or stretched about the frame's median, so only the shape changes), and
with the focal length scaled; optionally also at a depth model's prediction, with the true and
with scaled focal lengths; with --focal-search also the focal length that minimises the prior
at the model's depth, searched without the truth. Prints the prior per procedure and its mean
over all.

    .venv/bin/python benchmarks/shading_scan.py --data data/val data/test \
        --model data/runs/chain-ft-frozen-w03/model.safetensors
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from hybrid.dataset import list_procedures
from learned.config import DepthConfig
from learned.losses import specular
from learned.model import load_depth_model, to_tensor
from learned.shading import shading_loss

POWERS = (0.5, 0.63, 0.8, 0.9, 1.0, 1.1, 1.25, 1.5)
FOCALS = (0.6, 0.8, 0.9, 1.0, 1.1, 1.25, 1.5)
SEARCH = np.geomspace(0.25, 1.5, 91)
"""Focal lengths (× image width) of --focal-search, 2% apart."""


def focal_search(images: torch.Tensor, depth: torch.Tensor, usable: torch.Tensor,
                 gamma: float) -> float:
    """The focal length (pixels, fx = fy, principal point at the image centre) that minimises
    the prior over the frames with the given depth: a per-video estimate needing no truth."""
    height, width = images.shape[-2:]
    values = []
    for f in SEARCH * width:
        K = torch.tensor([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
        values.append(float(shading_loss(images, depth, K.expand(len(images), 3, 3), usable,
                                         gamma)))
    return float(SEARCH[int(np.argmin(values))] * width)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--model", type=Path, help="also the prior at this model's depth")
    parser.add_argument("--every", type=int, default=50, help="frames between frames used")
    parser.add_argument("--focal-search", action="store_true",
                        help="also the focal length minimising the prior at the model's depth")
    parser.add_argument("--gamma", type=float, default=DepthConfig().display_gamma,
                        help="gamma the prior assumes (the simulator's styles: 2.2, dusk 1.9)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.focal_search and not args.model:
        parser.error("--focal-search needs --model")
    model = load_depth_model(args.model) if args.model else None
    errors = []
    rows: dict[str, list[float]] = {}
    for proc in [p for d in args.data for p in list_procedures(d, whole_images=True)]:
        ts = range(0, proc.num_frames, args.every)
        images = torch.stack([to_tensor(proc.rgb(t)) for t in ts])
        truth = torch.stack([torch.from_numpy(proc.depth(t))[None] for t in ts])
        usable = (truth > 0) & ~specular(images)
        truth = truth.clamp(min=0.01)
        K = torch.tensor(proc.camera.K, dtype=torch.float32).expand(len(images), 3, 3)
        median = truth.flatten(1).median(dim=1).values[:, None, None, None]
        cases = {f"depth^{p}": (truth**p * median ** (1 - p), K) for p in POWERS}
        for f in FOCALS:
            cases[f"focal x{f}"] = (truth, K * torch.tensor([[f], [f], [1.0]]))
        if model is not None:  # the model's depth, with the true K and with K scaled
            with torch.no_grad():
                predicted = model.predict_depth(images)
            cases["model"] = (predicted, K)
            for f in FOCALS:
                cases[f"model, focal x{f}"] = (predicted, K * torch.tensor([[f], [f], [1.0]]))
        values = {name: float(shading_loss(images, depth, k, usable, args.gamma))
                  for name, (depth, k) in cases.items()}
        for name, value in values.items():
            rows.setdefault(name, []).append(value)
        print(f"{proc.path}: " + "  ".join(f"{k} {v:.3f}" for k, v in values.items()))
        if args.focal_search:
            found = focal_search(images, predicted, usable, args.gamma)
            errors.append(abs(found / proc.camera.fx - 1))
            print(f"{proc.path}: focal search fx {found:.1f} px (true {proc.camera.fx:.1f}, "
                  f"error {errors[-1]:.1%})")
    print("mean: " + "  ".join(f"{k} {np.mean(v):.3f}" for k, v in rows.items()))
    if errors:
        print(f"focal search: mean fx error {np.mean(errors):.1%}, largest {max(errors):.1%}")


if __name__ == "__main__":
    main()
