"""Zoom consistency of the intrinsics head: a crop of a frame is a frame of a longer camera.

Cutting a w x h box out of a pinhole image and resizing it to the full W x H projects the
scene as a camera of focal length s·f would, s = W / w, with the principal point moved and
scaled alike. So, without any ground truth, the K the head reads from a zoomed pair must be
the K it reads from the whole pair, zoomed. View synthesis alone pulls the head only weakly
towards the right focal length, and the head came to give nearly one focal length for every
camera (docs/depth.md); this term asks it to follow the image's scale. What the camera adds
on the image plane does not follow the zoom: a crop enlarges the vignetting and the sensor
noise with the scene.

A resized crop is blurrier than a frame, which would let the head tell the two apart by blur
alone. The whole frame is therefore compared at the same loss of detail: shrunk to the crop's
size and enlarged back, by the same interpolation as the crop (the shrink also averages the
sensor noise down, which the crop keeps).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F


@dataclass(frozen=True)
class ZoomPairs:
    """Frames of one batch as zoomed crops and as whole frames at the crops' detail."""

    zoomed: torch.Tensor
    """(B, N, 3, H, W): each sample's box of its frames, enlarged to (H, W)."""
    whole: torch.Tensor
    """(B, N, 3, H, W): each sample's whole frames, shrunk to its box size and enlarged back."""
    boxes: torch.Tensor
    """(B, 4) float: x0, y0, w, h of each sample's box in pixels of the frames."""


def zoom_pairs(frames: torch.Tensor, zoom_max: float, generator: torch.Generator | None = None
               ) -> ZoomPairs:
    """A random box per sample (the same for its N frames): its size 1/s of the frame's, s
    log-uniform in [1, zoom_max], its position uniform. frames (B, N, 3, H, W)."""
    if not zoom_max > 1:
        raise ValueError(f"zoom_max must be > 1, got {zoom_max}")
    batch, _, _, height, width = frames.shape
    draws = torch.rand(batch, 3, generator=generator)
    boxes = []
    for s, (u, v) in zip((zoom_max ** draws[:, 0]).tolist(), draws[:, 1:].tolist(),
                         strict=True):
        h, w = _box_size((height, width), s)
        boxes.append((round(u * (width - w)), round(v * (height - h)), w, h))
    return views_of(frames, boxes)


def centred_box(size: tuple[int, int], zoom: float) -> tuple[int, int, int, int]:
    """(x0, y0, w, h) of the centred box 1/zoom of an image of size (H, W)."""
    h, w = _box_size(size, zoom)
    return (size[1] - w) // 2, (size[0] - h) // 2, w, h


def _box_size(size: tuple[int, int], zoom: float) -> tuple[int, int]:
    """(h, w) of a box 1/zoom of an image of size (H, W), in whole pixels."""
    return max(2, round(size[0] / zoom)), max(2, round(size[1] / zoom))


def views_of(frames: torch.Tensor, boxes: list[tuple[int, int, int, int]]) -> ZoomPairs:
    """Each sample's frames (B, N, 3, H, W) cut to its box (x0, y0, w, h) and enlarged, and
    whole at that box's detail."""
    size = frames.shape[-2:]
    zoomed, whole = [], []
    for sample, (x0, y0, w, h) in zip(frames, boxes, strict=True):
        zoomed.append(_enlarge(sample[..., y0:y0 + h, x0:x0 + w], size))
        shrunk = F.interpolate(sample, size=(h, w), mode="bilinear", antialias=True,
                               align_corners=False)
        whole.append(_enlarge(shrunk, size))
    return ZoomPairs(torch.stack(zoomed), torch.stack(whole),
                     torch.tensor(boxes, dtype=frames.dtype, device=frames.device))


def _enlarge(images: torch.Tensor, size: tuple[int, int] | torch.Size) -> torch.Tensor:
    return F.interpolate(images, size=size, mode="bilinear", align_corners=False)


def zoomed_intrinsics(K: torch.Tensor, boxes: torch.Tensor, size: tuple[int, int]
                      ) -> torch.Tensor:
    """(B, 3, 3) intrinsics of the boxes (B, 4: x0, y0, w, h) of frames of intrinsics K, each
    enlarged to size (H, W); pixel centres at integer coordinates, as in
    hybrid.types.Camera.resized (here batched, in torch, so that gradients pass)."""
    height, width = size
    sx, sy = width / boxes[:, 2], height / boxes[:, 3]
    out = K.clone()
    out[:, 0, 0] = K[:, 0, 0] * sx
    out[:, 1, 1] = K[:, 1, 1] * sy
    out[:, 0, 2] = sx * (K[:, 0, 2] - boxes[:, 0] + 0.5) - 0.5
    out[:, 1, 2] = sy * (K[:, 1, 2] - boxes[:, 1] + 0.5) - 0.5
    return out


def zoom_consistency(K_zoomed: torch.Tensor, K_whole: torch.Tensor, boxes: torch.Tensor,
                     size: tuple[int, int]) -> torch.Tensor:
    """Mean L1 between the K read from the zoomed frames and the K read from the whole ones
    carried through the zoom: focal lengths in log, the principal point in units of the
    image's size. Zero for a head that follows the zoom exactly."""
    height, width = size
    expected = zoomed_intrinsics(K_whole, boxes, size)
    focal = (torch.log(K_zoomed[:, 0, 0] / expected[:, 0, 0]).abs()
             + torch.log(K_zoomed[:, 1, 1] / expected[:, 1, 1]).abs())
    centre = ((K_zoomed[:, 0, 2] - expected[:, 0, 2]).abs() / width
              + (K_zoomed[:, 1, 2] - expected[:, 1, 2]).abs() / height)
    return (focal + centre).mean()
