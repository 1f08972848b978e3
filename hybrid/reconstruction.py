"""The geometric branch up to the surface: metric scale, TSDF mesh and fitted lumen.

Reads per-frame z-depth (any scale), one K in the depth maps' pixels, and camera-to-world poses
in the same scale (smoothed by fusion.posegraph beforehand); returns poses in cm, the scale,
the coloured mesh and the lumen.

Scale rule: depth and translation share one unknown scale (monocular video). A first lumen is
fitted to a point cloud back-projected from every `cloud_stride`-th frame; the scale makes the
median radius fitted to it `typical_radius_cm`. Depth and poses are multiplied by it, fused
into a TSDF with `voxel_cm` voxels, and the lumen is fitted again, to the mesh. With known
metric inputs (the simulator's) pass the scale instead.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from fusion.tsdf import FusedMesh, TsdfConfig, fuse
from hybrid.coverage import DELTA_PAIRS_CM
from hybrid.lumen_fit import FittedLumen, LumenFitConfig, fit_lumen, metric_scale
from hybrid.types import InputError, check_poses, sampling_stride

LOOK_AHEAD_CM = max(d1 for _, d1 in DELTA_PAIRS_CM)
"""The farthest reach of a look-ahead band of the Δ pairs `c2d2 run` measures: the metric
lumen goes on at least this far beyond its deep end, so that no camera's band is cut short
by the end of the tube (geometric_coverage with pairs reaching further would need more)."""


@dataclass(frozen=True)
class ReconstructionConfig:
    """Scale rule, TSDF and lumen fit of the geometric branch."""

    typical_radius_cm: float = 2.5
    """The median lumen radius the scale rule assumes (adult colon: 5 cm across; the
    simulator draws radii of 1.5-3.5 cm)."""
    voxel_cm: float = 0.2
    """TSDF voxel size once the scale is fixed. The mesh serves the lumen fit, which thins
    the surface to cubes of a tenth of the radius (2.5 mm at the typical radius), and the
    report: 2 mm fuses about twice as fast as 1 mm (docs/geometric.md)."""
    depth_max_cm: float = 6.0
    """Depth beyond which pixels are not fused (the far lumen is dark and uncertain)."""
    cloud_stride: int = 10
    """Frames between those back-projected for the first (scale) lumen fit (more in a video
    longer than hybrid.types.SAMPLED_FRAMES of them)."""
    cloud_pixel_stride: int = 4
    """Pixels between those back-projected, along each image axis."""
    tsdf_stride: int = 2
    """Fuse every n-th frame into the TSDF. The mesh serves the lumen fit and the report;
    coverage tests each frame against its own depth. 2 halves the time at the same oracle
    geometric MAE (docs/geometric.md)."""
    lumen: LumenFitConfig = field(default_factory=LumenFitConfig)
    """Lumen fit."""


@dataclass
class Reconstruction:
    """The surface side of the geometric branch, in cm."""

    poses: np.ndarray
    """(N, 4, 4) camera-to-world poses, cm."""
    scale: float
    """cm per unit of the input depth and poses."""
    mesh: FusedMesh
    lumen: FittedLumen


class ScaledDepth(Sequence):
    """Depth maps multiplied by a scale and zeroed outside the image region, read lazily."""

    def __init__(self, depth: Sequence[np.ndarray], scale: float,
                 region: np.ndarray | None = None):
        self.depth, self.scale, self.region = depth, scale, region

    def __len__(self) -> int:
        return len(self.depth)

    def __getitem__(self, index: int) -> np.ndarray:
        d = np.asarray(self.depth[index], dtype=np.float32) * np.float32(self.scale)
        return d if self.region is None else np.where(self.region, d, np.float32(0))


def back_project(depth: Sequence[np.ndarray], K: np.ndarray, poses: np.ndarray,
                 frame_stride: int, pixel_stride: int) -> np.ndarray:
    """World points (M, 3) of valid pixels of every frame_stride-th frame."""
    points = []
    Kinv = np.linalg.inv(K)
    for f in range(0, len(poses), frame_stride):
        d = np.asarray(depth[f])[::pixel_stride, ::pixel_stride]
        v, u = np.nonzero(d > 0)
        pix = np.stack([u * pixel_stride, v * pixel_stride, np.ones_like(u)], 1).astype(float)
        cam = (pix @ Kinv.T) * d[v, u][:, None]
        points.append(cam @ poses[f, :3, :3].T + poses[f, :3, 3])
    return np.concatenate(points) if points else np.zeros((0, 3))


def reconstruct(depth: Sequence[np.ndarray], K: np.ndarray, poses: np.ndarray,
                rgb: Sequence[np.ndarray] | None = None, region: np.ndarray | None = None,
                config: ReconstructionConfig = ReconstructionConfig(),
                scale: float | None = None, fps: float = 30.0, name: str = "video",
                progress: bool = False, along: np.ndarray | None = None,
                first_frame: int = 0) -> Reconstruction:
    """Scale, mesh and lumen of one video (see the module docstring); along: each frame's
    place along the colon, which orients the lumen (fit_lumen); first_frame: the first
    frame's number in the video (for a window of it), which messages give."""
    poses = check_poses(poses, name=f"{name} poses")
    if len(depth) != len(poses) or (rgb is not None and len(rgb) != len(poses)):
        raise InputError(f"{name}: {len(depth)} depth maps, {len(poses)} poses"
                         + ("" if rgb is None else f", {len(rgb)} images")
                         + "; give one of each per frame")
    if scale is None:
        masked = ScaledDepth(depth, 1.0, region)
        cloud = back_project(masked, K, poses, sampling_stride(len(poses), config.cloud_stride),
                             config.cloud_pixel_stride)
        first = fit_lumen(poses, cloud, fps, config.lumen, name=f"{name} (scale fit)",
                          along=along)
        scale = metric_scale(first, config.typical_radius_cm)
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(f"{name}: the metric scale must be a positive number, got {scale}")
    metric = poses.copy()
    metric[:, :3, 3] *= scale
    scaled = ScaledDepth(depth, scale, region)
    fused = range(0, len(poses), config.tsdf_stride)  # frames not fused are not even read
    frames = ((scaled[i], None if rgb is None else rgb[i]) for i in fused)
    tsdf = TsdfConfig(voxel_size=config.voxel_cm, depth_max=config.depth_max_cm)
    mesh = fuse(frames, K, metric[fused], tsdf, name=name, progress=progress,
                numbers=[first_frame + i for i in fused])
    lumen = fit_lumen(metric, mesh.vertices, fps, config.lumen, name=name, along=along,
                      ahead_at_least=LOOK_AHEAD_CM)
    return Reconstruction(metric, float(scale), mesh, lumen)
