"""Simulated procedures at a lower frame rate, for `c2d2 eval`: every k-th frame of each, its
camera's frame rate divided by k, and its ground truth computed again on those frames (the
same 10-s segments, k times fewer frames each). How the pipeline reads video at the real
clip's 6 fps, where it has no labels.

    python benchmarks/frame_rate.py --data data/heldout --every 5 --out data/heldout-6fps
    c2d2 eval --data data/heldout-6fps --out data/eval-heldout-6fps
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np

from hybrid.coverage import Lumen, compute_coverage
from hybrid.dataset import REGION_FILE, Procedure, frame_name


def subsample(proc: Procedure, every: int, out: Path) -> Path:
    """Write proc's every `every`-th frame as a procedure under out (skipped if there)."""
    final = out / proc.path.name
    if final.is_dir():
        made = json.loads((final / "meta.json").read_text()).get("every_kth_frame")
        if made != every:
            raise SystemExit(f"{final} holds every {made}th frame, not every {every}th: "
                             f"choose another --out")
        return final
    segment_frames = proc.coverage.segment_frames
    if segment_frames % every:
        raise SystemExit(f"{proc.path}: its {segment_frames}-frame segments do not divide by "
                         f"{every}")
    work = final.with_name(final.name + ".partial")
    shutil.rmtree(work, ignore_errors=True)
    for kind in ("rgb", "depth"):
        (work / kind).mkdir(parents=True)
        for new, old in enumerate(range(0, proc.num_frames, every)):
            _link(proc.path / kind / frame_name(old), work / kind / frame_name(new))
    for name in ("colon.ply", "lumen.npy", REGION_FILE):
        if (proc.path / name).is_file():  # region.png: only with --octagon
            _link(proc.path / name, work / name)
    camera = replace(proc.camera, fps=proc.camera.fps / every)
    camera.save(work / "camera.json")
    poses = proc.poses[::every]
    np.save(work / "poses.npy", poses)
    # the source's meta, with the copy's frame count; its configs stay the source's
    meta = json.loads((proc.path / "meta.json").read_text()) | {
        "every_kth_frame": every, "num_frames": len(poses)}
    (work / "meta.json").write_text(json.dumps(meta, indent=1))
    compute_coverage(proc.mesh(), Lumen(proc.lumen), poses, camera, segment_frames // every,
                     region=proc.region).save(work / "coverage.json")
    work.rename(final)
    return final


def _link(source: Path, target: Path) -> None:
    """A hard link where the file system allows it, else a copy."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", nargs="+", type=Path, required=True,
                        help="folders of procedures")
    parser.add_argument("--every", type=int, required=True, help="keep every k-th frame")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for folder in args.data:
        for path in sorted(p for p in folder.iterdir() if (p / "meta.json").is_file()):
            proc = Procedure.open(path)
            made = Procedure.open(subsample(proc, args.every, args.out))
            print(f"{path} -> {made.path}: {made.num_frames} frames at {made.camera.fps:g} fps, "
                  f"truth {[round(float(v), 2) for v in made.coverage.segment_labels()]} "
                  f"(at {proc.camera.fps:g} fps "
                  f"{[round(float(v), 2) for v in proc.coverage.segment_labels()]})", flush=True)


if __name__ == "__main__":
    main()
