"""Toy coverage samples and a shrunk preset for the coverage networks' tests; importing this
needs neither Open3D nor the pipeline, so the GPU test of these networks runs where they are
absent."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from learned.config import COVERAGE_PRESETS
from learned.coverage_data import ProcedureSamples
from learned.coverage_nets import CoverageModel

SMALL = replace(COVERAGE_PRESETS["fast"], height=16, width=20, frame_channels=(4, 8, 8, 8, 8),
                segment_frames=20, segment_stride=5, segment_channels=(4, 4, 4, 4, 4, 4),
                segment_kernels=(1, 3, 3, 3, 3, 3), segment_strides=(1, 1, 1, 1, 1, 1),
                frame_epochs=30, frame_batch=16, frame_lr=1e-2, segment_epochs=150,
                segment_batch=8, segment_lr=1e-2, travel_hops=0)
"""The fast coverage preset shrunk for tests (its preset name stays 'fast'), with the short
travel only: the toy samples carry one block of travel values."""


def toy_samples(count: int = 3, frames: int = 60, seed: int = 0) -> list[ProcedureSamples]:
    """Random smooth inputs whose per-frame labels are a function of the input and of the
    travel (0 where the camera moves forwards, z > 0, as when it looks back during a
    withdrawal), and window labels the mean of their frames' first label."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        level = np.cumsum(rng.normal(0, 0.3, frames))
        inputs = (level[:, None, None, None] * np.linspace(-1, 1, SMALL.width)
                  + rng.normal(0, 0.05, (frames, 1, SMALL.height, SMALL.width)))
        travel = toy_travel(frames, rng)
        slope = np.abs(level)
        labels = np.stack([1 / (1 + slope), 1 / (1 + 0.5 * slope), 1 / (1 + 0.2 * slope)], 1)
        labels *= (travel[:, 2:3] < 0)
        starts = np.arange(0, frames - SMALL.segment_frames + 1, SMALL.segment_stride)
        window = np.array([labels[s:s + SMALL.segment_frames, 0].mean() for s in starts])
        out.append(ProcedureSamples(f"toy/{k}", inputs.astype(np.float16), travel,
                                    np.zeros((frames, 0), np.float32),
                                    np.zeros((frames, 0), np.float32),
                                    labels.astype(np.float32), starts, window, starts[:1],
                                    window[:1]))
    return out


def toy_travel(frames: int, rng: np.random.Generator) -> np.ndarray:
    """(N, 4) unit directions, mostly backwards (-z) with forward (+z) stretches, and speed."""
    forward = np.cumsum(rng.normal(0, 1, frames)) > 1.0
    direction = np.column_stack([rng.normal(0, 0.2, (frames, 2)),
                                 np.where(forward, 1.0, -1.0)])
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return np.column_stack([direction, rng.normal(0, 0.3, frames)]).astype(np.float32)


def frame_loss(model: CoverageModel, samples: list[ProcedureSamples]) -> float:
    pred = np.concatenate([model.frame_outputs(s.inputs, s.cues)[0] for s in samples])
    return float(np.mean((pred - np.concatenate([s.frame_labels for s in samples])) ** 2))


def segment_loss(model: CoverageModel, samples: list[ProcedureSamples]) -> float:
    errors = []
    for s in samples:
        features = model.frame_outputs(s.inputs, s.cues)[1]
        errors += list(model.segment_outputs(features, s.window_starts.tolist())
                       - s.window_labels)
    return float(np.mean(np.square(errors)))
