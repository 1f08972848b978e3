"""Simulated fisheye procedures (`c2d2 simulate --fisheye`) resampled to the camera of their
pinhole twins with the true lens (`hybrid.lens`): what undistorting the frames before every
stage would give, were the lens known. The ground truth stays the fisheye's (the wall the
endoscopist saw); the image region is where the fisheye image reaches (black elsewhere);
the depth stays z-depth (the camera does not move). Resumes: finished folders are kept.

    python benchmarks/fisheye_to_pinhole.py --data data/heldout-fisheye \
        --out data/heldout-fisheye-pinhole
    c2d2 eval --data data/heldout-fisheye-pinhole --out data/eval-fisheye-pinhole-h1
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import cv2
from tqdm import tqdm

from hybrid.dataset import (
    REGION_FILE,
    frame_name,
    list_procedures,
    write_depth,
    write_region,
    write_rgb,
)
from hybrid.lens import pinhole_twin, resample, resample_mask, resampling_maps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="fisheye procedures")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    for proc in tqdm(list_procedures(args.data), desc="procedures"):
        final = args.out / proc.path.name
        if final.is_dir():
            continue
        work = final.with_name(final.name + ".partial")
        shutil.rmtree(work, ignore_errors=True)
        (work / "rgb").mkdir(parents=True)
        (work / "depth").mkdir()
        target = pinhole_twin(proc.camera)
        maps = resampling_maps(proc.camera, target)
        region = resample_mask(proc.region, maps)
        for i in range(proc.num_frames):
            rgb = resample(proc.rgb(i), maps)
            rgb[~region] = 0
            write_rgb(work / "rgb" / frame_name(i), rgb)
            depth = resample(proc.depth(i), maps, cv2.INTER_NEAREST)
            depth[~region] = 0  # no surface known there
            write_depth(work / "depth" / frame_name(i), depth)
        write_region(work / REGION_FILE, region)
        target.save(work / "camera.json")
        for name in ("poses.npy", "colon.ply", "lumen.npy", "coverage.json"):
            shutil.copy(proc.path / name, work / name)
        meta = {**proc.meta, "resampled_from": str(proc.path), "lens": proc.camera.model}
        (work / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")
        work.rename(final)


if __name__ == "__main__":
    main()
