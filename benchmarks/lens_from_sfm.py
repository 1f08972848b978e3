"""Can structure from motion tell an endoscope's lens from its video? The probe behind
`c2d2 run --find-lens` (whose rule `benchmarks/find_lens.py` applies).

Each stretch of frames (as the depth network sees them, at the self-calibration's stretches,
contrast step and square pixels: `fusion.self_calibration.calibrate_sequence`) is mapped by
pycolmap with COLMAP's SIMPLE_RADIAL_FISHEYE camera, r = f (θ + k θ³) (k = 0: the
equidistant lens of `c2d2 simulate --fisheye`; a pinhole, r = f tan θ, reads as k near 1/3
over small angles, more over wide ones). Printed per stretch: frames placed, f and k, the
angle across the width they give, and the camera's true model and angle (camera.json); then
per lens, over the stretches that placed at least half their frames, the median k and the
angle's error.

    python benchmarks/lens_from_sfm.py --data data/heldout-fisheye data/heldout \
        --procedures 6 --stretches 3 --workers 2
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from fusion.self_calibration import SelfCalibrationConfig, calibrate_sequence
from fusion.sfm_baseline import CAMERA_MODEL, FISHEYE_MODEL
from hybrid.dataset import list_procedures
from learned.config import DEPTH_PRESETS
from learned.frames import open_sequence

_SIZE = (DEPTH_PRESETS["fast"].height, DEPTH_PRESETS["fast"].width)
"""The frames' size: the shipped depth network's."""


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
    config = SelfCalibrationConfig(windows=args.stretches, length=args.length, min_agreeing=1,
                                   camera_model=args.model,
                                   initial_field_of_view=args.initial_fov)
    by_lens: dict[str, list[tuple[float, float]]] = {}
    for path in [*map(Path, truth), *args.inputs]:
        found = calibrate_sequence(open_sequence(path, _SIZE), config, workers=args.workers)
        lens, angle = truth.get(str(path), ("unknown", float("nan")))
        known = f"true: {lens}, {angle:.1f} deg"
        for s in found.stretches:
            if s.fx is None:
                print(f"{path} {s.start}: no model ({known})")
                continue
            k = s.k or 0.0  # the pinhole camera's is 0
            print(f"{path} {s.start}: placed {s.registered:.2f} f {s.fx:.1f} k {k:+.3f} angle "
                  f"{found.width_angle(s):.1f} ({known}) reprojection "
                  f"{s.reprojection_error:.2f} px", flush=True)
            if s in found.placed:
                by_lens.setdefault(lens, []).append((k, found.width_angle(s) - angle))
    for lens, values in by_lens.items():
        k, error = np.array(values).T
        angle = ("" if lens == "unknown" else f"; angle error median {np.median(error):+.1f}, "
                 f"median absolute {np.median(np.abs(error)):.1f} deg")
        print(f"{lens}: {len(k)} stretches placed; k median {np.median(k):+.3f} "
              f"[{k.min():+.3f}, {k.max():+.3f}]{angle}")


if __name__ == "__main__":
    main()
