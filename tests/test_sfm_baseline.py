"""pycolmap structure from motion inside an analytically rendered, textured tube.

The camera moves forward along the axis of a cylinder of radius 2 cm with a little sideways
wobble and yaw; the wall carries a blurred random texture in (angle, z). Frames are seen
through a disc-shaped mask with a black border, as through an endoscope.
"""

from __future__ import annotations

import cv2
import numpy as np
import pycolmap
import pytest

from fusion.sfm_baseline import run_sfm
from hybrid.types import InputError
from learned.metrics import trajectory_errors

RADIUS, HEIGHT, WIDTH, FOCAL, FRAMES = 2.0, 128, 160, 80.0, 24
K = np.array([[FOCAL, 0, (WIDTH - 1) / 2], [0, FOCAL, (HEIGHT - 1) / 2], [0, 0, 1]])
_v, _u = np.mgrid[0:HEIGHT, 0:WIDTH]
MASK = np.hypot(_u - K[0, 2], _v - K[1, 2]) < 90
"""Round field of view: cuts the corners (a smaller disc cuts the near wall, which SfM needs)."""


def wall_texture(size: int = 1024) -> np.ndarray:
    """Blurred uniform noise, grey levels 0-255, indexed by (z, angle)."""
    noise = np.random.default_rng(0).uniform(0, 255, (size, size)).astype(np.float32)
    return cv2.normalize(cv2.GaussianBlur(noise, (0, 0), 2.0), None, 0, 255, cv2.NORM_MINMAX)


def pose_at(i: int) -> np.ndarray:
    """Camera-to-world: 1 mm forward per frame, a sideways wobble and a yaw of up to 3°."""
    yaw = 0.05 * np.sin(i / 3)
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]]
    pose[:3, 3] = [0.3 * np.sin(i / 5), 0.2 * np.cos(i / 4), 0.1 * i]
    return pose


def render(pose: np.ndarray, texture: np.ndarray) -> np.ndarray:
    """RGB of the textured wall by ray-cylinder intersection, darker with distance, masked."""
    rays = np.stack([(_u - K[0, 2]) / FOCAL, (_v - K[1, 2]) / FOCAL, np.ones(_u.shape)], -1)
    d, p = rays @ pose[:3, :3].T, pose[:3, 3]
    a = d[..., 0] ** 2 + d[..., 1] ** 2
    b = 2 * (p[0] * d[..., 0] + p[1] * d[..., 1])
    c = p[0] ** 2 + p[1] ** 2 - RADIUS**2
    z = (-b + np.sqrt(b * b - 4 * a * c)) / (2 * np.maximum(a, 1e-12))
    hit = p + z[..., None] * d
    size = len(texture)
    col = (np.arctan2(hit[..., 1], hit[..., 0]) + np.pi) / (2 * np.pi) * size
    row = hit[..., 2] / 12.0 * size
    grey = cv2.remap(texture, col.astype(np.float32), row.astype(np.float32), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_WRAP) / (1 + 0.05 * z**2) * MASK
    return np.repeat(grey[..., None], 3, axis=-1).clip(0, 255).astype(np.uint8)


def test_sfm_recovers_focal_length_and_trajectory(tmp_path):
    poses = np.stack([pose_at(i) for i in range(FRAMES)])
    texture = wall_texture()
    result = run_sfm([render(p, texture) for p in poses], MASK, tmp_path)
    assert result.registered.all()
    assert np.isfinite(result.poses).all()
    # The principal point stays at the image centre (OpenCV convention), as rendered.
    np.testing.assert_allclose(result.K[:2, 2], K[:2, 2])
    # 24 frames with a 2.3 cm baseline at 128x160 give f within a few percent (2.2% measured).
    assert abs(result.K[0, 0] - FOCAL) / FOCAL < 0.05
    errors = trajectory_errors(result.poses, poses)
    assert errors["ate"] < 0.02  # cm: under 1% of the path
    assert errors["rpe_rotation_deg"] < 0.2
    # The camera mask reached COLMAP: every keypoint lies inside it.
    database = pycolmap.Database.open(tmp_path / "database.db")
    for image in database.read_all_images():
        x, y = database.read_keypoints(image.image_id)[:, :2].T.astype(int)
        assert MASK[y, x].all()


def test_sfm_without_texture_raises(tmp_path):
    with pytest.raises(InputError, match="no model"):
        run_sfm([np.full((64, 80, 3), 128, np.uint8)] * 4, None, tmp_path, name="grey")


@pytest.mark.parametrize("images, mask, match", [
    ([np.zeros((8, 8, 3), np.uint8)], None, "at least 2 frames"),
    ([np.zeros((8, 8, 3), np.uint8), np.zeros((8, 9, 3), np.uint8)], None, "one size"),
    ([np.zeros((8, 8), np.uint8)] * 2, None, "RGB uint8"),
    ([np.zeros((8, 8, 3), np.float32)] * 2, None, "RGB uint8"),
    ([np.zeros((8, 8, 3), np.uint8)] * 2, np.ones((4, 4), bool), "mask"),
    ([np.zeros((8, 8, 3), np.uint8)] * 2, np.zeros((8, 8), bool), "mask"),
])
def test_bad_input_is_named(images, mask, match, tmp_path):
    with pytest.raises(InputError, match=match):
        run_sfm(images, mask, tmp_path)
