"""The motion net's rotation over the pair gap: estimated directly, or chained from small steps.

Whole-image procedures only (others are refused): it feeds their frames to the networks as
they are, where c2d2 fills the black corners of ones simulated with `--octagon`
(FrameSequence.network_frame).

For simulated procedures, every `--every` frames t: the rotation from frame t - gap to t (gap:
the model's pair_gap_s) as the motion net estimates it from that pair, and as the composition
of its estimates between consecutive frames (`--steps 1`) or every few frames. Prints per camera
axis (x right, y down, z forward) the least-squares slope of each on the true rotation (1:
found, 0: none found) and their correlation, and the predicted / true fx of the consecutive
pairs. The chain term of training (DepthConfig.w_chain) rests on the difference.

    .venv/bin/python benchmarks/chain_rotation.py --data data/val \
        [--model learned/checkpoints/depth-fast.safetensors] [--steps 1 3]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from depth_diagnosis import axis_slopes
from kornia.geometry.conversions import rotation_matrix_to_axis_angle

from hybrid.dataset import list_procedures
from learned.checkpoints import SHIPPED_DEPTH
from learned.geometry import compose_chain
from learned.model import load_depth_model, to_tensor


def degrees(transforms: torch.Tensor) -> np.ndarray:
    """(N, 3) axis-angle rotations in degrees of (N, 4, 4) transforms."""
    return np.degrees(rotation_matrix_to_axis_angle(transforms[:, :3, :3].float()).numpy())


def chained(steps: torch.Tensor, starts: np.ndarray, gap: int, step: int) -> torch.Tensor:
    """(N, 4, 4) transforms from frame s + gap back to frame s, composed from steps[i]: frame
    i + step -> frame i."""
    return compose_chain(steps[starts[:, None] + np.arange(0, gap, step)[None]])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--model", type=Path, default=SHIPPED_DEPTH)
    parser.add_argument("--every", type=int, default=7, help="frames between pairs")
    parser.add_argument("--steps", type=int, nargs="+", default=[1, 3],
                        help="frames per step of the chains")
    args = parser.parse_args()
    torch.set_num_threads(2)
    model = load_depth_model(args.model)
    rows: dict[str, list[np.ndarray]] = {"true": [], "direct": []}
    focal = []
    with torch.no_grad():
        for proc in (p for d in args.data for p in list_procedures(d, whole_images=True)):
            gap = max(1, round(proc.camera.fps * model.config.pair_gap_s))
            images = torch.stack([to_tensor(proc.rgb(i)) for i in range(proc.num_frames)])
            starts = np.arange(0, proc.num_frames - gap, args.every)
            true = [np.linalg.inv(proc.poses[s]) @ proc.poses[s + gap] for s in starts]
            rows["true"].append(degrees(torch.tensor(np.stack(true))))
            rows["direct"].append(degrees(model.pair_transform(images[starts + gap],
                                                               images[starts])[0]))
            for step in args.steps:
                if gap % step:
                    raise SystemExit(f"--steps {step} does not divide the pair gap, {gap} frames")
                steps, K = model.pair_transform(images[step:], images[:-step])
                if step == 1:
                    focal.append(float(K[:, 0, 0].median()) / proc.camera.fx)
                rows.setdefault(f"chain of {step}-frame steps", []).append(
                    degrees(chained(steps, starts, gap, step)))
    true = np.concatenate(rows.pop("true"))
    rms = np.sqrt((true**2).mean(0)).astype(float).round(2).tolist()
    print(f"{len(true)} pairs {model.config.pair_gap_s:g} s apart; true rms x/y/z {rms} deg"
          + (f"; consecutive pairs' fx / true {np.mean(focal):.2f}" if focal else ""))
    for name, values in rows.items():
        predicted = np.concatenate(values)
        corr = [np.corrcoef(predicted[:, k], true[:, k])[0, 1] for k in range(3)]
        print(f"{name:26s} slope x/y/z {np.round(axis_slopes(predicted, true), 2).tolist()}"
              f"  correlation {np.round(corr, 2).tolist()}")


if __name__ == "__main__":
    main()
