"""View-synthesis losses (paper eq. 1; Gordon et al. 2019; monodepth2).

photometric (L1 + SSIM, optionally on blurred images or also at coarser resolutions) with
per-pixel minimum over sources and auto-masking, occlusion-aware depth consistency,
rotation/translation cycle consistency, edge-aware smoothness, and optionally rigid flow
against classical optical flow and an inverse-square shading prior (learned.shading).
Endoscopy helps: per-pair brightness match, specular and border masks, and an optional
inverse-square correction for the light that moves with the camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from kornia.filters import gaussian_blur2d
from kornia.losses import inverse_depth_smoothness_loss
from kornia.metrics import ssim

from learned.config import DepthConfig
from learned.geometry import Warp, project, transform_from, warp
from learned.shading import shading_loss

_SPECULAR_THRESHOLD = 0.96
"""A pixel whose mean RGB exceeds this is a specular highlight."""


def photometric_error(a: torch.Tensor, b: torch.Tensor, config: DepthConfig) -> torch.Tensor:
    """(B, 1, H, W) per-pixel w_ssim·(1 - SSIM)/2 + w_l1·L1, averaged over channels."""
    l1 = (a - b).abs().mean(1, keepdim=True)
    dssim = ((1 - ssim(a, b, config.ssim_window)) / 2).clamp(0, 1).mean(1, keepdim=True)
    return config.w_ssim * dssim + config.w_l1 * l1


def _blur_reach(config: DepthConfig) -> int:
    """Pixels the photo_blur kernel reaches on each side (3 standard deviations)."""
    return math.ceil(3 * config.photo_blur)


def _reach(config: DepthConfig) -> int:
    """Pixels on each side that a compared pixel's error reads: the SSIM window's half and
    the photo_blur kernel's reach."""
    return config.ssim_window // 2 + _blur_reach(config)


def within_region(region: torch.Tensor, config: DepthConfig) -> torch.Tensor:
    """(B, 1, H, W) pixels of the image region whose error reads no pixel outside it (beyond
    the image's own edge counts as inside: a frame without a border loses nothing)."""
    grow = _reach(config)
    outside = F.max_pool2d((~region.bool()).float(), 2 * grow + 1, 1, grow) > 0
    return region.bool() & ~outside


def denoised(image: torch.Tensor, config: DepthConfig) -> torch.Tensor:
    """The image as the photometric error sees it: blurred by config.photo_blur (or as is)."""
    sigma = config.photo_blur
    if sigma == 0:
        return image
    size = 2 * _blur_reach(config) + 1
    return gaussian_blur2d(image, (size, size), (sigma, sigma), border_type="replicate")


def _coarse_error(source: torch.Tensor, target: torch.Tensor, w: Warp, mask: torch.Tensor,
                  level: int, config: DepthConfig, full: torch.Tensor) -> torch.Tensor:
    """Photometric error at 1/2^level resolution, brought back to (B, 1, H, W).

    Target and source are block means; each block of the target samples the coarse source at
    the mean of its pixels' landing points. Pixels of blocks that are not wholly usable (`mask`:
    image region, no highlight, landing in the source) keep their full-resolution error `full`.
    """
    factor = 2**level
    source, target = F.avg_pool2d(source, factor), F.avg_pool2d(target, factor)
    height, width = source.shape[-2:]
    where = (F.avg_pool2d(w.where.permute(0, 3, 1, 2), factor) + 0.5) / factor - 0.5
    grid = torch.stack([2 * where[:, 0] / (width - 1) - 1, 2 * where[:, 1] / (height - 1) - 1],
                       dim=-1)
    image = F.grid_sample(source, grid, mode="bilinear", padding_mode="border",
                          align_corners=True)
    image = _relit(image, F.avg_pool2d(w.ray_ratio, factor), config)
    usable = F.avg_pool2d(mask.float(), factor) > 0.999
    if config.brightness_match:
        image = match_brightness(image, target, usable)
    error = photometric_error(image, target, config)
    return torch.where(_to_full(usable, factor), _to_full(error, factor), full)


def _identity_error(source: torch.Tensor, target: torch.Tensor, config: DepthConfig
                    ) -> torch.Tensor:
    """Error of the un-warped source, averaged over the same resolutions as the warped one."""
    errors = [photometric_error(source, target, config)]
    for level in range(1, config.coarse_levels + 1):
        factor = 2**level
        errors.append(_to_full(photometric_error(F.avg_pool2d(source, factor),
                                                 F.avg_pool2d(target, factor), config), factor))
    return torch.stack(errors).mean(0)


def _to_full(coarse: torch.Tensor, factor: int) -> torch.Tensor:
    """Each coarse pixel repeated over its factor x factor block."""
    return coarse.repeat_interleave(factor, dim=-2).repeat_interleave(factor, dim=-1)


def match_brightness(warped: torch.Tensor, target: torch.Tensor, mask: torch.Tensor
                     ) -> torch.Tensor:
    """Affine per-channel map of `warped` so that its mean and std over mask match target's."""
    weight = mask.float()
    count = weight.sum(dim=(2, 3), keepdim=True).clamp(min=1.0)

    def stats(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mean = (x * weight).sum(dim=(2, 3), keepdim=True) / count
        var = (((x - mean) ** 2) * weight).sum(dim=(2, 3), keepdim=True) / count
        return mean, var.clamp(min=1e-6).sqrt()

    mean_w, std_w = stats(warped)
    mean_t, std_t = stats(target)
    return (warped - mean_w) * (std_t / std_w).detach() + mean_t.detach()


def specular(image: torch.Tensor, grow: int = 1) -> torch.Tensor:
    """(B, 1, H, W) bool mask of near-white highlights, grown by `grow` pixels."""
    bright = (image.mean(1, keepdim=True) > _SPECULAR_THRESHOLD).float()
    return torch.nn.functional.max_pool2d(bright, 2 * grow + 1, 1, grow) > 0


def highlights(image: torch.Tensor, config: DepthConfig) -> torch.Tensor:
    """Highlights of a sharp image, grown by the reach of a compared pixel's error (the SSIM
    window and the photo_blur kernel), so that no compared pixel reads their light."""
    return specular(image, max(1, _reach(config)))


def flow_error(where: torch.Tensor, flow: torch.Tensor, trusted: torch.Tensor,
               scale_px: float) -> torch.Tensor:
    """Mean Cauchy distance log(1 + (d / scale_px)^2) between where target pixels land by a
    depth, motion and K, `where` (B, H, W, 2), and where the optical flow (B, H, W, 2)
    takes them, over the trusted pixels (B, H, W) whose flow lands inside the image. The
    Cauchy penalty keeps pulling from far away and shrugs off the flow's gross errors."""
    height, width = flow.shape[1:3]
    pixels = torch.stack(torch.meshgrid(torch.arange(width, device=flow.device),
                                        torch.arange(height, device=flow.device),
                                        indexing="xy"), -1).to(flow.dtype)
    landing = pixels + flow
    keep = trusted & (landing[..., 0] >= 0) & (landing[..., 0] <= width - 1) \
        & (landing[..., 1] >= 0) & (landing[..., 1] <= height - 1)
    distance = (where - landing).norm(dim=-1)
    cost = torch.log1p((distance / scale_px) ** 2)
    return (cost * keep).sum() / keep.sum().clamp(min=1)


@dataclass
class LossTerms:
    total: torch.Tensor
    photometric: torch.Tensor
    smoothness: torch.Tensor
    depth_consistency: torch.Tensor
    rotation_cycle: torch.Tensor
    translation_cycle: torch.Tensor
    flow: torch.Tensor
    shading: torch.Tensor
    chain: torch.Tensor = field(default_factory=lambda: torch.zeros(()))
    """Set by DepthModel.loss when config.w_chain > 0."""
    zoom: torch.Tensor = field(default_factory=lambda: torch.zeros(()))
    """Set by DepthModel.loss when config.w_zoom > 0."""
    map_view: torch.Tensor = field(default_factory=lambda: torch.zeros(()))
    """This and the three below: set by learned.map_triplets.with_map_terms (train-depth
    --maps)."""
    map_rotation: torch.Tensor = field(default_factory=lambda: torch.zeros(()))
    map_direction: torch.Tensor = field(default_factory=lambda: torch.zeros(()))
    map_focal: torch.Tensor = field(default_factory=lambda: torch.zeros(()))

    def as_floats(self) -> dict[str, float]:
        return {k: float(v.detach()) for k, v in vars(self).items()}


def view_synthesis_loss(
    target: torch.Tensor,
    sources: list[torch.Tensor],
    target_depth: torch.Tensor,
    source_depths: list[torch.Tensor],
    motions: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]],
    K: torch.Tensor,
    region: torch.Tensor,
    config: DepthConfig,
    flows: list[tuple[torch.Tensor, torch.Tensor]] | None = None,
) -> LossTerms:
    """Loss of one batch of (target, sources) with predicted depths, motions and K.

    motions[k] = (rotation, translation) target->source and (rotation, translation)
    source->target, each (B, 3). region (B, 1, H, W) marks the endoscope's image area.
    flows[k] = (optical flow target -> source k (B, H, W, 2), trusted (B, H, W)), needed when
    config.w_flow > 0 (learned.flow.batch_flows).
    """
    if config.w_flow > 0 and flows is None:
        raise ValueError("w_flow > 0 needs the optical flows of the target to each source")
    usable = within_region(region, config)
    if config.specular_mask:
        usable = usable & ~highlights(target, config)
    seen_target = denoised(target, config)
    errors, identity_errors = [], []
    consistency, rot_cycle, trans_cycle, flow_errors = [], [], [], []
    for k, (source, source_depth, (r_ts, t_ts, r_st, t_st)) in enumerate(zip(
            sources, source_depths, motions, strict=True)):
        T_ts = transform_from(r_ts, t_ts)
        T_st = transform_from(r_st, t_st)
        seen_source = denoised(source, config)
        # one warp for the sharp source (its highlights), the blurred one (compared) and the
        # region (the sequence's, the same in every frame): a pixel that lands in the source's
        # border is not compared
        both = [source] if seen_source is source else [source, seen_source]
        w = warp(torch.cat([*both, region.float()], 1), target_depth, T_ts, K, source_depth)
        sharp, seen = w.image[:, :3], w.image[:, -4:-1]
        compared = usable & ~highlights(sharp, config) if config.specular_mask else usable
        mask = compared & w.valid & within_region(w.image[:, -1:] > 0.999, config)
        if config.mask_out_of_view:
            compared = mask
        image = _relit(seen, w.ray_ratio, config)
        if config.brightness_match:
            image = match_brightness(image, seen_target, mask)
        levels = [photometric_error(image, seen_target, config)]
        levels += [_coarse_error(seen_source, seen_target, w, mask, level, config, levels[0])
                   for level in range(1, config.coarse_levels + 1)]
        error = torch.stack(levels).mean(0)
        errors.append(torch.where(compared, error, torch.full_like(error, 1e3)))
        identity_errors.append(_identity_error(seen_source, seen_target, config))
        consistency.append(_depth_consistency(w, mask))
        if config.w_flow > 0:  # steers motion and K only: the flow's errors would bend depth
            rigid = project(target_depth.detach(), T_ts, K)[2]
            flow, trusted = flows[k]
            flow_errors.append(flow_error(rigid, flow, trusted & usable[:, 0],
                                          config.flow_scale_px))
        cycle = T_st @ T_ts
        eye = torch.eye(3, device=cycle.device, dtype=cycle.dtype)
        rot_cycle.append(((cycle[:, :3, :3] - eye) ** 2).mean())
        trans_cycle.append((cycle[:, :3, 3].norm(dim=1) / (
            t_ts.norm(dim=1) + t_st.norm(dim=1) + 1e-6)).mean())

    best, _ = torch.stack(errors).min(dim=0)
    keep = best < 1e2  # some source saw the pixel
    if config.automask:
        identity, _ = torch.stack(identity_errors).min(dim=0)
        identity = identity + 1e-5 * torch.randn_like(identity)  # break ties as monodepth2
        keep = keep & (best < identity)
    photometric = (best * keep).sum() / keep.sum().clamp(min=1)
    disparity = 1.0 / target_depth
    disparity = disparity / disparity.mean(dim=(2, 3), keepdim=True)
    smoothness = inverse_depth_smoothness_loss(disparity, target)
    depth_consistency = torch.stack(consistency).mean()
    rotation_cycle = torch.stack(rot_cycle).mean()
    translation_cycle = torch.stack(trans_cycle).mean()
    flow = torch.stack(flow_errors).mean() if flow_errors else torch.zeros_like(photometric)
    shading = _shading(target, target_depth, K, usable, config)
    total = (photometric + config.w_smooth * smoothness
             + config.w_depth_consistency * depth_consistency
             + config.w_rotation_cycle * rotation_cycle
             + config.w_translation_cycle * translation_cycle
             + config.w_flow * flow
             + config.w_shading * shading)
    return LossTerms(total, photometric, smoothness, depth_consistency, rotation_cycle,
                     translation_cycle, flow, shading)


def _shading(target: torch.Tensor, depth: torch.Tensor, K: torch.Tensor, usable: torch.Tensor,
             config: DepthConfig) -> torch.Tensor:
    """The shading prior on the target, its gradient reaching what config.shading_steers says."""
    if config.w_shading == 0:
        return torch.zeros((), device=target.device)
    if config.shading_steers == "depth":
        K = K.detach()
    elif config.shading_steers == "intrinsics":
        depth = depth.detach()
    return shading_loss(target, depth, K, usable, config.display_gamma)


def _relit(image: torch.Tensor, ray_ratio: torch.Tensor, config: DepthConfig) -> torch.Tensor:
    """Warped source intensity, corrected for the light at the camera if configured: times the
    squared ratio of the ray lengths (source / target), in the video's gamma encoding."""
    if not config.inverse_square:
        return image
    return image * ray_ratio.clamp(0.5, 2.0) ** (2.0 / config.display_gamma)


def _depth_consistency(w: Warp, mask: torch.Tensor) -> torch.Tensor:
    """Relative depth disagreement where the target's point is not hidden in the source.

    A target point in front of the source's own surface (z <= sampled depth) should lie on it;
    a point behind it is occluded in the source and is not penalised.
    """
    z, d = w.depth_in_source, w.sampled_source_depth
    visible = mask & (z <= d)
    error = (z - d).abs() / (z + d)
    return (error * visible).sum() / visible.sum().clamp(min=1)
