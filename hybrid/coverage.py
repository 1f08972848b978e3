"""Ground-truth coverage of a mesh by a camera trajectory (paper section 4.1, design.md).

ℓ*(x) is the arc length of the lumen point nearest to x. For a segment with camera ℓ* range
[ℓmin, ℓmax], the maximal visible set is V = {m : ℓmin + Δ0 <= ℓ*(m) <= ℓmax + Δ1}; a vertex
is actually seen (A) when some frame has it inside the image, in front of the camera and not
occluded (an exact ray test against the mesh). Coverage = area(A ∩ V) / area(V), with each
vertex weighted by a third of the area of its triangles. Works for any triangle mesh: open or
closed, vertices in any order.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree
from tqdm import tqdm

from hybrid.types import Camera, InputError, check_poses
from hybrid.workdir import write_json

if TYPE_CHECKING:
    import open3d as o3d

DELTA_PAIRS_CM: tuple[tuple[float, float], ...] = ((1.0, 3.0), (1.0, 4.0), (1.0, 6.0))
"""The paper's (Δ0, Δ1) pairs, in cm."""
DEFAULT_PAIR_CM: tuple[float, float] = (1.0, 4.0)
"""The pair whose segment coverage is the default segment label."""
SEGMENT_FRAMES = 300
"""Frames per segment: 10 s at 30 fps."""
_OCCLUSION_MARGIN = 1e-3
"""A hit closer than (1 - margin) of the way to a vertex occludes it."""


def pair_key(pair: tuple[float, float]) -> str:
    """JSON key of a Δ pair, e.g. '1-4'."""
    return f"{pair[0]:g}-{pair[1]:g}"


@dataclass(frozen=True)
class SurfaceMesh:
    """A triangle mesh with per-vertex area weights (cm, cm²)."""

    vertices: np.ndarray
    triangles: np.ndarray
    vertex_area: np.ndarray

    @classmethod
    def from_arrays(cls, vertices: np.ndarray, triangles: np.ndarray, name: str = "mesh"
                    ) -> SurfaceMesh:
        """Validate, drop degenerate triangles and unused vertices, compute vertex areas."""
        vertices = np.asarray(vertices, dtype=np.float64)
        triangles = np.asarray(triangles)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
            raise InputError(f"{name} has no vertices (shape {vertices.shape})")
        if triangles.ndim != 2 or triangles.shape[1] != 3 or len(triangles) == 0:
            raise InputError(f"{name} has no triangles; give a triangle mesh, not a point cloud")
        if not np.isfinite(vertices).all():
            raise InputError(f"{name} has NaN or infinite vertex coordinates")
        if triangles.min() < 0 or triangles.max() >= len(vertices):
            raise InputError(f"{name} has triangle indices outside its {len(vertices)} vertices")
        a, b, c = (vertices[triangles[:, k]] for k in range(3))
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        keep = area > 0
        if not keep.any():
            raise InputError(f"{name} has only degenerate (zero-area) triangles")
        triangles, area = triangles[keep], area[keep]
        used, remap = np.unique(triangles, return_inverse=True)
        triangles = remap.reshape(-1, 3).astype(np.int32)
        vertex_area = np.bincount(triangles.ravel(), np.repeat(area / 3, 3), minlength=used.size)
        return cls(vertices[used], triangles, vertex_area)

    @classmethod
    def load(cls, path: Path) -> SurfaceMesh:
        """Read any mesh format trimesh reads (PLY, OBJ, STL, OFF, ...)."""
        import trimesh

        path = Path(path)
        if not path.is_file():
            raise InputError(f"mesh file not found: {path}")
        try:
            mesh = trimesh.load(path, process=False)
        except Exception as err:  # trimesh raises many types for unreadable files
            raise InputError(f"cannot read mesh {path}: {err}") from err
        if isinstance(mesh, trimesh.Scene):
            mesh = mesh.to_mesh()
        faces = getattr(mesh, "faces", None)
        if faces is None or len(faces) == 0:
            raise InputError(f"{path} has no triangles; give a triangle mesh, not a point cloud")
        return cls.from_arrays(mesh.vertices, faces, name=str(path))

    def raycasting_scene(self) -> o3d.t.geometry.RaycastingScene:
        import open3d as o3d  # here, so that the coverage networks import without Open3D

        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(self.vertices.astype(np.float32)),
                            o3d.core.Tensor(self.triangles.astype(np.uint32)))
        return scene


class Lumen:
    """A lumen centerline parametrised by arc length ℓ from its first point (the rectum end)."""

    def __init__(self, points: np.ndarray, name: str = "lumen", spacing_cm: float = 0.02):
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise InputError(f"{name} must be an (M, 3) array of centerline points, got "
                             f"{points.shape}")
        if len(points) < 2:
            raise InputError(f"{name} needs at least 2 centerline points, got {len(points)}")
        if not np.isfinite(points).all():
            raise InputError(f"{name} has NaN or infinite points")
        steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
        if steps.sum() <= 0:
            raise InputError(f"{name} has zero length: all its points coincide")
        self.points = points
        self.arclength = np.concatenate([[0.0], np.cumsum(steps)])
        # Dense resampling so that the nearest sample is within spacing/2 of the true nearest.
        dense = np.arange(0.0, self.arclength[-1] + spacing_cm, spacing_cm).clip(
            max=self.arclength[-1])
        self._dense_ell = dense
        self._dense_pts = np.stack([np.interp(dense, self.arclength, points[:, k])
                                    for k in range(3)], axis=1)
        self._tree = cKDTree(self._dense_pts)

    @property
    def length(self) -> float:
        return float(self.arclength[-1])

    def project(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ℓ* of each point in x (..., 3) and its nearest lumen point."""
        _, idx = self._tree.query(np.asarray(x, dtype=np.float64))
        return self._dense_ell[idx], self._dense_pts[idx]


@dataclass
class SegmentCoverage:
    """Coverage of one segment of consecutive frames [start, stop)."""

    index: int
    start: int
    stop: int
    ell_min: float
    ell_max: float
    coverage: dict[str, float | None]


@dataclass
class CoverageResult:
    """Per-frame and per-segment coverage for each Δ pair (None where V is empty)."""

    delta_pairs: list[tuple[float, float]]
    segment_frames: int
    per_frame: dict[str, list[float | None]]
    segments: list[SegmentCoverage] = field(default_factory=list)
    default_pair: tuple[float, float] = DEFAULT_PAIR_CM

    def to_json(self) -> dict:
        return {
            "delta_pairs_cm": [list(p) for p in self.delta_pairs],
            "default_pair_cm": list(self.default_pair),
            "segment_frames": self.segment_frames,
            "per_frame": self.per_frame,
            "segments": [vars(s) for s in self.segments],
        }

    @classmethod
    def from_json(cls, data: dict) -> CoverageResult:
        return cls(
            delta_pairs=[tuple(p) for p in data["delta_pairs_cm"]],
            segment_frames=data["segment_frames"],
            per_frame=data["per_frame"],
            segments=[SegmentCoverage(**s) for s in data["segments"]],
            default_pair=tuple(data["default_pair_cm"]),
        )

    def save(self, path: Path) -> None:
        write_json(path, self.to_json())

    def segment_labels(self, pair: tuple[float, float] | None = None) -> np.ndarray:
        """Segment coverages for one pair (default pair if None), NaN where undefined."""
        key = pair_key(pair or self.default_pair)
        return np.array([np.nan if s.coverage[key] is None else s.coverage[key]
                         for s in self.segments])

    def window_table(self) -> np.ndarray:
        """(S, 2) float64: each segment's start frame and default-pair coverage (NaN where
        undefined); of overlapping windows, the segment network's training labels."""
        starts = np.array([s.start for s in self.segments], dtype=np.float64)
        return np.column_stack([starts, self.segment_labels()])

    def back_to_back(self) -> CoverageResult:
        """The segments starting every segment_frames frames, numbered from 0. Of overlapping
        windows whose stride divides segment_frames, that is what a run without a stride gives
        (each window's coverage depends on its own frames only)."""
        kept = [s for s in self.segments if s.start % self.segment_frames == 0]
        return replace(self, segments=[replace(s, index=i) for i, s in enumerate(kept)])


class VisibilityOracle:
    """Which mesh vertices a camera sees: in the image region, in front, and not occluded.

    region: (height, width) bool mask of the pixels the endoscope shows (an octagon or circle
    on real ones); None: the whole image.
    """

    def __init__(self, mesh: SurfaceMesh, camera: Camera, region: np.ndarray | None = None):
        self.mesh = mesh
        self.camera = camera
        self.scene = mesh.raycasting_scene()
        if region is not None:
            region = np.asarray(region)
            if region.shape != (camera.height, camera.width) or region.dtype != bool:
                raise InputError(f"the image region must be a bool mask of the camera's size "
                                 f"{(camera.height, camera.width)}, got {region.dtype} "
                                 f"{region.shape}")
        self.region = region

    def visible(self, pose: np.ndarray, vertex_ids: np.ndarray) -> np.ndarray:
        """Boolean mask over vertex_ids for one camera-to-world pose."""
        cam = self.camera
        R, p = pose[:3, :3], pose[:3, 3]
        rel = self.mesh.vertices[vertex_ids] - p
        xc = rel @ R  # camera coordinates, = R^T (X - p)
        u, v, in_front = cam.project(xc)
        mask = in_front & (u >= -0.5) & (u <= cam.width - 0.5) & (v >= -0.5) & (
            v <= cam.height - 0.5)
        if self.region is not None:  # the pixel it projects into must be shown
            inside = np.flatnonzero(mask)
            column = np.clip(np.floor(u[inside] + 0.5), 0, cam.width - 1).astype(int)
            row = np.clip(np.floor(v[inside] + 0.5), 0, cam.height - 1).astype(int)
            mask[inside] = self.region[row, column]
        candidates = np.flatnonzero(mask)
        if candidates.size:
            rays = np.concatenate([np.broadcast_to(p, (candidates.size, 3)), rel[candidates]],
                                  axis=1).astype(np.float32)
            import open3d as o3d

            occluded = self.scene.test_occlusions(
                o3d.core.Tensor(rays), tnear=0.0, tfar=1.0 - _OCCLUSION_MARGIN).numpy()
            mask[candidates[occluded]] = False
        return mask

    def check_inside(self, positions: np.ndarray, lumen: Lumen, name: str = "poses") -> None:
        """Raise if a camera centre lies outside the wall around the lumen.

        From the nearest lumen point, a ray towards the camera must meet the wall beyond the camera
        (a ray that meets no wall, e.g. out of an open end, means the camera is outside).
        """
        _, nearest = lumen.project(positions)
        offset = positions - nearest
        dist = np.linalg.norm(offset, axis=1)
        direction = offset / np.where(dist > 1e-9, dist, 1.0)[:, None]
        direction[dist <= 1e-9] = (1.0, 0.0, 0.0)
        rays = np.concatenate([nearest, direction], axis=1).astype(np.float32)
        import open3d as o3d

        wall = self.scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        outside = np.flatnonzero(~(np.isfinite(wall) & (wall > dist)))
        if outside.size:
            raise InputError(
                f"{name}: camera centres of frames {outside[:10].tolist()} are outside the mesh "
                f"(no wall between the lumen and the camera); check that poses, mesh and lumen "
                f"share one coordinate frame and unit (cm)"
            )


def compute_coverage(
    mesh: SurfaceMesh,
    lumen: Lumen,
    poses: np.ndarray,
    camera: Camera,
    segment_frames: int = SEGMENT_FRAMES,
    delta_pairs: tuple[tuple[float, float], ...] = DELTA_PAIRS_CM,
    progress: bool = False,
    poses_name: str = "poses",
    segment_stride: int | None = None,
    region: np.ndarray | None = None,
) -> CoverageResult:
    """Per-frame coverage for every frame and per-segment coverage for full segments.

    Segments start every segment_stride frames (default: segment_frames, i.e. back to back;
    a smaller stride gives overlapping windows, e.g. as training samples). Frames after the
    last full segment get per-frame values but no segment. poses_name names the poses in error
    messages (e.g. their file). region: the camera's image region (VisibilityOracle).
    """
    poses = check_poses(poses, name=poses_name)
    stride = segment_frames if segment_stride is None else segment_stride
    if segment_frames < 1 or stride < 1:
        raise InputError(f"segment length and stride must be at least 1 frame, got "
                         f"{segment_frames} and {stride}")
    oracle = VisibilityOracle(mesh, camera, region)
    oracle.check_inside(poses[:, :3, 3], lumen, name=poses_name)
    vertex_ell, _ = lumen.project(mesh.vertices)
    order = np.argsort(vertex_ell)
    sorted_ell = vertex_ell[order]
    area_below = np.concatenate([[0.0], np.cumsum(mesh.vertex_area[order])])

    def area_between(lo: float, hi: float) -> float:
        """Area of the vertices with lo <= ℓ* <= hi."""
        return area_below[np.searchsorted(sorted_ell, hi, side="right")] - area_below[
            np.searchsorted(sorted_ell, lo, side="left")]

    def coverage_of(seen: np.ndarray, lo: float, hi: float) -> float | None:
        total = area_between(lo, hi)
        ell = vertex_ell[seen]
        inside = seen[(ell >= lo) & (ell <= hi)]
        return float(mesh.vertex_area[inside].sum() / total) if total > 0 else None

    camera_ell, _ = lumen.project(poses[:, :3, 3])
    n = len(poses)
    windows = [(s, s + segment_frames) for s in range(0, n - segment_frames + 1, stride)]
    # Each frame is tested against the ℓ* band of its own V and of every window holding it.
    lo = min(d0 for d0, _ in delta_pairs)
    hi = max(d1 for _, d1 in delta_pairs)
    band_lo, band_hi = camera_ell + lo, camera_ell + hi
    for start, stop in windows:
        band_lo[start:stop] = np.minimum(band_lo[start:stop], camera_ell[start:stop].min() + lo)
        band_hi[start:stop] = np.maximum(band_hi[start:stop], camera_ell[start:stop].max() + hi)

    per_frame = {pair_key(p): [None] * n for p in delta_pairs}
    segments = []
    last_seen = np.full(len(mesh.vertices), -1)  # the last frame so far that saw each vertex
    for f in tqdm(range(n), desc="coverage", unit="frame", disable=not progress):
        a = np.searchsorted(sorted_ell, band_lo[f], side="left")
        b = np.searchsorted(sorted_ell, band_hi[f], side="right")
        ids = order[a:b]
        seen = ids[oracle.visible(poses[f], ids)]
        for d0, d1 in delta_pairs:
            per_frame[pair_key((d0, d1))][f] = coverage_of(seen, camera_ell[f] + d0,
                                                            camera_ell[f] + d1)
        last_seen[seen] = f
        while len(segments) < len(windows) and windows[len(segments)][1] == f + 1:
            start, stop = windows[len(segments)]
            union = np.flatnonzero(last_seen >= start)  # seen by a frame of [start, f]
            e_min, e_max = camera_ell[start:stop].min(), camera_ell[start:stop].max()
            coverage = {pair_key((d0, d1)): coverage_of(union, e_min + d0, e_max + d1)
                        for d0, d1 in delta_pairs}
            segments.append(SegmentCoverage(len(segments), start, stop, float(e_min),
                                            float(e_max), coverage))
    return CoverageResult(list(delta_pairs), segment_frames, per_frame, segments)
