"""Structure from motion on every stretch of training videos: poses, K and sparse depth to
train the depth network with (`benchmarks/depth_bounds.py --signal sfm`).

Each procedure is cut into non-overlapping stretches of `--length` consecutive frames, each
mapped on its own as the self-calibration maps its stretches (`fusion.self_calibration`: the
frames at the network's size with their lightness equalised, the image region as the camera
mask, one thread). Per procedure one file in --out (`map_path`) holds, for each frame, the stretch
it belongs to, its camera-to-world pose in its stretch's model (NaN where not placed) and its
sparse depth (the model's points it observes); and per stretch its first frame, fraction of
frames placed and focal length. Nothing here reads the ground truth. A procedure whose file
exists is skipped, so an interrupted run resumes.

    .venv/bin/python benchmarks/sfm_maps.py --data data/train-pink data/train-dusk \\
        --out data/sfm-maps --workers 2
"""

from __future__ import annotations

import argparse
import logging
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from fusion.self_calibration import SelfCalibrationConfig, contrast_enhanced
from fusion.sfm_baseline import NoModel, run_sfm
from learned.config import DepthConfig
from learned.frames import open_sequence
from learned.train import expand_inputs


def map_path(maps: Path, procedure: str | Path) -> Path:
    """The map file of a procedure folder (`<set>-<procedure>.npz`, e.g. train-pink-proc_0000)."""
    procedure = Path(procedure)
    return maps / f"{procedure.parent.name}-{procedure.name}.npz"


def map_procedure(path: Path, out: Path, length: int) -> str:
    """Map every stretch of one procedure; write `out`. One line on what was mapped."""
    cv2.setNumThreads(1)
    config = DepthConfig()
    seq = open_sequence(path, (config.height, config.width))
    if abs(seq.pixel_aspect - 1) > 1e-6:
        raise ValueError(f"{path}: frames with non-square pixels are not handled here")
    contrast = SelfCalibrationConfig()
    count = seq.num_frames
    stretch = np.full(count, -1)
    poses = np.full((count, 4, 4), np.nan)
    observed: list[np.ndarray] = []
    starts = list(range(0, count - length + 1, length))
    fx, registered = np.full(len(starts), np.nan), np.zeros(len(starts))
    for k, start in enumerate(starts):
        ids = range(start, start + length)
        images = [contrast_enhanced(seq.frame(i), contrast) for i in ids]
        with tempfile.TemporaryDirectory() as work:
            try:
                sfm = run_sfm(images, seq.region, Path(work), f"{seq.name} {start}")
            except NoModel:
                continue
        fx[k], registered[k] = sfm.K[0, 0], sfm.registered.mean()
        stretch[ids.start:ids.stop] = np.where(sfm.registered, k, -1)
        poses[ids.start:ids.stop] = sfm.poses
        observed += [np.column_stack([np.full(len(o), i), o])
                     for i, o in zip(ids, sfm.observations, strict=True)]
    tmp = out.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, starts=np.array(starts), fx=fx, registered=registered,
                        stretch=stretch, poses=poses, length=length,
                        observations=np.concatenate(observed or [np.zeros((0, 4))])
                        .astype(np.float32))
    tmp.replace(out)
    return (f"{seq.name}: {int(np.isfinite(fx).sum())} of {len(starts)} stretches mapped, "
            f"{int((stretch >= 0).sum())} frames placed")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--length", type=int, default=120, help="frames per stretch")
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    args.out.mkdir(parents=True, exist_ok=True)
    todo = [(p, map_path(args.out, p)) for p in expand_inputs(args.data)]
    todo = [(p, out) for p, out in todo if not out.exists()]
    with ProcessPoolExecutor(args.workers) as pool:
        jobs = [pool.submit(map_procedure, p, out, args.length) for p, out in todo]
        for job in tqdm(jobs, desc="map procedures", unit="procedure"):
            tqdm.write(job.result())


if __name__ == "__main__":
    main()
