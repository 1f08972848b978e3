"""Depth-network inference speed (frames/s) on this CPU or a GPU, for each preset.

Times DepthNet alone and DepthNet + MotionNet (the pair's motion and intrinsics) in batches,
with freshly initialised weights (speed does not depend on the weights).

    .venv/bin/python benchmarks/bench_depth.py --presets fast paper --batch 16 [--device cuda]
        [--set motion_net=correlation]
"""

from __future__ import annotations

import argparse
import time

import torch

from learned.config import depth_config, parse_overrides
from learned.device import pick_device
from learned.model import DepthModel


def frames_per_second(fn, batch: int, seconds: float, device: torch.device) -> float:
    def synchronised():
        fn()
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    synchronised()  # warm-up
    count, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        synchronised()
        count += batch
    return count / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["fast", "paper"])
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="change each preset's config (e.g. motion_net=correlation)")
    args = parser.parse_args()
    overrides = parse_overrides(args.set)
    device = pick_device(args.device)
    where = torch.cuda.get_device_name(device) if device.type == "cuda" else \
        f"{torch.get_num_threads()} threads"
    print(f"torch {torch.__version__}, {where}, batch {args.batch}")
    for preset in args.presets:
        config = depth_config(preset, **overrides)
        model = DepthModel(config).eval().to(device)
        images = torch.rand(args.batch, 3, config.height, config.width, device=device)
        with torch.no_grad():
            depth_fps = frames_per_second(lambda m=model, x=images: m.predict_depth(x), args.batch,
                                          args.seconds, device)
            both_fps = frames_per_second(
                lambda m=model, x=images: (m.predict_depth(x), m.pair_motion(x[:-1], x[1:])),
                args.batch, args.seconds, device)
        print(f"{preset:6s} {config.height}x{config.width}: depth {depth_fps:7.1f} frames/s, "
              f"depth + motion/intrinsics {both_fps:7.1f} frames/s")


if __name__ == "__main__":
    main()
