"""CORAL domain adaptation (Sun, Feng and Saenko 2016) of the per-segment network.

The pooled layer z of the per-segment network (its second-to-last layer) is mapped by
z -> A (z - μt) + μs with A = Cs^(1/2) Ct^(-1/2), so that on the target domain (unlabelled
video) its mean and covariance become the synthetic training windows' μs and Cs. Both
covariances get a small ridge (1e-5 of their mean variance). The samples are the windows
every segment_stride frames, each in its mirror views, but overlapping windows and the views
of one window are far from independent: a target of fewer segments' worth of video (T frames
each) than z has dimensions leaves its covariance near singular, and A would blow up the
directions it lacks (five windows of one 14-s video stretch one direction 130 times:
benchmarks/coral_small_target.py), so each side needs more segments than dimensions. The source
statistics can be taken from held-out synthetic videos instead of the training windows
(`set_source`).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import torch

from hybrid.types import InputError
from learned.coverage_nets import CoverageModel

RIDGE = 1e-5
"""Relative ridge added to both covariances."""


def _power(cov: np.ndarray, exponent: float) -> np.ndarray:
    """Symmetric matrix power of a positive definite matrix."""
    values, vectors = np.linalg.eigh(cov)
    return (vectors * values ** exponent) @ vectors.T


def _covariance(rows: np.ndarray) -> np.ndarray:
    """(C, C) covariance of (n, C) rows, also for C = 1."""
    return np.atleast_2d(np.cov(rows, rowvar=False))


def _ridged(cov: np.ndarray) -> np.ndarray:
    return cov + RIDGE * max(float(np.trace(cov)) / len(cov), 1e-12) * np.eye(len(cov))


def coral_transform(source_mean: np.ndarray, source_cov: np.ndarray, target: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """A and b such that A z + b has the source's mean and covariance over the target rows z."""
    target = np.asarray(target, dtype=np.float64)
    if target.ndim != 2 or target.shape[1] != len(source_mean):
        raise InputError(f"target embeddings must be (n, {len(source_mean)}), got "
                         f"{target.shape}")
    if len(target) <= target.shape[1]:  # fewer rows leave the target covariance singular
        raise InputError(f"CORAL needs more target samples than their {target.shape[1]} "
                         f"dimensions, got {len(target)}; give more or longer unlabelled "
                         f"videos")
    if not np.isfinite(target).all():
        raise InputError("target embeddings contain NaN or infinite values")
    A = _power(_ridged(np.asarray(source_cov, np.float64)), 0.5) @ _power(
        _ridged(_covariance(target)), -0.5)
    return A, source_mean - A @ target.mean(0)


def window_embeddings(model: CoverageModel, features: Iterable[np.ndarray], stride: int,
                      role: str = "target") -> np.ndarray:
    """The pooled layer (n, len(MIRRORS), C) of the n windows every `stride` frames of each
    video's features, in each mirror view, from more segments' worth of video than C (see
    the module). `features` may be a generator: each video's are dropped once embedded."""
    T, dims = model.config.segment_frames, model.segment.fc.in_features
    embedded, segments, longest = [], 0, 0
    for video in features:
        segments, longest = segments + len(video) // T, max(longest, len(video))
        if starts := list(range(0, len(video) - T + 1, stride)):
            embedded.append(model.segment_embeddings(video, starts).double().cpu().numpy())
    if not embedded:
        raise InputError(f"CORAL needs {role} videos of at least {T} frames (one segment); "
                         f"the longest has {longest}")
    if segments <= dims:
        raise InputError(f"CORAL needs more {role} video than {dims} segments of {T} frames "
                         f"(the dimensions it aligns; overlapping windows and mirror views "
                         f"are not independent samples), got {segments}; give more or longer "
                         f"videos")
    return np.concatenate(embedded)


def set_source(model: CoverageModel, source_features: Iterable[np.ndarray], stride: int
               ) -> int:
    """Replace CORAL's source statistics (by default the training windows') by those of
    windows of synthetic videos the model was not trained on; returns their number."""
    embedded = window_embeddings(model, source_features, stride, role="source")
    rows = embedded.reshape(-1, embedded.shape[-1])
    model.segment.source_mean.copy_(torch.from_numpy(rows.mean(0)).float())
    model.segment.source_cov.copy_(torch.from_numpy(_covariance(rows)).float())
    model.segment.held_out_source.fill_(1.0)
    return len(embedded)


def adapt(model: CoverageModel, target_features: Iterable[np.ndarray], stride: int) -> int:
    """Fit the model's CORAL transform on windows of unlabelled videos' per-frame features
    (every mirror view of each window a sample).

    Returns the number of target windows used. Windows start every `stride` frames.
    """
    embedded = window_embeddings(model, target_features, stride)
    net = model.segment
    A, b = coral_transform(net.source_mean.double().cpu().numpy(),
                           net.source_cov.double().cpu().numpy(),
                           embedded.reshape(-1, embedded.shape[-1]))
    net.coral_matrix.copy_(torch.from_numpy(A).float())
    net.coral_offset.copy_(torch.from_numpy(b).float())
    return len(embedded)
