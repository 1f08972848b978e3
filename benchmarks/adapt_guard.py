"""Which inputs adapting the depth model would take: the starting model's photometric error.

For each input (simulated procedures, videos, image folders; folders of them as train-depth
takes them), the depth model's photometric error on fixed batches of its triplets
(`learned.adapt.photometric_error`, what `--adapt-steps` reads first) and whether it lies
between `learned.adapt.CLEAR` and `NOISY` (adapted to) or outside (kept as it is), and the
seconds the error took. Then, per folder given, the range of the errors.

    python benchmarks/adapt_guard.py data/train-pink data/train-dusk data/test data/val \
        ../shared/data/real-clip/colonoscopy_192px_6fps.mp4
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from learned.adapt import CLEAR, NOISY, photometric_error, worth_adapting
from learned.checkpoints import SHIPPED_DEPTH
from learned.frames import open_sequence
from learned.model import load_depth_model
from learned.train import expand_inputs, input_name


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("inputs", nargs="+", type=Path)
    parser.add_argument("--checkpoint", type=Path, default=SHIPPED_DEPTH)
    args = parser.parse_args()
    torch.set_num_threads(1)  # light work; leaves the other core to whatever runs beside it
    model = load_depth_model(args.checkpoint)
    size = (model.config.height, model.config.width)
    ranges = {}
    for given in args.inputs:
        errors = []
        for path in expand_inputs([given]):
            seq = open_sequence(path, size)
            started = time.perf_counter()
            error = photometric_error(model, seq)
            errors.append(error)
            print(f"{input_name(path)} {error:.4f} "
                  f"{'adapted to' if worth_adapting(error) else 'kept as it is'} "
                  f"({time.perf_counter() - started:.1f} s)", flush=True)
        ranges[given] = (min(errors), max(errors), len(errors))
    print(f"bounds (learned.adapt.CLEAR, NOISY): {CLEAR}, {NOISY}")
    for given, (low, high, count) in ranges.items():
        print(f"{given}: {count} inputs, {low:.4f}-{high:.4f}")


if __name__ == "__main__":
    main()
