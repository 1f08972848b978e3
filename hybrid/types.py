"""Types shared by every package: camera intrinsics, pose checks, input errors, thread counts.

This module imports nothing from the project, so `learned` and `fusion` may use it too.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

#: Lens models a Camera describes (see Camera.model).
CAMERA_MODELS = ("pinhole", "equidistant")

#: Image size (height, width) of each preset.
PRESET_IMAGE_SIZE = {"fast": (128, 160), "paper": (320, 384)}


class InputError(ValueError):
    """Bad user input: the message names the input and says what to do."""


@dataclass(frozen=True)
class Camera:
    """Intrinsics in pixels of a width x height image (OpenCV convention).

    model: 'pinhole', or 'equidistant', a fisheye lens whose image radius grows with the
    angle from the optical axis, r = f θ (OpenCV's fisheye model without its distortion
    terms). Its fx, fy are the magnification at the image centre, where it and a pinhole
    camera of the same K agree.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    fps: float = 30.0
    model: str = "pinhole"

    def __post_init__(self) -> None:
        values = (self.width, self.height, self.fx, self.fy, self.cx, self.cy, self.fps)
        if not all(np.isfinite(v) for v in values):
            raise InputError(f"camera has a non-finite value: {self}")
        if self.width < 1 or self.height < 1 or self.fx <= 0 or self.fy <= 0 or self.fps <= 0:
            raise InputError(f"camera needs positive width, height, fx, fy and fps: {self}")
        if self.model not in CAMERA_MODELS:
            raise InputError(f"camera model must be one of {CAMERA_MODELS}, got {self.model!r}")

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix (float64); with a fisheye model, not the whole projection."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view in degrees: the angle across the image's width at the
        focal length fx, through the camera's model."""
        half = self.width / (2 * self.fx)
        return float(np.degrees(2 * (half if self.model == "equidistant" else np.arctan(half))))

    def resized(self, width: int, height: int) -> Camera:
        """The same camera for an image resized to width x height (pixel-centre convention)."""
        sx, sy = width / self.width, height / self.height
        return Camera(
            width, height, self.fx * sx, self.fy * sy,
            (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, self.fps, self.model,
        )

    def pixel_rays(self) -> np.ndarray:
        """(height, width, 3) float64 direction of each pixel centre's ray in camera
        coordinates, scaled to z = 1 (so a hit's distance along it is its z-depth); an error
        for a fisheye that sees 90° or more off its axis, where z-depth is not defined."""
        v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        a, b = (u - self.cx) / self.fx, (v - self.cy) / self.fy
        if self.model == "equidistant":  # at the angle θ = |(a, b)|, z = 1 lies tan θ out
            theta = np.hypot(a, b)
            if theta.max() >= np.pi / 2:
                raise InputError(f"this equidistant camera sees {np.degrees(theta.max()):.0f}° "
                                 f"off its axis; z-depth is defined below 90°: {self}")
            stretch = np.where(theta > 1e-9, np.tan(theta) / np.maximum(theta, 1e-9), 1.0)
            a, b = a * stretch, b * stretch
        return np.stack([a, b, np.ones_like(a)], axis=-1)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel coordinates u, v of (N, 3) points in camera coordinates, and whether each is
        in front of the camera (z > 0); behind a pinhole u, v mean nothing (an equidistant
        lens images those at more than 90° from its axis)."""
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        in_front = z > 1e-6
        zs = np.where(in_front, z, 1.0)
        if self.model == "equidistant":  # a pinhole's z that gives the same image radius
            rho = np.hypot(x, y)
            zs = np.where(rho > 1e-12, rho / np.maximum(np.arctan2(rho, z), 1e-300), zs)
        return self.fx * x / zs + self.cx, self.fy * y / zs + self.cy, in_front

    def save(self, path: Path) -> None:
        Path(path).write_text(json.dumps(asdict(self), indent=2) + "\n")

    @classmethod
    def load(cls, path: Path) -> Camera:
        path = Path(path)
        if not path.is_file():
            raise InputError(f"camera file not found: {path}")
        try:
            data = json.loads(path.read_text())
            return cls(**{k: data[k] for k in ("width", "height", "fx", "fy", "cx", "cy")},
                       fps=data.get("fps", 30.0), model=data.get("model", "pinhole"))
        except (json.JSONDecodeError, KeyError, TypeError) as err:
            raise InputError(
                f"camera file {path} must be JSON with width, height, fx, fy, cx, cy, fps: {err}"
            ) from err


def failure_reason(err: Exception) -> str:
    """How a failure is recorded as a result: an InputError's message, or 'Type: message'. A
    lack of memory or disk (MemoryError, OSError) says nothing of the input and is raised
    again instead, so that nothing recorded keeps a rerun from trying again."""
    if isinstance(err, MemoryError | OSError):
        raise err
    return str(err) if isinstance(err, InputError) else f"{type(err).__name__}: {err}"


def check_poses(poses: np.ndarray, name: str = "poses") -> np.ndarray:
    """Validate an (N, 4, 4) stack of rigid camera-to-world poses; return it as float64."""
    poses = np.asarray(poses)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) == 0:
        raise InputError(f"{name} must have shape (N, 4, 4) with N >= 1, got {poses.shape}")
    poses = poses.astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(poses).all(axis=(1, 2)))
    if bad.size:
        raise InputError(f"{name} has NaN or infinite values at frames {bad[:10].tolist()}")
    R = poses[:, :3, :3]
    ortho_err = np.abs(R.transpose(0, 2, 1) @ R - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((ortho_err > 1e-4) | (np.linalg.det(R) < 0)
                         | (np.abs(poses[:, 3] - [0, 0, 0, 1]).max(axis=1) > 1e-9))
    if bad.size:
        raise InputError(
            f"{name} must be rigid camera-to-world transforms (rotation + translation, last row "
            f"0 0 0 1); frames {bad[:10].tolist()} are not"
        )
    return poses


def check_depth(depth: np.ndarray, shape: tuple[int, int] | None, what: str) -> np.ndarray:
    """A non-empty (H, W) depth map (of `shape` if given) as float32 (the map itself if it is
    float32 already), finite and not negative (0 marks an invalid pixel), or an InputError
    naming `what`."""
    depth = np.asarray(depth)
    if depth.ndim != 2 or depth.size == 0 or (shape is not None and depth.shape != shape):
        raise InputError(f"{what}: depth must be a non-empty (H, W) map"
                         f"{'' if shape is None else f' of the first frame size {shape}'}, "
                         f"got shape {depth.shape}")
    depth = depth.astype(np.float32, copy=False)
    if not np.isfinite(depth).all() or (depth < 0).any():
        raise InputError(f"{what}: depth has NaN, infinite or negative values; mark invalid "
                         f"pixels with 0")
    return depth


def read_mask(path: Path, what: str = "mask") -> np.ndarray:
    """(H, W) bool mask from an image file (grey above 127 is inside), or an InputError naming
    `what`."""
    import cv2  # not for every user of these types

    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError(f"cannot read {what} image {path}")
    if not (image > 127).any():
        raise InputError(f"{what} image {path} is all black: it marks no pixel as image (white "
                         f"= image)")
    return image > 127


def chain_poses(relative: np.ndarray) -> np.ndarray:
    """(N, 4, 4) camera-to-world poses, the first the identity, from (N-1, 4, 4) relative poses
    (relative[t] maps camera t's points into camera t+1): P[t+1] = P[t] · inverse(relative[t])."""
    poses = [np.eye(4)]
    for T in relative:
        poses.append(poses[-1] @ np.linalg.inv(T))
    return np.stack(poses)


def thread_count(threads: int | None, name: str, most: int | None = None) -> int:
    """`threads` if given (at least 1), else one per CPU core this process may run on, at most
    `most`."""
    if threads is not None:
        if threads < 1:
            raise InputError(f"{name} must be at least 1 (or None for one per core), got "
                             f"{threads}")
        return threads
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else \
        os.cpu_count() or 1
    return min(cores, most or cores)


SAMPLED_FRAMES = 500
"""At most this many frames of a video are sampled where a statistic of the whole video is
taken (the odometry's depth unit, the cloud of the first lumen fit), so that its memory does
not grow with the video's length."""


def sampling_stride(frames: int, stride: int) -> int:
    """Every `stride`-th of `frames` frames, or a longer stride that samples at most
    SAMPLED_FRAMES of them."""
    return max(stride, -(-frames // SAMPLED_FRAMES))
