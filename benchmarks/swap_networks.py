"""A depth checkpoint with the depth network of one model and the motion network (ego-motion
and intrinsics head) of another, both of the same preset: to tell what the coverage networks
gain or lose from each (their inputs are unit-free: median-normalised depth and the direction
and relative speed of travel, so the two networks need not share a unit). The metadata is
the motion model's, with the depth model's path recorded.

    .venv/bin/python benchmarks/swap_networks.py --depth data/runs/maps-scratch/model.safetensors \
        --motion learned/checkpoints/depth-fast.safetensors \
        --out data/runs/swap-mapsdepth/model.safetensors
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from safetensors.torch import save_file

from learned.checkpoint import read_checkpoint


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--depth", type=Path, required=True, help="model whose depth net to take")
    parser.add_argument("--motion", type=Path, required=True, help="model whose motion net to take")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    (depth, depth_meta), (motion, meta) = read_checkpoint(args.depth), read_checkpoint(args.motion)
    if depth_meta["config"]["preset"] != meta["config"]["preset"]:
        raise SystemExit(f"the models are of different presets: {depth_meta['config']['preset']}"
                         f" and {meta['config']['preset']}")
    parts = {**{k: v for k, v in depth.items() if k.startswith("depth.")},
             **{k: v for k, v in motion.items() if k.startswith("motion.")}}
    meta = {**meta, "config": json.dumps(meta["config"]), "step": str(meta["step"]),
            "depth_network_from": str(args.depth)}
    meta.pop("optimizer_groups", None)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_file(parts, str(args.out), metadata=meta)
    print(f"{args.out}: {len(parts)} tensors, depth net of {args.depth}, motion of {args.motion}")


if __name__ == "__main__":
    main()
