"""How the intrinsics head's focal length follows a zoom of its input.

For sampled pairs of each procedure (frames `pair_gap_s` apart), the head reads K from a
centred crop of the pair enlarged by s and from the whole pair at the crop's detail
(learned.zoom). A head that reads the image's scale gives fx(s) = s·fx(1): a response
log(fx(s) / fx(1)) / log(s) of 1. A head that gives one focal length whatever it sees
gives 0. Printed per zoom, with the mean over procedures.

    .venv/bin/python benchmarks/zoom_response.py \\
        --model learned/checkpoints/depth-fast.safetensors --data data/heldout
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from learned.frames import open_sequence
from learned.model import load_depth_model, to_tensor
from learned.train import expand_inputs
from learned.zoom import centred_box, views_of


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, required=True, help="depth model (.safetensors)")
    parser.add_argument("--data", type=Path, nargs="+", required=True,
                        help="procedures or folders of them")
    parser.add_argument("--zooms", type=float, nargs="+", default=[1.25, 1.5])
    parser.add_argument("--pairs", type=int, default=16, help="pairs sampled per procedure")
    args = parser.parse_args()
    model = load_depth_model(args.model)
    size = (model.config.height, model.config.width)
    responses = {s: [] for s in args.zooms}
    for path in expand_inputs(args.data):
        seq = open_sequence(path, size)
        gap = max(1, round(seq.fps * model.config.pair_gap_s))
        picks = np.linspace(gap, seq.num_frames - 1, args.pairs).round().astype(int)
        a = to_tensor(np.stack([seq.network_frame(t - gap) for t in picks]))
        b = to_tensor(np.stack([seq.network_frame(t) for t in picks]))
        pairs = torch.stack([a, b], 1)
        for s in args.zooms:
            box = centred_box(size, s)
            with torch.no_grad():
                K_zoomed, K_whole = model.zoom_intrinsics(views_of(pairs, [box] * len(picks)))
            realised = size[1] / box[2]  # the box is whole pixels: W / w, not s exactly
            ratio = (K_zoomed[:, 0, 0] / K_whole[:, 0, 0]).log().mean()
            responses[s].append(float(ratio) / np.log(realised))
    for s, values in responses.items():
        print(f"zoom {s:.2f}: response {np.mean(values):.2f} (procedures {min(values):.2f} to "
              f"{max(values):.2f}, {len(values)} procedures)")


if __name__ == "__main__":
    main()
