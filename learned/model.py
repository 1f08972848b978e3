"""The depth + motion + intrinsics model: its forward pass on triplets, and loading it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from learned.checkpoint import load_model
from learned.config import DepthConfig
from learned.flow import flows_to_sources
from learned.losses import LossTerms, view_synthesis_loss
from learned.nets import DepthNet, MotionNet


class DepthModel(nn.Module):
    """DepthNet and MotionNet together, as trained by view synthesis."""

    def __init__(self, config: DepthConfig):
        super().__init__()
        self.config = config
        self.depth = DepthNet(config)
        self.motion = MotionNet(config)

    def pair_motion(self, a: torch.Tensor, b: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor,
                               torch.Tensor]:
        """Motion a->b and b->a (axis-angle, translation each), and K averaged over both orders.

        a, b: (B, 3, H, W). The a->b transform maps points of camera a into camera b.
        """
        rotation, translation, K = self.motion(torch.cat([torch.cat([a, b], 1),
                                                          torch.cat([b, a], 1)], 0))
        n = a.shape[0]
        return (rotation[:n], translation[:n], rotation[n:], translation[n:],
                0.5 * (K[:n] + K[n:]))

    def loss(self, frames: torch.Tensor, region: torch.Tensor,
             depths: torch.Tensor | None = None) -> LossTerms:
        """View-synthesis loss of triplets frames (B, 3 frames, 3, H, W): previous, target, next.

        depths (B, 3, 1, H, W), if given, replace the depth network (to probe the motion net).
        """
        batch = frames.shape[0]
        if depths is None:
            depths = self.depth(frames.flatten(0, 1)).unflatten(0, (batch, 3))
        target = frames[:, 1]
        motions, intrinsics = [], []
        for k in (0, 2):
            r_ts, t_ts, r_st, t_st, K = self.pair_motion(target, frames[:, k])
            motions.append((r_ts, t_ts, r_st, t_st))
            intrinsics.append(K)
        K = torch.stack(intrinsics).mean(0)
        sources = [frames[:, 0], frames[:, 2]]
        return view_synthesis_loss(target, sources, depths[:, 1], [depths[:, 0], depths[:, 2]],
                                   motions, K, region, self.config,
                                   flows_to_sources(target, sources, self.config))


def to_tensor(images: np.ndarray, device: torch.device | str = "cpu") -> torch.Tensor:
    """RGB uint8 (..., H, W, 3) -> float (..., 3, H, W) in [0, 1], on `device`."""
    images = torch.from_numpy(np.ascontiguousarray(images)).to(device)
    return images.movedim(-1, -3).float() / 255.0


def load_depth_model(path: Path, preset: str | None = None,
                     device: torch.device | str = "cpu") -> DepthModel:
    """A trained model in eval mode on `device`; checks that it is of the expected preset if
    one is given."""
    return load_model(path, "depth", DepthConfig, DepthModel, preset).to(device)
