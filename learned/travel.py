"""Direction of travel in each camera's own axes, from the motion network: the per-frame cue
that tells a camera looking down the lumen from one looking back towards the rectum.

A depth image looking towards the cecum and one looking back towards the rectum are alike,
but during a withdrawal the first moves backwards (-z) and the second forwards (+z). The
per-frame coverage network takes this as four numbers besides the depth, and four more over a
baseline chained from the same pairs (`CoverageConfig.travel_hops`); an input the paper does
not have (`CoverageConfig.travel_gap = 0` gives the paper's depth-only network).
"""

from __future__ import annotations

import numpy as np

from hybrid.types import InputError

TRAVEL_SIZE = 4
"""Per-frame travel values: unit direction (x, y, z) and log relative speed."""
MAX_LOG_SPEED = 3.0
"""The log relative speed is clipped to ±this (a pause gives a length near 0)."""


def travel_features(relative: np.ndarray, frames: int, withdrawal: bool = True,
                    name: str = "relative poses") -> np.ndarray:
    """(N, 4) float32 travel of each of `frames` frames from relative poses (N-g, 4, 4) of the
    pairs (t, t+g), each mapping camera t's points into camera t+g's.

    Columns: the unit direction of the camera's displacement from t to t+g in camera t's axes,
    negated for an insertion (so that looking down the lumen gives z < 0 in both), and the log
    of that displacement's length over its median in the video, clipped to ±3. The last g
    frames repeat the last pair's values.
    """
    relative = np.asarray(relative, dtype=np.float64)
    if relative.ndim != 3 or relative.shape[1:] != (4, 4) or not 1 <= len(relative) < frames:
        raise InputError(f"{name}: expected (M, 4, 4) relative poses with 1 <= M < {frames} "
                         f"frames, got {relative.shape}")
    if not np.isfinite(relative).all():
        raise InputError(f"{name}: NaN or infinite relative poses; recompute them")
    # Camera t+g's centre in camera t's axes: -R^T t.
    centre = -np.einsum("nji,nj->ni", relative[:, :3, :3], relative[:, :3, 3])
    length = np.linalg.norm(centre, axis=1)
    direction = centre / np.maximum(length, 1e-12)[:, None]
    if not withdrawal:
        direction = -direction
    scale = max(float(np.median(length)), 1e-12)
    speed = np.clip(np.log(np.maximum(length, 1e-12) / scale), -MAX_LOG_SPEED, MAX_LOG_SPEED)
    values = np.concatenate([direction, speed[:, None]], axis=1)
    picks = np.minimum(np.arange(frames), len(values) - 1)
    return values[picks].astype(np.float32)


def chain_relative(relative: np.ndarray, gap: int, hops: int,
                   name: str = "relative poses") -> np.ndarray:
    """(M - gap (hops - 1), 4, 4) relative poses of the pairs (t, t + hops gap), chained from
    the M relative poses of the pairs (t, t + gap): a longer baseline."""
    if hops < 1:
        raise ValueError(f"hops must be at least 1, got {hops}")
    relative = np.asarray(relative, dtype=np.float64)
    count = len(relative) - gap * (hops - 1)
    if count < 1:
        raise InputError(f"{name}: the travel over {hops} hops of {gap} frame(s) needs more than "
                         f"{gap * hops} frames, got {len(relative) + gap}; give a longer video, "
                         f"or train networks with fewer hops (--set travel_hops=...)")
    chained = relative[:count]
    for hop in range(1, hops):
        chained = relative[hop * gap:hop * gap + count] @ chained
    return chained


def no_travel(frames: int) -> np.ndarray:
    """(N, 0): the travel input of a depth-only network."""
    return np.zeros((frames, 0), dtype=np.float32)
