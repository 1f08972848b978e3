"""Histogram of ground-truth segment coverage over simulated withdrawals.

Draws colons and withdrawals exactly as `c2d2 simulate` does (same generator per
(seed, index)) but skips rendering, which does not change coverage. Prints the histogram and
writes a PNG.

    .venv/bin/python benchmarks/segment_histogram.py --procedures 12 \
        --out docs/segment_histogram.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hybrid.coverage import Lumen, SurfaceMesh, compute_coverage, pair_key  # noqa: E402
from hybrid.sim.colon import make_colon  # noqa: E402
from hybrid.sim.simulate import SimConfig, draw_camera  # noqa: E402
from hybrid.sim.trajectory import make_withdrawal  # noqa: E402


def segment_coverages(procedures: int, seed: int, config: SimConfig) -> dict[str, np.ndarray]:
    """Segment coverage of each Δ pair over procedures 0 .. procedures-1 of seed."""
    values: dict[str, list[float]] = {}
    for index in range(procedures):
        rng = np.random.default_rng([seed, index])
        colon = make_colon(config.colon, rng)
        camera = draw_camera(config, rng)
        poses = make_withdrawal(colon, config.trajectory, rng)
        result = compute_coverage(SurfaceMesh.from_arrays(colon.vertices, colon.triangles),
                                  Lumen(colon.centerline), poses, camera, config.segment_frames)
        for pair in result.delta_pairs:
            values.setdefault(pair_key(pair), []).extend(result.segment_labels(pair).tolist())
        print(f"procedure {index}: {len(poses)} frames, {len(result.segments)} segments, "
              f"default-pair coverage {np.round(result.segment_labels(), 2).tolist()}")
    return {k: np.array(v) for k, v in values.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--procedures", type=int, default=12)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("docs/segment_histogram.png"))
    args = parser.parse_args()
    values = segment_coverages(args.procedures, args.seed, SimConfig())
    bins = np.linspace(0, 1, 11)
    fig, ax = plt.subplots(figsize=(6, 3.5), layout="constrained")
    for k, v in values.items():
        counts, _ = np.histogram(v, bins)
        classes, _ = np.histogram(v, [0.0, 0.4, 0.8, 1.0])
        print(f"Δ = {k} cm: {v.size} segments, mean {v.mean():.3f}, min {v.min():.3f}, "
              f"max {v.max():.3f}; counts per 0.1 bin {counts.tolist()}; "
              f"3-class [0,0.4) [0.4,0.8) [0.8,1]: {classes.tolist()}")
        ax.hist(v, bins, histtype="step", lw=1.5, label=f"Δ = {k} cm")
    ax.set_xlabel("segment coverage (ground truth)")
    ax.set_ylabel("segments")
    ax.legend()
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
