"""How the ground truth changes with the way a procedure is filmed: the segment coverage
(default Δ pair) of procedures simulated with an option (`--octagon`, `--fisheye`) against
the same procedures without it (folders of the same names), its mean, largest drop and
largest rise.

    python benchmarks/truth_change.py --base data/heldout2 --variant data/heldout2-octagon
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from hybrid.coverage import pair_key
from hybrid.dataset import Procedure, list_procedures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, required=True, help="the procedures without it")
    parser.add_argument("--variant", type=Path, required=True, help="the same, with it")
    args = parser.parse_args()
    changes = []
    for variant in list_procedures(args.variant):
        base = Procedure.open(args.base / variant.path.name).coverage
        key = pair_key(base.default_pair)
        changes += [b.coverage[key] - a.coverage[key]
                    for a, b in zip(base.segments, variant.coverage.segments, strict=True)]
    changes = np.array(changes)
    print(f"{len(changes)} segments: truth of {args.variant} minus {args.base}'s, mean "
          f"{changes.mean():+.4f}, largest drop {changes.min():+.4f}, largest rise "
          f"{changes.max():+.4f}")


if __name__ == "__main__":
    main()
