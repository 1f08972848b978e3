"""Ingestion: any recorded video (or image folder, or simulated procedure) into frames at the
networks' size, streamed, with the image region and per-frame quality flags.

Reads the input twice, one frame at a time, so memory does not grow with the video's length:
pass 1 finds the image region (pixels that are ever brighter than the border: black border,
circular or octagonal mask; the largest bright component, holes filled, so static overlays in
the border drop out) and counts the frames; pass 2 crops to the region's bounding box, resizes
and writes `frames.npy` (N, H, W, 3) uint8 block by block. Frames keep the video's own
rate; segments are cut by time downstream.

Quality flags per frame (inside the region): dark (mean grey < 30), overexposed (over 25% of
pixels above 245), blurred (variance of the Laplacian of the grey frame below 20 at the
networks' size). A video that decodes fewer frames than its container declares (FFmpeg skips
corrupt frames and goes on, or stops where a file is cut short) is kept with the frames that
decode and the loss is recorded (`decode_warning`).

`scan` and `sampled` read only some frames of an input, written nowhere (the run's lens
stage maps stretches of them before the input is ingested).

A video filmed through a fisheye lens of a known field of view (`fisheye_fov_deg`, across
the image region's width, equidistant, centred) has each frame's crop resampled at the
input's resolution, before the resize, to the pinhole camera that sees the same angle across
the width (`hybrid.lens`; at most `WIDEST_DEG`), so that every later stage reads a pinhole
video; the region becomes the part of it the lens shows, and the frames are black outside.
The quality flags are read on the frames as recorded (resampling blurs what it enlarges).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from hybrid.lens import WIDEST_DEG, equidistant, pinhole_twin, resampling_maps
from hybrid.npyio import NpyWriter
from hybrid.types import InputError
from hybrid.workdir import write_json
from learned.frames import (
    IMAGE_FOLDER_FPS,
    VIDEO_SUFFIXES,
    Crop,
    FrameSequence,
    check_fps,
    detect_region,
    image_files,
    is_procedure,
    read_image,
)

DARK_GREY = 30
"""Mean grey level (0-255) under which a frame is too dark."""
OVEREXPOSED_FRACTION = 0.25
"""Fraction of pixels above 245 over which a frame is overexposed."""
BLUR_VARIANCE = 20.0
"""Variance of the Laplacian under which a frame is blurred (or featureless)."""


@dataclass
class Ingested:
    """What ingestion wrote, as recorded in ingest.json."""

    source: str
    fps: float
    frames: int
    input_width: int
    input_height: int
    crop: dict
    dark: list[bool]
    overexposed: list[bool]
    blurred: list[bool]
    decode_warning: str | None = None
    fisheye_fov_deg: float | None = None

    @property
    def usable(self) -> np.ndarray:
        return ~(np.array(self.dark) | np.array(self.overexposed) | np.array(self.blurred))

    def save(self, path: Path) -> None:
        write_json(path, asdict(self))

    @classmethod
    def load(cls, path: Path) -> Ingested:
        return cls(**json.loads(Path(path).read_text()))


@dataclass
class _Source:
    name: str
    fps: float
    open: Callable[[], Iterator[np.ndarray]]
    """A fresh iterator over the RGB frames."""
    count_hint: int
    """The container's frame count (0 if unknown)."""
    region: np.ndarray | None = None


@dataclass
class Scanned:
    """An input read once: its frames counted, its image region and the region's box."""

    source: _Source
    count: int
    region: np.ndarray
    """(H, W) bool at the input's size."""
    crop: Crop


def scan(path: Path, region: np.ndarray | None = None, fps: float | None = None,
         progress: bool = False) -> Scanned:
    """Pass 1 over an input: count its frames and find its image region (`region`, in input
    pixels, when given)."""
    source = _open(Path(path), fps, region)
    first_pass = tqdm(source.open(), total=source.count_hint or None, unit="frame",
                      desc=f"scan {Path(path).name}", disable=not progress)
    brightest, count, shape = None, 0, None
    for frame in first_pass:
        if shape is None:
            shape = frame.shape
        elif frame.shape != shape:
            raise InputError(f"{path}: frame {count} is {frame.shape}, the first was {shape}")
        grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
        brightest = grey if brightest is None else np.maximum(brightest, grey)
        count += 1
    if count == 0:
        raise InputError(f"{path}: no frames could be decoded (empty or corrupt video)")
    if count < 2:
        raise InputError(f"{path}: only 1 frame; C2D2 needs a video")
    if region is None:
        try:
            region = source.region if source.region is not None else detect_region(
                [np.repeat(brightest[..., None], 3, axis=2)])
        except InputError as err:
            raise InputError(f"{path}: {err}") from err
    return Scanned(source, count, region, Crop.of(region, shape, str(path)))


def sampled(scanned: Scanned, size: tuple[int, int], indices: Iterable[int]) -> FrameSequence:
    """Frames `indices` (and the first) of a scanned input, cut to its image region and
    resized to `size`, read once more as far as the last of them: a FrameSequence of the
    input's length, of which only those frames can be read."""
    wanted = {0, *indices}
    frames: dict[int, np.ndarray] = {}
    for index, frame in enumerate(scanned.source.open()):
        if index in wanted:
            frames[index] = scanned.crop.fit(frame, size, cv2.INTER_AREA)
        if len(frames) == len(wanted):
            break
    if len(frames) != len(wanted):
        raise InputError(f"{scanned.source.name}: the second reading ended before frame "
                         f"{min(wanted - frames.keys())} of the {scanned.count} the first "
                         f"counted; the file changed or decodes unreliably: copy or re-encode it")
    return FrameSequence(scanned.source.name, scanned.source.fps, size, frames.__getitem__,
                         scanned.count, region=scanned.crop.fit_region(scanned.region, size),
                         crop=scanned.crop)


def ingest(path: Path, size: tuple[int, int], frames_out: Path, region: np.ndarray | None = None,
           fps: float | None = None, progress: bool = False,
           fisheye_fov_deg: float | None = None) -> tuple[Ingested, np.ndarray]:
    """Write frames_out (N, H, W, 3) uint8 and return the record and the region at (H, W)."""
    scanned = scan(path, region, fps, progress)
    source, count, region, crop = scanned.source, scanned.count, scanned.region, scanned.crop
    small_region = crop.fit_region(region, size)  # of the frames as recorded: their flags
    to_pinhole, written_region = None, small_region
    if fisheye_fov_deg is not None:  # at the input's resolution, before the resize
        lens = equidistant(fisheye_fov_deg, crop.width, crop.height)
        to_pinhole = resampling_maps(lens, pinhole_twin(lens, WIDEST_DEG))
        written_region = crop.fit_region(region, size, to_pinhole)
    # The Laplacian at the region's edge reads the step to the black border, also where the
    # region meets the frame's edge: keep it out.
    sharpness_region = cv2.erode(small_region.astype(np.uint8), np.ones((5, 5), np.uint8),
                                 borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    if not sharpness_region.any():
        raise InputError(f"{path}: the image region is {int(small_region.sum())} pixels at the "
                         f"networks' size {size}, too thin to judge the frames by; give a mask "
                         f"(--mask) that covers the image, filled")
    stack = NpyWriter(frames_out, (count, *size, 3), np.uint8)
    dark, bright, blurred = [], [], []
    try:
        for index, frame in enumerate(tqdm(source.open(), total=count, unit="frame",
                                           desc=f"ingest {Path(path).name}",
                                           disable=not progress)):
            if index == count:
                break
            small = crop.fit(frame, size, cv2.INTER_AREA)
            if to_pinhole is None:
                stack[index:index + 1] = small[None]
            else:  # its edge was continued beyond the lens's reach
                pinhole = crop.fit(frame, size, cv2.INTER_AREA, to_pinhole)
                pinhole[~written_region] = 0
                stack[index:index + 1] = pinhole[None]
            grey = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)
            inside = grey[small_region]
            dark.append(bool(inside.mean() < DARK_GREY))
            bright.append(bool((inside > 245).mean() > OVEREXPOSED_FRACTION))
            blurred.append(bool(cv2.Laplacian(grey, cv2.CV_64F)[sharpness_region].var()
                                < BLUR_VARIANCE))
        if len(dark) != count:
            raise InputError(f"{path}: the second reading gave {len(dark)} frames, the first "
                             f"{count}; the file changed or decodes unreliably: copy or "
                             f"re-encode it")
    except BaseException:
        stack.discard()
        raise
    stack.close()
    warning = None
    if source.count_hint > count:
        # FFmpeg skips undecodable frames and goes on, so the lost ones may be anywhere.
        warning = (f"{source.count_hint - count} of the {source.count_hint} frames the "
                   f"container declares could not be decoded (corrupt video) and are missing; "
                   f"frames after a damaged part are up to "
                   f"{(source.count_hint - count) / source.fps:.1f} s early")
    record = Ingested(source.name, source.fps, count, crop.input_width, crop.input_height,
                      asdict(crop), dark, bright, blurred, warning, fisheye_fov_deg)
    return record, written_region


def _open(path: Path, fps: float | None, region: np.ndarray | None) -> _Source:
    check_fps(fps)
    if not path.exists():
        raise InputError(f"input not found: {path}")
    if is_procedure(path, fps, region):
        from hybrid.dataset import Procedure

        proc = Procedure.open(path)
        frames = range(proc.num_frames)
        return _Source(str(path), proc.camera.fps, lambda: map(proc.rgb, frames),
                       proc.num_frames, proc.region)
    if path.is_dir():
        files = image_files(path)
        return _Source(str(path), fps or IMAGE_FOLDER_FPS, lambda: map(read_image, files),
                       len(files))
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise InputError(f"{path}: not a video ({', '.join(sorted(VIDEO_SUFFIXES))}), a folder "
                         f"of images or a simulated procedure")
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise InputError(f"cannot open video {path}: unreadable or not a video")
    rate = fps or capture.get(cv2.CAP_PROP_FPS)
    count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
    capture.release()
    if not rate or not np.isfinite(rate) or rate <= 0:
        raise InputError(f"{path}: the video declares no frame rate; give one with `c2d2 run "
                         f"--fps`")
    return _Source(str(path), float(rate), lambda: _decode(path), max(count, 0))


def _decode(path: Path) -> Iterator[np.ndarray]:
    capture = cv2.VideoCapture(str(path))
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                return
            yield cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
    finally:
        capture.release()


