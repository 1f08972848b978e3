"""Can structure from motion tell an endoscope's lens from its video? A probe for a
calibration-free `--fisheye-fov`.

Each stretch of frames (as the depth network sees them, at the self-calibration's stretches,
contrast step and square pixels: `fusion.self_calibration`) is mapped by pycolmap with
COLMAP's SIMPLE_RADIAL_FISHEYE camera, r = f (θ + k θ³) (k = 0: the equidistant lens of
`c2d2 simulate --fisheye`; a pinhole, r = f tan θ, reads as k near 1/3 over small angles, more
over wide ones). Printed per stretch: frames placed, f and k, the angle across the width they
give, and the camera's true model and angle (camera.json); then per lens, over the stretches
that placed at least half their frames, the median k and the angle's error.

    python benchmarks/lens_from_sfm.py --data data/heldout-fisheye data/heldout \
        --procedures 6 --stretches 3 --workers 2
"""

from __future__ import annotations

import argparse
import tempfile
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from fusion.self_calibration import (
    SelfCalibrationConfig,
    SquarePixels,
    contrast_enhanced,
    half_angle,
    stretch_starts,
)
from fusion.sfm_baseline import CAMERA_MODEL, FISHEYE_MODEL, NoModel, run_sfm
from hybrid.dataset import list_procedures
from learned.config import DEPTH_PRESETS
from learned.frames import open_sequence

_SIZE = (DEPTH_PRESETS["fast"].height, DEPTH_PRESETS["fast"].width)
"""The frames' size: the shipped depth network's."""


def map_stretch(name: str, start: int, images: list[np.ndarray], mask: np.ndarray,
                scale: float, model: str, start_fov: float) -> dict:
    """One stretch's square-pixel frames mapped with the COLMAP camera `model`; `scale` takes
    the mapper's pixels to the frames' x pixels, in which f is given."""
    row = {"procedure": name, "start": start, "placed": 0.0}
    with tempfile.TemporaryDirectory() as work:
        try:
            sfm = run_sfm(images, mask, Path(work), f"{name} {start}",
                          initial_field_of_view=start_fov, camera_model=model)
        except NoModel:
            return row
    f, k = sfm.camera_params[0], (sfm.camera_params[3] if len(sfm.camera_params) > 3 else 0.0)
    row.update(placed=float(sfm.registered.mean()), f=float(f) * scale, k=float(k),
               angle=float(np.degrees(2 * half_angle(model, mask.shape[1] / 2 / f, k))),
               reprojection_error=sfm.reprojection_error)
    return row


def inputs_parser(description: str, procedures: int | None) -> argparse.ArgumentParser:
    """The options naming the inputs: --data (simulated procedures, the first --procedures of
    each folder), --inputs (videos or image folders), and --workers."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--data", type=Path, nargs="*", default=[],
                        help="folders of simulated procedures (their lens known)")
    parser.add_argument("--inputs", type=Path, nargs="*", default=[],
                        help="videos or image folders (their lens unknown)")
    parser.add_argument("--procedures", type=int, default=procedures,
                        help="the first N of each folder")
    parser.add_argument("--workers", type=int, default=2)
    return parser


def true_lenses(args: argparse.Namespace) -> dict[str, tuple[str, float]]:
    """Each simulated procedure's path: its camera's model and angle across the width."""
    return {str(proc.path): (proc.camera.model, proc.camera.hfov_deg)
            for folder in args.data for proc in list_procedures(folder)[:args.procedures]}


def main() -> None:
    parser = inputs_parser(__doc__.splitlines()[0], 6)
    parser.add_argument("--stretches", type=int, default=3)
    parser.add_argument("--length", type=int, default=120, help="frames per stretch")
    parser.add_argument("--model", default=FISHEYE_MODEL, choices=[FISHEYE_MODEL, CAMERA_MODEL])
    parser.add_argument("--initial-fov", type=float, default=120.0,
                        help="degrees across the longer side the mapper's f starts from "
                             "(through an equidistant lens for the fisheye model; a prior it "
                             "needs)")
    args = parser.parse_args()
    truth = true_lenses(args)
    layout = SelfCalibrationConfig(windows=args.stretches, length=args.length, min_agreeing=1)
    with ProcessPoolExecutor(args.workers, get_context("spawn")) as pool:
        jobs = []
        for path in [*map(Path, truth), *args.inputs]:
            seq = open_sequence(path, _SIZE)  # once: a video is decoded here
            square = SquarePixels(seq.size, seq.pixel_aspect)
            for start in stretch_starts(seq.num_frames, layout):
                ids = range(start, min(start + args.length, seq.num_frames))
                images = [square(contrast_enhanced(seq.frame(i), layout)) for i in ids]
                jobs.append(pool.submit(map_stretch, str(path), start, images,
                                        square.mask(seq.region), square.scale[0], args.model,
                                        args.initial_fov))
        rows = [job.result() for job in jobs]
    by_lens: dict[str, list[tuple[float, float]]] = {}
    for row in rows:
        lens, angle = truth.get(row["procedure"], ("unknown", float("nan")))
        known = f"true: {lens}, {angle:.1f} deg"
        if "f" not in row:
            print(f"{row['procedure']} {row['start']}: no model ({known})")
            continue
        print(f"{row['procedure']} {row['start']}: placed {row['placed']:.2f} f {row['f']:.1f} "
              f"k {row['k']:+.3f} angle {row['angle']:.1f} ({known}) "
              f"reprojection {row['reprojection_error']:.2f} px", flush=True)
        if row["placed"] >= 0.5:
            by_lens.setdefault(lens, []).append((row["k"], row["angle"] - angle))
    for lens, values in by_lens.items():
        k, error = np.array(values).T
        angle = ("" if lens == "unknown" else f"; angle error median {np.median(error):+.1f}, "
                 f"median absolute {np.median(np.abs(error)):.1f} deg")
        print(f"{lens}: {len(k)} stretches placed; k median {np.median(k):+.3f} "
              f"[{k.min():+.3f}, {k.max():+.3f}]{angle}")


if __name__ == "__main__":
    main()
