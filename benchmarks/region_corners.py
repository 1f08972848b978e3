"""How much of each corner an image region cuts off: the legs of the four corner cuts.

For each region image given (a work folder's region.png, at the network's size; or a simulated
procedure's), per corner the run of outside pixels along its edge row and its edge column,
as fractions of the image's shorter side, and the share of the image outside the region.
The figures behind `c2d2 simulate --octagon`'s range (hybrid.sim.simulate.OCTAGON_CUT):

    python benchmarks/region_corners.py data/real-s54-final/clip/region.png \
        data/real-s54-final/cvc_seq*/region.png

(A detected region is eroded by 2 px, which adds about 2 px to each leg.)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from hybrid.types import read_mask


def corner_legs(region: np.ndarray) -> list[tuple[int, int]]:
    """(along the row, along the column) outside pixels from each corner: top-left,
    top-right, bottom-left, bottom-right."""
    def run(edge: np.ndarray) -> int:  # outside pixels before the first inside one
        return int(np.argmax(edge)) if edge.any() else len(edge)

    return [(run(flipped[0]), run(flipped[:, 0]))
            for flipped in (region, region[:, ::-1], region[::-1], region[::-1, ::-1])]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("regions", type=Path, nargs="+")
    args = parser.parse_args()
    for path in args.regions:
        region = read_mask(path, "region")
        side = min(region.shape)
        legs = corner_legs(region)
        fractions = " ".join(f"{a / side:.2f}/{b / side:.2f}" for a, b in legs)
        print(f"{path}  {region.shape[0]}x{region.shape[1]}  outside {1 - region.mean():.3f}  "
              f"legs (row/column, of {side} px): {fractions}")


if __name__ == "__main__":
    main()
