"""Where the time of one ColonRenderer.render call goes, stage by stage.

cProfile cannot split the inline NumPy work of ColonRenderer.render, so this script repeats
its steps (as in hybrid/sim/render.py at commit 70f398b; update it if render changes) with a
timer around each stage, on the poses of one simulated procedure, and checks that the repeated
steps give the renderer's own depth.

Run from the repository root:

    .venv/bin/python benchmarks/profile_render.py --preset fast --frames 300
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

import cv2
import numpy as np
import open3d as o3d

from hybrid.sim.appearance import get_style, make_texture
from hybrid.sim.colon import make_colon
from hybrid.sim.render import _REFERENCE_DISTANCE_CM, ColonRenderer
from hybrid.sim.simulate import SimConfig, draw_camera, with_overrides
from hybrid.sim.trajectory import make_withdrawal


class Stages:
    """Accumulates the time since the previous mark under each stage name."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.last = time.perf_counter()

    def mark(self, name: str) -> None:
        now = time.perf_counter()
        self.seconds[name] += now - self.last
        self.last = now


def render_in_stages(r: ColonRenderer, pose: np.ndarray, rng: np.random.Generator,
                     t: Stages) -> np.ndarray:
    """The steps of ColonRenderer.render, timed; returns the depth."""
    t.mark("(outside)")
    R, p = pose[:3, :3], pose[:3, 3]
    dirs = r._rays_cam @ R.T.astype(np.float32)
    rays = np.concatenate([np.broadcast_to(p.astype(np.float32), dirs.shape), dirs], axis=-1)
    t.mark("build rays")
    hit = r.scene.cast_rays(o3d.core.Tensor(rays))
    t.mark("cast_rays")
    depth = hit["t_hit"].numpy()
    valid = np.isfinite(depth)
    tri = np.where(valid, hit["primitive_ids"].numpy(), 0).astype(np.int64)
    bary = hit["primitive_uvs"].numpy()
    weights = np.stack([1 - bary[..., 0] - bary[..., 1], bary[..., 0], bary[..., 1]], axis=-1)
    t.mark("hit arrays, weights")
    corners = r._corners[tri]
    t.mark("gather corner attributes")
    attributes = np.einsum("hwk,hwkc->hwc", weights, corners)
    t.mark("einsum interpolation")
    normal = attributes[..., 2:]
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True).clip(1e-12)
    t.mark("normalise normals")
    albedo = cv2.remap(r.texture, attributes[..., 1], attributes[..., 0], cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_WRAP)
    t.mark("texture remap")
    ray_len = np.linalg.norm(dirs, axis=-1)
    distance = np.where(valid, depth, 1.0) * ray_len
    facing = np.abs((normal * dirs).sum(axis=-1)) / ray_len
    falloff = (_REFERENCE_DISTANCE_CM / distance) ** 2
    s = r.style
    diffuse = albedo * (s.ambient + s.light_gain * (facing * falloff)[..., None])
    highlight = (s.specular * facing**s.shininess * falloff)[..., None]
    linear = (diffuse + highlight) * r._vignette * valid[..., None]
    t.mark("shading")
    sigma = s.blur_sigma_px * r.camera.width / 160.0
    if sigma > 0:
        linear = cv2.GaussianBlur(linear, (0, 0), sigma)
    t.mark("blur")
    image = np.clip(linear, 0.0, 1.0) ** (1.0 / s.gamma)
    t.mark("gamma")
    image += s.noise_std * rng.standard_normal(image.shape, dtype=np.float32)
    t.mark("sensor noise")
    (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    depth = np.where(valid, depth, 0.0).astype(np.float32)
    t.mark("quantise")
    return depth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="fast", choices=["fast", "paper"])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    config = with_overrides(SimConfig(preset=args.preset), max_frames=args.frames)
    rng = np.random.default_rng([args.seed, 0])
    colon = make_colon(config.colon, rng)
    camera = draw_camera(config, rng)
    poses = make_withdrawal(colon, config.trajectory, rng)
    style = get_style(config.style)
    circumference = 2 * np.pi * float(np.mean(config.colon.radius_range_cm))
    texture = make_texture(config.colon.length_cm, circumference, style, rng)
    renderer = ColonRenderer(colon, texture, style, camera, circumference)
    renderer.render(poses[0], rng)  # builds the BVH
    stages = Stages()
    depths = [render_in_stages(renderer, pose, rng, stages) for pose in poses]
    stages.seconds.pop("(outside)", None)
    same = all(np.array_equal(depth, renderer.render(pose, rng)[1])
               for depth, pose in zip(depths, poses, strict=True))
    total = sum(stages.seconds.values())
    print(f"{args.preset} ({camera.height}x{camera.width}), {len(poses)} frames: "
          f"{1e3 * total / len(poses):.2f} ms per render (depth as the renderer's: {same})")
    for name, seconds in stages.seconds.items():
        print(f"  {name:28s} {1e3 * seconds / len(poses):6.2f} ms  {100 * seconds / total:5.1f} %")


if __name__ == "__main__":
    main()
