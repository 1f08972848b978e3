"""The learned coverage of the same footage in two sets of runs (e.g. with two coverage
models; no ground truth): per group of runs, each set's mean, in how many segments the second
reads higher, the per-segment difference (second minus first: median and largest absolute
value, and its range), the correlation of the two, in how many segments the 3-class label
changes and each set's deficient segments; for real_runs.json, also each set's median focal
length (fx, input pixels) and its largest change in one run.

Reads the real_runs.json of benchmarks/real_runs.py (groups: the clip as a withdrawal, as an
insertion, and the CVC-ClinicDB sequences pooled, over the runs both sets finished) or the
coverage.json of one `c2d2 run` (one group).

    python benchmarks/compare_runs.py docs/real/real-l1.json docs/real/real-cov72.json
    python benchmarks/compare_runs.py data/real-coral/clip-old/coverage.json \\
        data/real-coral/clip-new/coverage.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from learned.coverage_eval import three_class

GROUPS = {"clip as a withdrawal": "clip-withdrawal", "clip as an insertion": "clip-insertion",
          "CVC-ClinicDB": "cvc_seq"}


def groups(path: Path) -> dict[str, dict[str, list[dict]]]:
    """Group name -> run name -> that run's segments."""
    data = json.loads(path.read_text())
    if "segments" in data:  # a c2d2 run's coverage.json
        return {"run": {"run": data["segments"]}}
    return {group: {name: run["segments"] for name, run in data.items()
                    if name.startswith(prefix) and "segments" in run}
            for group, prefix in GROUPS.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=Path, help="real_runs.json or coverage.json")
    parser.add_argument("second", type=Path, help="the same kind of file, of the same footage")
    args = parser.parse_args()
    first, second = groups(args.first), groups(args.second)
    for group, runs in first.items():
        names = sorted(runs.keys() & second[group].keys())
        a = [s for n in names for s in runs[n]]
        b = [s for n in names for s in second[group][n]]
        if not a or len(a) != len(b):
            print(f"{group}: no runs to compare" if not a else
                  f"{group}: the runs have different segments; not the same footage")
            continue
        x, y = (np.array([s["learned"] for s in ss]) for ss in (a, b))
        d = y - x
        print(f"{group} ({len(names)} runs, {len(x)} segments): mean {x.mean():.3f} -> "
              f"{y.mean():.3f}; higher in {np.sum(d > 0)} of {len(d)}; |difference| median "
              f"{np.median(np.abs(d)):.3f}, largest {np.abs(d).max():.3f} (from {d.min():+.3f} "
              f"to {d.max():+.3f}); correlation {np.corrcoef(x, y)[0, 1]:.2f}; 3-class "
              f"changes in {np.sum(three_class(x) != three_class(y))}; deficient "
              f"{sum(s['deficient'] for s in a)} -> {sum(s['deficient'] for s in b)}")
        if fx := focal_lengths(args.first, args.second, names):
            before, after = np.array(fx).T
            print(f"  fx median {np.median(before):.1f} -> {np.median(after):.1f} px, largest "
                  f"change {np.abs(after - before).max():.1f} px")


def focal_lengths(first: Path, second: Path, names: list[str]) -> list[tuple[float, float]]:
    """(before, after) fx of the named runs of two real_runs.json that both record it."""
    if "segments" in json.loads(first.read_text()):  # a coverage.json: no intrinsics
        return []
    a, b = (json.loads(path.read_text()) for path in (first, second))
    return [(a[n]["intrinsics"]["fx"], b[n]["intrinsics"]["fx"]) for n in names
            if a[n].get("intrinsics") and b[n].get("intrinsics")]


if __name__ == "__main__":
    main()
