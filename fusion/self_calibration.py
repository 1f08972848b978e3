"""The focal length from the video alone: structure from motion on short stretches of frames.

The depth network's intrinsics head hardly follows the camera (`docs/depth.md`). pycolmap's
bundle adjustment recovers f within a few percent wherever it maps a stretch of consecutive
frames well, but some stretches map with f far off. So up to `windows` evenly spaced,
non-overlapping stretches of `length` consecutive frames are mapped, each on its own
(`fusion.sfm_baseline.run_sfm`, frames as the network sees them with their lightness
equalised by CLAHE, and the image region as the camera mask). A stretch is *mapped* when the
mapper places at least `min_registered` of its frames and its f gives a field of view of at
least `min_field_of_view` (an endoscope is wide-angle). The estimate needs a
consensus: the largest group of mapped stretches whose focal lengths all lie within
`agreement` of each other (largest over smallest) must hold at least `min_agreeing` of them;
K is then that group's median f, with the principal point at the image centre. Otherwise
there is no estimate. Each stretch also keeps figures of its map's quality and of the
camera's motion, which need no ground truth (`Stretch`).

Mapped with COLMAP's one-coefficient fisheye camera instead (`camera_model`), the stretches
tell the lens (`SelfCalibration.lens`): a ray θ off the axis lands f (θ + k θ³) from the
centre, so an equidistant fisheye reads k near 0 and a pinhole, f tan θ, k near 1/3 or more
(`docs/depth.md`, "Telling the lens from the video"). The consensus is then the mapped
stretches that read as a pinhole, or the largest group of those that read as a fisheye whose
angles across the width agree, whichever holds more (neither when they hold as many).
"""

from __future__ import annotations

import json
import logging
import tempfile
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from functools import partial
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from tqdm import tqdm

from fusion.sfm_baseline import CAMERA_MODEL, FISHEYE_MODEL, NoModel, run_sfm
from hybrid import LOG_FORMAT
from hybrid.types import InputError

if TYPE_CHECKING:
    from learned.frames import FrameSequence

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SelfCalibrationConfig:
    """How the stretches are laid out and when their focal lengths make an estimate."""

    windows: int = 5
    """Most stretches mapped, evenly spaced over the input without overlapping."""
    length: int = 120
    """Consecutive frames per stretch (4 s at 30 fps)."""
    min_registered: float = 0.5
    """Fraction of a stretch's frames the mapper must place for the stretch to be mapped."""
    agreement: float = 0.15
    """Most relative spread (largest f over smallest, minus 1) of a group that agrees."""
    min_agreeing: int = 2
    """Agreeing stretches needed for an estimate (so a video shorter than min_agreeing *
    length frames gets none, and is not mapped at all)."""
    contrast: float = 3.0
    """Clip limit of the contrast-limited adaptive histogram equalisation (CLAHE) of each
    frame's lightness before SIFT, on `contrast_tiles` x `contrast_tiles` tiles; 0 maps the
    frames as they are. Dim, blurred, noisy frames (the simulator's dusk style) give SIFT too
    little contrast to map otherwise."""
    contrast_tiles: int = 4
    min_field_of_view: float = 60.0
    """Narrowest field of view (degrees, the wider of the two across the frames as given, so
    that a crop's orientation does not matter) of a stretch that counts as mapped.
    Colonoscopes are built wide-angle (140-170 degrees by their makers' specifications); 60
    still admits a crop of 21% of the width of a 140-degree pinhole image (of about half a
    140-degree fisheye image's, which the mapper's pinhole camera reads at about 100). The
    simulator's cameras span 90-130; the real clip's stretches mapped at 12-53
    (`docs/depth.md`, "Real footage")."""
    initial_field_of_view: float = 0.0
    """Field of view (degrees, across the frames' longer side) of the camera each stretch's
    mapper starts from, before bundle adjustment refines f; 0 starts from COLMAP's default,
    f = 1.2 x the longer side (45 degrees)."""
    highlights: bool = False
    """Keep SIFT off each frame's specular highlights (`highlight_free`): they slide over
    the wall as the light moves with the camera, so features on them break the static scene
    the mapper assumes."""
    camera_model: str = CAMERA_MODEL
    """The mapper's camera: `CAMERA_MODEL` (a pinhole: the focal length, `SelfCalibration.K`)
    or `FISHEYE_MODEL` (the lens, `SelfCalibration.lens`; it needs initial_field_of_view,
    taken through an equidistant lens)."""

    def __post_init__(self):
        if (not 1 <= self.min_agreeing <= self.windows or self.length < 2
                or not 0 < self.min_registered <= 1 or not self.agreement > 0
                or not self.contrast >= 0 or self.contrast_tiles < 1
                or not 0 <= self.min_field_of_view < 180
                or not 0 <= self.initial_field_of_view < 180
                or self.camera_model not in (CAMERA_MODEL, FISHEYE_MODEL)
                or (self.camera_model == FISHEYE_MODEL and not self.initial_field_of_view)):
            raise InputError(f"self-calibration needs 1 <= min_agreeing <= windows, length >= 2,"
                             f" 0 < min_registered <= 1, agreement > 0, contrast >= 0, "
                             f"contrast_tiles >= 1, min_field_of_view and "
                             f"initial_field_of_view in [0, 180), and camera_model "
                             f"{CAMERA_MODEL} or {FISHEYE_MODEL} (this one with an "
                             f"initial_field_of_view), got {self}")


@dataclass(frozen=True)
class Stretch:
    """What the mapper made of one stretch."""

    start: int
    frames: int
    registered: float
    """Fraction of the stretch's frames placed (0 when no model was built)."""
    fx: float | None
    """At the network's size; None when no model was built."""
    reprojection_error: float | None = None
    """Mean reprojection error of the map, in px of the square-pixel images given to the
    mapper. This and the three figures below are None when no model was built, and in records
    made before they were kept."""
    points: int | None = None
    """3D points of the map."""
    track_length: float | None = None
    """Mean number of frames that observe a point of the map."""
    turn: float | None = None
    """The largest angle between the viewing axis of the first placed frame and another's
    (degrees). Without such a turn f is undetermined: scaling f and the sideways coordinates
    of every point and camera by reciprocal factors changes no image (a roll about the viewing
    axis does not help either)."""
    k: float | None = None
    """The fisheye camera's coefficient (`SelfCalibrationConfig.camera_model`); None under the
    pinhole camera and when no model was built."""


FISHEYE_BELOW = 0.2
"""A stretch mapped with the fisheye camera whose k is below this reads as an equidistant
fisheye, one at or above it as a pinhole: between the one's 0 and the other's 1/3 or more
(measured: |k| <= 0.07 on 36 fisheye stretches, k > 0.45 on 28 pinhole ones, `docs/depth.md`,
"Telling the lens from the video"; but on dim video two fisheye stretches read 0.33 and 0.40,
`docs/pipeline.md`, "Telling the lens from the video: `--find-lens`")."""


def half_angle(model: str, ratio: float, k: float = 0.0) -> float:
    """Radians off the axis of a ray that lands `ratio` focal lengths from the centre: through
    a pinhole, arctan(ratio); through the fisheye, the smallest positive root θ of θ + k θ³ =
    ratio (NaN without one, as for k < 0 far out)."""
    if model == CAMERA_MODEL:
        return float(np.arctan(ratio))
    roots = np.roots([k, 0.0, 1.0, -ratio]) if k else np.array([ratio])
    real = [r.real for r in roots if abs(r.imag) < 1e-9 and r.real > 0]
    return float(min(real)) if real else float("nan")


@dataclass(frozen=True)
class FoundLens:
    """The lens the fisheye camera's stretches agree on."""

    model: str
    """'equidistant' or 'pinhole' (`hybrid.types.Camera.model`)."""
    width_deg: float
    """Degrees across the frames' width: the agreeing stretches' median (for a pinhole, a
    loose reading the run does not use)."""


@dataclass(frozen=True)
class SelfCalibration:
    """The stretches of one input as mapped, and the K (under the fisheye camera, the lens)
    their consensus gives."""

    frames: int
    """Frames of the input."""
    stretches: list[Stretch]
    config: SelfCalibrationConfig
    size: tuple[int, int]
    """(H, W) of the frames."""
    fy_over_fx: float
    """fy / fx of the frames (the mapper's fx scaled by the frames' pixel aspect)."""

    @property
    def placed(self) -> list[Stretch]:
        """Stretches that built a model placing at least `min_registered` of their frames."""
        return [s for s in self.stretches
                if s.fx is not None and s.registered >= self.config.min_registered]

    @property
    def mapped(self) -> list[Stretch]:
        """Placed stretches whose fx gives a field of view of at least `min_field_of_view`."""
        return [s for s in self.placed
                if self.field_of_view(s) >= self.config.min_field_of_view]

    def field_of_view(self, stretch: Stretch) -> float:
        """Field of view (degrees) of a stretch that built a model, the wider of the horizontal
        and the vertical."""
        height, width = self.size
        ratio = max(width / 2 / stretch.fx, height / 2 / (stretch.fx * self.fy_over_fx))
        return float(np.degrees(2 * half_angle(self.config.camera_model, ratio,
                                               stretch.k or 0.0)))

    def width_angle(self, stretch: Stretch) -> float:
        """Degrees across the frames' width of a stretch that built a model."""
        return float(np.degrees(2 * half_angle(self.config.camera_model,
                                               self.size[1] / 2 / stretch.fx, stretch.k or 0.0)))

    def lens_of(self, stretch: Stretch) -> str:
        """'equidistant' or 'pinhole': what a stretch mapped with the fisheye camera reads as
        (`FISHEYE_BELOW`)."""
        return "equidistant" if stretch.k < FISHEYE_BELOW else "pinhole"

    def _largest_group(self, stretches: list[Stretch], value: Callable[[Stretch], float]
                       ) -> list[Stretch]:
        """The largest group of `stretches` whose values lie within `agreement` of each
        other (of equal groups, the tightest), in order of their start."""
        ranked = sorted(stretches, key=value)
        best: list[Stretch] = []
        for i, low in enumerate(ranked):
            group = [s for s in ranked[i:] if value(s) <= value(low) * (1 + self.config.agreement)]
            if len(group) > len(best) or (len(group) == len(best) and value(group[-1]) / value(low)
                                          < value(best[-1]) / value(best[0])):
                best = group
        return sorted(best, key=lambda s: s.start)

    @property
    def agreeing(self) -> list[Stretch]:
        """The largest group of mapped stretches whose fx lie within `agreement` of each
        other. Under the fisheye camera, the larger (none when they are as large) of the
        mapped stretches that read as a pinhole and the largest group of those that read as a
        fisheye whose angles across the width agree: the run resamples a fisheye at its angle,
        but reads a pinhole as it is, and the fisheye camera fits a pinhole's angle loosely
        (99 to 152 degrees over the stretches of `data/heldout`'s proc_0007, truly 114.6:
        `docs/fisheye/find_lens.txt`)."""
        if self.config.camera_model == CAMERA_MODEL:
            return self._largest_group(self.mapped, lambda s: s.fx)
        fisheye = self._largest_group([s for s in self.mapped
                                       if self.lens_of(s) == "equidistant"], self.width_angle)
        pinhole = [s for s in self.mapped if self.lens_of(s) == "pinhole"]
        return [] if len(fisheye) == len(pinhole) else max(fisheye, pinhole, key=len)

    @property
    def K(self) -> np.ndarray | None:
        """(3, 3) at the frames' size under the pinhole camera; None without a consensus."""
        if self.config.camera_model != CAMERA_MODEL:
            raise ValueError(f"stretches mapped with {self.config.camera_model} give a lens, "
                             f"not a K")
        if len(self.agreeing) < self.config.min_agreeing:
            return None
        fx = float(np.median([s.fx for s in self.agreeing]))
        height, width = self.size
        return np.array([[fx, 0, (width - 1) / 2], [0, fx * self.fy_over_fx, (height - 1) / 2],
                         [0, 0, 1]])

    @property
    def lens(self) -> FoundLens | None:
        """The lens under the fisheye camera; None without a consensus."""
        if self.config.camera_model != FISHEYE_MODEL:
            raise ValueError(f"stretches mapped with {self.config.camera_model} give a K, not "
                             f"a lens")
        agreeing = self.agreeing
        if len(agreeing) < self.config.min_agreeing:
            return None
        return FoundLens(self.lens_of(agreeing[0]),
                         float(np.median([self.width_angle(s) for s in agreeing])))

    def describe(self) -> str:
        """One line: what the estimate is, or why there is none, and every stretch."""
        if len(self.stretches) < self.config.min_agreeing:
            return (f"{self.frames} frames hold fewer than {self.config.min_agreeing} "
                    f"stretches of {self.config.length}: not mapped")
        if self.config.camera_model == CAMERA_MODEL:
            K = self.K
            head = ("no consensus" if K is None else
                    f"fx {K[0, 0]:.1f}, fy {K[1, 1]:.1f} at the network's size")
            seen = [(s.start, round(s.registered, 2), s.fx and round(s.fx, 1))
                    for s in self.stretches]
            listed = "first frame, fraction placed, fx"
        else:
            lens = self.lens
            head = ("no consensus" if lens is None else
                    f"{lens.model}, {lens.width_deg:.0f} degrees across the width")
            seen = [(s.start, round(s.registered, 2)) + (() if s.fx is None else (
                round(s.k, 3), _rounded(self.width_angle(s)))) for s in self.stretches]
            listed = "first frame, fraction placed, k, degrees across the width"
        views = {s.start: self.field_of_view(s) for s in self.placed}
        narrow = [start for start, view in views.items()
                  if view < self.config.min_field_of_view]
        if narrow:
            head += (f"; the stretches from frames {narrow} mapped at a field of view under "
                     f"{self.config.min_field_of_view:g} degrees, too narrow for an endoscope, "
                     f"and do not count")
        if unseen := [start for start, view in views.items() if not np.isfinite(view)]:
            head += (f"; the stretches from frames {unseen} mapped with a k that sends no ray "
                     f"to the frames' edge, and do not count")
        return f"{head} (per stretch: {listed}: {seen})"

    @classmethod
    def from_record(cls, record: dict, config: SelfCalibrationConfig | None = None
                    ) -> SelfCalibration:
        """Back from `record()`, under its own config or another one (the stretches as
        mapped; nothing is mapped again)."""
        if config is None:
            config = config_of_record(record)
        elif config.camera_model != config_of_record(record).camera_model:
            raise ValueError(f"a record of stretches mapped with "
                             f"{config_of_record(record).camera_model} read as mapped with "
                             f"{config.camera_model}")
        return cls(record["frames"], [Stretch(**s) for s in record["stretches"]], config,
                   tuple(record["size"]), record["fy_over_fx"])

    def record(self) -> dict:
        """JSON-ready: the config, the frames' size and aspect, every stretch, which were
        mapped and agreed, and the K (network size) or under the fisheye camera the lens
        (None without a consensus)."""
        if self.config.camera_model == CAMERA_MODEL:
            K = self.K
            found = {"K": None if K is None else K.tolist()}
        else:
            lens = self.lens
            found = {"lens": None if lens is None else asdict(lens)}
        return {"config": asdict(self.config), "frames": self.frames, "size": list(self.size),
                "fy_over_fx": self.fy_over_fx, "stretches": [asdict(s) for s in self.stretches],
                "mapped": [s.start for s in self.mapped],
                "agreeing": [s.start for s in self.agreeing], **found}


FIELDS_ADDED = {"contrast": 0.0, "min_field_of_view": 0.0, "highlights": False,
                "initial_field_of_view": 0.0, "camera_model": CAMERA_MODEL}
"""Fields added to SelfCalibrationConfig since records were first kept, each with the value
that gives what records made before it did (no contrast step, no bound, no masks, COLMAP's
start, a pinhole)."""


def config_of_record(record: dict) -> SelfCalibrationConfig:
    """The config a `SelfCalibration.record()` was made under, fields added since included."""
    return SelfCalibrationConfig(**{**FIELDS_ADDED, **record["config"]})


def eval_records(paths: list[Path]) -> dict[str, dict]:
    """The stretches' records (`SelfCalibration.record`) in JSONs of `c2d2 eval-depth
    --self-calibrate`, pooled, by input name ('folder/procedure'); a name in two of them is
    refused."""
    found: dict[str, dict] = {}
    for path in paths:
        for name, record in json.loads(Path(path).read_text())["self_calibration"].items():
            if name in found:
                raise InputError(f"{name}: in more than one of {', '.join(map(str, paths))}")
            found[name] = record
    return found


def calibrate_sequence(seq: FrameSequence,
                       config: SelfCalibrationConfig = SelfCalibrationConfig(),
                       progress: bool = False, workers: int = 1) -> SelfCalibration:
    """self_calibrate on a learned.frames.FrameSequence (the frames as the network sees them)."""
    return self_calibrate(seq.frame, seq.num_frames, seq.region, seq.name, seq.pixel_aspect,
                          config, progress, workers)


def stretch_spans(count: int, config: SelfCalibrationConfig) -> list[range]:
    """The frames of each stretch mapped (`stretch_starts`): none when fewer than
    min_agreeing fit, as no consensus is then possible."""
    starts = stretch_starts(count, config)
    if len(starts) < config.min_agreeing:
        return []
    return [range(start, min(start + config.length, count)) for start in starts]


def stretch_starts(count: int, config: SelfCalibrationConfig) -> list[int]:
    """First frames of the stretches: as many as fit without overlapping (at most `windows`,
    at least one, of the whole input when it is shorter than `length`), evenly spaced."""
    n = min(config.windows, max(count // config.length, 1))
    return [int(s) for s in np.linspace(0, max(count - config.length, 0), n).round()]


def self_calibrate(frame: Callable[[int], np.ndarray], count: int, region: np.ndarray,
                   name: str, pixel_aspect: float = 1.0,
                   config: SelfCalibrationConfig = SelfCalibrationConfig(),
                   progress: bool = False, workers: int = 1) -> SelfCalibration:
    """Map each stretch of the `count` frames, up to `workers` at once.

    frame(i): RGB uint8 (H, W, 3) at the network's size; region: (H, W) bool image region;
    pixel_aspect: fy / fx of the frames; each frame is first enlarged to square pixels
    (`SquarePixels`), and f is scaled back along each axis. With workers > 1 the stretches are
    mapped in spawned processes of one thread each, which gives what one process gives (the
    mapper in two threads of one process does not: `fusion.sfm_baseline._map`).
    """
    height, width = region.shape
    square = SquarePixels((height, width), pixel_aspect)
    mask = square.mask(region)
    spans = stretch_spans(count, config)

    def stretch(ids: range) -> partial:
        """The mapping of one stretch, ready to run here or in a worker."""
        frames = [frame(i) for i in ids]
        kept = ([square.mask(region & highlight_free(f)) for f in frames] if config.highlights
                else None)
        return partial(_map_stretch, ids, [square(contrast_enhanced(f, config)) for f in frames],
                       mask, kept, f"{name} frames {ids.start}-{ids.stop - 1}", square.scale[0],
                       config.initial_field_of_view or None, config.camera_model)

    bar = {"desc": f"self-calibrate {name}", "disable": not progress, "unit": "stretch"}
    if workers > 1 and len(spans) > 1:
        with ProcessPoolExecutor(min(workers, len(spans)), get_context("spawn"),
                                 initializer=_start_mapper,
                                 initargs=(logging.getLogger().level,)) as pool:
            jobs = [pool.submit(stretch(ids)) for ids in spans]
            try:
                found = [job.result() for job in tqdm(jobs, **bar)]
            except BaseException:  # an error: do not map the stretches still waiting
                pool.shutdown(cancel_futures=True)
                raise
    else:
        found = [stretch(ids)() for ids in tqdm(spans, **bar)]
    return SelfCalibration(count, found, config, (height, width), square.fy_over_fx)


def _start_mapper(log_level: int) -> None:
    """A spawned mapping process logs as its parent does."""
    logging.basicConfig(level=log_level, format=LOG_FORMAT)


def _map_stretch(ids: range, images: list[np.ndarray], mask: np.ndarray,
                 frame_masks: list[np.ndarray] | None, name: str, scale: float,
                 initial_field_of_view: float | None, camera_model: str) -> Stretch:
    """One stretch as mapped; `scale` takes the mapper's f to the network's size."""
    with tempfile.TemporaryDirectory() as work:
        try:
            sfm = run_sfm(images, mask, Path(work), name, frame_masks, initial_field_of_view,
                          camera_model)
        except NoModel as err:  # this stretch is not mapped
            log.info("%s", err)
            return Stretch(ids.start, len(ids), 0.0, None)
    k = float(sfm.camera_params[3]) if camera_model == FISHEYE_MODEL else None
    return Stretch(ids.start, len(ids), float(sfm.registered.mean()), float(sfm.K[0, 0]) * scale,
                   sfm.reprojection_error, sfm.points, sfm.track_length,
                   _turn(sfm.poses[sfm.registered]), k)


def _rounded(degrees: float) -> int | None:
    """Degrees to the nearest whole one, None for NaN."""
    return round(degrees) if np.isfinite(degrees) else None


def _turn(poses: np.ndarray) -> float:
    """Stretch.turn of (N, 4, 4) camera-to-world poses, N >= 1."""
    axes = poses[:, :3, 2]
    return float(np.degrees(np.arccos(np.clip(axes[1:] @ axes[0], -1, 1))).max(initial=0))


@dataclass(frozen=True)
class SquarePixels:
    """Frames of `size` (H, W) whose pixels have the aspect `pixel_aspect` (fy / fx, not 1
    where the network's resize stretched the two axes of a crop with square pixels
    differently), enlarged along one axis to square pixels for the mapper, whose camera has
    square pixels (a smaller image maps fewer of its frames)."""

    size: tuple[int, int]
    pixel_aspect: float

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) of the enlarged frames."""
        height, width = self.size
        return (round(height * max(1 / self.pixel_aspect, 1.0)),
                round(width * max(self.pixel_aspect, 1.0)))

    @property
    def scale(self) -> tuple[float, float]:
        """Frame pixels per enlarged pixel along x and y (f and pixel coordinates back)."""
        (height, width), (rows, columns) = self.size, self.shape
        return width / columns, height / rows

    @property
    def fy_over_fx(self) -> float:
        """fy / fx of the frames for a square-pixel f of the mapper."""
        return self.scale[1] / self.scale[0]

    def __call__(self, image: np.ndarray) -> np.ndarray:
        rows, columns = self.shape
        return image if self.shape == tuple(self.size) else cv2.resize(
            image, (columns, rows), interpolation=cv2.INTER_LINEAR)

    def mask(self, region: np.ndarray) -> np.ndarray:
        """The enlarged (H, W) bool image region."""
        return self(region.astype(np.uint8) * 255) > 127


def contrast_enhanced(image: np.ndarray, config: SelfCalibrationConfig) -> np.ndarray:
    """RGB uint8 with its lightness (CIELAB L) equalised by CLAHE (`config.contrast`; the
    image itself when 0)."""
    if not config.contrast:
        return image
    lab = cv2.cvtColor(image, cv2.COLOR_RGB2LAB)
    tiles = (config.contrast_tiles, config.contrast_tiles)
    lab[..., 0] = cv2.createCLAHE(config.contrast, tiles).apply(lab[..., 0])
    return cv2.cvtColor(lab, cv2.COLOR_LAB2RGB)


_HIGHLIGHT_SIZE = 9
"""Width in pixels of the white top-hat: highlights narrower than this stand out."""
_HIGHLIGHT_RISE = 30
"""Lightness (CIELAB L, 0-255) by which a highlight exceeds the top-hat's opening."""
_HIGHLIGHT_GLARE = 240
"""Lightness of glare, a highlight of any width."""
_HIGHLIGHT_GROW = 2
"""Pixels by which highlights are grown, so that no SIFT feature sits on their edges."""


def highlight_free(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: False on the specular highlights of an RGB uint8 frame: pixels whose
    white top-hat (lightness, lightly smoothed, minus its opening by a disk of
    `_HIGHLIGHT_SIZE` px) exceeds `_HIGHLIGHT_RISE`, or whose lightness exceeds
    `_HIGHLIGHT_GLARE`, grown by `_HIGHLIGHT_GROW` px."""
    lightness = cv2.cvtColor(cv2.GaussianBlur(image, (3, 3), 0), cv2.COLOR_RGB2LAB)[..., 0]
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (_HIGHLIGHT_SIZE,) * 2)
    rise = cv2.morphologyEx(lightness, cv2.MORPH_TOPHAT, disk)
    bright = ((rise > _HIGHLIGHT_RISE) | (lightness > _HIGHLIGHT_GLARE)).astype(np.uint8)
    grow = np.ones((2 * _HIGHLIGHT_GROW + 1,) * 2, np.uint8)
    return cv2.dilate(bright, grow) == 0
