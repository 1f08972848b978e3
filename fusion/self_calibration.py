"""The focal length from the video alone: structure from motion on short windows of frames.

The depth network's intrinsics head hardly follows the camera (`docs/depth.md`). pycolmap's
bundle adjustment recovers f within a few percent wherever it maps a stretch of consecutive
frames, but one stretch in a few goes far off. So `windows` evenly spaced stretches of `length`
consecutive frames are mapped, each on its own (`fusion.sfm_baseline.run_sfm`, frames as the
network sees them, with the image region as the camera mask); a stretch counts when the mapper
places at least `min_registered` of its frames, and K is the median focal length over the
stretches that count, with the principal point at the image centre.
"""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from fusion.sfm_baseline import run_sfm
from hybrid.types import InputError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SelfCalibrationConfig:
    windows: int = 5
    """Stretches mapped, evenly spaced over the input."""
    length: int = 120
    """Consecutive frames per stretch (4 s at 30 fps)."""
    min_registered: float = 0.5
    """Fraction of a stretch's frames the mapper must place for its focal length to count."""

    def __post_init__(self):
        if self.windows < 1 or self.length < 2 or not 0 < self.min_registered <= 1:
            raise InputError(f"self-calibration needs windows >= 1, length >= 2 and "
                             f"0 < min_registered <= 1, got {self}")


@dataclass(frozen=True)
class WindowFocal:
    """What the mapper made of one stretch."""

    start: int
    frames: int
    registered: float
    """Fraction of the stretch's frames placed (0 when no model was built)."""
    focal: float | None
    """fx in the network's pixels, None when no model was built."""


@dataclass(frozen=True)
class SelfCalibration:
    K: np.ndarray | None
    """(3, 3) at the network's size; None when no stretch counts."""
    windows: list[WindowFocal]
    config: SelfCalibrationConfig

    @property
    def counted(self) -> list[float]:
        """The focal lengths that went into K."""
        return [w.focal for w in self.windows
                if w.focal is not None and w.registered >= self.config.min_registered]

    def record(self) -> dict:
        """JSON-ready summary: the focal lengths per stretch and which counted."""
        return {"config": asdict(self.config), "windows": [asdict(w) for w in self.windows],
                "counted": len(self.counted),
                "focal_spread_iqr": (float(np.subtract(*np.percentile(self.counted, [75, 25])))
                                     if self.counted else None)}


def calibrate_sequence(seq, config: SelfCalibrationConfig = SelfCalibrationConfig(),
                       progress: bool = False) -> SelfCalibration:
    """self_calibrate on a learned.frames.FrameSequence (the frames as the network sees them)."""
    return self_calibrate(seq.frame, seq.num_frames, seq.region, seq.name, seq.pixel_aspect,
                          config, progress)


def window_starts(num_frames: int, config: SelfCalibrationConfig) -> list[int]:
    """First frames of the stretches: evenly spaced, distinct, each of `length` frames (one
    stretch of the whole input when it is shorter)."""
    last = max(num_frames - config.length, 0)
    return sorted({int(s) for s in np.linspace(0, last, config.windows).round()})


def self_calibrate(frame: Callable[[int], np.ndarray], count: int, region: np.ndarray,
                   name: str, pixel_aspect: float = 1.0,
                   config: SelfCalibrationConfig = SelfCalibrationConfig(),
                   progress: bool = False) -> SelfCalibration:
    """Map each stretch of the `count` frames and take the median focal length of those that
    count.

    frame(i): RGB uint8 (H, W, 3) at the network's size; region: (H, W) bool image region;
    pixel_aspect: fy / fx of the frames (not 1 where the network's resize stretched the two
    axes of a crop with square pixels differently). The mapper's camera has square pixels, so each
    frame is first enlarged along one axis to square pixels (a smaller image maps fewer of
    its frames), and f is scaled back along each axis.
    """
    height, width = region.shape
    columns = round(width * max(pixel_aspect, 1.0))
    rows = round(height * max(1 / pixel_aspect, 1.0))

    def square(image: np.ndarray) -> np.ndarray:
        return image if (rows, columns) == (height, width) else cv2.resize(
            image, (columns, rows), interpolation=cv2.INTER_LINEAR)

    mask = square(region.astype(np.uint8) * 255) > 127
    found = []
    for start in tqdm(window_starts(count, config), desc=f"self-calibrate {name}",
                      disable=not progress, unit="stretch"):
        ids = range(start, min(start + config.length, count))
        with tempfile.TemporaryDirectory() as work:
            try:
                sfm = run_sfm([square(frame(i)) for i in ids], mask, Path(work),
                              name=f"{name} frames {ids.start}-{ids.stop - 1}")
            except InputError as err:  # no model from this stretch: it does not count
                log.info("%s", err)
                found.append(WindowFocal(start, len(ids), 0.0, None))
                continue
        found.append(WindowFocal(start, len(ids), float(sfm.registered.mean()),
                                 float(sfm.K[0, 0])))
    result = SelfCalibration(None, found, config)
    if not result.counted:
        return result
    f = float(np.median(result.counted))
    K = np.array([[f * width / columns, 0, (width - 1) / 2],
                  [0, f * height / rows, (height - 1) / 2], [0, 0, 1]])
    return SelfCalibration(K, found, config)
