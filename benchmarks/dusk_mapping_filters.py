"""Does a denoising filter before the contrast step help structure from motion map dusk video?

Maps stretches of `--length` frames at the given starts of each procedure as `c2d2 sfm-maps`
does (network size, lightness equalised by CLAHE, the image region as the mask, one thread),
with the frames first passed through one filter: none, OpenCV's non-local means
(`fastNlMeansDenoisingColored`, h 10) or a bilateral filter (diameter 7, colour sigma 40,
space sigma 5). Prints per stretch the fraction of frames placed and the focal length's error
against the procedure's true camera.

    .venv/bin/python benchmarks/dusk_mapping_filters.py --filter bilateral \\
        --data data/train-dusk/proc_0000 data/train-dusk/proc_0003 data/train-dusk/proc_0006
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np

from fusion.self_calibration import SelfCalibrationConfig, contrast_enhanced
from fusion.sfm_baseline import NoModel, run_sfm
from learned.config import DepthConfig
from learned.frames import open_sequence

FILTERS = {"none": lambda rgb: rgb,
           "nlm": lambda rgb: cv2.fastNlMeansDenoisingColored(rgb[..., ::-1].copy(), None, 10,
                                                               10, 5, 15)[..., ::-1].copy(),
           "bilateral": lambda rgb: cv2.bilateralFilter(rgb, 7, 40, 5)}
"""Each takes and gives RGB uint8 (OpenCV's colour denoising expects BGR)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--filter", choices=sorted(FILTERS), required=True)
    parser.add_argument("--starts", type=int, nargs="+", default=[0, 360, 720])
    parser.add_argument("--length", type=int, default=120)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    config, contrast = DepthConfig(), SelfCalibrationConfig()
    print("| procedure | start | frames placed | fx error |")
    print("| --- | --- | --- | --- |")
    for path in args.data:
        seq = open_sequence(path, (config.height, config.width))
        if max(args.starts) + args.length > seq.num_frames:
            parser.error(f"{path}: {seq.num_frames} frames, too few for a stretch of "
                         f"{args.length} at frame {max(args.starts)}")
        for start in args.starts:
            images = [contrast_enhanced(FILTERS[args.filter](seq.frame(i)), contrast)
                      for i in range(start, start + args.length)]
            with tempfile.TemporaryDirectory() as work:
                try:
                    sfm = run_sfm(images, seq.region, Path(work), f"{seq.name} {start}")
                except NoModel:
                    print(f"| {seq.name} | {start} | 0% | no model |")
                    continue
            error = sfm.K[0, 0] / seq.camera.K[0, 0] - 1
            print(f"| {seq.name} | {start} | {np.mean(sfm.registered):.0%} | {error:+.1%} |")


if __name__ == "__main__":
    main()
