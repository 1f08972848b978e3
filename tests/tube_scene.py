"""An analytically rendered, textured tube seen through an endoscope-like disc mask.

The camera moves forward along the axis of a cylinder of radius 2 cm with a little sideways
wobble and yaw; the wall carries a blurred random texture in (angle, z). Rendered through a
pinhole, or an equidistant fisheye of the same focal length. Used by the structure from
motion tests.
"""

from __future__ import annotations

import cv2
import numpy as np

from hybrid.types import Camera

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


def _rays(pose: np.ndarray, lens: str = "pinhole") -> np.ndarray:
    """World directions of the pixels' rays through `lens` ('pinhole' or 'equidistant', of
    focal length FOCAL at the image centre), scaled to unit depth along the camera's axis."""
    camera = Camera(WIDTH, HEIGHT, FOCAL, FOCAL, K[0, 2], K[1, 2], model=lens)
    return camera.pixel_rays() @ pose[:3, :3].T


def depth(pose: np.ndarray, lens: str = "pinhole") -> np.ndarray:
    """(HEIGHT, WIDTH) depth along the camera's axis of the wall, by ray-cylinder intersection."""
    d, p = _rays(pose, lens), pose[:3, 3]
    a = d[..., 0] ** 2 + d[..., 1] ** 2
    b = 2 * (p[0] * d[..., 0] + p[1] * d[..., 1])
    c = p[0] ** 2 + p[1] ** 2 - RADIUS**2
    return (-b + np.sqrt(b * b - 4 * a * c)) / (2 * np.maximum(a, 1e-12))


def render(pose: np.ndarray, texture: np.ndarray, lens: str = "pinhole") -> np.ndarray:
    """RGB of the textured wall through `lens`, darker with distance, masked."""
    z = depth(pose, lens)
    hit = pose[:3, 3] + z[..., None] * _rays(pose, lens)
    size = len(texture)
    col = (np.arctan2(hit[..., 1], hit[..., 0]) + np.pi) / (2 * np.pi) * size
    row = hit[..., 2] / 12.0 * size
    grey = cv2.remap(texture, col.astype(np.float32), row.astype(np.float32), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_WRAP) / (1 + 0.05 * z**2) * MASK
    return np.repeat(grey[..., None], 3, axis=-1).clip(0, 255).astype(np.uint8)
