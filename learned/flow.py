"""Optical flow between training frames (OpenCV's DIS), a wide-reaching target for rigid flow.

A motion fitted to the photometric loss from rest settles with sideways translation standing
in for pitch and yaw (benchmarks/direct_pose.py). DIS optical flow is found coarse to fine and
reaches displacements of many pixels; with `w_flow` the rigid flow of the predicted motion and
K is pulled towards it where it passes a forward-backward check (learned.losses.flow_error).
Measured, it does not help (docs/depth.md, "Rotation out of reach"), so it is off by default.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from learned.config import DepthConfig

FB_TOLERANCE_PX = 1.0
"""Largest forward-backward mismatch (pixels) of a flow vector that is trusted."""


def dis_flow(target: np.ndarray, source: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flow (H, W, 2) from RGB uint8 target to source (target pixel x lies at x + flow in the
    source) and (H, W) bool where it agrees with the backward flow within FB_TOLERANCE_PX."""
    gray = [cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) for image in (target, source)]
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    forward = dis.calc(gray[0], gray[1], None)
    backward = dis.calc(gray[1], gray[0], None)
    height, width = gray[0].shape
    landing = np.stack(np.meshgrid(np.arange(width, dtype=np.float32),
                                   np.arange(height, dtype=np.float32)), -1) + forward
    back = cv2.remap(backward, landing[..., 0], landing[..., 1], cv2.INTER_LINEAR)
    trusted = np.linalg.norm(forward + back, axis=-1) < FB_TOLERANCE_PX
    return forward, trusted


def batch_flows(targets: torch.Tensor, sources: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """dis_flow of each pair of (B, 3, H, W) images in [0, 1] (on any device): flows
    (B, H, W, 2) and trusted (B, H, W), on the images' device."""
    def rgb(images: torch.Tensor) -> np.ndarray:
        return (images.detach() * 255).round().byte().permute(0, 2, 3, 1).cpu().numpy()

    pairs = [dis_flow(t, s) for t, s in zip(rgb(targets), rgb(sources), strict=True)]
    flows = torch.from_numpy(np.stack([flow for flow, _ in pairs])).to(targets.device)
    trusted = torch.from_numpy(np.stack([ok for _, ok in pairs])).to(targets.device)
    return flows, trusted


def flows_to_sources(target: torch.Tensor, sources: list[torch.Tensor], config: DepthConfig
                     ) -> list[tuple[torch.Tensor, torch.Tensor]] | None:
    """batch_flows of the target to each source when the config's flow term is on (w_flow >
    0), the `flows` that learned.losses.view_synthesis_loss then needs; else None."""
    return [batch_flows(target, source) for source in sources] if config.w_flow > 0 else None
