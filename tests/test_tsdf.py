"""TSDF fusion against an analytic scene: the inside of an open cylinder around the z axis.

z-depth and colour are rendered here by ray-cylinder intersection (not by the simulator), so the
fused surface can be checked against the radius R.
"""

from __future__ import annotations

import numpy as np
import pytest

from fusion.tsdf import FusedMesh, TsdfConfig, fuse
from hybrid.types import InputError

RADIUS, LENGTH = 2.0, 10.0
HEIGHT, WIDTH, FOCAL = 128, 160, 80.0
K = np.array([[FOCAL, 0, (WIDTH - 1) / 2], [0, FOCAL, (HEIGHT - 1) / 2], [0, 0, 1]])
VOXEL = 0.05
CONFIG = TsdfConfig(voxel_size=VOXEL, depth_max=5.0, block_count=500)


def pose_at(z: float, offset=(0.0, 0.0), tilt_deg: float = 0.0) -> np.ndarray:
    """Camera-to-world pose at (offset, z) looking along +z, tilted about the x axis."""
    a = np.radians(tilt_deg)
    pose = np.eye(4)
    pose[:3, :3] = [[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]
    pose[:3, 3] = [*offset, z]
    return pose


def wall_color(theta: np.ndarray) -> np.ndarray:
    """RGB that varies smoothly around the wall: (128 + 100 cos θ, 128 + 100 sin θ, 50)."""
    return np.stack([128 + 100 * np.cos(theta), 128 + 100 * np.sin(theta),
                     np.full_like(theta, 50)], axis=-1)


def render(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """z-depth (0 where the ray leaves through an open end) and RGB of the cylinder wall."""
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / FOCAL, (v - K[1, 2]) / FOCAL, np.ones_like(u)], axis=-1)
    d = rays @ pose[:3, :3].T  # world direction per unit of z-depth
    p = pose[:3, 3]
    a = d[..., 0] ** 2 + d[..., 1] ** 2
    b = 2 * (p[0] * d[..., 0] + p[1] * d[..., 1])
    c = p[0] ** 2 + p[1] ** 2 - RADIUS**2  # < 0: the camera is inside
    z = (-b + np.sqrt(b * b - 4 * a * c)) / (2 * np.maximum(a, 1e-12))
    hit = p + z[..., None] * d
    valid = (a > 1e-12) & (hit[..., 2] >= 0) & (hit[..., 2] <= LENGTH)
    rgb = wall_color(np.arctan2(hit[..., 1], hit[..., 0]))
    return np.where(valid, z, 0).astype(np.float32), rgb.round().astype(np.uint8)


POSES = np.stack([pose_at(z) for z in np.arange(0.0, 3.01, 0.5)]
                 + [pose_at(1.0, (0.3, -0.2), 8.0), pose_at(2.0, (-0.3, 0.2), -8.0)])
WELL_SEEN = (3.0, 6.0)
"""z range seen around the whole wall by several cameras: a camera at z sees the full ring from
z + 2.5 (the vertical half-field is atan(64/80)) to z + depth_max."""


@pytest.fixture(scope="module")
def colored_mesh() -> FusedMesh:
    return fuse((render(p) for p in POSES), K, POSES, CONFIG)


def test_fused_wall_lies_on_the_cylinder(colored_mesh):
    v = colored_mesh.vertices
    seen = v[(v[:, 2] > WELL_SEEN[0]) & (v[:, 2] < WELL_SEEN[1])]
    error = np.hypot(seen[:, 0], seen[:, 1]) - RADIUS
    # Marching cubes interpolates the zero crossing linearly; with R = 40 voxels the distance
    # field is nearly linear across a voxel, so the error comes from the depth being sampled at
    # the nearest pixel (footprint 5 cm / 80 px ≈ 1.3 voxels at depth_max, along the wall,
    # where it shifts the radius by a fraction of that at the incidence angle).
    assert abs(np.median(error)) < 0.5 * VOXEL
    assert np.percentile(np.abs(error), 95) < VOXEL
    # The whole ring is there: every 10° by 0.5 cm cell of the well-seen band has vertices.
    theta = np.degrees(np.arctan2(seen[:, 1], seen[:, 0])) + 180
    cells, _, _ = np.histogram2d(theta, seen[:, 2], bins=(36, 6), range=((0, 360), WELL_SEEN))
    assert (cells > 0).all()


def test_fused_mesh_carries_the_wall_colour(colored_mesh, tmp_path):
    v = colored_mesh.vertices
    expected = wall_color(np.arctan2(v[:, 1], v[:, 0]))
    # Colour changes by 100 levels per radian, 2.5 levels per voxel of arc: voxel averaging
    # and nearest-pixel sampling stay under 2 levels on average.
    assert colored_mesh.colors.dtype == np.uint8
    assert np.abs(colored_mesh.colors - expected).mean() < 2
    loaded = FusedMesh.load(colored_mesh.save(tmp_path / "mesh.ply"))
    np.testing.assert_allclose(loaded.vertices, colored_mesh.vertices, atol=1e-6)
    np.testing.assert_array_equal(loaded.triangles, colored_mesh.triangles)
    np.testing.assert_array_equal(loaded.colors, colored_mesh.colors)
    assert [p.name for p in tmp_path.iterdir()] == ["mesh.ply"]


def test_depth_only_fusion_has_no_colour(tmp_path):
    mesh = fuse(((render(p)[0], None) for p in POSES[:4]), K, POSES[:4],
                TsdfConfig(voxel_size=0.1, depth_max=5.0, block_count=200))
    assert mesh.colors is None
    assert FusedMesh.load(mesh.save(tmp_path / "mesh.ply")).colors is None
    assert abs(np.median(np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 1])) - RADIUS) < 0.05


SMALL = np.full((16, 20), 1.0, np.float32)
SMALL_K = np.array([[20.0, 0, 10], [0, 20, 8], [0, 0, 1]])
ONE = np.eye(4)[None]


def test_weight_threshold_counts_frames():
    """A voxel seen by n frames has weight n and is meshed when n > weight_threshold."""
    two = np.stack([np.eye(4)] * 2)
    config = TsdfConfig(voxel_size=0.05, block_count=50, weight_threshold=1.5)
    mesh = fuse([(SMALL, None)] * 2, SMALL_K, two, config)
    assert np.allclose(mesh.vertices[:, 2], 1.0, atol=1e-3)
    with pytest.raises(InputError, match="no surface reconstructed"):
        fuse([(SMALL, None)], SMALL_K, ONE, config)


@pytest.mark.parametrize("field, match", [
    ("voxel_size", "needs positive voxel_size "), ("truncation_voxels", "needs positive "
     "truncation_voxels "), ("depth_max", "needs positive depth_max "),
    ("block_count", "needs positive block_count "), ("weight_threshold", "needs positive values "),
])
def test_config_rejects_bad_values(field, match):
    with pytest.raises(InputError, match=f"^TsdfConfig {match}"):
        TsdfConfig(**{field: -1})


def test_config_rejects_a_block_size_that_is_not_whole():
    with pytest.raises(InputError, match="^TsdfConfig needs positive block_resolution "):
        TsdfConfig(block_resolution=16.5)


def test_whole_numbers_and_floats_are_taken_where_open3d_wants_the_other():
    """Open3D's bindings refuse an int depth limit or truncation and a float block size: the
    same fusion with depth_max=5, truncation_voxels=4 and block_resolution=16.0."""
    config = TsdfConfig(voxel_size=0.1, depth_max=5, truncation_voxels=4, block_count=200,
                        block_resolution=16.0)
    mesh = fuse(((render(p)[0], None) for p in POSES[:4]), K, POSES[:4], config)
    assert abs(np.median(np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 1])) - RADIUS) < 0.05


@pytest.mark.parametrize("frames, K, poses, match", [
    ([(np.zeros((16, 20), np.float32), None)], SMALL_K, ONE, "every depth pixel is 0"),
    ([(np.zeros((0, 0), np.float32), None)], SMALL_K, ONE, "non-empty"),
    ([(np.where(np.eye(16, 20) > 0, np.nan, SMALL), None)], SMALL_K, ONE, "NaN"),
    ([(np.full((16, 20), np.inf, np.float32), None)], SMALL_K, ONE, "infinite"),
    ([(SMALL, None)], SMALL_K, np.full((1, 4, 4), np.nan), "NaN"),
    ([(SMALL, None)], SMALL_K, np.eye(4)[None, :3], "shape"),
    ([(SMALL, None)], np.eye(2), ONE, "3x3"),
    ([(SMALL, None)], np.diag([-20.0, 20, 1]), ONE, "positive fx"),
    ([(SMALL, None)] * 2, SMALL_K, ONE, "more frames than"),
    ([(SMALL, None)], SMALL_K, np.stack([np.eye(4)] * 2), "1 frames for 2 poses"),
    ([(SMALL, np.zeros((16, 20), np.uint8))], SMALL_K, ONE, "rgb must be uint8"),
    ([(SMALL, None), (SMALL, np.zeros((16, 20, 3), np.uint8))], SMALL_K,
     np.stack([np.eye(4)] * 2), "every frame or for none"),
    ([(np.full((16, 20), 9.0, np.float32), None)] * 3, SMALL_K, np.stack([np.eye(4)] * 3),
     "no surface reconstructed"),
])
def test_bad_input_is_named(frames, K, poses, match):
    config = TsdfConfig(voxel_size=0.05, depth_max=5.0, block_count=50, weight_threshold=0.5)
    with pytest.raises(InputError, match=f"^test depth.*{match}"):
        fuse(frames, K, poses, config, name="test depth")


def test_a_bad_frame_is_named_by_its_number_in_the_video():
    """Fusing every 2nd frame of a video from its frame 10, the 3rd frame fused is frame 14."""
    frames = [(SMALL, None), (SMALL, None), (np.full((16, 20), np.nan, np.float32), None)]
    config = TsdfConfig(voxel_size=0.05, depth_max=5.0, block_count=50)
    with pytest.raises(InputError, match="^test depth frame 14: depth has NaN"):
        fuse(frames, SMALL_K, np.stack([np.eye(4)] * 3), config, name="test depth",
             numbers=[10, 12, 14])
