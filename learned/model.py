"""The depth + motion + intrinsics model: its forward pass on triplets, and loading it."""

from __future__ import annotations

from contextlib import AbstractContextManager, contextmanager, nullcontext
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from kornia.geometry.conversions import rotation_matrix_to_axis_angle
from torch import nn

from learned.checkpoint import load_model
from learned.config import DepthConfig
from learned.flow import flows_to_sources
from learned.geometry import compose_chain, mean_transform, transform_from
from learned.losses import LossTerms, view_synthesis_loss
from learned.nets import DepthNet, MotionNet
from learned.zoom import ZoomPairs, zoom_consistency, zoom_pairs


class DepthModel(nn.Module):
    """DepthNet and MotionNet together, as trained by view synthesis."""

    def __init__(self, config: DepthConfig):
        super().__init__()
        self.config = config
        self.depth = DepthNet(config)
        self.motion = MotionNet(config)

    def predict_depth(self, rgb: torch.Tensor) -> torch.Tensor:
        """Depth (B, 1, H, W) of rgb (B, 3, H, W) as inference reads it: the geometric mean of
        the depth of the frame and of its config.depth_views - 1 mirror images, each mirrored
        back (a mirrored frame is a frame of a mirrored colon)."""
        if self.config.depth_views == 1:
            return self.depth(rgb)
        mirrors = ((-1,), (-2,), (-1, -2))[:self.config.depth_views - 1]
        log_depth = self.depth(rgb).log()
        for dims in mirrors:
            log_depth = log_depth + self.depth(rgb.flip(dims)).flip(dims).log()
        return (log_depth / self.config.depth_views).exp()

    def pair_motion(self, a: torch.Tensor, b: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor,
                               torch.Tensor]:
        """Motion a->b and b->a (axis-angle, translation each), and K averaged over both orders.

        a, b: (B, 3, H, W). The a->b transform maps points of camera a into camera b. While
        training (the motion network in training mode, gradients on), config.motion_noise adds
        Gaussian noise to both frames, of one standard deviation per pair.
        """
        if self.config.motion_noise and self.motion.training and torch.is_grad_enabled():
            sigma = self.config.motion_noise * torch.rand(a.shape[0], 1, 1, 1, device=a.device)
            a, b = a + sigma * torch.randn_like(a), b + sigma * torch.randn_like(b)
        rotation, translation, K = self.motion(torch.cat([torch.cat([a, b], 1),
                                                          torch.cat([b, a], 1)], 0))
        n = a.shape[0]
        return (rotation[:n], translation[:n], rotation[n:], translation[n:],
                0.5 * (K[:n] + K[n:]))

    def pair_transform(self, a: torch.Tensor, b: torch.Tensor
                       ) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, 4, 4) float64 transforms a -> b, each the mean of the forward and the inverted
        backward estimate, and the pairs' intrinsics (B, 3, 3)."""
        r_ab, t_ab, r_ba, t_ba, K = self.pair_motion(a, b)
        forward = transform_from(r_ab, t_ab).double()
        backward = torch.linalg.inv(transform_from(r_ba, t_ba).double())
        return mean_transform(forward, backward), K

    def triplet_motion(self, frames: torch.Tensor
                       ) -> tuple[list[tuple[torch.Tensor, ...]], torch.Tensor]:
        """Of triplets frames (B, >= 3, 3, H, W) (previous, target, next, ...): the motions
        target -> previous and target -> next (each as pair_motion gives it: axis-angle and
        translation there and back) and K averaged over both pairs."""
        motions, intrinsics = [], []
        for k in (0, 2):
            *motion, K = self.pair_motion(frames[:, 1], frames[:, k])
            motions.append(tuple(motion))
            intrinsics.append(K)
        return motions, torch.stack(intrinsics).mean(0)

    def loss(self, frames: torch.Tensor, region: torch.Tensor,
             depths: torch.Tensor | None = None, chain_target: torch.Tensor | None = None
             ) -> LossTerms:
        """View-synthesis loss of triplets frames (B, 3 + n, 3, H, W): previous, target, next,
        then n frames that only `chained_rotation` reads.

        depths (B, 3, 1, H, W), if given, replace the depth network (to probe the motion net).
        chain_target (B, 3): the rotation target -> previous that the chain term (config.w_chain
        > 0) pulls the estimate towards, from `chained_rotation`.
        """
        batch = frames.shape[0]
        if depths is None:
            depths = self.depth(frames[:, :3].flatten(0, 1)).unflatten(0, (batch, 3))
        target = frames[:, 1]
        motions, K = self.triplet_motion(frames)
        sources = [frames[:, 0], frames[:, 2]]
        terms = view_synthesis_loss(target, sources, depths[:, 1], [depths[:, 0], depths[:, 2]],
                                    motions, K, region, self.config.ordinary_view(),
                                    flows_to_sources(target, sources, self.config))
        if self.config.w_chain:
            if chain_target is None:
                raise ValueError("config.w_chain > 0 needs the chain_target rotations")
            chain = (motions[0][0] - chain_target).abs().sum(1).mean()
            terms = replace(terms, total=terms.total + self.config.w_chain * chain, chain=chain)
        if self.config.w_zoom:
            zoom = self.zoom_loss(frames[:, :2])
            terms = replace(terms, total=terms.total + self.config.w_zoom * zoom, zoom=zoom)
        return terms

    def zoom_loss(self, pairs: torch.Tensor) -> torch.Tensor:
        """Zoom consistency (learned.zoom) of the K read from pairs (B, 2, 3, H, W)."""
        views = zoom_pairs(pairs, self.config.zoom_max)
        return zoom_consistency(*self.zoom_intrinsics(views), views.boxes, pairs.shape[-2:])

    def zoom_intrinsics(self, views: ZoomPairs) -> tuple[torch.Tensor, torch.Tensor]:
        """K (B, 3, 3) the head reads from the zoomed pairs and from the whole ones (frame 1
        as the target, frame 0 as the source, as DepthModel.loss pairs them)."""
        # One batch, so that batch norm does not normalise away what all the crops share.
        both = torch.cat([views.zoomed, views.whole])
        with self.crop_batch():
            K = self.pair_motion(both[:, 1], both[:, 0])[-1]
        return K[:len(views.boxes)], K[len(views.boxes):]

    def crop_batch(self) -> AbstractContextManager:
        """The context the crop batches (the zoom term's, map_zoom's) pass the motion network
        in: they move its batch-norm running statistics only if config.zoom_updates_bn."""
        return nullcontext() if self.config.zoom_updates_bn else bn_momentum(self.motion, 0.0)


@contextmanager
def bn_momentum(module: nn.Module, momentum: float | None):
    """Batch norm in `module` with this momentum for the duration: 0 leaves the running
    statistics as they are (training still normalises each batch by its own), None makes
    them a cumulative average."""
    norms = [m for m in module.modules() if isinstance(m, nn.BatchNorm2d)]
    momenta = [m.momentum for m in norms]
    for m in norms:
        m.momentum = momentum
    try:
        yield norms
    finally:
        for m, previous in zip(norms, momenta, strict=True):
            m.momentum = previous


@torch.no_grad()
def chained_rotation(model: DepthModel, frames: torch.Tensor) -> torch.Tensor:
    """(B, 3) axis-angle rotation target -> previous composed from the model's motion
    estimates between consecutive frames of the chain previous, frames[:, 3:]..., target
    (frames as in DepthModel.loss), in eval mode as at inference. The motion net finds more of
    the rotation in small steps than over the pair gap (docs/depth.md)."""
    chain = torch.cat([frames[:, :1], frames[:, 3:], frames[:, 1:2]], 1)
    batch, count = chain.shape[:2]
    training = model.motion.training
    model.motion.eval()
    try:
        steps = model.pair_transform(chain[:, 1:].flatten(0, 1), chain[:, :-1].flatten(0, 1))[0]
    finally:
        model.motion.train(training)
    composed = compose_chain(steps.unflatten(0, (batch, count - 1)))  # frame k+1 -> frame k
    return rotation_matrix_to_axis_angle(composed[:, :3, :3].float())


def to_tensor(images: np.ndarray, device: torch.device | str = "cpu") -> torch.Tensor:
    """RGB uint8 (..., H, W, 3) -> float (..., 3, H, W) in [0, 1], on `device`."""
    images = torch.from_numpy(np.ascontiguousarray(images)).to(device)
    return images.movedim(-1, -3).float() / 255.0


def load_depth_model(path: Path, preset: str | None = None,
                     device: torch.device | str = "cpu") -> DepthModel:
    """A trained model in eval mode on `device`; checks that it is of the expected preset if
    one is given."""
    return load_model(path, "depth", DepthConfig, DepthModel, preset).to(device)
