"""How much ground-truth coverage changes with the mesh resolution of the simulated colon.

For each seed, one colon (ColonConfig with --length-cm) is drawn at three mesh resolutions
from the same generator state: default (ring spacing 0.1 cm, 128 vertices around), half
(0.2 cm, 64) and double (0.05 cm, 256). make_colon draws the shape on a fixed 1 mm grid, so
the three meshes should sample one surface. The script checks this: it prints the largest
distance between vertices that the grids share (a coarse grid point is also a point of the finer
grid), and leaves out of the pooled table any seed where it exceeds --max-gap-cm (the mesh
frames of make_colon can start rotated about the lumen at another resolution, which turns the
folds; see docs/mesh_resolution.md). One withdrawal is drawn on the default colon and the same
poses are used at every resolution.

Per-frame and per-segment coverage (hybrid.coverage.compute_coverage, every Δ pair) at half
and double resolution are compared with the default one: mean and max absolute difference and
the mean signed difference (bias, other minus default), pooled over seeds (frames or segments
where either value is undefined are skipped).

Run from the repository root:

    .venv/bin/python benchmarks/mesh_resolution.py --seeds 0 1 2 3
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hybrid.coverage import DEFAULT_PAIR_CM, Lumen, SurfaceMesh, compute_coverage, pair_key
from hybrid.sim.colon import ColonConfig, make_colon
from hybrid.sim.simulate import SimConfig, draw_camera
from hybrid.sim.trajectory import TrajectoryConfig, make_withdrawal

RESOLUTIONS = {"half": (0.2, 64), "default": (0.1, 128), "double": (0.05, 256)}
"""Name: (ring spacing cm, segments around)."""


def shared_grid_gap(coarse, fine, ring_step: int, around_step: int) -> float:
    """Largest distance between coarse vertices and the fine vertices at the same grid point."""
    n_around = fine.fold_depth.shape[1]
    fine_grid = fine.vertices[:-1].reshape(-1, n_around, 3)[::ring_step, ::around_step]
    coarse_grid = coarse.vertices[:-1].reshape(fine_grid.shape)
    return float(np.linalg.norm(coarse_grid - fine_grid, axis=-1).max())


def run_seed(seed: int, length_cm: float, segment_frames: int) -> tuple[dict, float]:
    """Coverage at each resolution for one colon and one withdrawal, and the largest gap."""
    colons = {}
    for name, (spacing, around) in RESOLUTIONS.items():
        config = ColonConfig(length_cm=length_cm, ring_spacing_cm=spacing, segments_around=around)
        colons[name] = make_colon(config, np.random.default_rng([seed, 0]))
    rng = np.random.default_rng([seed, 1])
    camera = draw_camera(SimConfig(preset="fast"), rng)
    poses = make_withdrawal(colons["default"], TrajectoryConfig(), rng)
    gaps = (shared_grid_gap(colons["half"], colons["default"], 2, 2),
            shared_grid_gap(colons["default"], colons["double"], 2, 2))
    results = {}
    for name, colon in colons.items():
        start = time.perf_counter()
        results[name] = compute_coverage(
            SurfaceMesh.from_arrays(colon.vertices, colon.triangles), Lumen(colon.centerline),
            poses, camera, segment_frames=segment_frames)
        print(f"  seed {seed} {name:7s}: {len(colon.vertices):6d} vertices, "
              f"{time.perf_counter() - start:5.1f} s")
    print(f"  seed {seed}: {len(poses)} frames, {len(results['default'].segments)} segments; "
          f"shared-grid vertex gap half/default {gaps[0]:.2e} cm, "
          f"default/double {gaps[1]:.2e} cm")
    return results, max(gaps)


def differences(per_seed: list[dict], name: str, key: str) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame and per-segment differences of `name` minus default, pooled over seeds."""
    frames, segments = [], []
    for results in per_seed:
        ref, other = results["default"], results[name]
        a = np.array(ref.per_frame[key], dtype=float)
        b = np.array(other.per_frame[key], dtype=float)
        frames.append((b - a)[np.isfinite(a) & np.isfinite(b)])
        a = np.array([s.coverage[key] for s in ref.segments], dtype=float)
        b = np.array([s.coverage[key] for s in other.segments], dtype=float)
        segments.append((b - a)[np.isfinite(a) & np.isfinite(b)])
    return np.concatenate(frames), np.concatenate(segments)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    parser.add_argument("--length-cm", type=float, default=40.0)
    parser.add_argument("--segment-frames", type=int, default=300)
    parser.add_argument("--max-gap-cm", type=float, default=0.05,
                        help="leave out seeds whose meshes differ by more at shared grid points")
    args = parser.parse_args()

    per_seed = []
    for seed in args.seeds:
        results, gap = run_seed(seed, args.length_cm, args.segment_frames)
        if gap > args.max_gap_cm:
            _, segments = differences([results], "half", pair_key(DEFAULT_PAIR_CM))
            print(f"  seed {seed} LEFT OUT: not the same shape at every resolution (gap "
                  f"{gap:.2f} cm); its half-vs-default segment differences (1-4): "
                  f"{np.round(segments, 3).tolist()}")
        else:
            per_seed.append(results)
    print(f"\npooled over {len(per_seed)} seeds")
    keys = list(per_seed[0]["default"].per_frame)
    print("\n| vs default | Δ (cm) | frames | frame mean abs | frame max abs | frame bias "
          "| segments | segment mean abs | segment max abs | segment bias |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name in ("half", "double"):
        for key in keys:
            spacing, around = RESOLUTIONS[name]
            cells = [f"{name} ({spacing:g} cm, {around})", key]
            for diff in differences(per_seed, name, key):
                cells.append(str(diff.size))
                if diff.size:
                    cells += [f"{np.abs(diff).mean():.4f}", f"{np.abs(diff).max():.4f}",
                              f"{diff.mean():+.4f}"]
                else:
                    cells += ["-", "-", "-"]
            print("| " + " | ".join(cells) + " |")
    key = pair_key(DEFAULT_PAIR_CM)
    ref = np.concatenate([np.array(r["default"].per_frame[key], dtype=float) for r in per_seed])
    print(f"\n(default resolution, per-frame coverage {key}: mean {np.nanmean(ref):.3f}, "
          f"std {np.nanstd(ref):.3f})")


if __name__ == "__main__":
    main()
