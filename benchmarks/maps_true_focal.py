"""Maps of simulated inputs with their focal lengths put on the truth (an ablation).

Every stretch's fx in an input's map (`c2d2 sfm-maps`) is multiplied by one factor: the
camera's true fx over the median fx of the input's agreeing stretches. The agreement rule
reads only ratios of focal lengths, so the same stretches agree and train, and their
consensus is now the true camera's; poses and points are kept as mapped. Inputs with no
agreeing stretch are copied unchanged. It asks whether the head's level follows the maps'
focal lengths (docs/depth.md, "Cameras shared by the styles").

    .venv/bin/python benchmarks/maps_true_focal.py --data data/train-dusk-cam1 \\
        --maps data/sfm-maps-cam1 --out data/sfm-maps-cam1-truef
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from fusion.sfm_maps import map_path
from learned.config import DepthConfig
from learned.frames import open_sequence
from learned.map_triplets import MapTriplets
from learned.train import TripletSampler, expand_inputs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True,
                        help="simulated training inputs")
    parser.add_argument("--maps", type=Path, required=True, help="their maps")
    parser.add_argument("--out", type=Path, required=True, help="folder for the new maps")
    args = parser.parse_args()
    config = DepthConfig()
    sampler = TripletSampler([open_sequence(p, (config.height, config.width))
                              for p in expand_inputs(args.data)], config.pair_gap_s)
    args.out.mkdir(parents=True, exist_ok=True)
    for k, seq in enumerate(sampler.sequences):
        _, fx, _, stretch, _ = MapTriplets([seq], [sampler.gaps[k]], args.maps,
                                           config.map_min_points).maps[0]
        agreeing = np.unique(stretch[stretch >= 0])
        factor = seq.camera.K[0, 0] / np.median(fx[agreeing]) if agreeing.size else 1.0
        found = dict(np.load(map_path(args.maps, seq.name), allow_pickle=False))
        found["fx"] = found["fx"] * factor
        np.savez(map_path(args.out, seq.name), **found)
        print(f"{seq.name}: {agreeing.size} agreeing stretches, fx x {factor:.3f}")


if __name__ == "__main__":
    main()
