"""What in the simulator's images biases the colour term of RGB-D odometry?

The renderer samples the wall's texture (40 texels a cm, detail down to 1-2 texels) once per
pixel, and a pixel spans 0.05-0.2 cm of wall at 2-8 cm. This re-renders the first N frames of
a simulated procedure from its own scene with S x S supersampling (S times the width and
height, blur in the same angle, no noise; averaged back over each S x S block of the
displayed (gamma-encoded, 8-bit) image, then the style's noise added once; S = 1: no
supersampling) and the style's fields changed by --set
(e.g. vignetting=0, specular=0), and prints, for the procedure's own frames and the
re-rendered ones: their mean absolute difference (grey levels) and the relative poses (gap
1) that the odometry (`--method`) finds on the true depth and K from the true start, scored
as benchmarks/odometry_rotation.py scores them.

    python benchmarks/colour_bias.py --procedure data/heldout/proc_0001 --frames 150
    python benchmarks/colour_bias.py --procedure data/heldout/proc_0001 --factor 1 \
        --set vignetting=0
    python benchmarks/colour_bias.py --procedure data/heldout/proc_0001 --factor 1 \
        --set light_gain=0 --set ambient=1 --set specular=0 --set vignetting=0 \
        --set noise_std=0 --set blur_sigma_px=0          # flat light: the albedo alone
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict, replace
from pathlib import Path

import cv2
import numpy as np
from geometric_eval import true_relative
from odometry_rotation import figures

from fusion.odometry import refine_relative_poses
from hybrid.dataset import Procedure
from hybrid.sim.render import ColonRenderer
from hybrid.sim.simulate import Scene, SimConfig, draw_scene, with_overrides
from hybrid.types import Camera


def scene_of(proc: Procedure) -> tuple[Scene, SimConfig]:
    """The procedure's scene, drawn again from its seed, index and settings (those of
    `c2d2 simulate --style --length-cm --max-frames`, the others at their defaults)."""
    meta = json.loads((proc.path / "meta.json").read_text())
    saved = meta["config"]
    config = with_overrides(SimConfig(preset=saved["preset"], style=saved["style"]),
                            saved["colon"]["length_cm"], saved["trajectory"]["max_frames"])
    if json.loads(json.dumps(asdict(config))) != saved:
        raise SystemExit(f"{proc.path}: simulated with settings this script does not rebuild")
    return draw_scene(config, meta["seed"], meta["index"]), config


def rendered(scene: Scene, config: SimConfig, factor: int, frames: int, changes: dict,
             rng: np.random.Generator) -> list[np.ndarray]:
    """The first frames rendered at factor x the size with the style's fields `changes`,
    averaged back, noise added once."""
    cam = scene.camera
    big = Camera(cam.width * factor, cam.height * factor, cam.fx * factor, cam.fy * factor,
                 (cam.cx + 0.5) * factor - 0.5, (cam.cy + 0.5) * factor - 0.5, cam.fps)
    style = replace(scene.renderer.style, **changes)
    noise = style.noise_std
    style = replace(style, noise_std=0.0)
    circumference = 2 * np.pi * float(np.mean(config.colon.radius_range_cm))  # as draw_scene
    renderer = ColonRenderer(scene.colon, scene.renderer.texture, style, big, circumference)
    out = []
    for i in range(frames):
        rgb, _ = renderer.render(scene.poses[i], rng)
        small = cv2.resize(rgb.astype(np.float32) / 255.0, (cam.width, cam.height),
                           interpolation=cv2.INTER_AREA)
        small += noise * rng.standard_normal(small.shape, dtype=np.float32)
        out.append((np.clip(small, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--procedure", type=Path, required=True)
    parser.add_argument("--frames", type=int, default=150, help="first N frames")
    parser.add_argument("--factor", type=int, default=4, help="supersampling per axis")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="a numeric style field for the re-render "
                             "(hybrid.sim.appearance.Style)")
    parser.add_argument("--method", default="intensity", choices=("hybrid", "intensity"),
                        help="an odometry that reads colour")
    parser.add_argument("--median", type=float, default=0.3,
                        help="refine_relative_poses' median (the depth's unit while aligned)")
    args = parser.parse_args()
    proc = Procedure.open(args.procedure)
    scene, config = scene_of(proc)
    count = min(args.frames, proc.num_frames)
    own = [proc.rgb(i) for i in range(count)]
    changes = {k: float(v) for k, v in (item.split("=", 1) for item in args.set)}
    again = rendered(scene, config, args.factor, count, changes, np.random.default_rng(0))
    depth = [proc.depth(i) for i in range(count)]
    truth = true_relative(proc.poses[:count], (1,))[1]
    difference = np.mean([np.abs(a.astype(float) - b).mean() for a, b in zip(own, again,
                                                                           strict=True)])
    print(f"{proc.path}: {count} frames, re-rendered at {args.factor}x{args.factor} "
          f"supersampling with {changes or 'the style as it was'}; mean absolute difference "
          f"{difference:.2f} grey levels")
    for name, frames in (("own frames", own), ("re-rendered", again)):
        refined = refine_relative_poses({1: truth}, depth, frames, proc.camera.K,
                                        name=name, method=args.method, median=args.median)
        print(f"  {name:13s} {args.method}: {figures(refined.relative[1], truth, True)}",
              flush=True)


if __name__ == "__main__":
    main()
