"""Geometric coverage of each segment from its own, local reconstruction.

Learned poses drift: over a whole video the camera path, and the single lumen fitted around
it, can be centimetres off, and late segments then look uncovered. Here each segment is
reconstructed on its own window (the segment and `context` frames either side): its poses
re-based on the window's first frame, a given metric scale (`c2d2 run`: the whole video's)
or the window's own scale rule, TSDF and lumen fit of hybrid.reconstruction, then
hybrid.geometric_coverage on the segment's frames. Drift then only accumulates within a
window.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from hybrid.coverage import DEFAULT_PAIR_CM, DELTA_PAIRS_CM, SegmentCoverage, pair_key
from hybrid.geometric_coverage import GeometricConfig, GeometricCoverage, geometric_coverage
from hybrid.reconstruction import ReconstructionConfig, ScaledDepth, reconstruct
from hybrid.types import InputError, failure_reason, thread_count

log = logging.getLogger(__name__)


class _Window(Sequence):
    """Frames [start, stop) of a sequence, indexed from 0."""

    def __init__(self, items: Sequence, start: int, stop: int):
        self.items, self.start, self.stop = items, start, stop

    def __len__(self) -> int:
        return self.stop - self.start

    def __getitem__(self, index: int):
        if not 0 <= index < len(self):
            raise IndexError(index)
        return self.items[self.start + index]


@dataclass
class LocalSegment:
    """One segment's geometric coverage (its map on its own lumen), or why there is none."""

    segment: SegmentCoverage
    result: GeometricCoverage | None
    error: str | None = None

    @property
    def support(self) -> float | None:
        """The share of the segment's V on wall its lumen was fitted to (None: no result, or
        an empty V; GeometricCoverage.support)."""
        return None if self.result is None else self.result.support[0]


def local_segment_coverage(depth: Sequence[np.ndarray], K: np.ndarray, poses: np.ndarray,
                           segment_frames: int, context: int, region: np.ndarray | None,
                           reconstruction: ReconstructionConfig, geometric: GeometricConfig,
                           fps: float = 30.0, name: str = "video",
                           scale: float | None = None, threads: int | None = None,
                           visibility_depth: Sequence[np.ndarray] | None = None,
                           along: np.ndarray | None = None) -> list[LocalSegment]:
    """Coverage of every full segment, each from a reconstruction of its own window.

    depth and poses in one (any) unit, made metric by `scale` (cm per unit) or, if None, by
    each window's scale rule; a segment whose window cannot be reconstructed (the camera
    barely moves, no surface, or an error of a library) gets coverage None and the reason,
    the other segments their own. Segments are computed in
    `threads` threads at once (None: one per core, at most 2: the TSDF holds Python's lock, so
    more gain little, and each holds its window's volume); the result does not depend on it.
    visibility_depth, in depth's unit: the depth the visibility test reads, where it is not
    the one reconstructed (a diagnostic of benchmarks/geometric_eval.py). along: (N,) each
    frame's place along the colon, growing towards the cecum (e.g. its ℓ on the whole video's
    lumen), which orients each window's lumen (None: the window's frames in time, fit_lumen).
    """
    n = len(poses)
    if n < segment_frames:
        raise InputError(f"{name}: {n} frames is shorter than one segment ({segment_frames})")
    config = replace(geometric, segment_frames=segment_frames)
    seen = depth if visibility_depth is None else visibility_depth

    def one(index: int) -> LocalSegment:
        start = index * segment_frames
        stop = start + segment_frames
        first, last = max(0, start - context), min(n, stop + context)
        local = np.linalg.inv(poses[first]) @ poses[first:last]
        label = f"{name} segment {index}"
        try:
            rec = reconstruct(_Window(depth, first, last), K, local, region=region,
                              config=reconstruction, scale=scale, fps=fps, name=label,
                              along=None if along is None else along[first:last],
                              first_frame=first)
            result = geometric_coverage(
                rec.lumen, rec.poses[start - first:stop - first],
                ScaledDepth(_Window(seen, start, stop), rec.scale, region), K, region, config,
                name=label, first_frame=start)
            return LocalSegment(replace(result.segments[0], index=index, start=start, stop=stop),
                                result)
        except Exception as err:  # one window's failure must not cost the other segments
            reason = failure_reason(err)
            if not isinstance(err, InputError):
                log.warning("%s failed", label, exc_info=True)
            empty = SegmentCoverage(index, start, stop, None, None,
                                    {pair_key(p): None for p in DELTA_PAIRS_CM})
            return LocalSegment(empty, None, reason)

    with ThreadPoolExecutor(thread_count(threads, "segment threads", most=2)) as pool:
        return list(pool.map(one, range(n // segment_frames)))


def save_maps(segments: list[LocalSegment], folder: Path, title: str) -> None:
    """coverage_map.npz (per segment: ell, theta_deg, seen, expected) and coverage_map.png
    (one unrolled panel per segment, on its own lumen: seen, missed, outside V)."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    folder = Path(folder)
    folder.mkdir(exist_ok=True)
    arrays = {}
    done = [s for s in segments if s.result is not None]
    for s in done:
        cells = s.result.cells
        arrays.update({f"segment{s.segment.index}_ell": cells.ell,
                       f"segment{s.segment.index}_theta_deg": np.degrees(cells.theta),
                       f"segment{s.segment.index}_seen": s.result.first_seen >= 0,
                       f"segment{s.segment.index}_expected": s.result.expected})
    np.savez_compressed(folder / "coverage_map.npz", **arrays)
    columns = min(max(len(done), 1), 10)
    rows = max(1, -(-len(done) // columns))
    fig, axes = plt.subplots(rows, columns, figsize=(max(1.6 * columns + 1, 6), 3.2 * rows),
                             squeeze=False)
    key = pair_key(DEFAULT_PAIR_CM)
    for ax in axes.flat:
        ax.axis("off")
    for ax, s in zip(axes.flat, done, strict=False):
        result, (lo, hi) = s.result, (s.segment.ell_min + DEFAULT_PAIR_CM[0],
                                      s.segment.ell_max + DEFAULT_PAIR_CM[1])
        rows_in = (result.cells.ell >= lo) & (result.cells.ell <= hi)
        state = np.where(result.first_seen[rows_in] >= 0, 1, 2)
        ax.axis("on")
        ax.imshow(state, aspect="auto", origin="lower", interpolation="nearest", vmin=0, vmax=2,
                  cmap=ListedColormap(["0.9", "#4c9a2a", "#d62728"]),
                  extent=(0, 360, 0, hi - lo))
        value = s.segment.coverage[key]
        ax.set_title(f"{s.segment.index}: {'n/a' if value is None else f'{value:.2f}'}",
                     fontsize=8)
        ax.set_xticks([0, 180, 360])
        ax.tick_params(labelsize=7)
    axes[0, 0].set_ylabel("ℓ in the segment's V (cm)", fontsize=8)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(folder / "coverage_map.png", dpi=90)
    plt.close(fig)
