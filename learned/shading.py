"""The light at the camera as a depth cue: an inverse-square shading prior.

An endoscope lights the wall from the camera, so a wall point's linear intensity is
I = a · cos(θ) / r², with r its distance, θ the angle between its normal and the ray, and a
its albedo times the light's gain (the lens's vignetting, not modelled, reads as albedo too).
Given a depth map and K, the residual e = log I − log cos θ + 2 log r estimates log a; it is
one constant over an evenly coloured wall when the depth has the right shape, whatever its
scale. Unlike parallax, it
does not vanish near the focus of expansion, the far lumen that view synthesis leaves
compressed (docs/depth.md).

The prior: well-lit pixels (I large enough that the ambient light and the sensor's noise do not
dominate) keep e near the image's median over them (L1); every usable pixel is kept at or
above it (hinge), since ambient light only adds to I: a dark pixel may lie farther than the
falloff alone says, never nearer.
"""

from __future__ import annotations

import torch
from kornia.geometry.depth import depth_to_3d_v2, depth_to_normals

_LIT = 0.2
"""Encoded mean RGB from which a pixel is well lit (two-sided term)."""
_DARKEST = 0.02
"""Encoded mean RGB is floored here before linearising: below it sensor noise is all there
is."""
_GRAZING = 0.05
"""Smallest cos θ used: normals from a depth map are noisy at grazing angles."""


def shading_residual(image: torch.Tensor, depth: torch.Tensor, K: torch.Tensor,
                     gamma: float) -> torch.Tensor:
    """(B, 1, H, W) e = log I − log cos θ + 2 log r of images (B, 3, H, W) in [0, 1] encoded
    with `gamma`, depth (B, 1, H, W) and K (B, 3, 3)."""
    linear = _brightness(image).clamp(min=_DARKEST) ** gamma
    points = depth_to_3d_v2(depth[:, 0], K).permute(0, 3, 1, 2)
    distance = points.norm(dim=1, keepdim=True)
    normals = depth_to_normals(depth, K)
    cos = ((normals * points).sum(1, keepdim=True) / distance).abs().clamp(min=_GRAZING)
    return torch.log(linear) - torch.log(cos) + 2 * torch.log(distance)


def shading_loss(image: torch.Tensor, depth: torch.Tensor, K: torch.Tensor,
                 usable: torch.Tensor, gamma: float) -> torch.Tensor:
    """Mean over images of the prior (module docstring) on the usable pixels (B, 1, H, W)."""
    e = shading_residual(image, depth, K, gamma)
    lit = usable & (_brightness(image) > _LIT)
    median = torch.where(lit, e, torch.nan).flatten(1).nanmedian(dim=1).values
    median = median.nan_to_num(0.0)[:, None, None, None]  # no lit pixel: the image adds 0
    has_lit = lit.flatten(1).any(dim=1)
    prior = _mean_over((e - median).abs(), lit) + _mean_over(torch.relu(median - e), usable)
    return torch.where(has_lit, prior, torch.zeros_like(prior)).mean()


def _brightness(image: torch.Tensor) -> torch.Tensor:
    """(B, 1, H, W) encoded mean RGB."""
    return image.mean(1, keepdim=True)


def _mean_over(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(B,) mean of x (B, 1, H, W) over each image's masked pixels (0 where none)."""
    return (x * mask).flatten(1).sum(1) / mask.flatten(1).sum(1).clamp(min=1)
