"""Frame sequences at the network's size: simulated procedures, image folders, videos.

Real endoscope frames carry a black border (circular or octagonal mask, overlays). The image
region is detected from the frames (pixels that are ever bright: 24 sampled images of a
folder, every frame of a video), the frames are cropped to its bounding box and resized; the
region becomes a mask so that losses ignore the border. The networks read each frame with its
border filled by the nearest pixels inside (`FrameSequence.network_frame`): they learned on
the simulator's whole images. `Crop` maps intrinsics back to the input's own pixels. A video
is streamed into a temporary file of network-sized frames.
"""

from __future__ import annotations

import logging
import math
import os
import re
import shutil
import tempfile
import weakref
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.ndimage import distance_transform_edt

from hybrid.lens import resample, resample_mask
from hybrid.types import Camera, InputError

log = logging.getLogger(__name__)

VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".mpg", ".mpeg", ".webm", ".m4v", ".wmv"}
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}
IMAGE_FOLDER_FPS = 30.0
"""The frame rate a folder of images is read at unless one is given (it carries none)."""
_DARK = 20
"""Grey level (0-255) below which a pixel that is never brighter belongs to the border."""


@dataclass(frozen=True)
class Crop:
    """The image region's bounding box in input pixels, and the input size."""

    x0: int
    y0: int
    width: int
    height: int
    input_width: int
    input_height: int

    @classmethod
    def of(cls, region: np.ndarray, shape: tuple[int, ...], name: str) -> Crop:
        """The bounding box of an input's image region, a non-empty bool mask of the frame
        size `shape` (H, W[, 3]), or an InputError naming `name`."""
        if region.shape != tuple(shape[:2]):
            raise InputError(f"{name}: the image region must be a mask of the frame size "
                             f"{tuple(shape[:2])}, got {region.shape}")
        if not region.any():
            raise InputError(f"{name}: the image region is empty: it shows no pixel of the "
                             f"frame")
        ys, xs = np.nonzero(region)
        return cls(int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1),
                   int(ys.max() - ys.min() + 1), region.shape[1], region.shape[0])

    def cut(self, image: np.ndarray) -> np.ndarray:
        """An input-sized image cut to the box."""
        return image[self.y0:self.y0 + self.height, self.x0:self.x0 + self.width]

    def fit(self, image: np.ndarray, size: tuple[int, int], interpolation: int,
            lens: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """An input-sized image cut to the box, resampled by `lens` (hybrid.lens maps of the
        box's size, for a fisheye video) when given, and resized to size (H, W)."""
        cut = self.cut(image) if lens is None else resample(self.cut(image), lens)
        return cv2.resize(cut, (size[1], size[0]), interpolation=interpolation)

    def fit_region(self, region: np.ndarray, size: tuple[int, int],
                   lens: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """The image region cut, resampled and resized like the frames, nearest by pixel
        centres (plain INTER_NEAREST samples the top-left of each cell, which moves the region
        by up to a pixel against the INTER_AREA frames)."""
        cut = self.cut(region) if lens is None else resample_mask(self.cut(region), lens)
        return cv2.resize(cut.astype(np.uint8), (size[1], size[0]),
                          interpolation=cv2.INTER_NEAREST_EXACT).astype(bool)

    def camera_to_input(self, camera: Camera) -> Camera:
        """Intrinsics of the network-sized crop expressed in the input's pixels."""
        full = camera.resized(self.width, self.height)
        return Camera(self.input_width, self.input_height, full.fx, full.fy,
                      full.cx + self.x0, full.cy + self.y0, camera.fps)


NETWORK_INPUT = ("frames' border filled from the nearest pixels inside, the coverage input's "
                 "border the depth network's own")
"""How the networks read a frame's border (`FrameSequence.network_frame`, and
`learned.coverage_nets.normalise_depth` for the coverage networks), as work folders record it:
one made while they read it otherwise is not resumed on a bordered video."""


def nearest_inside(region: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns), each (H, W): for every pixel the nearest pixel of the (H, W) bool
    region (itself inside it), so that image[rows, columns] fills the border from within."""
    _, (rows, columns) = distance_transform_edt(~region, return_indices=True)
    return rows, columns


def detect_region(frames: list[np.ndarray]) -> np.ndarray:
    """(H, W) bool image region: pixels ever brighter than the border, largest component.

    frames: RGB uint8 frames sampled over the sequence.
    """
    brightest = np.max([cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames], axis=0)
    bright = (brightest > _DARK).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(bright, connectivity=8)
    if count <= 1:
        raise InputError("every frame is black: no image region found")
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    region = (labels == largest).astype(np.uint8)
    # Fill holes (dark lumen, overlays inside the region), then trim the soft edge.
    filled = region.copy()
    contours, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(filled, contours, -1, 1, thickness=cv2.FILLED)
    return cv2.erode(filled, np.ones((5, 5), np.uint8)).astype(bool)


class FrameSequence:
    """Frames of one video-like input, cropped to the image region and resized to (H, W)."""

    @classmethod
    def ingested(cls, name: str, record, frames: Path, region: np.ndarray) -> FrameSequence:
        """The frames that hybrid.ingest wrote to `frames` (cut to the image region and
        resized; `record` its Ingested), read back on demand; region at their size."""
        from hybrid.npyio import NpyRows

        return cls(name, record.fps, region.shape, NpyRows(frames).__getitem__, record.frames,
                   region=region, crop=Crop(**record.crop))

    def __init__(self, name: str, fps: float, size: tuple[int, int], loader, count: int,
                 region: np.ndarray | None = None, camera: Camera | None = None,
                 depth_loader=None, poses: np.ndarray | None = None, crop: Crop | None = None):
        """loader(i): frame i at the input's size, or, with `crop` given, already cut to that
        box of the input and resized to `size` (`region` then at `size`)."""
        if count < 2:
            raise InputError(f"{name}: needs at least 2 frames, found {count}")
        self.name, self.fps, self.size, self.num_frames = name, fps, size, count
        self._load = loader
        self._depth = depth_loader
        self.poses = poses
        self._fitted = crop is not None
        self._fill: tuple[np.ndarray, np.ndarray] | None = None
        self.camera = None if camera is None else camera.resized(size[1], size[0])
        first = loader(0)
        if first.ndim != 3 or first.shape[2] != 3:
            raise InputError(f"{name}: frames must be RGB with 3 channels, got shape {first.shape}")
        if self._fitted:
            if region is None or region.shape != tuple(size) or first.shape[:2] != tuple(size):
                raise InputError(f"{name}: fitted frames and region must be {size}")
            if depth_loader is not None:
                raise InputError(f"{name}: fitted frames come without ground-truth depth")
            self.crop, self.region = crop, region
            return
        picks = np.linspace(0, count - 1, min(count, 24)).round().astype(int)
        full_region = region if region is not None else detect_region([loader(i) for i in picks])
        self.crop = Crop.of(full_region, first.shape, name)
        self.region = self.crop.fit_region(full_region, size)

    @property
    def pixel_aspect(self) -> float:
        """fy / fx of the frames for an input with square pixels: not 1 where the resize from
        the crop to the network's size stretches the two axes differently."""
        return (self.size[0] / self.crop.height) / (self.size[1] / self.crop.width)

    def frame(self, index: int) -> np.ndarray:
        """RGB uint8 (H, W, 3) at network size."""
        image = self._load(index)
        return image if self._fitted else self.crop.fit(image, self.size, cv2.INTER_AREA)

    def network_frame(self, index: int) -> np.ndarray:
        """The frame as the depth and motion networks read it: outside the image region each
        pixel takes the colour of the nearest pixel inside. Black corners made the shipped
        coverage read 0.01 lower on the simulator's octagon views (docs/coverage.md, "The
        image region"); the losses still compare pixels inside the region only."""
        image = self.frame(index)
        if self.region.all():
            return image
        if self._fill is None:
            self._fill = nearest_inside(self.region)
        return image[self._fill]

    def depth(self, index: int) -> np.ndarray | None:
        """Ground-truth z-depth at network size (simulated inputs only)."""
        if self._depth is None:
            return None
        return self.crop.fit(self._depth(index), self.size, cv2.INTER_NEAREST_EXACT)


def check_fps(fps: float | None) -> None:
    """A frame rate given for an input must be a positive number (None: the input's own)."""
    if fps is not None and not 0 < fps < math.inf:
        raise InputError(f"--fps must be a positive number, got {fps}")


def image_files(path: Path) -> list[Path]:
    """The images of a folder in frame order: names compared with their runs of digits as
    numbers, so that 2.png comes before 10.png as it does before 010.png."""
    files = [p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
    if not files:
        raise InputError(f"{path}: no images ({', '.join(sorted(IMAGE_SUFFIXES))}) in folder")
    return sorted(files, key=lambda p: (_numbered(p.name), p.name))


def _numbered(name: str) -> list[str | int]:
    """A name split into text and runs of digits, the digits as numbers (re.split with a group
    alternates the two, so like parts meet like parts when names are compared)."""
    return [int(part) if i % 2 else part for i, part in enumerate(re.split(r"(\d+)", name))]


def open_sequence(path: Path, size: tuple[int, int], region: np.ndarray | None = None,
                  fps: float | None = None) -> FrameSequence:
    """A simulated procedure folder, a folder of images, or a video file.

    region: the image region in input pixels (bool); detected from the frames if None.
    fps: the frame rate of a video or image folder (None: the video's own; IMAGE_FOLDER_FPS
    for images).
    """
    path = Path(path)
    check_fps(fps)
    if not path.exists():
        raise InputError(f"input not found: {path}")
    if is_procedure(path, fps, region):
        return _simulated(path, size)
    if path.is_dir():
        return _image_folder(path, size, region, fps or IMAGE_FOLDER_FPS)
    if path.suffix.lower() in VIDEO_SUFFIXES:
        return _video(path, size, region, fps)
    raise InputError(f"{path}: not a video ({', '.join(sorted(VIDEO_SUFFIXES))}), a folder of "
                     f"images or a simulated procedure")


def is_procedure(path: Path, fps: float | None = None, region: np.ndarray | None = None
                 ) -> bool:
    """Whether `path` is a simulated procedure (a folder with rgb/ and camera.json); one given
    a frame rate or an image region is refused (it has its own of each)."""
    path = Path(path)
    if not (path.is_dir() and (path / "rgb").is_dir() and (path / "camera.json").is_file()):
        return False
    if region is not None:
        raise InputError(f"{path}: a simulated procedure has its own image region; drop the "
                         f"mask")
    if fps is not None:
        raise InputError(f"{path}: a simulated procedure has its own frame rate; drop --fps")
    return True


def _simulated(path: Path, size: tuple[int, int]) -> FrameSequence:
    from hybrid.dataset import Procedure

    proc = Procedure.open(path)
    return FrameSequence(str(path), proc.camera.fps, size, proc.rgb, proc.num_frames,
                         region=proc.region, camera=proc.camera, depth_loader=proc.depth,
                         poses=proc.poses)


def read_image(path: Path) -> np.ndarray:
    """An image file as RGB uint8 (grey, 16-bit and alpha images converted)."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(f"cannot read image {path}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _image_folder(path: Path, size: tuple[int, int], region: np.ndarray | None, fps: float
                  ) -> FrameSequence:
    files = image_files(path)
    shape = read_image(files[0]).shape

    def load(index: int) -> np.ndarray:
        image = read_image(files[index])
        if image.shape != shape:
            raise InputError(f"{path}: image {files[index].name} is {image.shape}, the first "
                             f"({files[0].name}) {shape}; the frames of a video share one size")
        return image

    return FrameSequence(str(path), fps, size, load, len(files), region=region)


def _video(path: Path, size: tuple[int, int], region: np.ndarray | None, fps: float | None
           ) -> FrameSequence:
    """Stream the video into a temporary file of network-sized frames, read back on demand, so
    that no frame is held at the video's own size (hybrid.ingest, as `c2d2 run` does)."""
    from hybrid.ingest import ingest  # it builds on this module

    folder = Path(tempfile.mkdtemp(prefix="c2d2-frames-"))
    try:
        record, small_region = ingest(path, size, folder / "frames.npy", region, fps)
        seq = FrameSequence.ingested(str(path), record, folder / "frames.npy", small_region)
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    weakref.finalize(seq, _remove_own, folder, os.getpid())
    if record.decode_warning:
        log.warning("%s: %s", path, record.decode_warning)
    return seq


def _remove_own(folder: Path, owner: int) -> None:
    """Delete a temporary folder, but only from the process that made it (not a fork)."""
    if os.getpid() == owner:
        shutil.rmtree(folder, ignore_errors=True)
