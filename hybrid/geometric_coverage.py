"""Geometric coverage: which cells of the fitted lumen's tube each segment saw, and where the
wall was missed.

Reads a fitted lumen, camera-to-world poses, per-frame z-depth and the intrinsics, all in one
unit (cm once the scale is fixed); returns per-segment coverage and an unrolled (ℓ, θ) map.

The expected wall of a segment is the tube around the fitted centreline between ℓmin + Δ0 and
ℓmax + Δ1 (ℓmin, ℓmax: the ℓ* range of the segment's camera centres), cut into cells
`cell_length` long and 360°/`cells_around` wide, each weighing r(ℓ)·dθ·dℓ. A frame sees a cell
when the cell's centre lies in front of the camera, projects into the image region, and is not
hidden: it is at most `occlusion_tolerance` × r(ℓ) deeper than the largest depth of the 2×2
pixels around its projection (the tube only approximates the wall, which folds lift and sink by
a fraction of the radius; the largest of four keeps a wall seen at a grazing angle, whose depth
changes fast from pixel to pixel, from hiding itself).
Coverage = seen area / expected area, as in the ground truth (hybrid.coverage) with tube cells
in place of mesh vertices. Each segment's support is the share of its expected wall lying where
the lumen was fitted to the surface (beyond the surface the tube is a straight continuation);
little support means the coverage rests on the tube's shape more than on the reconstruction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from hybrid.coverage import (
    DEFAULT_PAIR_CM,
    DELTA_PAIRS_CM,
    SEGMENT_FRAMES,
    Lumen,
    SegmentCoverage,
    pair_key,
)
from hybrid.lumen_fit import FittedLumen
from hybrid.types import InputError, check_depth, check_poses


@dataclass(frozen=True)
class GeometricConfig:
    """Cells of the expected wall and the visibility test."""

    cell_length_cm: float = 0.2
    """Cell length along the centreline."""
    cells_around: int = 72
    """Cells around the tube (5° each)."""
    occlusion_tolerance: float = 0.05
    """A cell deeper than the observed depth by more than this × r(ℓ) is hidden."""
    segment_frames: int = SEGMENT_FRAMES
    """Frames per segment."""


@dataclass
class TubeCells:
    """Cell centres (L, K, 3) and areas (L, K) at arc lengths ell (L,) and angles theta (K,)."""

    ell: np.ndarray
    theta: np.ndarray
    points: np.ndarray
    area: np.ndarray


def tube_cells(lumen: FittedLumen, cell_length: float, cells_around: int) -> TubeCells:
    """Cells around the centreline, with rotation-minimising frames so θ does not twist."""
    arclength = lumen.arclength
    ell = np.arange(0.5 * cell_length, arclength[-1], cell_length)
    if len(ell) < 2:
        raise InputError(f"the lumen is {arclength[-1]:.3g} long, too short for two cells of "
                         f"{cell_length:g}; no tube to measure coverage on")
    centre = np.stack([np.interp(ell, arclength, lumen.points[:, k]) for k in range(3)], 1)
    radius = np.interp(ell, arclength, lumen.radius)
    tangent = np.gradient(centre, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True).clip(1e-12)
    normal = np.zeros_like(centre)
    seed = np.array([1.0, 0.0, 0.0]) if abs(tangent[0, 0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    normal[0] = np.cross(tangent[0], seed)
    normal[0] /= np.linalg.norm(normal[0])
    for i in range(1, len(ell)):  # double reflection (Wang et al. 2008)
        v1 = centre[i] - centre[i - 1]
        r = normal[i - 1] - 2 * (v1 @ normal[i - 1]) / (v1 @ v1) * v1
        t = tangent[i - 1] - 2 * (v1 @ tangent[i - 1]) / (v1 @ v1) * v1
        v2 = tangent[i] - t
        normal[i] = r - 2 * (v2 @ r) / max(v2 @ v2, 1e-24) * v2
    binormal = np.cross(tangent, normal)
    theta = (np.arange(cells_around) + 0.5) * 2 * np.pi / cells_around
    ring = (np.cos(theta)[None, :, None] * normal[:, None] + np.sin(theta)[None, :, None]
            * binormal[:, None])
    points = centre[:, None] + radius[:, None, None] * ring
    area = np.repeat((radius * 2 * np.pi / cells_around * cell_length)[:, None], cells_around, 1)
    return TubeCells(ell, theta, points, area)


@dataclass
class GeometricCoverage:
    """Per-segment coverage and the unrolled map of the cells (seen, expected)."""

    segments: list[SegmentCoverage]
    cells: TubeCells
    first_seen: np.ndarray
    """(L, K) int32: index of the first segment that saw each cell, -1 if none did."""
    expected: np.ndarray
    """(L, K) bool: the cell lies in the default-pair V of some segment."""
    support: list[float | None]
    """Per segment, the share of its default-pair V (by area) where the lumen was fitted to
    the reconstructed surface (`FittedLumen.fitted`) rather than continued straight beyond
    it or interpolated across a stretch without usable cross-sections; None where V is empty
    or the default pair was not asked for. How much of the coverage rests on wall the video
    reconstructed."""

    def labels(self, pair: tuple[float, float] = DEFAULT_PAIR_CM) -> np.ndarray:
        key = pair_key(pair)
        return np.array([np.nan if s.coverage[key] is None else s.coverage[key]
                         for s in self.segments])


def geometric_coverage(lumen: FittedLumen, poses: np.ndarray, depth: Sequence[np.ndarray],
                       K: np.ndarray, region: np.ndarray | None = None,
                       config: GeometricConfig = GeometricConfig(),
                       delta_pairs: tuple[tuple[float, float], ...] = DELTA_PAIRS_CM,
                       progress: bool = False, name: str = "video",
                       first_frame: int = 0) -> GeometricCoverage:
    """Coverage of each full segment of consecutive frames (see the module docstring).

    depth: per-frame (H, W) z-depth (0 = invalid), indexable; region: (H, W) bool image region;
    first_frame: the first frame's number in the video (for a window of it), which messages
    give.
    """
    poses = check_poses(poses, name=f"{name} poses")
    n = len(poses)
    if len(depth) != n:
        raise InputError(f"{name}: {len(depth)} depth maps for {n} poses")
    T = config.segment_frames
    if n < T:
        raise InputError(f"{name}: {n} frames is shorter than one segment ({T} frames); "
                         f"geometric coverage needs at least one full segment")
    first = check_depth(depth[0], None, f"{name} frame {first_frame}")
    region = np.ones(first.shape, dtype=bool) if region is None else np.asarray(region)
    if region.dtype != bool or region.shape != first.shape:
        raise InputError(f"{name}: the image region must be a bool mask of the depth's size "
                         f"{first.shape}, got {region.dtype} {region.shape}")
    cells = tube_cells(lumen, config.cell_length_cm, config.cells_around)
    camera_ell, _ = Lumen(lumen.points, name=f"{name} lumen").project(poses[:, :3, 3])
    row_radius = np.interp(cells.ell, lumen.arclength, lumen.radius)
    height, width = first.shape
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    lo = min(d0 for d0, _ in delta_pairs)
    hi = max(d1 for _, d1 in delta_pairs)
    on_wall = (np.ones(len(cells.ell), dtype=bool) if lumen.fitted is None else
               np.interp(cells.ell, lumen.arclength, lumen.fitted.astype(float)) >= 0.5)
    first_seen = np.full(cells.area.shape, -1, dtype=np.int32)
    expected = np.zeros(cells.area.shape, dtype=bool)
    segments, support = [], []
    bar = tqdm(total=n - n % T, desc="geometric coverage", unit="frame", disable=not progress)
    for start in range(0, n - T + 1, T):
        e_min, e_max = camera_ell[start:start + T].min(), camera_ell[start:start + T].max()
        # the rows of every pair's V, both ends included as in_v below and in the truth
        a = np.searchsorted(cells.ell, e_min + lo, side="left")
        b = np.searchsorted(cells.ell, e_max + hi, side="right")
        seen = np.zeros((b - a, len(cells.theta)), dtype=bool)
        points = cells.points[a:b].reshape(-1, 3)
        tolerance = np.repeat(config.occlusion_tolerance * row_radius[a:b], len(cells.theta))
        for f in range(start, start + T):
            d = check_depth(depth[f], first.shape, f"{name} frame {first_frame + f}")
            R, p = poses[f, :3, :3], poses[f, :3, 3]
            xc = (points - p) @ R
            z = xc[:, 2]
            front = z > 1e-6
            zs = np.where(front, z, 1.0)
            u = fx * xc[:, 0] / zs + cx
            v = fy * xc[:, 1] / zs + cy
            inside = front & (u >= -0.5) & (u < width - 0.5) & (v >= -0.5) & (v < height - 0.5)
            ui = np.rint(u).astype(np.int64).clip(0, width - 1)
            vi = np.rint(v).astype(np.int64).clip(0, height - 1)
            u0 = np.floor(u).astype(np.int64).clip(0, width - 2)
            v0 = np.floor(v).astype(np.int64).clip(0, height - 2)
            observed = np.maximum.reduce([d[v0, u0], d[v0, u0 + 1], d[v0 + 1, u0],
                                          d[v0 + 1, u0 + 1]])
            visible = inside & region[vi, ui] & (observed > 0) & (z <= observed + tolerance)
            seen |= visible.reshape(seen.shape)
            bar.update(1)
        rows = first_seen[a:b]
        rows[(rows < 0) & seen] = len(segments)
        coverage, segment_support = {}, None
        for d0, d1 in delta_pairs:
            in_v = (cells.ell[a:b] >= e_min + d0) & (cells.ell[a:b] <= e_max + d1)
            total = cells.area[a:b][in_v].sum()
            coverage[pair_key((d0, d1))] = (float(cells.area[a:b][in_v][seen[in_v]].sum()
                                                  / total) if total > 0 else None)
            if (d0, d1) == DEFAULT_PAIR_CM:
                expected[a:b][in_v] = True
                if total > 0:
                    segment_support = float(cells.area[a:b][in_v & on_wall[a:b]].sum() / total)
        segments.append(SegmentCoverage(len(segments), start, start + T, float(e_min),
                                        float(e_max), coverage))
        support.append(segment_support)
    bar.close()
    return GeometricCoverage(segments, cells, first_seen, expected, support)
