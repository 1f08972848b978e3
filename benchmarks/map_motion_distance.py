"""How far each depth model's motion network and K head lie from the structure-from-motion
maps, on the maps' training triplets: the terms `train-depth --maps` pulls on with
`w_map_motion` (learned.map_triplets.map_motion_errors), the same batches for every model.

Prints the maps' own rotation (its L1 size: how far a network that never turns would lie),
then per model the rotation's L1 distance (axis-angle, summed over the axes, mean over the
two pairs of a triplet, in radians and degrees), 1 - cos of the angle between the
translations, and |log| of the focal lengths' ratio.

    python benchmarks/map_motion_distance.py --data data/train-pink data/train-dusk \
        --maps data/sfm-maps --model learned/checkpoints/depth-fast.safetensors \
        --model data/runs/maps-scratch/model.safetensors
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from learned.frames import open_sequence
from learned.map_triplets import MapTriplets, map_motion_errors
from learned.model import load_depth_model
from learned.train import TripletSampler, expand_inputs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True,
                        help="the training inputs the maps were made of")
    parser.add_argument("--maps", type=Path, required=True, help="`c2d2 sfm-maps` output")
    parser.add_argument("--model", type=Path, action="append", required=True,
                        help="a depth checkpoint (repeat to compare)")
    parser.add_argument("--batches", type=int, default=25)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--min-points", type=int, default=20,
                        help="DepthConfig.map_min_points")
    args = parser.parse_args()
    torch.set_num_threads(1)
    models = [load_depth_model(path) for path in args.model]
    config = models[0].config
    size = (config.height, config.width)
    sampler = TripletSampler([open_sequence(p, size) for p in expand_inputs(args.data)],
                             config.pair_gap_s, 0)
    maps = MapTriplets(sampler.sequences, sampler.gaps, args.maps, args.min_points)
    batches = [maps.batch(args.batch_size, np.random.default_rng([args.seed, i]))
               for i in range(args.batches)]
    still = np.mean([float(torch.stack([side[0].abs().sum(1).mean() for side in batch.motions])
                               .mean()) for batch in batches])
    print(f"the maps' own rotation, as far as a motion network that never turns would lie: "
          f"{still:.4f} rad ({np.degrees(still):.2f}°)")
    for path, model in zip(args.model, models, strict=True):
        if (model.config.height, model.config.width) != size:
            raise SystemExit(f"{path}: another preset's size than {args.model[0]}")
        model.eval()
        with torch.no_grad():
            errors = np.mean([[float(e) for e in map_motion_errors(
                *model.triplet_motion(batch.frames), batch)] for batch in batches], axis=0)
        print(f"{path}: rotation {errors[0]:.4f} rad ({np.degrees(errors[0]):.2f}°), "
              f"direction {errors[1]:.4f}, focal {errors[2]:.4f}")


if __name__ == "__main__":
    main()
