"""Speed and accuracy of TSDF fusion (fusion.tsdf) with the true depth, K and poses.

The first --frames frames of one simulated procedure are fused at the procedure's own size
(the fast preset, 128x160) and upsampled to the paper preset's 320x384 (depth nearest, RGB
bilinear, K by Camera.resized), at each --voxel-sizes (cm), with colour. Frames are read and
resized outside the timed calls. Reported: integration frames/s (TsdfVolume.integrate only),
extraction seconds, mesh size, and the distance of the fused vertices to the ground-truth
colon.ply (Open3D RaycastingScene.compute_distance): mean, median and 95th percentile in cm.

Run from the repository root:

    .venv/bin/python benchmarks/bench_tsdf.py --procedure data/test/proc_0000 --frames 300
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np
import open3d as o3d

from fusion.tsdf import TsdfConfig, TsdfVolume
from hybrid.dataset import Procedure
from hybrid.types import PRESET_IMAGE_SIZE


def run(frames: list, camera, poses: np.ndarray, config: TsdfConfig, scene) -> dict:
    """Fuse frames resized to camera's size; time integration and extraction; measure error."""
    size = (camera.width, camera.height)
    volume = TsdfVolume(camera.K, config)
    integrate = 0.0
    for (depth, rgb), pose in zip(frames, poses, strict=True):
        if depth.shape[::-1] != size:
            depth = cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST)
            rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_LINEAR)
        start = time.perf_counter()
        volume.integrate(depth, rgb, pose)
        integrate += time.perf_counter() - start
    start = time.perf_counter()
    mesh = volume.extract()
    extract = time.perf_counter() - start
    query = o3d.core.Tensor(mesh.vertices.astype(np.float32))
    distance = scene.compute_distance(query).numpy()
    return {"fps": len(frames) / integrate, "extract_s": extract, "vertices": len(mesh.vertices),
            "mean": distance.mean(), "median": np.median(distance),
            "p95": np.percentile(distance, 95)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--procedure", default="data/test/proc_0000")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--voxel-sizes", type=float, nargs="+", default=[0.1, 0.05])
    parser.add_argument("--depth-max", type=float, default=TsdfConfig.depth_max)
    args = parser.parse_args()
    proc = Procedure.open(args.procedure)
    count = min(args.frames, proc.num_frames)
    frames = [(proc.depth(i), proc.rgb(i)) for i in range(count)]
    poses = proc.poses[:count]
    scene = proc.mesh().raycasting_scene()
    print(f"{args.procedure}: {count} frames, open3d {o3d.__version__}")
    print("| size | voxel (cm) | integrate (frames/s) | extract (s) | vertices "
          "| mean dist (cm) | median (cm) | p95 (cm) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for preset in ("fast", "paper"):
        height, width = PRESET_IMAGE_SIZE[preset]
        camera = proc.camera.resized(width, height)
        for voxel in args.voxel_sizes:
            config = TsdfConfig(voxel_size=voxel, depth_max=args.depth_max)
            r = run(frames, camera, poses, config, scene)
            print(f"| {height}x{width} | {voxel} | {r['fps']:.0f} | {r['extract_s']:.2f} "
                  f"| {r['vertices']} | {r['mean']:.4f} | {r['median']:.4f} | {r['p95']:.4f} |",
                  flush=True)


if __name__ == "__main__":
    main()
