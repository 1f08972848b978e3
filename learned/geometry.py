"""Differentiable view synthesis: back-project a depth map, move it, project and sample.

Shapes are batch-first; images (B, C, H, W), depth (B, 1, H, W), K (B, 3, 3), transforms
(B, 4, 4) mapping points of the target camera into the source camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from kornia.geometry.depth import depth_to_3d_v2


def transform_from(rotation: torch.Tensor, translation: torch.Tensor) -> torch.Tensor:
    """(B, 4, 4) rigid transform from axis-angle (B, 3) and translation (B, 3)."""
    T = torch.eye(4, device=rotation.device, dtype=rotation.dtype).repeat(rotation.shape[0], 1, 1)
    T[:, :3, :3] = axis_angle_to_rotation_matrix(rotation)
    T[:, :3, 3] = translation
    return T


def mean_transform(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Average of two estimates (B, 4, 4) of the same transform, its rotation projected back
    to SO(3)."""
    mean = 0.5 * (a + b)
    U, _, Vt = torch.linalg.svd(mean[:, :3, :3])
    det = torch.linalg.det(U @ Vt)
    D = torch.diag_embed(torch.stack([torch.ones_like(det), torch.ones_like(det), det], -1))
    mean[:, :3, :3] = U @ D @ Vt
    return mean


def compose_chain(steps: torch.Tensor) -> torch.Tensor:
    """(B, 4, 4) product steps[:, 0] @ steps[:, 1] @ ... of (B, n, 4, 4) transforms: with step k
    mapping frame k+1 into frame k, the transform from frame n into frame 0."""
    composed = steps[:, 0]
    for k in range(1, steps.shape[1]):
        composed = composed @ steps[:, k]
    return composed


@dataclass
class Warp:
    """A source image warped into the target view."""

    image: torch.Tensor
    """(B, C, H, W) source sampled at the target pixels' projections."""
    valid: torch.Tensor
    """(B, 1, H, W) bool: projection lands inside the source image, in front of it."""
    depth_in_source: torch.Tensor
    """(B, 1, H, W) z of the target's 3-D points in the source camera."""
    sampled_source_depth: torch.Tensor | None
    """(B, 1, H, W) the source's own depth sampled at the same places (if given)."""
    ray_ratio: torch.Tensor
    """(B, 1, H, W) distance to the source camera / distance to the target camera."""
    where: torch.Tensor
    """(B, H, W, 2) where each target pixel lands in the source, in source pixels (u, v)."""


def project(target_depth: torch.Tensor, T_target_to_source: torch.Tensor, K: torch.Tensor
            ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The target pixels' 3-D points (B, H, W, 3) in the target camera, the same points in the
    source camera, and where they land in the source (B, H, W, 2), in pixels (u, v)."""
    points = depth_to_3d_v2(target_depth[:, 0], K)
    R, t = T_target_to_source[:, :3, :3], T_target_to_source[:, :3, 3]
    moved = torch.einsum("bij,bhwj->bhwi", R, points) + t[:, None, None, :]
    z = moved[..., 2]
    z_safe = torch.where(z > 1e-3, z, torch.full_like(z, 1e-3))
    u = K[:, 0, 0, None, None] * moved[..., 0] / z_safe + K[:, 0, 2, None, None]
    v = K[:, 1, 1, None, None] * moved[..., 1] / z_safe + K[:, 1, 2, None, None]
    return points, moved, torch.stack([u, v], dim=-1)


def warp(source: torch.Tensor, target_depth: torch.Tensor, T_target_to_source: torch.Tensor,
         K: torch.Tensor, source_depth: torch.Tensor | None = None) -> Warp:
    """Synthesise the target view from the source image, the target depth, the motion and K."""
    _, _, height, width = source.shape
    points, moved, where = project(target_depth, T_target_to_source, K)
    z = moved[..., 2]
    u, v = where[..., 0], where[..., 1]
    grid = torch.stack([2 * u / (width - 1) - 1, 2 * v / (height - 1) - 1], dim=-1)
    inside = (grid.abs() <= 1).all(dim=-1) & (z > 1e-3)

    def sample(x: torch.Tensor) -> torch.Tensor:
        return F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=True)

    ratio = moved.norm(dim=-1) / points.norm(dim=-1).clamp(min=1e-6)
    return Warp(
        image=sample(source),
        valid=inside[:, None],
        depth_in_source=z[:, None],
        sampled_source_depth=None if source_depth is None else sample(source_depth),
        ray_ratio=ratio[:, None],
        where=where,
    )
