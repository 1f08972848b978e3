"""The camera's field of view, an input of the per-frame coverage network.

From the same place a wider camera sees more of the wall, and a depth map does not say how
wide its camera is (the simulated cameras span 90-130 degrees). Two numbers per video: the log
tangents of the half-angles across and down the image, log(W / 2 fx) and log(H / 2 fy), which
do not depend on the resolution the intrinsics are given at. The principal point is taken to be
central (the simulator's is; the motion network's lies within a few per cent of the centre).
Networks trained with `view_hidden` take a third value, 1 where the field of view is known;
where it is not, all three are 0.
"""

from __future__ import annotations

import numpy as np

from hybrid.types import InputError

VIEW_SIZE = 2
"""Per-frame field-of-view values: log tangent of the half-angle across, then down."""


def view_values(K: np.ndarray, width: int, height: int, frames: int,
                name: str = "intrinsics") -> np.ndarray:
    """(frames, 2) float32: the field-of-view values of a (width x height) camera K, repeated
    for each frame."""
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.isfinite(K).all() or not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(f"{name}: expected a 3x3 camera matrix with positive focal lengths, "
                         f"got {K.tolist()}")
    values = np.log([width / (2 * K[0, 0]), height / (2 * K[1, 1])])
    return np.tile(values.astype(np.float32), (frames, 1))


def known_view(view: np.ndarray) -> np.ndarray:
    """(frames, 3) float32: field-of-view values (frames, 2) and a third value, 'known', 1: the
    input of networks trained with view_hidden."""
    return np.concatenate([view, np.ones((len(view), 1))], axis=1).astype(np.float32)


def hidden_view(frames: int) -> np.ndarray:
    """(frames, 3) float32 zeros: the input of networks trained with view_hidden for a camera
    whose field of view is not known ('known' 0)."""
    return np.zeros((frames, VIEW_SIZE + 1), dtype=np.float32)
