"""The two-stage coverage networks (paper section 4.2) and the rule that normalises their input.

Stage 1, `FrameNet`: one depth image and the frame's cues, its direction of travel
(learned.travel) and optionally its camera's field of view (learned.view) and its depth scale
against its video's (`relative_scale`) -> coverage of that
frame for the three (Δ0, Δ1) pairs; its penultimate layer (global average of
the last ResNet stage) is the frame's feature vector.
Stage 2, `SegmentNet`: the T x F features of a segment -> six 1-D convolutions -> average over
time -> an affine CORAL transform (identity until adapted) -> a fully connected layer -> one
coverage in [0, 1]. `CoverageModel.segment_outputs` then maps it through the calibration
table the segment network holds (learned.calibration): fitted on the cross-validation with
`calibrate=true`, the identity otherwise.

A mirrored colon is covered alike, so `CoverageModel` predicts from the four mirror views of
each frame (`MIRRORS`): per-frame coverage is their mean, the features keep all four
((N, 4, F)), and a segment's coverage is the mean over the four mirrored feature sequences.

Depth is known only up to scale, so each depth map is normalised by its own median over the
image region and passed as log(depth / median): 0 at the median depth, symmetric in near and
far. Outside the region the map keeps the depth network's own values there (it read the frame
filled from inside, `learned.frames.FrameSequence.network_frame`).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch
from torch import nn

from hybrid.coverage import DELTA_PAIRS_CM
from hybrid.types import InputError
from learned.calibration import apply_table, identity_table
from learned.checkpoint import checkpoint_metadata, file_tag, load_model, save_checkpoint
from learned.config import CoverageConfig
from learned.device import device_of
from learned.nets import ResNetEncoder
from learned.travel import TRAVEL_SIZE


def region_medians(depth: np.ndarray, region: np.ndarray, name: str = "depth") -> np.ndarray:
    """(N,) median of each of the (N, H, W) depth maps inside the (H, W) bool region; a clear
    error on NaN, infinite or non-positive depth there."""
    if depth.ndim != 3 or depth.shape[1:] != region.shape:
        raise InputError(f"{name}: expected (N, H, W) depth maps of the region's size "
                         f"{region.shape}, got {depth.shape}")
    inside = depth[:, region]
    bad = ~np.isfinite(inside) | (inside <= 0)
    if bad.any():
        frames = np.flatnonzero(bad.any(axis=1))[:10].tolist()
        raise InputError(f"{name}: NaN, infinite or non-positive depth inside the image region "
                         f"in frames {frames}; recompute the depth")
    return np.median(inside, axis=1)


def normalise_depth(depth: np.ndarray, region: np.ndarray, size: tuple[int, int],
                    name: str = "depth", by_median: bool = True) -> np.ndarray:
    """(N, H, W) depth and (H, W) bool region -> (N, 1, h, w) float32 per-frame net input.

    The median is taken inside the region. Outside it the map keeps its own values (the
    depth network's, which read the frame filled from inside): on the simulator's octagon
    views they served the shipped coverage networks better than a constant (0.015 lower
    coverage) or a fill of the depth from inside (up to 0.011 more error; docs/coverage.md,
    "The image region"). by_median=False keeps the depth's own scale: log(depth). InputError
    on NaN, infinite or non-positive depth anywhere.
    """
    depth = np.asarray(depth, dtype=np.float32)
    median = region_medians(depth, region, name)
    scale = median if by_median else np.ones_like(median)
    bad = ~(np.isfinite(depth) & (depth > 0)).reshape(len(depth), -1).all(axis=1)
    if bad.any():  # region_medians checked inside the region
        raise InputError(f"{name}: NaN, infinite or non-positive depth outside the image region "
                         f"in frames {np.flatnonzero(bad)[:10].tolist()}; the coverage network "
                         f"reads the depth there too: recompute it")
    logs = np.log(depth / scale[:, None, None])
    height, width = size
    small = [cv2.resize(d, (width, height), interpolation=cv2.INTER_AREA) for d in logs]
    return np.stack(small)[:, None].astype(np.float32)


def relative_scale(medians: np.ndarray, name: str = "depth") -> np.ndarray:
    """(N, 1) float32 scale cue of a video's frames from their (N,) median depths:
    log(median / the video's median of them). The median normalisation hides how far the wall
    is, which the coverage of a band a fixed number of centimetres ahead depends on; within a
    video the depth network keeps its scale, so a frame's depth against the video's typical
    depth tells a narrow stretch of colon from a wide one."""
    medians = np.asarray(medians, dtype=np.float64)
    if medians.ndim != 1 or not len(medians) or not (np.isfinite(medians).all()
                                                     and (medians > 0).all()):
        raise InputError(f"{name}: expected positive finite per-frame median depths, got "
                         f"{medians.shape} values")
    return np.log(medians / np.median(medians))[:, None].astype(np.float32)


MIRRORS = ((False, False), (True, False), (False, True), (True, True))
"""The mirror views of a frame: (left-right, up-down) flips."""


def mirrored(depth: torch.Tensor, cues: torch.Tensor, flips: torch.Tensor, travel: int
             ) -> tuple[torch.Tensor, torch.Tensor]:
    """Depth (B, 1, h, w) and cues (B, cue_size) of the mirrored views: flips (B, 2) bool
    mirrors left-right (image x; travel x negated) and up-down (image y; travel y negated).
    `travel`: how many travel columns the cues begin with, in blocks of (x, y, z, speed); the
    field of view and the depth scale are unchanged by a mirror."""
    depth = torch.where(flips[:, 0, None, None, None], depth.flip(-1), depth)
    depth = torch.where(flips[:, 1, None, None, None], depth.flip(-2), depth)
    signs = torch.ones_like(cues)
    for block in range(0, travel, TRAVEL_SIZE):
        signs[:, block:block + 2] = 1.0 - 2.0 * flips.to(cues.dtype)
    cues = cues * signs
    return depth, cues


def resample_features(features: np.ndarray, segment_frames: int, window: int) -> np.ndarray:
    """Per-frame features of a video whose segments last `segment_frames` frames, resampled in
    time (nearest frame) so that a segment lasts `window` frames, the per-segment network's T.
    Segment k of the video is then the window starting at k * window."""
    count = len(features) * window // segment_frames
    picks = np.minimum((np.arange(count) * segment_frames / window).astype(int),
                       len(features) - 1)
    return features[picks]


class FrameNet(nn.Module):
    """Normalised depth (B, 1, h, w) and cues (B, config.cue_size): travel, field of view,
    depth scale -> per-frame coverage (B, 3); features() gives (B, F). The cues enter the encoder as
    constant planes beside the depth, so that every layer can condition on them."""

    def __init__(self, config: CoverageConfig):
        super().__init__()
        self.encoder = ResNetEncoder(1 + config.cue_size, config.frame_channels,
                                     config.frame_blocks, config.bottleneck)
        self.head = nn.Linear(config.feature_size, len(DELTA_PAIRS_CM))

    def features(self, depth: torch.Tensor, cues: torch.Tensor) -> torch.Tensor:
        planes = cues[:, :, None, None].expand(-1, -1, *depth.shape[-2:])
        # channels last: 1.3-1.5 times the stage-1 steps a second here (docs/benchmarks.md)
        x = torch.cat([depth, planes], dim=1).contiguous(memory_format=torch.channels_last)
        return self.encoder(x)[-1].mean(dim=(2, 3))

    def coverage(self, features: torch.Tensor) -> torch.Tensor:
        """Per-frame coverage (..., 3) from features (..., F)."""
        return torch.sigmoid(self.head(features))

    def forward(self, depth: torch.Tensor, cues: torch.Tensor) -> torch.Tensor:
        return self.coverage(self.features(depth, cues))


class SegmentNet(nn.Module):
    """Per-frame features (B, T, F) -> segment coverage (B,) in [0, 1]."""

    def __init__(self, config: CoverageConfig):
        super().__init__()
        size = config.feature_size
        self.register_buffer("feature_mean", torch.zeros(size))
        self.register_buffer("feature_std", torch.ones(size))
        layers: list[nn.Module] = []
        cin = size
        for cout, kernel, stride in zip(config.segment_channels, config.segment_kernels,
                                        config.segment_strides, strict=True):
            layers += [nn.Conv1d(cin, cout, kernel, stride, padding=kernel // 2), nn.ReLU()]
            cin = cout
        self.convs = nn.Sequential(*layers)
        # CORAL (Sun et al. 2016): z -> A z + b on the pooled layer; identity until adapted.
        # source_mean/source_cov: that layer's statistics on the synthetic training windows
        # (or on held-out synthetic windows: learned.coral.set_source).
        self.register_buffer("coral_matrix", torch.eye(cin))
        self.register_buffer("coral_offset", torch.zeros(cin))
        self.register_buffer("source_mean", torch.zeros(cin))
        self.register_buffer("source_cov", torch.eye(cin))
        self.fc = nn.Linear(cin, 1)
        # The output's calibration (learned.calibration), applied by CoverageModel's
        # segment_outputs; identity unless train_coverage fits it (calibrate=true).
        # held_out_source: 1 once set_source has put held-out windows' statistics in place of
        # the training windows' (see calibrates).
        self.register_buffer("calibration", torch.from_numpy(identity_table()))  # float64
        self.register_buffer("held_out_source", torch.zeros(()))
        self.register_load_state_dict_pre_hook(_defaults_before)

    def embed(self, features: torch.Tensor) -> torch.Tensor:
        """The second-to-last layer: (B, T, F) -> (B, C), before the CORAL transform."""
        x = ((features - self.feature_mean) / self.feature_std).transpose(1, 2)
        return self.convs(x).mean(dim=2)

    def head(self, embedding: torch.Tensor) -> torch.Tensor:
        """CORAL transform and the final layer: (B, C) -> (B,)."""
        adapted = embedding @ self.coral_matrix.T + self.coral_offset
        return torch.sigmoid(self.fc(adapted))[:, 0]

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.head(self.embed(features))

    def holds_table(self) -> bool:
        """Whether the model holds a calibration table other than the identity."""
        return not torch.equal(self.calibration, self.calibration.new_tensor(identity_table()))

    def calibrates(self) -> bool:
        """Whether the calibration table applies. It was fitted on held-out outputs, which the
        network shrinks towards the mean; CORAL onto the training windows' statistics maps a
        target into the unshrunk regime of the training windows, so then it does not."""
        unadapted = torch.equal(self.coral_matrix, torch.eye(len(self.coral_matrix),
                                                             device=self.coral_matrix.device)) \
            and not self.coral_offset.any()
        return unadapted or bool(self.held_out_source)


def _defaults_before(module, state_dict, prefix, *args) -> None:
    """Checkpoints saved before the calibration existed are uncalibrated (identity) and, if
    adapted, were adapted onto the training windows' statistics."""
    state_dict.setdefault(prefix + "calibration", module.calibration.new_tensor(identity_table()))
    state_dict.setdefault(prefix + "held_out_source", module.held_out_source.new_zeros(()))


def count_parameters(module: nn.Module) -> int:
    """Trainable parameters (buffers such as the CORAL transform are not counted)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)


class CoverageModel(nn.Module):
    """Both stages with their config; predicts from normalised depth or from features."""

    def __init__(self, config: CoverageConfig):
        super().__init__()
        self.config = config
        self.frame = FrameNet(config)
        self.segment = SegmentNet(config)
        self.depth_tag: str | None = None
        """SHA-256 prefix of the depth checkpoint whose output the per-frame network learned
        from (None in checkpoints made before it was recorded)."""

    def check_depth(self, depth_checkpoint: Path, name: str) -> None:
        """Refuse depth maps from another depth model than the one these networks learned on."""
        if self.depth_tag is None:
            return
        tag = file_tag(depth_checkpoint)
        if tag != self.depth_tag:
            raise InputError(f"{name}: these coverage networks learned on the output of the "
                             f"depth model {self.depth_tag} (SHA-256 prefix), not of "
                             f"{depth_checkpoint} ({tag}); give that depth model, or coverage "
                             f"networks trained on this one")

    @torch.no_grad()
    def frame_outputs(self, inputs: np.ndarray, cues: np.ndarray, batch: int = 32
                      ) -> tuple[np.ndarray, np.ndarray]:
        """(N, 1, h, w) normalised depth and (N, cue_size) cues -> per-frame coverage (N, 3),
        the mean over the mirror views, and the features (N, len(MIRRORS), F) of each view.
        `batch` frames per pass (4 times as many views; 32 ran 1.6 times faster than 256 on
        this CPU: `benchmarks/bench_coverage.py --frame-batch`)."""
        expected = (1, self.config.height, self.config.width)
        if inputs.ndim != 4 or inputs.shape[1:] != expected:
            raise InputError(f"per-frame input must be (N, {expected}) normalised depth for the "
                             f"{self.config.preset!r} preset, got {inputs.shape}")
        if cues.shape != (len(inputs), self.config.cue_size):
            raise InputError(f"per-frame cues must be (N, {self.config.cue_size}) for "
                             f"N = {len(inputs)} frames (travel_gap {self.config.travel_gap}, "
                             f"field_of_view {self.config.field_of_view!r}, depth_scale "
                             f"{self.config.depth_scale}), got {cues.shape}")
        self.eval()
        device = device_of(self)
        flips = torch.tensor(MIRRORS, device=device)
        coverage, features = [], []
        for start in range(0, len(inputs), batch):
            x = torch.from_numpy(np.ascontiguousarray(inputs[start:start + batch],
                                                      dtype=np.float32)).to(device)
            m = torch.from_numpy(np.ascontiguousarray(cues[start:start + batch],
                                                      dtype=np.float32)).to(device)
            views = [mirrored(x, m, flip.expand(len(x), 2), self.config.travel_size)
                     for flip in flips]
            f = self.frame.features(torch.cat([v[0] for v in views]),
                                    torch.cat([v[1] for v in views]))
            f = f.view(len(flips), len(x), -1).transpose(0, 1)
            features.append(f.cpu().numpy())
            coverage.append(self.frame.coverage(f).mean(dim=1).cpu().numpy())
        return np.concatenate(coverage), np.concatenate(features)

    @torch.no_grad()
    def segment_embeddings(self, features: np.ndarray, starts: list[int], batch: int = 32
                           ) -> torch.Tensor:
        """The per-segment network's pooled layer (S, len(MIRRORS), C) for the windows
        [s, s + T) of one video's (N, len(MIRRORS), F) features, one row per mirror view.
        `batch` windows per pass bounds the memory where one video has many: training,
        evaluation and `c2d2 adapt` read overlapping windows every 30 frames (`c2d2 adapt` on
        a 30-minute video: 162 MiB at 32 against 797 at 256; docs/benchmarks.md, "Where the
        peak is")."""
        T, F, M = self.config.segment_frames, self.config.feature_size, len(MIRRORS)
        if features.ndim != 3 or features.shape[1:] != (M, F):
            raise InputError(f"features must be (N, {M}, {F}) (frames, mirror views, features) "
                             f"for the {self.config.preset!r} preset, got {features.shape}")
        if len(features) < T:
            raise InputError(f"a segment needs {T} frames, but the video has {len(features)}")
        if any(s < 0 or s + T > len(features) for s in starts):
            raise InputError(f"segment windows must lie within the {len(features)} frames")
        self.eval()
        device = device_of(self)
        embedded = [torch.zeros(0, M, self.segment.fc.in_features, device=device)]
        for k in range(0, len(starts), batch):
            windows = np.stack([features[s:s + T] for s in starts[k:k + batch]])  # (B, T, M, F)
            x = torch.from_numpy(windows.transpose(0, 2, 1, 3).reshape(-1, T, F)
                                 .astype(np.float32)).to(device)
            embedded.append(self.segment.embed(x).view(len(windows), M, -1))
        return torch.cat(embedded)

    @torch.no_grad()
    def segment_outputs(self, features: np.ndarray, starts: list[int], calibrated: bool = True
                        ) -> np.ndarray:
        """Coverage (S,) of the windows [s, s + T) of one video's (N, len(MIRRORS), F)
        features: the mean over the mirror views, calibrated where the table applies
        (`SegmentNet.calibrates`) unless asked not to."""
        embedded = self.segment_embeddings(features, starts)
        values = self.segment.head(embedded.flatten(0, 1)).view(len(starts), len(MIRRORS))
        values = values.mean(dim=1).double()
        if calibrated and self.segment.calibrates():
            values = apply_table(self.segment.calibration, values)
        return values.cpu().numpy()

    def save(self, path: Path, step: int = 0) -> None:
        save_checkpoint(path, {"frame": self.frame, "segment": self.segment},
                        self.config.to_dict(), step, kind="coverage",
                        extra=None if self.depth_tag is None else {"depth_model": self.depth_tag})


def load_coverage_model(path: Path, preset: str | None = None,
                        device: torch.device | str = "cpu") -> CoverageModel:
    """A trained coverage model in eval mode on `device`; checks its preset if one is given."""
    model = load_model(path, "coverage", CoverageConfig, CoverageModel, preset).to(device)
    model.depth_tag = checkpoint_metadata(path).get("depth_model")
    return model
