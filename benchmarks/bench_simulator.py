"""Throughput and memory of the colon simulator and of ground-truth coverage.

For each image-size preset (fast 128x160, paper 320x384) on one procedure of --frames frames
(default 120 cm colon, frames capped with max_frames), it measures:

- render: frames/s of ColonRenderer.render alone (the first, BVH-building call is excluded);
- label: frames/s of compute_coverage on the same poses (whole call, setup included);
- combined: frames / (render time + label time);
- png: frames/s of writing the RGB and depth PNGs of the rendered frames;
- end-to-end: frames/s of simulate_procedure (colon, texture, render, PNGs, mesh, coverage),
  and its fixed per-procedure setup (colon + texture + renderer).

Process CPU time / wall time is printed as "cpu" (1.0 = one core busy, 2.0 = both).

With --memory-frames N1 N2 ..., it also simulates procedures of N frames each in a fresh
process (fast preset, slow withdrawal so that the colon is long enough) and prints the peak
resident set of that process (VmHWM in /proc/self/status; not ru_maxrss, which Linux carries
over from the parent through fork and exec) and the end-to-end rate. 18000 frames is a
10-minute procedure. Linux only.

Run from the repository root:

    .venv/bin/python benchmarks/bench_simulator.py
    .venv/bin/python benchmarks/bench_simulator.py --memory-frames 2000 6000 18000
    .venv/bin/python benchmarks/bench_simulator.py --presets fast --profile
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from multiprocessing import get_context
from pathlib import Path

from hybrid.coverage import Lumen, SurfaceMesh, compute_coverage
from hybrid.dataset import frame_name, write_depth, write_rgb
from hybrid.sim.simulate import SimConfig, draw_scene, simulate_procedure, with_overrides


class Clock:
    """Wall and process CPU time of a block."""

    def __enter__(self) -> Clock:
        self.wall0, self.cpu0 = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc: object) -> None:
        self.wall = time.perf_counter() - self.wall0
        self.cpu = time.process_time() - self.cpu0


def build(config: SimConfig, seed: int, index: int = 0):
    """Colon, camera, poses and renderer drawn as simulate_procedure draws them."""
    with Clock() as setup:
        scene = draw_scene(config, seed, index)
    return scene.colon, scene.camera, scene.poses, scene.renderer, scene.rng, setup.wall


def bench_preset(preset: str, frames: int, seed: int, profile: bool) -> None:
    config = with_overrides(SimConfig(preset=preset), max_frames=frames)
    colon, camera, poses, renderer, rng, setup_s = build(config, seed)
    n = len(poses)
    renderer.render(poses[0], rng)  # builds the BVH
    profiler = cProfile.Profile() if profile else None
    with Clock() as render:
        if profiler:
            profiler.enable()
        images = [renderer.render(pose, rng) for pose in poses]
        if profiler:
            profiler.disable()
    mesh = SurfaceMesh.from_arrays(colon.vertices, colon.triangles)
    lumen = Lumen(colon.centerline)
    with Clock() as label:
        if profiler:
            profiler.enable()
        compute_coverage(mesh, lumen, poses, camera, segment_frames=config.segment_frames)
        if profiler:
            profiler.disable()
    with tempfile.TemporaryDirectory() as tmp, Clock() as png:
        for i, (rgb, depth) in enumerate(images):
            write_rgb(Path(tmp) / f"rgb_{frame_name(i)}", rgb)
            write_depth(Path(tmp) / f"depth_{frame_name(i)}", depth)
    with tempfile.TemporaryDirectory() as tmp, Clock() as e2e:
        simulate_procedure(Path(tmp), seed, 0, config)

    h, w = camera.height, camera.width
    print(f"\n{preset} ({h}x{w}), {n} frames, {len(colon.vertices)} vertices, "
          f"{len(colon.triangles)} triangles")
    print(f"  setup (colon, texture, renderer) {setup_s:6.2f} s")
    rows = [("render", render), ("label", label), ("png", png)]
    for name, clock in rows:
        print(f"  {name:10s} {n / clock.wall:7.1f} frames/s  {1e3 * clock.wall / n:6.2f} ms/frame"
              f"  cpu {clock.cpu / clock.wall:4.2f}")
    both = render.wall + label.wall
    print(f"  {'combined':10s} {n / both:7.1f} frames/s  {1e3 * both / n:6.2f} ms/frame")
    print(f"  {'end-to-end':10s} {n / e2e.wall:7.1f} frames/s  {1e3 * e2e.wall / n:6.2f} ms/frame"
          f"  cpu {e2e.cpu / e2e.wall:4.2f}  (total {e2e.wall:.1f} s)")
    if profiler:
        out = io.StringIO()
        pstats.Stats(profiler, stream=out).sort_stats("tottime").print_stats(15)
        print("  profile of render + label (sorted by own time):")
        print("\n".join("    " + line for line in out.getvalue().splitlines()[4:] if line))


def simulate_long(frames: int, seed: int) -> tuple[int, float, float]:
    """In a fresh process: frames, wall seconds and peak RSS (MiB) of one long procedure."""
    base = SimConfig(preset="fast")
    slow = replace(base.trajectory, mean_speed_cm_s=(0.15, 0.15), max_frames=frames)
    config = replace(base, trajectory=slow)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        folder = simulate_procedure(Path(tmp), seed, 0, config)
        wall = time.perf_counter() - start
        written = len(list((folder / "rgb").iterdir()))
    status = Path("/proc/self/status").read_text()
    peak_kib = next(int(line.split()[1]) for line in status.splitlines()
                    if line.startswith("VmHWM:"))
    return written, wall, peak_kib / 1024


def bench_memory(lengths: list[int], seed: int) -> None:
    print("\nlong procedures (fast preset, mean speed 0.15 cm/s, one fresh process each)")
    for frames in lengths:
        with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
            written, wall, peak = pool.submit(simulate_long, frames, seed).result()
        print(f"  {written:6d} frames ({written / 1800:5.1f} min at 30 fps): "
              f"peak RSS {peak:7.1f} MiB, {wall:6.1f} s, {written / wall:5.1f} frames/s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--presets", nargs="*", default=["fast", "paper"],
                        choices=["fast", "paper"])
    parser.add_argument("--frames", type=int, default=300, help="frames per timed procedure")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--profile", action="store_true",
                        help="print a cProfile of render + label for each preset")
    parser.add_argument("--memory-frames", type=int, nargs="*", default=[],
                        help="lengths of long procedures whose peak RSS to measure")
    args = parser.parse_args()
    for preset in args.presets:
        bench_preset(preset, args.frames, args.seed, args.profile)
    if args.memory_frames:
        bench_memory(args.memory_frames, args.seed)


if __name__ == "__main__":
    main()
