"""Frame-to-model tracking (KinectFusion's way) against the pipeline's frame-to-frame poses.

For each simulated procedure, over the first N frames: the shipped depth model's depth, K and
relative poses (gaps 1 and 2), refined by RGB-D odometry and smoothed by the pose graph, as
`c2d2 run` makes them; then Open3D's `t.pipelines.slam.Model`: each frame is tracked against
a ray-cast of the TSDF fused so far, seen from where the refined step puts the frame (point
to plane by default, Open3D's choice; `--method hybrid` adds the ray-cast colour), and then
fused. With `--truth` the tracker gets the simulator's depth and K instead (the pipeline's
poses still come from the network; the steps that start the tracker are put in cm by the
ratio of the median depths): whether the tracker itself works. ATE and RPE (after Sim(3)
alignment, cm and degrees) against the true poses, and their means. The tracker's voxel,
truncation and outlier bound are fractions of the median depth, since the network's depth
has no unit.

    .venv/bin/python benchmarks/frame_to_model.py \\
        --data data/cov-pink/proc_0012 data/cov-dusk/proc_0013 [--truth]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import open3d as o3d
import torch

from fusion.odometry import OdometryConfig, median_depth, refine_relative_poses
from fusion.posegraph import PoseGraphConfig, smooth_trajectory
from learned.checkpoints import SHIPPED_DEPTH
from learned.frames import open_sequence
from learned.infer import infer_sequence
from learned.metrics import trajectory_errors
from learned.model import load_depth_model

SIZE = (128, 160)
METHODS = {"point-to-plane": o3d.t.pipelines.odometry.Method.PointToPlane,
           "hybrid": o3d.t.pipelines.odometry.Method.Hybrid}


def track(frames: list[np.ndarray], depth: list[np.ndarray], K: np.ndarray, steps: np.ndarray,
          method: str, voxel: float, truncation: float, blocks: int, unit: float
          ) -> tuple[np.ndarray, int]:
    """Camera-to-world poses tracked frame to model (RGB frames, depth 0 outside the image
    region, distances in `unit`s), each started from the previous pose moved by `steps[t]`
    (camera t points into camera t+1), and how many frames failed to track (they keep the
    start)."""
    device = o3d.core.Device("CPU:0")
    model = o3d.t.pipelines.slam.Model(voxel * unit, 16, blocks, o3d.core.Tensor(np.eye(4)),
                                       device)
    height, width = depth[0].shape
    intrinsics = o3d.core.Tensor(np.asarray(K, np.float64))
    frame = o3d.t.pipelines.slam.Frame(height, width, intrinsics, device)
    cast = o3d.t.pipelines.slam.Frame(height, width, intrinsics, device)
    far = 3 * unit
    poses, failed = [np.eye(4)], 0
    for t in range(len(depth)):
        frame.set_data_from_image("depth", o3d.t.geometry.Image(depth[t][..., None]))
        frame.set_data_from_image("color", o3d.t.geometry.Image(
            np.ascontiguousarray(frames[t], np.float32) / 255))
        if t > 0:
            start = poses[-1] @ np.linalg.inv(steps[t - 1])
            model.update_frame_pose(t, o3d.core.Tensor(start))
            model.synthesize_model_frame(cast, 1.0, 0.01 * unit, far, truncation,
                                         method == "hybrid")
            try:
                result = model.track_frame_to_model(frame, cast, 1.0, far,
                                                    OdometryConfig().depth_outlier * unit,
                                                    METHODS[method])
                poses.append(start @ result.transformation.numpy())
            except RuntimeError:
                failed += 1
                poses.append(start)
        model.update_frame_pose(t, o3d.core.Tensor(poses[-1]))
        model.integrate(frame, 1.0, far, truncation)
    return np.stack(poses), failed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True,
                        help="simulated procedure folders")
    parser.add_argument("--frames", type=int, default=300, help="first N frames of each")
    parser.add_argument("--method", choices=sorted(METHODS), default="point-to-plane",
                        help="the tracker's residual")
    parser.add_argument("--voxel", type=float, default=0.03,
                        help="TSDF voxel, a fraction of the median depth")
    parser.add_argument("--truncation", type=float, default=4.0, help="in voxels")
    parser.add_argument("--blocks", type=int, default=40000,
                        help="TSDF blocks of 16^3 voxels to reserve (too few crash Open3D)")
    parser.add_argument("--truth", action="store_true",
                        help="track with the simulator's depth and K (the control)")
    parser.add_argument("--checkpoint", type=Path, default=SHIPPED_DEPTH)
    args = parser.parse_args()
    torch.set_num_threads(1)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    o3d.utility.set_max_threads(1)  # Open3D's parallel sums differ from run to run
    model = load_depth_model(args.checkpoint)
    print("| procedure | poses | ATE (cm) | RPE (cm) | RPE (deg) |")
    print("| --- | --- | --- | --- | --- |")
    table: dict[str, list[dict[str, float]]] = {}
    for path in args.data:
        seq = open_sequence(path, SIZE)
        count = min(args.frames, seq.num_frames)
        inferred = infer_sequence(model, seq, (1, 2), frames=range(count))
        K = np.median(inferred.K_pairs, axis=0)
        frames = [seq.frame(i) for i in range(count)]
        refined = refine_relative_poses(inferred.relative, inferred.depth, frames, K,
                                        seq.region, name=path.name)
        rows = {"pipeline (odometry, pose graph)":
                smooth_trajectory(refined.relative, PoseGraphConfig()).poses}
        steps = refined.relative[1]
        unit = median_depth(inferred.depth, seq.region, path.name)
        if args.truth:
            depth = [np.asarray(seq.depth(i), np.float32) for i in range(count)]
            steps = steps.copy()
            true_unit = median_depth(depth, seq.region, path.name)
            steps[:, :3, 3] *= true_unit / unit
            unit = true_unit
            K = seq.camera.K
        else:
            depth = [np.asarray(d, np.float32) for d in inferred.depth]
        if seq.region is not None:
            depth = [np.where(seq.region, d, np.float32(0)) for d in depth]
        poses, failed = track(frames, depth, K, steps, args.method, args.voxel, args.truncation,
                              args.blocks, unit)
        tracker = f"frame to model, {args.method}" + (", true depth and K" if args.truth else "")
        rows[tracker] = poses
        for name, poses in rows.items():
            errors = trajectory_errors(poses, seq.poses[:count])
            table.setdefault(name, []).append(errors)
            untracked = f" ({failed} frames untracked)" if name == tracker and failed else ""
            print(f"| {path.parent.name}/{path.name} | {name}{untracked} | {_cells(errors)}")
    for name, errors in table.items():
        mean = {k: float(np.mean([e[k] for e in errors])) for k in errors[0]}
        print(f"| **mean** | {name} | {_cells(mean)}")


def _cells(errors: dict[str, float]) -> str:
    keys = ("ate", "rpe_translation", "rpe_rotation_deg")
    return " | ".join(f"{errors[k]:.3f}" for k in keys) + " |"


if __name__ == "__main__":
    main()
