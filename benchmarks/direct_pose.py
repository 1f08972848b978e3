"""Fit each triplet's motion directly to the training loss, with the true depth and K given.

No network: for triplets of simulated procedures, the two motions target -> source (axis-angle
and translation; each backward motion is the exact inverse) are optimised by Adam on
learned.losses.view_synthesis_loss, starting from no motion (or from the truth; `--grid`
also from a 3 x 3 grid of pitches and yaws, keeping the fit of lowest loss). Prints, per
rotation axis of the camera (x right, y down, z forward), the least-squares slope of the fitted
angles on the true ones (1: found; 0: no rotation found about that axis) and their
correlation, and the mean loss at the truth and at the fit. If a direct fit from rest stops
short of the true rotation, the loss itself steers a learner away from it, whatever network
predicts the motion.

    .venv/bin/python benchmarks/direct_pose.py --data data/val [--set coarse_levels=3]
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from depth_diagnosis import axis_slopes, triplets
from kornia.geometry.conversions import rotation_matrix_to_axis_angle

from hybrid.dataset import list_procedures
from learned.config import DepthConfig, parse_overrides
from learned.flow import flows_to_sources
from learned.geometry import transform_from
from learned.losses import view_synthesis_loss


def with_inverse(rotation: torch.Tensor, translation: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """(rotation, translation) and the exact inverse motion, as the loss takes them."""
    back = torch.linalg.inv(transform_from(rotation, translation))
    return rotation, translation, rotation_matrix_to_axis_angle(back[:, :3, :3]), back[:, :3, 3]


def fit(frames, depths, truth, K, config: DepthConfig, iterations: int, start: str,
        lr: tuple[float, float], grid_deg: float = 0.0):
    """The fitted rotations (2, 3) of both sources (the lowest-loss fit over the starts), and
    the loss at the truth and at the fit."""
    region = torch.ones(1, 1, *frames.shape[-2:])
    sources = [frames[:, 0], frames[:, 2]]
    flows = flows_to_sources(frames[:, 1], sources, config)  # once, not every iteration

    def loss(motion: list[torch.Tensor]) -> torch.Tensor:
        pairs = [with_inverse(motion[2 * k], motion[2 * k + 1]) for k in range(2)]
        return view_synthesis_loss(frames[:, 1], sources, depths[1], [depths[0], depths[2]],
                                   pairs, K, region, config, flows).total

    def descend(initial: list[torch.Tensor]) -> tuple[list[torch.Tensor], float]:
        motion = [t.clone().requires_grad_() for t in initial]
        optimizer = torch.optim.Adam([{"params": motion[0::2], "lr": lr[0]},  # radians
                                      {"params": motion[1::2], "lr": lr[1]}])  # cm
        for _ in range(iterations):
            value = loss(motion)
            optimizer.zero_grad()
            value.backward()
            optimizer.step()
        with torch.no_grad():
            return motion, float(loss(motion))

    true = [truth[0][0], truth[0][1], truth[1][0], truth[1][1]]
    motion, at_fit = min((descend(initial) for initial in starts(true, start, grid_deg)),
                         key=lambda fitted: fitted[1])
    with torch.no_grad():
        losses = float(loss(true)), at_fit
    fitted = torch.cat([motion[0], motion[2]]).detach().numpy()
    return fitted, torch.cat([true[0], true[2]]).numpy(), losses


def starts(true: list[torch.Tensor], start: str, grid_deg: float) -> list[list[torch.Tensor]]:
    """Initial motions: the truth, or rest, and with grid_deg > 0 also every pitch and yaw of
    -grid_deg, 0, +grid_deg for the first source (the opposite for the second), no
    translation."""
    if start == "truth":
        return [true]
    rest = [torch.zeros_like(t) for t in true]
    out = [rest]
    if grid_deg > 0:
        step = np.radians(grid_deg)
        for pitch in (-step, 0.0, step):
            for yaw in (-step, 0.0, step):
                if pitch or yaw:
                    turn = torch.tensor([[pitch, yaw, 0.0]], dtype=true[0].dtype)
                    out.append([turn, rest[1], -turn, rest[3]])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--every", type=int, default=120, help="frames between targets")
    parser.add_argument("--iterations", type=int, default=300)
    parser.add_argument("--start", choices=["rest", "truth"], default="rest")
    parser.add_argument("--lr", type=float, nargs=2, default=[2e-3, 5e-3],
                        metavar=("ROTATION", "TRANSLATION"),
                        help="Adam steps: radians and cm (simulator units)")
    parser.add_argument("--grid", type=float, default=0.0, metavar="DEG",
                        help="also start from pitch and yaw of -DEG, 0, +DEG (9 starts) and "
                             "keep the fit of lowest loss: a search over rotation")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        help="a loss setting, e.g. coarse_levels=3 (learned/config.py)")
    args = parser.parse_args()
    config = replace(DepthConfig(), **parse_overrides(args.overrides))
    fitted, true, losses = [], [], []
    for _, frames, depths, motions, K in triplets(list_procedures(args.data),
                                                  config.pair_gap_s, args.every):
        f, t, values = fit(frames, depths, motions, K, config, args.iterations, args.start,
                           tuple(args.lr), args.grid)
        fitted.append(f)
        true.append(t)
        losses.append(values)
    fitted, true = np.degrees(np.concatenate(fitted)), np.degrees(np.concatenate(true))
    print(f"{len(losses)} triplets, start at {args.start} (grid {args.grid:g} deg), "
          f"{args.iterations} Adam iterations, steps {args.lr[0]:g} rad / {args.lr[1]:g} cm")
    for k, (axis, slope) in enumerate(zip("xyz", axis_slopes(fitted, true), strict=True)):
        corr = np.corrcoef(fitted[:, k], true[:, k])[0, 1]
        print(f"rotation about {axis}: slope {slope:.2f}, correlation {corr:.2f}, "
              f"true rms {np.sqrt(np.mean(true[:, k] ** 2)):.2f} deg")
    at_truth, at_fit = np.mean(losses, axis=0)
    print(f"loss at the truth {at_truth:.4f}, at the fit {at_fit:.4f}")


if __name__ == "__main__":
    main()
