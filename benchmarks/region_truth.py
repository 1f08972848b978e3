"""How much less wall the ground truth counts through an image region: the segment coverage
(default Δ pair) of procedures simulated with `--octagon` against the same procedures
without it (folders of the same names), its mean and largest drop.

    python benchmarks/region_truth.py --whole data/heldout2 --octagon data/heldout2-octagon
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from hybrid.coverage import pair_key
from hybrid.dataset import Procedure, list_procedures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--whole", type=Path, required=True)
    parser.add_argument("--octagon", type=Path, required=True)
    args = parser.parse_args()
    drops = []
    for octagon in list_procedures(args.octagon):
        whole = Procedure.open(args.whole / octagon.path.name).coverage
        key = pair_key(whole.default_pair)
        drops += [b.coverage[key] - a.coverage[key]
                  for a, b in zip(whole.segments, octagon.coverage.segments, strict=True)]
    drops = np.array(drops)
    print(f"{len(drops)} segments: truth through the octagon minus the whole image's, mean "
          f"{drops.mean():+.4f}, largest drop {drops.min():+.4f}, largest rise {drops.max():+.4f}")


if __name__ == "__main__":
    main()
