"""End-to-end speed per stage and peak memory of `c2d2 run` against the video's length.

Builds an MJPG video of N frames (30 fps, 160x128) by playing a simulated procedure's frames
forwards and backwards (ping-pong, so motion stays continuous), runs `c2d2 run` on it in a
child process, and prints seconds and frames/s per stage (from timing.json), end-to-end frames/s
and the child's peak resident memory.

    python benchmarks/bench_pipeline.py --procedure data/test/proc_0000 --frames 1800 18000
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2

from hybrid.dataset import Procedure


def make_video(proc: Procedure, frames: int, path: Path) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), proc.camera.fps,
                             (proc.camera.width, proc.camera.height))
    period = 2 * proc.num_frames - 2
    for t in range(frames):
        k = t % period
        index = k if k < proc.num_frames else period - k
        writer.write(cv2.cvtColor(proc.rgb(index), cv2.COLOR_RGB2BGR))
    writer.release()
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--procedure", type=Path, default=Path("data/test/proc_0000"))
    parser.add_argument("--frames", type=int, nargs="+", default=[1800])
    args = parser.parse_args()
    proc = Procedure.open(args.procedure)
    with tempfile.TemporaryDirectory() as tmp:
        for frames in args.frames:
            video = make_video(proc, frames, Path(tmp) / f"video_{frames}.avi")
            out = Path(tmp) / f"run_{frames}"
            before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
            tic = time.time()
            done = subprocess.run([str(Path(sys.executable).with_name("c2d2")), "run",
                                   str(video), "--out", str(out)], capture_output=True, text=True)
            seconds = time.time() - tic
            peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
            if done.returncode not in (0, 3):
                print(done.stderr[-2000:])
                raise SystemExit(f"c2d2 run failed on {frames} frames")
            timing = json.loads((out / "timing.json").read_text())
            stages = "  ".join(f"{k} {v:.1f} s ({frames / max(v, 1e-9):.0f}/s)"
                               for k, v in timing.items())
            note = "" if peak > before else " (peak not above an earlier run's)"
            print(f"{frames} frames ({frames / 30 / 60:.1f} min): {seconds:.0f} s, "
                  f"{frames / seconds:.1f} frames/s end to end, peak RSS "
                  f"{peak / 1024:.0f} MiB{note}\n  {stages}", flush=True)


if __name__ == "__main__":
    main()
