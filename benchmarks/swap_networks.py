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

from safetensors import safe_open
from safetensors.torch import save_file


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--depth", type=Path, required=True, help="model whose depth net to take")
    parser.add_argument("--motion", type=Path, required=True, help="model whose motion net to take")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    parts, metas = {}, {}
    for name, path in (("depth", args.depth), ("motion", args.motion)):
        with safe_open(str(path), "pt") as f:
            metas[name] = f.metadata()
            names = f.keys()  # a safetensors file is not iterable
            parts.update({k: f.get_tensor(k) for k in names if k.startswith(name + ".")})
    presets = {n: json.loads(m["config"])["preset"] for n, m in metas.items()}
    if len(set(presets.values())) != 1:
        raise SystemExit(f"the models are of different presets: {presets}")
    meta = {**metas["motion"], "depth_network_from": str(args.depth)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_file(parts, str(args.out), metadata=meta)
    print(f"{args.out}: {len(parts)} tensors, depth net of {args.depth}, motion of {args.motion}")


if __name__ == "__main__":
    main()
