"""The intrinsics head's focal length on simulated procedures whose images are changed after
rendering (an inference probe: which part of a style's look moves the head).

One change, in display values (after the style's gamma), to the procedures of --styles:
--vignetting V swaps the style's vignetting for V (the ratio of the two vignetting factors,
hybrid.sim.render.vignette, raised to 1/gamma; the style's blur and noise came after the
vignetting, so this is close, not exact), --blur S adds a Gaussian blur of S pixels, --noise N
adds Gaussian noise of N (0..1 scale, seeded by the frame's index), --dim F multiplies the
image by F. The head is read as eval-depth reads it (the median K over all consecutive
pairs), and the JSON (fx_true, fx_head per procedure, the unchanged styles included) is read
by benchmarks/focal_by_style.py:

    .venv/bin/python benchmarks/head_appearance.py --model MODEL --vignetting 0.35 \\
        --styles dusk --data data/heldout data/test --out /tmp/dusk-vig.json
    .venv/bin/python benchmarks/focal_by_style.py --train data/train-pink data/train-dusk-cam1 \\
        --eval /tmp/dusk-vig.json
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from functools import partial
from pathlib import Path

import cv2
import numpy as np

from hybrid.dataset import Procedure, list_procedures
from hybrid.sim.appearance import STYLES, Style, get_style
from hybrid.sim.render import vignette
from learned.evaluate import head_focal_lengths
from learned.frames import FrameSequence
from learned.model import load_depth_model


def change(args: argparse.Namespace, style: Style, height: int, width: int
           ) -> Callable[[int, np.ndarray], np.ndarray]:
    """The asked change as f(frame index, uint8 RGB) -> uint8 RGB."""
    if args.vignetting is not None:
        gain = (vignette(height, width, args.vignetting) / vignette(height, width, style.vignetting)
                ) ** (1.0 / style.gamma)
        return lambda i, rgb: _uint8(rgb * gain[..., None])
    if args.blur is not None:
        return lambda i, rgb: cv2.GaussianBlur(rgb, (0, 0), args.blur)
    if args.noise is not None:
        return lambda i, rgb: _uint8(
            rgb + np.random.default_rng(i).normal(0.0, args.noise * 255.0, rgb.shape))
    return lambda i, rgb: _uint8(rgb * args.dim)


def changed(args: argparse.Namespace, path: Path, size: tuple[int, int]) -> FrameSequence:
    """Procedure `path` as open_sequence opens it (without its depth and poses, which the head
    does not read), its frames changed if its style is named."""
    proc = Procedure.open(path)
    style, cam, load = get_style(proc.style), proc.camera, proc.rgb
    if style.name in args.styles:
        alter = change(args, style, cam.height, cam.width)
        load = lambda i: alter(i, proc.rgb(i))  # noqa: E731
    return FrameSequence(str(path), cam.fps, size, load, proc.num_frames,
                         region=proc.region, camera=cam)


def _uint8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, required=True, help="a train-depth model")
    parser.add_argument("--data", type=Path, nargs="+", required=True,
                        help="folders of simulated procedures")
    parser.add_argument("--styles", nargs="+", required=True, choices=sorted(STYLES),
                        help="the styles whose images are changed")
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--vignetting", type=float, help="the vignetting to swap in")
    what.add_argument("--blur", type=float, help="extra blur, pixels")
    what.add_argument("--noise", type=float, help="extra noise, standard deviation (0..1)")
    what.add_argument("--dim", type=float, help="brightness factor")
    parser.add_argument("--out", type=Path, required=True, help="JSON to write")
    args = parser.parse_args()
    if not (args.vignetting is None or 0 <= args.vignetting < 1):
        parser.error(f"--vignetting must lie in [0, 1), got {args.vignetting}")
    if not (args.blur is None or args.blur > 0) or not (args.dim is None or args.dim > 0):
        parser.error("--blur and --dim must be positive")
    if not (args.noise is None or args.noise >= 0):
        parser.error(f"--noise must be >= 0, got {args.noise}")
    found = {Procedure.open(p.path).style for folder in args.data for p in list_procedures(folder)}
    if not found & set(args.styles):
        parser.error(f"no procedure in --data has a style of {args.styles} (found {sorted(found)})")
    model = load_depth_model(args.model)
    procedures = head_focal_lengths(model, args.data, partial(changed, args))
    args.out.write_text(json.dumps({"procedures": procedures}, indent=1))


if __name__ == "__main__":
    main()
