"""How sharply the photometric loss singles out the truth on simulated procedures.

Whole-image procedures only (others are refused): it feeds their frames to the networks as
they are, where c2d2 fills the black corners of ones simulated with `--octagon`
(FrameSequence.network_frame).

With the true depth, pose and K, warp a source frame `gap` frames away into the target and
measure the photometric error (L1 and 1-SSIM at several windows) over valid, non-specular
pixels; then again with the focal length 20% short, a 1° rotation offset, and the depth 30%
too far. The ratios (perturbed / truth) show how much signal training has to work with.

    .venv/bin/python benchmarks/loss_sensitivity.py --data data/val --gaps 5 9 18
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from kornia.metrics import ssim

from hybrid.dataset import list_procedures
from learned.geometry import transform_from, warp
from learned.losses import specular
from learned.model import to_tensor

WINDOWS = (3, 7, 11)


def errors(warped: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> dict[str, float]:
    out = {"l1": float((warped - target).abs().mean(1, keepdim=True)[mask].mean())}
    for w in WINDOWS:
        dssim = ((1 - ssim(warped, target, w)) / 2).clamp(0, 1).mean(1, keepdim=True)
        out[f"dssim{w}"] = float(dssim[mask].mean())
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--gaps", type=int, nargs="+", default=[5, 9, 18])
    parser.add_argument("--targets", type=int, default=14, help="target frames per procedure")
    args = parser.parse_args()
    for gap in args.gaps:
        table: dict[tuple[str, str], list[float]] = {}
        for proc in list_procedures(args.data, whole_images=True):
            K = torch.tensor(proc.camera.K, dtype=torch.float32)[None]
            short = K.clone()
            short[:, 0, 0] *= 0.8
            short[:, 1, 1] *= 0.8
            turn = transform_from(torch.tensor([[0.0, np.radians(1.0), 0.0]], dtype=torch.float32),
                                  torch.zeros(1, 3))
            for t in np.linspace(0, proc.num_frames - 1 - gap, args.targets).astype(int):
                target, source = to_tensor(proc.rgb(t))[None], to_tensor(proc.rgb(t + gap))[None]
                depth = torch.from_numpy(proc.depth(t))[None, None]
                T = torch.tensor(np.linalg.inv(proc.poses[t + gap]) @ proc.poses[t],
                                 dtype=torch.float32)[None]
                cases = {"truth": (T, K, depth), "focal-20%": (T, short, depth),
                         "rotation+1deg": (turn @ T, K, depth), "depth*1.3": (T, K, 1.3 * depth)}
                for case, (T_c, K_c, d_c) in cases.items():
                    w = warp(source, d_c, T_c, K_c)
                    mask = w.valid & (depth > 0) & ~specular(target) & ~specular(w.image)
                    for metric, value in errors(w.image, target, mask).items():
                        table.setdefault((metric, case), []).append(value)
        print(f"gap {gap} frames:")
        for metric in ["l1"] + [f"dssim{w}" for w in WINDOWS]:
            base = np.mean(table[(metric, "truth")])
            ratios = "  ".join(f"{case} x{np.mean(table[(metric, case)]) / base:.3f}"
                               for case in ("focal-20%", "rotation+1deg", "depth*1.3"))
            print(f"  {metric:8s} truth {base:.4f}  {ratios}")


if __name__ == "__main__":
    main()
