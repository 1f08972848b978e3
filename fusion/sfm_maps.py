"""Structure from motion on every stretch of training videos: motion, K and sparse depth for
`c2d2 train-depth --maps` (`learned.map_triplets`).

Each input is cut into non-overlapping stretches of `length` consecutive frames, each mapped on
its own as the self-calibration maps its stretches (`fusion.self_calibration`: the frames at
the depth network's size with their lightness equalised, the image region as the camera mask,
one thread). Per input one file (`map_path`) holds, for each frame, the stretch it belongs to,
its camera-to-world pose in its stretch's model (NaN where not placed) and its sparse depth
(the model's points it observes); per stretch its first frame, fraction of frames placed
and fx; and the input's resolved path, `fingerprint`, frame size and fy / fx (frames whose
pixels are not square are mapped enlarged to square pixels, as the self-calibration maps
them, and f and the points' pixels are given back at the frames' size). Nothing here reads
a ground truth. An input whose file exists is skipped, so an interrupted run resumes; files
are written whole or not at all.
"""

from __future__ import annotations

import multiprocessing
import os
import tempfile
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from fusion.self_calibration import SelfCalibrationConfig, SquarePixels, contrast_enhanced
from fusion.sfm_baseline import NoModel, run_sfm
from hybrid import workdir as W
from hybrid.types import InputError
from learned.frames import FrameSequence, open_sequence


def map_path(maps: Path, source: str | Path) -> Path:
    """The map file of an input (`<parent>-<name>.npz`, e.g. train-pink-proc_0000.npz)."""
    source = Path(source)
    return Path(maps) / f"{source.parent.name}-{source.name}.npz"


def fingerprint(seq: FrameSequence) -> np.ndarray:
    """Mean RGB of the first, middle and last frames at the sequence's size: what ties a map
    to its input wherever the input lies."""
    count = seq.num_frames
    return np.array([seq.frame(i).mean(axis=(0, 1)) for i in (0, count // 2, count - 1)],
                    np.float32)


def map_input(path: Path, out: Path, size: tuple[int, int], length: int) -> str:
    """Map every stretch of one input at `size` (H, W); write `out`. One line on what was
    mapped."""
    cv2.setNumThreads(1)
    seq = open_sequence(path, size)
    square = SquarePixels(seq.size, seq.pixel_aspect)
    (sx, sy), mask = square.scale, square.mask(seq.region)
    contrast = SelfCalibrationConfig()
    count = seq.num_frames
    stretch = np.full(count, -1)
    poses = np.full((count, 4, 4), np.nan)
    observed: list[np.ndarray] = []
    starts = list(range(0, count - length + 1, length))
    fx, registered = np.full(len(starts), np.nan), np.zeros(len(starts))
    for k, start in enumerate(starts):
        ids = range(start, start + length)
        images = [square(contrast_enhanced(seq.frame(i), contrast)) for i in ids]
        with tempfile.TemporaryDirectory() as work:
            try:
                sfm = run_sfm(images, mask, Path(work), f"{seq.name} {start}")
            except NoModel:
                continue
        fx[k], registered[k] = sfm.K[0, 0] * sx, sfm.registered.mean()
        stretch[ids.start:ids.stop] = np.where(sfm.registered, k, -1)
        poses[ids.start:ids.stop] = sfm.poses
        observed += [np.column_stack([np.full(len(o), i), (o[:, 0] + 0.5) * sx - 0.5,
                                      (o[:, 1] + 0.5) * sy - 0.5, o[:, 2]])
                     for i, o in zip(ids, sfm.observations, strict=True)]
    tmp = out.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, source=str(Path(path).resolve()), fingerprint=fingerprint(seq),
                        size=np.array(size),
                        fy_over_fx=square.fy_over_fx, length=length, starts=np.array(starts),
                        fx=fx, registered=registered, stretch=stretch, poses=poses,
                        observations=np.concatenate(observed or [np.zeros((0, 4))])
                        .astype(np.float32))
    tmp.replace(out)
    return (f"{seq.name}: {int(np.isfinite(fx).sum())} of {len(starts)} stretches mapped, "
            f"{int((stretch >= 0).sum())} frames placed")


def map_inputs(inputs: list[Path], out: Path, size: tuple[int, int], length: int = 120,
               workers: int = 1) -> Iterator[str]:
    """Map the inputs not yet mapped in `out`, `workers` at a time, each in a fresh process
    (spawned: a process forked from one running torch's threads can hang); one line per
    input, first those already mapped."""
    if length < 2 or workers < 1:
        raise InputError(f"stretches need at least 2 frames and at least 1 worker, got "
                         f"length {length} and {workers} workers")
    names = [map_path(out, p).name for p in inputs]
    if clash := sorted({n for n in names if names.count(n) > 1}):
        raise InputError(f"two inputs would share the map {out / clash[0]} (maps are named "
                         f"<folder>-<name>); map them into separate folders")
    W.make_folder(out)
    done = [p for p in inputs if map_path(out, p).exists()]
    for path in done:
        yield f"{path}: already mapped in {map_path(out, path)}"
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    with ProcessPoolExecutor(workers, multiprocessing.get_context("spawn")) as pool:
        jobs = [pool.submit(map_input, p, map_path(out, p), size, length)
                for p in inputs if p not in done]
        for job in jobs:
            yield job.result()
