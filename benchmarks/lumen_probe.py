"""Which part of one segment's reconstruction turns pose jitter into a coverage change.

Reads one procedure's work folder of a finished `c2d2 eval`, jitters the smoothed poses'
translations (normal noise per axis, in the network's unit; one draw per seed), rebuilds the
segment's window as `c2d2 run` did before its windows were oriented by the whole video's
lumen (hybrid.segment_geometry; each window in time here) three ways, and prints the
segment's geometric coverage (Δ = 1-4 cm) for each: everything refitted; the scale held at the
unjittered window's; the scale and the fitted lumen both held.

    python benchmarks/lumen_probe.py --work data/eval-heldout-shipped/heldout-proc_0015 \
        --segment 0 --pose-nudge 1e-3 --seeds 0 1 2 3
"""
from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from hybrid import workdir as W
from hybrid.coverage import DEFAULT_PAIR_CM, pair_key
from hybrid.geometric_coverage import geometric_coverage
from hybrid.lumen_fit import FittedLumen
from hybrid.npyio import NpyRows
from hybrid.pipeline import RunConfig, read_network_K, read_region, segment_frame_count
from hybrid.reconstruction import ScaledDepth, reconstruct
from hybrid.segment_geometry import _Window


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--work", type=Path, required=True, help="a procedure's work folder")
    parser.add_argument("--segment", type=int, default=0)
    parser.add_argument("--pose-nudge", type=float, default=1e-3)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    args = parser.parse_args()
    config = RunConfig()
    ingested = json.loads((args.work / W.INGEST).read_text())
    depth = NpyRows(args.work / W.DEPTH)
    K = read_network_K(args.work, *np.asarray(depth[0]).shape)
    region = read_region(args.work)
    poses = np.load(args.work / W.POSES)
    frames = segment_frame_count(config, ingested["fps"])
    start, stop = args.segment * frames, (args.segment + 1) * frames
    first, last = max(0, start - frames // 2), min(len(poses), stop + frames // 2)
    geometric = replace(config.geometric, segment_frames=frames)

    def coverage(jittered: np.ndarray, scale: float | None = None,
                 lumen: FittedLumen | None = None) -> tuple[float, float, FittedLumen]:
        local = np.linalg.inv(jittered[first]) @ jittered[first:last]
        rec = reconstruct(_Window(depth, first, last), K, local, region=region,
                          config=config.reconstruction, scale=scale, fps=ingested["fps"])
        result = geometric_coverage(
            rec.lumen if lumen is None else lumen, rec.poses[start - first:stop - first],
            ScaledDepth(_Window(depth, start, stop), rec.scale, region), K, region, geometric)
        return result.segments[0].coverage[pair_key(DEFAULT_PAIR_CM)], rec.scale, rec.lumen

    value, scale, lumen = coverage(poses)
    print(f"unjittered: {value:.3f} (scale {scale:.3f} cm per unit)")
    for seed in args.seeds:
        jittered = poses.copy()
        jittered[:, :3, 3] += args.pose_nudge * np.random.default_rng(seed).standard_normal(
            poses[:, :3, 3].shape)
        print(f"seed {seed}: refitted {coverage(jittered)[0]:.3f}, scale held "
              f"{coverage(jittered, scale)[0]:.3f}, scale and lumen held "
              f"{coverage(jittered, scale, lumen)[0]:.3f}")


if __name__ == "__main__":
    main()
