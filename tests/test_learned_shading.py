"""learned.shading: the inverse-square shading prior on an analytic, evenly coloured plane lit
from the camera."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from learned.config import DepthConfig
from learned.losses import _shading
from learned.shading import shading_loss, shading_residual

H, W = 48, 64
FX, FY, CX, CY = 40.0, 42.0, 31.5, 23.5
Z0, A, B = 4.0, 0.3, -0.2
"""Plane Z = Z0 + A·X + B·Y in the camera's frame: tilted, so depth and the angle of incidence
vary across the image."""
GAMMA = 2.2
ALBEDO = 8.0
"""Albedo times the light's gain: linear intensity a·cos θ / r² spans 0.048-0.565."""


def plane() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Gamma-encoded image (1, 3, H, W), z-depth (1, 1, H, W) and K (1, 3, 3), by hand."""
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    ray = np.stack([(u - CX) / FX, (v - CY) / FY, np.ones_like(u)], axis=-1)  # z = 1
    normal = np.array([-A, -B, 1.0]) / np.linalg.norm([-A, -B, 1.0])
    depth = Z0 / (ray @ np.array([-A, -B, 1.0]))
    distance = depth * np.linalg.norm(ray, axis=-1)
    cos = np.abs(ray @ normal) / np.linalg.norm(ray, axis=-1)
    linear = ALBEDO * cos / distance**2
    assert linear.min() > 0.04 and linear.max() < 0.6
    image = np.repeat((linear ** (1 / GAMMA))[None], 3, axis=0)
    K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
    return (torch.tensor(image[None], dtype=torch.float32),
            torch.tensor(depth[None, None], dtype=torch.float32),
            torch.tensor(K[None], dtype=torch.float32))


@pytest.fixture(scope="module")
def scene():
    image, depth, K = plane()
    usable = torch.zeros(1, 1, H, W, dtype=torch.bool)
    usable[..., 2:-2, 2:-2] = True  # normals from finite differences are exact inside
    return image, depth, K, usable


def test_residual_is_the_log_albedo_for_the_true_depth(scene):
    image, depth, K, usable = scene
    e = shading_residual(image, depth, K, GAMMA)[usable]
    assert float((e - np.log(ALBEDO)).abs().max()) < 2e-3


def test_the_prior_is_zero_at_the_truth_whatever_the_scale_and_grows_with_the_wrong_shape(
        scene):
    image, depth, K, usable = scene
    truth = float(shading_loss(image, depth, K, usable, GAMMA))
    assert truth < 2e-3
    assert abs(float(shading_loss(image, 3.7 * depth, K, usable, GAMMA)) - truth) < 1e-4
    median = depth.median()
    for power in (0.6, 1.5):  # compressed and stretched about the median
        shaped = depth**power * median ** (1 - power)
        assert float(shading_loss(image, shaped, K, usable, GAMMA)) > 0.05


def test_a_pixel_darker_than_the_falloff_says_may_lie_farther_not_nearer(scene):
    """The hinge: ambient light only brightens, so the prior pushes a dark patch away while its
    depth is too near for its darkness, and leaves it once it is farther. (Scaling a patch of a
    plane's depth keeps it planar, so normals inside the patch stay exact.)"""
    image, depth, K, usable = scene
    patch, inner = np.s_[..., 18:30, 26:38], np.s_[..., 21:27, 29:35]
    dark = image.clone()
    dark[patch] *= 0.25
    assert float(dark[patch].max()) < 0.2  # below the lit level: only the hinge sees it
    falloff = 0.25 ** (-GAMMA / 2)  # the distance factor that the patch's darkness says

    def gradient(factor: float) -> torch.Tensor:
        moved = depth.clone()
        moved[patch] *= factor
        moved.requires_grad_()
        shading_loss(dark, moved, K, usable, GAMMA).backward()
        return moved.grad[inner]

    assert bool((gradient(1.0) < 0).all()) and bool((gradient(0.7) < 0).all())
    assert float(gradient(1.2 * falloff).abs().max()) == 0


def test_an_image_with_no_lit_pixel_adds_nothing_and_keeps_gradients_finite(scene):
    image, depth, K, usable = scene
    dim = torch.cat([image, 0.1 * image])  # the second image has no pixel above the lit level
    depths = torch.cat([depth, depth]).requires_grad_()
    loss = shading_loss(dim, depths, K.expand(2, 3, 3), torch.cat([usable, usable]), GAMMA)
    loss.backward()
    loss = loss.detach()
    assert abs(float(loss) - 0.5 * float(shading_loss(image, depth, K, usable, GAMMA))) < 1e-6
    assert torch.isfinite(depths.grad).all() and float(depths.grad[1].abs().sum()) == 0


@pytest.mark.parametrize("steers", ["depth", "intrinsics", "both"])
def test_the_prior_steers_what_the_config_says(scene, steers):
    image, depth, K, usable = scene
    depth, K = (2.0 * depth).requires_grad_(), (1.1 * K).requires_grad_()  # off the truth
    config = replace(DepthConfig(), w_shading=0.1, shading_steers=steers, display_gamma=GAMMA)
    _shading(image, depth**0.8, K, usable, config).backward()

    def reached(x: torch.Tensor) -> bool:
        return x.grad is not None and bool(x.grad.abs().sum() > 0)

    assert reached(depth) == (steers != "intrinsics")
    assert reached(K) == (steers != "depth")


def test_the_prior_is_off_at_weight_zero_and_refuses_an_unknown_target(scene):
    image, depth, K, usable = scene
    assert float(_shading(image, depth, K, usable, DepthConfig())) == 0
    with pytest.raises(ValueError, match="shading_steers"):
        replace(DepthConfig(), shading_steers="albedo")
