"""Names of the files in the work directory of one video, and atomic writes.

A stage writes its outputs under temporary names and renames them when complete, so a file
with its final name is always whole and a stage whose outputs exist can be skipped.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from hybrid.types import InputError

LENS = "lens.json"
"""Structure from motion with a fisheye camera on stretches of the video as recorded
(fusion.self_calibration's record), when the run tells the lens from the video."""
FRAMES = "frames.npy"
"""(N, H, W, 3) uint8 frames at the networks' size, cropped to the image region."""
REGION = "region.png"
"""The image region at the networks' size (white = image)."""
INGEST = "ingest.json"
"""Source, frame rate, crop, per-frame quality flags, decoding warning."""
DEPTH = "depth.npy"
"""(N, H, W) float16 predicted depth (unknown scale)."""
RELATIVE = "relative_poses.npz"
"""Relative poses per frame gap ('gap1', 'gap2', ...): camera t -> camera t+g."""
INTRINSICS = "intrinsics.json"
"""K at the networks' size and in the input's pixels, with its spread."""
SELF_CALIBRATION = "self_calibration.json"
"""Structure from motion on stretches of the frames (fusion.self_calibration's record), when
the run self-calibrates the coverage networks' field of view."""
ODOMETRY = "odometry.json"
"""Per gap, how many relative poses RGB-D odometry could not refine (kept as inferred), and the
5th percentile and median of the refined pairs' fitness (fraction of pixels that found a
correspondence: about 1 between adjacent video frames)."""
POSEGRAPH = "posegraph.json"
"""How the pose graph's optimisation went: its error before and after, its iterations, and the
windows whose optimisation stopped at the iteration cap rather than by converging."""
POSES_RAW = "poses_raw.npy"
"""(N, 4, 4) camera-to-world poses chained from the consecutive relative poses the pose graph
reads (refined by RGB-D odometry unless it is off)."""
POSES = "poses_smoothed.npy"
"""(N, 4, 4) camera-to-world poses after the pose graph (unknown scale)."""
MESH = "mesh.ply"
"""The coloured TSDF mesh, cm."""
LUMEN = "lumen.json"
"""Fitted centreline and radius, cm."""
RECONSTRUCTION = "reconstruction.json"
"""Metric scale (cm per depth unit) and poses' unit."""
GEOMETRIC = "geometric.json"
"""Geometric coverage per segment (and why a segment has none)."""
MAPS = "maps"
"""Unrolled (ℓ, θ) maps of seen and missed wall, one per segment on its own lumen:
coverage_map.png and coverage_map.npz."""
LEARNED = "learned.json"
"""Learned coverage per frame (three Δ pairs) and per segment."""
COVERAGE_JSON = "coverage.json"
COVERAGE_CSV = "coverage.csv"
"""The cross-check: per segment, both coverages, their agreement and flags."""
GEOMETRIC_ERROR = "geometric_error.txt"
"""Why the geometric branch could not run on this video (the learned branch still reports)."""
ERROR = "error.txt"
"""Why a batch run of this video failed."""
REPORT = "report.html"
CONFIG = "config.json"
"""The resolved run configuration and the package version."""
TIMING = "timing.json"
"""Seconds per stage."""


def make_folder(path: Path, option: str = "--out") -> Path:
    """Create an output folder given as `option` (and its parents), or say why it cannot be
    one (a file in the way, no permission) and to choose another."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"cannot make the output folder {path}: {err.strerror or err}; "
                         f"choose another {option}") from err
    return path


def check_not_input(out: Path, source: Path) -> None:
    """Refuse an output folder that is the input folder itself: the outputs would join what it
    reads (for a batch, each work folder would take its video's name)."""
    if Path(source).is_dir() and Path(out).resolve() == Path(source).resolve():
        raise InputError(f"--out {out} is the input folder itself: the outputs would join what "
                         f"is read from it; choose another --out")


def write_text(path: Path, text: str) -> Path:
    """Write a text file atomically."""
    path = Path(path)
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


def write_json(path: Path, data) -> Path:
    return write_text(path, json.dumps(data, indent=1) + "\n")


def write_npy(path: Path, array) -> Path:
    """Write an array as .npy atomically."""
    import numpy as np

    path = Path(path)
    tmp = path.with_name(path.name + ".partial.npy")
    np.save(tmp, array)
    os.replace(tmp, path)
    return path


def write_png(path: Path, image) -> Path:
    """Write an image (uint8 array) as PNG atomically."""
    import cv2

    path = Path(path)
    tmp = path.with_name(path.name + ".partial.png")
    if not cv2.imwrite(str(tmp), image):
        raise OSError(f"cannot write {path}")
    os.replace(tmp, path)
    return path
