"""How much one procedure weighs in an evaluation: each branch's (or mode's) MAE over all
segments and the largest change when one procedure's segments are left out.

Reads the eval.json of `c2d2 eval` (branches learned and geometric) or the geometric_eval.json
of benchmarks/geometric_eval.py (each of its modes).

    python benchmarks/eval_spread.py data/eval-sim-w03/eval.json
    python benchmarks/eval_spread.py docs/geometric/thinned/geometric_eval.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def errors(data: dict) -> dict[str, list[tuple[str, float]]]:
    """Per branch or mode: (procedure, absolute error) of every segment with a value."""
    if "segments" in data:  # c2d2 eval
        return {branch: [(s["procedure"], abs(s[branch] - s["truth"])) for s in data["segments"]
                         if s[branch] is not None] for branch in ("learned", "geometric")}
    rows: dict[str, list[tuple[str, float]]] = {}
    for name, procedure in data["procedures"].items():
        for mode, result in procedure.items():
            if isinstance(result, dict) and "pred" in result:
                rows.setdefault(mode, []).extend(
                    (name, abs(p - t)) for p, t in zip(result["pred"], procedure["truth"],
                                                       strict=True) if p is not None)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("json", type=Path,
                        help="eval.json of c2d2 eval, or geometric_eval.json")
    for branch, rows in errors(json.loads(parser.parse_args().json.read_text())).items():
        procedures = sorted({p for p, _ in rows})
        mae = np.mean([e for _, e in rows])
        left_out = np.array([np.mean([e for q, e in rows if q != p]) for p in procedures])
        print(f"{branch:13s} MAE {mae:.3f}; leaving one of {len(procedures)} procedures out "
              f"gives {left_out.min():.3f}-{left_out.max():.3f}, up to "
              f"{np.max(np.abs(left_out - mae)):.3f} away")


if __name__ == "__main__":
    main()
