"""TSDF fusion of depth maps into one surface mesh (Open3D tensor VoxelBlockGrid).

Reads a stream of z-depth maps (optionally with RGB), one 3x3 K and camera-to-world poses;
returns a `FusedMesh` that `save` writes as PLY (the procedure's `mesh.ply`). The legacy
`ScalableTSDFVolume` is not used: it integrates nothing in Open3D 0.20.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import open3d as o3d
import open3d.core as o3c
from tqdm import tqdm

from hybrid.types import InputError, check_depth, check_poses

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TsdfConfig:
    """TSDF volume and extraction settings; lengths in the unit of the depth maps."""

    voxel_size: float = 0.1
    """Voxel edge length; the caller ties it to the depth's scale (0.1 = 1 mm for depth in cm)."""
    truncation_voxels: float = 4.0
    """Truncation distance of the signed distance, in voxels."""
    depth_max: float = 6.0
    """Depth beyond which pixels are ignored (the far, dark lumen is noisy)."""
    weight_threshold: float = 1.5
    """A voxel is meshed when its weight (frames that saw it) is strictly above this: 1.5 keeps
    surfaces seen by two frames or more (Open3D's default 3.0 needs four)."""
    block_resolution: int = 16
    """Voxels along each edge of a hashed block."""
    block_count: int = 2000
    """Blocks allocated up front (the hash map grows beyond it; each block with colour holds
    16³ voxels × 20 bytes = 80 kB)."""
    def __post_init__(self) -> None:
        positive = {"voxel_size": self.voxel_size, "truncation_voxels": self.truncation_voxels,
                    "depth_max": self.depth_max, "block_resolution": self.block_resolution,
                    "block_count": self.block_count}
        bad = [k for k, v in positive.items() if not (np.isfinite(v) and v > 0)]
        bad += [k for k in ("block_resolution", "block_count")
                if k not in bad and getattr(self, k) != int(getattr(self, k))]
        if bad or not (np.isfinite(self.weight_threshold) and self.weight_threshold >= 0):
            raise InputError(f"TsdfConfig needs positive {', '.join(bad) or 'values'} (whole "
                             f"numbers of blocks) and a weight_threshold >= 0: {self}")


@dataclass
class FusedMesh:
    """A triangle mesh extracted from the TSDF volume."""

    vertices: np.ndarray
    """(V, 3) float64 positions, in the poses' frame and unit."""
    triangles: np.ndarray
    """(T, 3) int32 vertex indices."""
    colors: np.ndarray | None = None
    """(V, 3) uint8 RGB, or None when fused without images."""

    def save(self, path: Path) -> Path:
        """Write a binary PLY atomically (temporary file, then rename); return the path."""
        import trimesh

        path = Path(path)
        colors = None if self.colors is None else np.column_stack(
            [self.colors, np.full(len(self.colors), 255, np.uint8)])
        mesh = trimesh.Trimesh(self.vertices, self.triangles, vertex_colors=colors,
                               process=False)
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_bytes(mesh.export(file_type="ply"))
        os.replace(tmp, path)
        return path

    @classmethod
    def load(cls, path: Path) -> FusedMesh:
        """Read a mesh written by `save`."""
        import trimesh

        path = Path(path)
        if not path.is_file():
            raise InputError(f"mesh file not found: {path}; run the fusion stage first")
        mesh = trimesh.load(path, process=False, force="mesh")
        colors = mesh.visual.vertex_colors[:, :3] if mesh.visual.kind == "vertex" else None
        return cls(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int32),
                   None if colors is None else np.asarray(colors, np.uint8))


class TsdfVolume:
    """A TSDF volume that takes frames one at a time (the colour mode is fixed by the first)."""

    def __init__(self, K: np.ndarray, config: TsdfConfig, name: str = "depth"):
        self.config, self.name = config, name
        self.intrinsic = o3c.Tensor(_check_intrinsics(K, name), o3c.float64)
        self.grid: o3d.t.geometry.VoxelBlockGrid | None = None
        self.with_color: bool | None = None
        self.shape: tuple[int, int] | None = None
        self.frames = 0
        self.any_valid = False

    def integrate(self, depth: np.ndarray, rgb: np.ndarray | None, pose: np.ndarray,
                  number: int | None = None) -> None:
        """Add one frame: depth (H, W) z-depth, 0 = invalid; rgb (H, W, 3) uint8 or None;
        pose (4, 4) camera-to-world; number: the frame's number in the video, for messages
        (default: how many frames came before it)."""
        what = f"{self.name} frame {self.frames if number is None else number}"
        self.frames += 1
        depth = check_depth(depth, self.shape, what)
        self.shape = depth.shape
        if self.grid is None:
            self.with_color = rgb is not None
            self.grid = _new_grid(self.config, self.with_color)
        if (rgb is not None) != self.with_color:
            raise InputError(f"{what}: give RGB for every frame or for none")
        color = None if rgb is None else _check_rgb(rgb, depth.shape, what)
        self.any_valid = self.any_valid or bool((depth > 0).any())
        if not ((depth > 0) & (depth <= self.config.depth_max)).any():
            return  # Open3D aborts on a frame that touches no block
        # Open3D wants world->camera, float64; float depth with depth_scale 1.
        extrinsic = o3c.Tensor(np.linalg.inv(pose), o3c.float64)
        depth_image = o3d.t.geometry.Image(o3c.Tensor(depth))
        # floats, as Open3D's bindings take no int here (nor floats for the grid's sizes)
        settings = (1.0, float(self.config.depth_max), float(self.config.truncation_voxels))
        blocks = self.grid.compute_unique_block_coordinates(depth_image, self.intrinsic,
                                                            extrinsic, *settings)
        if color is None:
            self.grid.integrate(blocks, depth_image, self.intrinsic, extrinsic, *settings)
        else:
            self.grid.integrate(blocks, depth_image, o3d.t.geometry.Image(o3c.Tensor(color)),
                                self.intrinsic, self.intrinsic, extrinsic, *settings)

    def extract(self) -> FusedMesh:
        """The isosurface of voxels seen by more than config.weight_threshold frames."""
        if not self.any_valid:
            raise InputError(f"{self.name}: no surface: every depth pixel is 0 (invalid); check "
                             f"the depth maps")
        empty = (f"{self.name}: no surface reconstructed (no voxel seen by more than "
                 f"{self.config.weight_threshold} frames within depth_max="
                 f"{self.config.depth_max}); check the depth scale, or raise depth_max or lower "
                 f"weight_threshold")
        try:
            mesh = self.grid.extract_triangle_mesh(self.config.weight_threshold)
        except RuntimeError as err:  # Open3D raises on a volume with no voxel above threshold
            raise InputError(f"{empty} (Open3D: {err})") from err
        if mesh.triangle.indices.shape[0] == 0:
            raise InputError(empty)
        colors = None
        if "colors" in mesh.vertex:
            colors = np.round(mesh.vertex.colors.numpy().clip(0, 1) * 255).astype(np.uint8)
        result = FusedMesh(mesh.vertex.positions.numpy().astype(np.float64),
                           mesh.triangle.indices.numpy().astype(np.int32), colors)
        log.info("%s: fused mesh with %d vertices, %d triangles", self.name,
                 len(result.vertices), len(result.triangles))
        return result


def fuse(frames: Iterable[tuple[np.ndarray, np.ndarray | None]], K: np.ndarray,
         poses: np.ndarray, config: TsdfConfig, name: str = "depth",
         progress: bool = False, numbers: Sequence[int] | None = None) -> FusedMesh:
    """Integrate depth (and colour) frames into a TSDF volume and extract its mesh.

    frames: one (depth, rgb) per pose, read one at a time; depth (H, W) float32 z-depth with
        0 = invalid; rgb (H, W, 3) uint8 or None (give it for every frame or for none).
    K: (3, 3) intrinsics in the frames' pixels. poses: (N, 4, 4) camera-to-world.
    numbers: each frame's number in the video, which messages give (default 0 to N-1).
    """
    volume = TsdfVolume(K, config, name)
    poses = check_poses(poses, name=f"{name} poses")
    if numbers is not None and len(numbers) != len(poses):
        raise InputError(f"{name}: {len(numbers)} frame numbers for {len(poses)} poses")
    count = 0
    frames = tqdm(frames, total=len(poses), desc=f"tsdf {name}", unit="frame",
                  disable=not progress)
    for index, (depth, rgb) in enumerate(frames):
        count = index + 1
        if index >= len(poses):
            raise InputError(f"{name}: more frames than the {len(poses)} poses; give one pose "
                             f"per frame")
        volume.integrate(depth, rgb, poses[index], None if numbers is None else numbers[index])
    if count != len(poses):
        raise InputError(f"{name}: {count} frames for {len(poses)} poses; give one pose per "
                         f"frame")
    return volume.extract()


def _new_grid(config: TsdfConfig, with_color: bool) -> o3d.t.geometry.VoxelBlockGrid:
    names, dtypes, channels = ["tsdf", "weight"], [o3c.float32, o3c.float32], [1, 1]
    if with_color:
        names, dtypes, channels = names + ["color"], dtypes + [o3c.float32], channels + [3]
    return o3d.t.geometry.VoxelBlockGrid(names, dtypes, channels, float(config.voxel_size),
                                         int(config.block_resolution), int(config.block_count))


def _check_intrinsics(K: np.ndarray, name: str) -> np.ndarray:
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(f"{name}: K must be a finite 3x3 intrinsic matrix with positive fx, fy "
                         f"(pixels of the depth maps), got {K.tolist()}")
    return K


def _check_rgb(rgb: np.ndarray, shape: tuple[int, int], what: str) -> np.ndarray:
    rgb = np.asarray(rgb)
    if rgb.shape != (*shape, 3) or rgb.dtype != np.uint8:
        raise InputError(f"{what}: rgb must be uint8 of shape {(*shape, 3)} like the depth, got "
                         f"{rgb.dtype} {rgb.shape}")
    return rgb.astype(np.float32) / 255
