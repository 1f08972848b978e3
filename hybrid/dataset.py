"""On-disk format of a simulated procedure, and its loader.

One folder per procedure:

    rgb/000000.png     RGB frames, 8-bit PNG (lossless)
    depth/000000.png   z-depth, 16-bit PNG: depth_cm = value * DEPTH_UNIT_CM, 0 = no surface
    camera.json        width, height, fx, fy, cx, cy (pixels), fps, model (pinhole, or
                       equidistant: `c2d2 simulate --fisheye`)
    poses.npy          (N, 4, 4) float64 camera-to-world poses, cm
    colon.ply          ground-truth mesh, cm
    lumen.npy          (M, 3) float64 centerline from the rectum end, cm
    coverage.json      ground-truth coverage (see hybrid.coverage.CoverageResult.to_json)
    meta.json          seed, style, preset, configs and package version
    region.png         the endoscope's image region (white inside), when it is not the whole
                       image (`c2d2 simulate --octagon`); black in the RGB frames outside it
    cache/             derived arrays, each rebuilt when missing (window labels, the
                       coverage networks' inputs)

A folder is written under a temporary name and renamed when complete, so a folder with the
final name is always whole.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np

from hybrid.coverage import CoverageResult, SurfaceMesh
from hybrid.types import Camera, InputError, check_poses, read_mask

DEPTH_UNIT_CM = 0.002
"""One step of the 16-bit depth PNGs: 20 µm, so the largest depth is 131 cm."""
REQUIRED_FILES = ("camera.json", "poses.npy", "colon.ply", "lumen.npy", "coverage.json",
                  "meta.json")
REGION_FILE = "region.png"


def window_labels_path(folder: Path, frames: int, stride: int) -> Path:
    """Where a procedure keeps the labels of its windows of `frames` frames every `stride`
    (CoverageResult.window_table): written by the simulator, or computed when first needed."""
    return Path(folder) / "cache" / f"windows-{frames}-{stride}.npy"


def frame_name(index: int) -> str:
    return f"{index:06d}.png"


def write_rgb(path: Path, rgb: np.ndarray) -> None:
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def write_depth(path: Path, depth_cm: np.ndarray) -> None:
    steps = np.round(depth_cm / DEPTH_UNIT_CM).clip(0, np.iinfo(np.uint16).max)
    cv2.imwrite(str(path), steps.astype(np.uint16))


def write_region(path: Path, region: np.ndarray) -> None:
    cv2.imwrite(str(path), region.astype(np.uint8) * 255)


def read_rgb(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(f"cannot read image {path}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def read_depth(path: Path) -> np.ndarray:
    steps = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if steps is None or steps.dtype != np.uint16:
        raise InputError(f"cannot read 16-bit depth image {path}")
    return steps.astype(np.float32) * DEPTH_UNIT_CM


@dataclass(frozen=True)
class Procedure:
    """A simulated procedure on disk; arrays are read when first used."""

    path: Path

    @classmethod
    def open(cls, path: Path) -> Procedure:
        path = Path(path)
        if not path.is_dir():
            raise InputError(f"{path} is a file, not a simulated procedure's folder" if
                             path.exists() else f"procedure folder not found: {path}")
        missing = [f for f in REQUIRED_FILES if not (path / f).is_file()]
        if missing:
            raise InputError(f"procedure folder {path} lacks {', '.join(missing)}; "
                             f"simulate it again with `c2d2 simulate`")
        return cls(path)

    @cached_property
    def camera(self) -> Camera:
        return Camera.load(self.path / "camera.json")

    @cached_property
    def region(self) -> np.ndarray:
        """(H, W) bool: the pixels the endoscope shows (region.png; all of them without it)."""
        shape = (self.camera.height, self.camera.width)
        if not (self.path / REGION_FILE).is_file():
            return np.ones(shape, dtype=bool)
        region = read_mask(self.path / REGION_FILE, "region")
        if region.shape != shape:
            raise InputError(f"{self.path / REGION_FILE}: expected a mask of the camera's size "
                             f"{shape}, got {region.shape}; simulate the procedure again with "
                             f"`c2d2 simulate`")
        # reaching every edge, the frames are not cropped, so camera.json stays their camera
        if not all(edge.any() for edge in (region[0], region[-1], region[:, 0], region[:, -1])):
            raise InputError(f"{self.path / REGION_FILE}: the image region must reach every "
                             f"edge of the image; simulate the procedure again with "
                             f"`c2d2 simulate`")
        return region

    @cached_property
    def poses(self) -> np.ndarray:
        return check_poses(self._read("poses.npy", np.load),
                           name=str(self.path / "poses.npy"))

    @cached_property
    def lumen(self) -> np.ndarray:
        return self._read("lumen.npy", np.load)

    @cached_property
    def coverage(self) -> CoverageResult:
        return self._read("coverage.json", lambda p: CoverageResult.from_json(
            json.loads(p.read_text())))

    @cached_property
    def meta(self) -> dict:
        return self._read("meta.json", lambda p: json.loads(p.read_text()))

    @property
    def style(self) -> str:
        """The appearance style it was rendered in (pink, dusk, nbi)."""
        return self._read("meta.json", lambda _: self.meta["config"]["style"])

    def _read(self, name: str, read):
        """read(path) of one of the folder's files, or an InputError naming it."""
        try:
            return read(self.path / name)
        except (ValueError, OSError, KeyError, TypeError) as err:  # JSONDecodeError included
            raise InputError(f"{self.path / name} cannot be read ({type(err).__name__}: {err}); "
                             f"simulate the procedure again with `c2d2 simulate`") from err

    @property
    def num_frames(self) -> int:
        return len(self.poses)

    def mesh(self) -> SurfaceMesh:
        return SurfaceMesh.load(self.path / "colon.ply")

    def rgb(self, index: int) -> np.ndarray:
        """Frame `index` as RGB uint8 (H, W, 3)."""
        return read_rgb(self.path / "rgb" / frame_name(index))

    def depth(self, index: int) -> np.ndarray:
        """z-depth of frame `index` in cm, float32 (H, W), 0 where invalid."""
        return read_depth(self.path / "depth" / frame_name(index))


def list_procedures(root: Path, whole_images: bool = False) -> list[Procedure]:
    """Every complete procedure folder directly under root, sorted by name; with
    whole_images, an error for one with an image region (`--octagon`), for tools that feed
    its frames to the networks as they are, black corners and all."""
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"dataset folder not found: {root}")
    found = [Procedure(p) for p in sorted(root.iterdir())
             if p.is_dir() and all((p / f).is_file() for f in REQUIRED_FILES)]
    if not found:
        raise InputError(f"no simulated procedures under {root}; make some with `c2d2 simulate`")
    if whole_images and (bordered := [p.path.name for p in found if not p.region.all()]):
        raise InputError(f"{root}: {', '.join(bordered[:5])} have an image region; this tool "
                         f"reads whole images only (simulate without --octagon)")
    return found
