"""How much of the rotation between frames the network finds, and how much the RGB-D odometry.

For each simulated procedure, over its first N frames: the shipped depth model's relative
poses for one frame gap, then the same refined by fusion.odometry (given iterations per
pyramid level; --half: at half resolution); against the true relative rotations, the per-axis
slopes (x, y, z of the rotation vector, least squares through 0), the mean rotation error, the
median angle between the estimated and the true translation directions, with --true-inputs the
median ratio of the odometry's translation lengths to the true ones, and the odometry's
milliseconds per pair (on one thread unless --threads; the refined poses do not depend on
it). --true-inputs: the odometry reads the simulator's depth
and K instead of the network's (the network's translations put in cm by the median depth
ratio); --true-start: it starts from the true relative poses, so that what moves them is the
odometry's objective alone; --light-power, --depth-max, --method and --median:
refine_relative_poses' diagnostic arguments.

    python benchmarks/odometry_rotation.py --data data/cov-pink/proc_0012 --iterations 10 5 3
    python benchmarks/odometry_rotation.py --data data/heldout --true-inputs --true-start \
        --method point-to-plane
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from depth_diagnosis import axis_slopes
from geometric_eval import depth_ratio, scaled_translations, true_relative
from scipy.spatial.transform import Rotation

from fusion.odometry import OdometryConfig, median_depth, refine_relative_poses
from hybrid.dataset import Procedure
from learned.checkpoints import SHIPPED_DEPTH
from learned.frames import open_sequence
from learned.infer import infer_sequence
from learned.model import load_depth_model
from learned.train import expand_inputs


def figures(estimated: np.ndarray, truth: np.ndarray, lengths: bool = False) -> str:
    """Axis slopes, mean rotation error, median translation direction error and, where the
    translations are in the truth's unit (`lengths`), their median length ratio."""
    a = Rotation.from_matrix(estimated[:, :3, :3]).as_rotvec()
    b = Rotation.from_matrix(truth[:, :3, :3]).as_rotvec()
    slopes = axis_slopes(a, b)
    wrong = Rotation.from_matrix(np.linalg.inv(estimated[:, :3, :3]) @ truth[:, :3, :3])
    error = np.degrees(np.linalg.norm(wrong.as_rotvec(), axis=1)).mean()
    u, v = (T[:, :3, 3] / np.linalg.norm(T[:, :3, 3], axis=1, keepdims=True)
            for T in (estimated, truth))
    direction = np.degrees(np.arccos(np.clip((u * v).sum(1), -1, 1)))
    ratio = np.linalg.norm(estimated[:, :3, 3], axis=1) / np.linalg.norm(truth[:, :3, 3], axis=1)
    return (f"slopes {' / '.join(f'{v:.2f}' for v in slopes)}  rotation error {error:.3f}°  "
            f"translation direction error {np.median(direction):.1f}°"
            + (f", length ratio {np.median(ratio):.2f}" if lengths else ""))


def halved(frames: list[np.ndarray], depth: np.ndarray, K: np.ndarray, region: np.ndarray
           ) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray, np.ndarray]:
    """Frames (area), depth and region (nearest) and K at half the size, pixel centres kept."""
    h, w = depth.shape[1:]
    small = [cv2.resize(f, (w // 2, h // 2), interpolation=cv2.INTER_AREA) for f in frames]
    depth = [cv2.resize(d, (w // 2, h // 2), interpolation=cv2.INTER_NEAREST) for d in depth]
    region = cv2.resize(region.astype(np.uint8), (w // 2, h // 2),
                        interpolation=cv2.INTER_NEAREST).astype(bool)
    K = K.copy()
    K[:2, :2] /= 2
    K[:2, 2] = (K[:2, 2] + 0.5) / 2 - 0.5
    return small, depth, K, region


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
    parser.add_argument("--true-inputs", action="store_true",
                        help="the odometry reads the simulator's depth and K")
    parser.add_argument("--true-start", action="store_true",
                        help="start from the true relative poses (needs --true-inputs)")
    parser.add_argument("--light-power", type=float, default=0.0,
                        help="refine_relative_poses' light_power")
    parser.add_argument("--depth-max", type=float, default=float("inf"),
                        help="refine_relative_poses' depth_max, in median depths")
    parser.add_argument("--method", default="hybrid",
                        choices=("hybrid", "point-to-plane", "intensity"),
                        help="refine_relative_poses' method")
    parser.add_argument("--median", type=float, default=None,
                        help="refine_relative_poses' median (default: the depth's own unit)")
    args = parser.parse_args()
    if args.true_start and not args.true_inputs:
        parser.error("--true-start puts true translations (cm) beside the depth: "
                     "add --true-inputs")
    torch.set_num_threads(1)
    model = load_depth_model(SHIPPED_DEPTH)
    config = OdometryConfig(iterations=tuple(args.iterations))
    for path in expand_inputs(args.data):
        seq = open_sequence(path, (model.config.height, model.config.width))
        count = min(args.frames, seq.num_frames)
        inferred = infer_sequence(model, seq, (args.gap,), frames=range(count))
        truth = true_relative(seq.poses[:count], (args.gap,))[args.gap]
        frames = [seq.frame(i) for i in range(count)]
        depth, K = inferred.depth, np.median(inferred.K_pairs, axis=0)
        network_median = median_depth(depth, seq.region, path.name)
        start = inferred.relative[args.gap]
        if args.true_inputs:
            proc = Procedure.open(path)
            true_depth = np.stack([proc.depth(i) for i in range(count)])
            start = truth if args.true_start else scaled_translations(
                start, depth_ratio(depth, true_depth))  # the network's translations in cm
            depth, K = true_depth, proc.camera.K
        region = seq.region
        if args.half:
            frames, depth, K, region = halved(frames, depth, K, region)
        tic = time.perf_counter()
        refined = refine_relative_poses({args.gap: start}, depth, frames, K, region,
                                        config=config, name=path.name, threads=args.threads,
                                        depth_max=args.depth_max, light_power=args.light_power,
                                        method=args.method, median=args.median)
        ms = (time.perf_counter() - tic) / len(truth) * 1000
        print(f"{path}: gap {args.gap}, {count} frames, network depth median "
              f"{network_median:.3f}\n"
              f"  network   {figures(inferred.relative[args.gap], truth)}\n"
              f"  odometry  {figures(refined.relative[args.gap], truth, args.true_inputs)}  "
              f"{ms:.2f} ms/pair on {args.threads} thread(s) (iterations {args.iterations}"
              f"{', half resolution' if args.half else ''}"
              f"{', true depth and K' if args.true_inputs else ''}"
              f"{', true start' if args.true_start else ''}, {args.method}"
              f"{'' if args.median is None else f', median depth {args.median}'})", flush=True)


if __name__ == "__main__":
    main()
