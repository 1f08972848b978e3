"""Render RGB and z-depth of a colon with Open3D's RaycastingScene.

A point light sits at the camera (inverse-square falloff); diffuse and specular shading,
vignetting, optical blur and sensor noise follow the style.
"""

from __future__ import annotations

import cv2
import numpy as np
import open3d as o3d

from hybrid.sim.appearance import TEXELS_PER_CM, Style
from hybrid.sim.colon import Colon
from hybrid.types import Camera

_REFERENCE_DISTANCE_CM = 2.0
"""Distance at which the diffuse irradiance equals the style's light gain."""


def vignette(height: int, width: int, strength: float) -> np.ndarray:
    """(H, W) float32 factor on linear intensity: 1 at the centre, 1 - strength at the corners,
    falling with the squared distance from the centre."""
    w, u = np.mgrid[0:height, 0:width].astype(np.float64)
    radius2 = ((u - (width - 1) / 2) ** 2 + (w - (height - 1) / 2) ** 2) / (
        ((width - 1) / 2) ** 2 + ((height - 1) / 2) ** 2)
    return (1.0 - strength * radius2).astype(np.float32)


class ColonRenderer:
    """Renders one colon, with its texture and style, for one camera."""

    def __init__(self, colon: Colon, texture: np.ndarray, style: Style, camera: Camera,
                 circumference_cm: float):
        self.camera = camera
        self.style = style
        self.texture = texture
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(colon.vertices.astype(np.float32)),
                                 o3d.core.Tensor(colon.triangles.astype(np.uint32)))
        tris = colon.triangles
        normals = _vertex_normals(colon.vertices, tris)[tris]
        uv = colon.surface_uv[tris]  # (T, 3, 2); unwrap triangles that cross the θ seam
        v = uv[..., 1]
        crosses = (v.max(axis=1) - v.min(axis=1)) > circumference_cm / 2
        v[crosses] = np.where(v[crosses] < circumference_cm / 2, v[crosses] + circumference_cm,
                              v[crosses])
        # Per-triangle corner attributes: texel row, texel column, normal (T, 3, 5).
        self._corners = np.concatenate([uv * TEXELS_PER_CM, normals], axis=-1).astype(np.float32)
        self._rays_cam = camera.pixel_rays().astype(np.float32)
        self._ray_len = np.linalg.norm(self._rays_cam, axis=-1)  # the same in any orientation
        self._vignette = vignette(camera.height, camera.width, style.vignetting)[..., None]

    def render(self, pose: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """RGB uint8 (H, W, 3) and z-depth float32 (H, W), 0 where no wall was hit."""
        R, p = pose[:3, :3], pose[:3, 3]
        dirs = self._rays_cam @ R.T.astype(np.float32)  # camera z = 1: t_hit is the z-depth
        rays = np.concatenate([np.broadcast_to(p.astype(np.float32), dirs.shape), dirs], axis=-1)
        hit = self.scene.cast_rays(o3d.core.Tensor(rays))
        depth = hit["t_hit"].numpy()
        valid = np.isfinite(depth)
        tri = np.where(valid, hit["primitive_ids"].numpy(), 0).astype(np.int64)
        bary = hit["primitive_uvs"].numpy()
        weights = np.stack([1 - bary[..., 0] - bary[..., 1], bary[..., 0], bary[..., 1]], axis=-1)
        attributes = np.einsum("hwk,hwkc->hwc", weights, self._corners[tri])
        normal = attributes[..., 2:]
        normal /= np.sqrt(np.einsum("hwc,hwc->hw", normal, normal))[..., None].clip(1e-12)

        albedo = cv2.remap(self.texture, attributes[..., 1], attributes[..., 0], cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_WRAP)
        ray_len = self._ray_len
        distance = np.where(valid, depth, 1.0) * ray_len
        facing = np.abs((normal * dirs).sum(axis=-1)) / ray_len
        falloff = (_REFERENCE_DISTANCE_CM / distance) ** 2
        s = self.style
        diffuse = albedo * (s.ambient + s.light_gain * (facing * falloff)[..., None])
        highlight = (s.specular * facing**s.shininess * falloff)[..., None]
        linear = (diffuse + highlight) * self._vignette * valid[..., None]
        sigma = s.blur_sigma_px * self.camera.width / 160.0
        if sigma > 0:
            linear = cv2.GaussianBlur(linear, (0, 0), sigma)
        image = np.clip(linear, 0.0, 1.0) ** (1.0 / s.gamma)
        image += s.noise_std * rng.standard_normal(image.shape, dtype=np.float32)
        rgb = (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        return rgb, np.where(valid, depth, 0.0).astype(np.float32)


def _vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (orientation is irrelevant: shading uses |n·l|)."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    face = np.cross(b - a, c - a)
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, triangles[:, k], face)
    return normals / np.linalg.norm(normals, axis=1, keepdims=True).clip(1e-12)
