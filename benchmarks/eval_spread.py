"""How much one procedure weighs in a `c2d2 eval` result: each branch's MAE over all segments
and the largest change when one procedure's segments are left out.

    python benchmarks/eval_spread.py data/eval-sim-w03/eval.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("eval_json", type=Path, help="eval.json written by c2d2 eval")
    segments = json.loads(parser.parse_args().eval_json.read_text())["segments"]
    procedures = sorted({s["procedure"] for s in segments})
    for branch in ("learned", "geometric"):
        rows = [(s["procedure"], abs(s[branch] - s["truth"])) for s in segments
                if s[branch] is not None]
        mae = np.mean([e for _, e in rows])
        left_out = [np.mean([e for q, e in rows if q != p]) for p in procedures]
        print(f"{branch:9s} MAE {mae:.3f}; leaving one of {len(procedures)} procedures out "
              f"moves it by up to {np.max(np.abs(np.array(left_out) - mae)):.3f}")


if __name__ == "__main__":
    main()
