"""How much of the rotation between frames the network finds, and how much the RGB-D odometry.

For each simulated procedure, over its first N frames: the shipped depth model's relative
poses for one frame gap, then the same refined by fusion.odometry (given iterations per
pyramid level; --half: at half resolution); against the true relative rotations, the per-axis
slopes (x, y, z of the rotation vector, least squares through 0), the mean rotation error and
the median angle between the estimated and the true translation directions, and the odometry's
milliseconds per pair (on one thread unless --threads; the refined poses do not depend on it).

    python benchmarks/odometry_rotation.py --data data/cov-pink/proc_0012 --iterations 10 5 3
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from depth_diagnosis import axis_slopes
from scipy.spatial.transform import Rotation

from fusion.odometry import OdometryConfig, refine_relative_poses
from learned.checkpoints import SHIPPED_DEPTH
from learned.frames import open_sequence
from learned.infer import infer_sequence
from learned.model import load_depth_model
from learned.train import expand_inputs


def figures(estimated: np.ndarray, truth: np.ndarray) -> str:
    a = Rotation.from_matrix(estimated[:, :3, :3]).as_rotvec()
    b = Rotation.from_matrix(truth[:, :3, :3]).as_rotvec()
    slopes = axis_slopes(a, b)
    wrong = Rotation.from_matrix(np.linalg.inv(estimated[:, :3, :3]) @ truth[:, :3, :3])
    error = np.degrees(np.linalg.norm(wrong.as_rotvec(), axis=1)).mean()
    u, v = (T[:, :3, 3] / np.linalg.norm(T[:, :3, 3], axis=1, keepdims=True)
            for T in (estimated, truth))
    direction = np.degrees(np.arccos(np.clip((u * v).sum(1), -1, 1)))
    return (f"slopes {' / '.join(f'{v:.2f}' for v in slopes)}  rotation error {error:.3f}°  "
            f"translation direction error {np.median(direction):.1f}°")


def halved(frames: list[np.ndarray], depth: np.ndarray, K: np.ndarray
           ) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Frames (area), depth (nearest) and K at half the size, pixel centres kept."""
    h, w = depth.shape[1:]
    small = [cv2.resize(f, (w // 2, h // 2), interpolation=cv2.INTER_AREA) for f in frames]
    depth = [cv2.resize(d, (w // 2, h // 2), interpolation=cv2.INTER_NEAREST) for d in depth]
    K = K.copy()
    K[:2, :2] /= 2
    K[:2, 2] = (K[:2, 2] + 0.5) / 2 - 0.5
    return small, depth, K


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", nargs="+", type=Path, required=True,
                        help="simulated procedures (or folders of them)")
    parser.add_argument("--frames", type=int, default=600, help="first N frames of each")
    parser.add_argument("--gap", type=int, default=1)
    parser.add_argument("--iterations", type=int, nargs="+",
                        default=list(OdometryConfig().iterations),
                        help="per pyramid level, coarsest first")
    parser.add_argument("--half", action="store_true", help="odometry at half resolution")
    parser.add_argument("--threads", type=int, default=1,
                        help="pairs aligned at once (ms/pair is then per this many cores)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    model = load_depth_model(SHIPPED_DEPTH)
    config = OdometryConfig(iterations=tuple(args.iterations))
    for path in expand_inputs(args.data):
        seq = open_sequence(path, (model.config.height, model.config.width))
        count = min(args.frames, seq.num_frames)
        inferred = infer_sequence(model, seq, (args.gap,), frames=range(count))
        poses = seq.poses[:count]
        truth = np.linalg.inv(poses[args.gap:]) @ poses[:-args.gap]
        frames = [seq.frame(i) for i in range(count)]
        depth, K = inferred.depth, np.median(inferred.K_pairs, axis=0)
        if args.half:
            frames, depth, K = halved(frames, depth, K)
        tic = time.perf_counter()
        refined = refine_relative_poses({args.gap: inferred.relative[args.gap]}, depth, frames,
                                        K, config=config, name=path.name,
                                        threads=args.threads)
        ms = (time.perf_counter() - tic) / len(truth) * 1000
        print(f"{path}: gap {args.gap}, {count} frames\n"
              f"  network   {figures(inferred.relative[args.gap], truth)}\n"
              f"  odometry  {figures(refined.relative[args.gap], truth)}  "
              f"{ms:.2f} ms/pair on {args.threads} thread(s) (iterations {args.iterations}"
              f"{', half resolution' if args.half else ''})", flush=True)


if __name__ == "__main__":
    main()
