"""Depth U-Net with a ResNet-style encoder, and the motion + intrinsics network (Gordon et al.).

Written with plain torch (torchvision does not import beside the CPU torch used here).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from learned.config import DepthConfig


class BasicBlock(nn.Module):
    """ResNet basic block: two 3x3 convolutions with a residual connection."""

    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.shortcut = nn.Identity() if stride == 1 and cin == cout else nn.Sequential(
            nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = F.relu(self.bn1(self.conv1(x)))
        return F.relu(self.bn2(self.conv2(out)) + self.shortcut(x))


class Bottleneck(nn.Module):
    """ResNet-50 bottleneck block: 1x1 reduce to cout/4, 3x3, 1x1 expand, residual."""

    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__()
        mid = cout // 4
        self.body = nn.Sequential(
            nn.Conv2d(cin, mid, 1, bias=False), nn.BatchNorm2d(mid), nn.ReLU(inplace=True),
            nn.Conv2d(mid, mid, 3, stride, 1, bias=False), nn.BatchNorm2d(mid),
            nn.ReLU(inplace=True), nn.Conv2d(mid, cout, 1, bias=False), nn.BatchNorm2d(cout))
        self.shortcut = nn.Identity() if stride == 1 and cin == cout else nn.Sequential(
            nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.body(x) + self.shortcut(x))


class ResNetEncoder(nn.Module):
    """ResNet encoder; returns features at strides 2, 4, 8, 16, 32.

    channels: stem, then each stage's output; bottleneck blocks give ResNet-50 with
    channels (64, 256, 512, 1024, 2048) and blocks (3, 4, 6, 3).
    """

    def __init__(self, in_channels: int, channels: tuple[int, ...], blocks: tuple[int, ...],
                 bottleneck: bool = False):
        super().__init__()
        block = Bottleneck if bottleneck else BasicBlock
        self.stem = nn.Sequential(nn.Conv2d(in_channels, channels[0], 7, 2, 3, bias=False),
                                  nn.BatchNorm2d(channels[0]), nn.ReLU(inplace=True))
        stages = []
        cin = channels[0]
        for k, (cout, n) in enumerate(zip(channels[1:], blocks, strict=True)):
            layers = [block(cin, cout, 1 if k == 0 else 2)]
            layers += [block(cout, cout, 1) for _ in range(n - 1)]
            stages.append(nn.Sequential(*layers))
            cin = cout
        self.stages = nn.ModuleList(stages)
        self.channels = channels

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        features = [self.stem(x)]
        x = F.max_pool2d(features[0], 3, 2, 1)
        for stage in self.stages:
            x = stage(x)
            features.append(x)
        return features


def _conv(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.ReflectionPad2d(1), nn.Conv2d(cin, cout, 3), nn.ELU(inplace=True))


class DepthNet(nn.Module):
    """RGB (B, 3, H, W) in [0, 1] -> depth (B, 1, H, W) in [min_depth, max_depth]."""

    def __init__(self, config: DepthConfig):
        super().__init__()
        self.config = config
        self.encoder = ResNetEncoder(3, config.encoder_channels, config.encoder_blocks)
        enc = config.encoder_channels
        dec = config.decoder_channels
        self.up_convs = nn.ModuleList()
        self.fuse_convs = nn.ModuleList()
        cin = enc[-1]
        for level in range(4, -1, -1):  # decoder levels at strides 16, 8, 4, 2, 1
            self.up_convs.append(_conv(cin, dec[level]))
            skip = enc[level - 1] if level > 0 else 0
            self.fuse_convs.append(_conv(dec[level] + skip, dec[level]))
            cin = dec[level]
        self.head = nn.Sequential(nn.ReflectionPad2d(1), nn.Conv2d(dec[0], 1, 3))
        self.register_buffer("mean", torch.tensor([0.45, 0.45, 0.45]).view(1, 3, 1, 1))

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        features = self.encoder((rgb - self.mean) / 0.225)
        x = features[-1]
        for k, (up, fuse) in enumerate(zip(self.up_convs, self.fuse_convs, strict=True)):
            level = 4 - k
            skip = features[level - 1] if level > 0 else None
            size = rgb.shape[-2:] if skip is None else skip.shape[-2:]  # any input size
            x = F.interpolate(up(x), size=size, mode="nearest")
            x = fuse(x if skip is None else torch.cat([x, skip], dim=1))
        disparity = torch.sigmoid(self.head(x))
        lo, hi = 1.0 / self.config.max_depth, 1.0 / self.config.min_depth
        return 1.0 / (lo + (hi - lo) * disparity)


def shift_correlation(a: torch.Tensor, b: torch.Tensor, reach: int) -> torch.Tensor:
    """Cosine similarity of features a (B, C, h, w) with b shifted by (dy, dx), each from
    -reach to reach: (B, (2 reach + 1)^2, h, w), channel (dy + reach) * (2 reach + 1) + dx +
    reach holding a[..., y, x] against b[..., y + dy, x + dx] (0 beyond b's edge)."""
    a, b = F.normalize(a, dim=1), F.normalize(b, dim=1)
    padded = F.pad(b, (reach, reach, reach, reach))
    height, width = a.shape[-2:]
    side = 2 * reach + 1
    return torch.stack([(a * padded[..., dy:dy + height, dx:dx + width]).sum(1)
                        for dy in range(side) for dx in range(side)], 1)


class PairCorrelation(nn.Module):
    """The correlation motion network's features of a frame pair (B, 6, H, W): one encoder
    for both frames (the motion encoder's stem and first stage, stride 4), the correlation of
    their features over shifts (shift_correlation), each pixel's place in the image beside
    it, then three strided convolutions. Returns a one-element list, as ResNetEncoder returns
    its stages."""

    def __init__(self, channels: tuple[int, ...], blocks: tuple[int, ...], reach: int):
        super().__init__()
        self.reach = reach
        self.encoder = ResNetEncoder(3, channels[:2], blocks[:1])
        layers, width = [], (2 * reach + 1) ** 2 + 2
        for out in (64, 96, 128):
            layers += [nn.Conv2d(width, out, 3, 2, 1), nn.BatchNorm2d(out), nn.ReLU(inplace=True)]
            width = out
        self.head = nn.Sequential(*layers)
        self.width = width

    def forward(self, pair: torch.Tensor) -> list[torch.Tensor]:
        a, b = (self.encoder(frame)[-1] for frame in pair.split(3, dim=1))
        volume = shift_correlation(a, b, self.reach)
        height, width = a.shape[-2:]
        y, x = torch.meshgrid(torch.linspace(-1, 1, height, device=pair.device),
                              torch.linspace(-1, 1, width, device=pair.device), indexing="ij")
        place = torch.stack([x, y]).to(pair.dtype).expand(len(pair), 2, height, width)
        return [self.head(torch.cat([volume, place], 1))]


class MotionNet(nn.Module):
    """Two frames -> 6-DoF motion from the first camera to the second, and intrinsics.

    Input: (B, 6, H, W), frames i and j stacked, read by one encoder or compared by
    PairCorrelation (config.motion_net). Output: axis-angle rotation (B, 3) and
    translation (B, 3) of the transform mapping points in camera i to camera j, and
    K (B, 3, 3) in pixels of the input size.
    """

    def __init__(self, config: DepthConfig):
        super().__init__()
        if config.motion_net == "correlation":
            self.encoder = PairCorrelation(config.motion_channels, config.motion_blocks,
                                           config.motion_reach)
            width = self.encoder.width
        else:
            self.encoder = ResNetEncoder(6, config.motion_channels, config.motion_blocks)
            width = config.motion_channels[-1]
        self.motion = nn.Conv2d(width, 6, 1)
        self.intrinsics = nn.Conv2d(width, 4, 1)
        # Small initial motions (Gordon et al. scale them by learned factors starting at 0.01).
        self.rotation_scale = nn.Parameter(torch.tensor(0.01))
        self.translation_scale = nn.Parameter(torch.tensor(0.01))
        nn.init.zeros_(self.intrinsics.weight)
        nn.init.zeros_(self.intrinsics.bias)
        # softplus(-0.4) = 0.51: fx starts at about half the width, fy at half the height.
        nn.init.constant_(self.intrinsics.bias[:2], -0.4)
        self.register_buffer("mean", torch.tensor([0.45] * 6).view(1, 6, 1, 1))

    def forward(self, pair: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        height, width = pair.shape[-2:]
        bottleneck = self.encoder((pair - self.mean) / 0.225)[-1].mean(dim=(2, 3), keepdim=True)
        motion = self.motion(bottleneck).flatten(1)
        rotation = motion[:, :3] * self.rotation_scale
        translation = motion[:, 3:] * self.translation_scale
        raw = self.intrinsics(bottleneck).flatten(1)
        K = torch.zeros(pair.shape[0], 3, 3, device=pair.device, dtype=pair.dtype)
        K[:, 0, 0] = F.softplus(raw[:, 0]) * width
        K[:, 1, 1] = F.softplus(raw[:, 1]) * height
        K[:, 0, 2] = (raw[:, 2] + 0.5) * width - 0.5
        K[:, 1, 2] = (raw[:, 3] + 0.5) * height - 0.5
        K[:, 2, 2] = 1.0
        return rotation, translation, K
