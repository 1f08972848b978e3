"""Frames of a fisheye lens resampled to a pinhole camera, the camera every stage assumes."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from hybrid.types import Camera, InputError

WIDEST_DEG = 130.0
"""The widest angle across the width of the pinhole a fisheye video is resampled to: the
widest the simulator draws (`SimConfig.hfov_deg`), so that the networks read a camera like
those they were trained on. A lens wider than that loses its edges."""


def check_fisheye_fov(fov_deg: float) -> None:
    """An InputError unless fov_deg is a fisheye's field of view, in (0, 360) degrees."""
    if not 0 < fov_deg < 360:
        raise InputError(f"a fisheye's field of view must lie between 0 and 360 degrees, got "
                         f"{fov_deg}")


def equidistant(fov_deg: float, width: int, height: int) -> Camera:
    """The equidistant fisheye camera of a width x height image that sees fov_deg across its
    width, square pixels, its principal point at the centre."""
    check_fisheye_fov(fov_deg)
    f = (width / 2) / np.radians(fov_deg / 2)
    return Camera(width, height, f, f, (width - 1) / 2, (height - 1) / 2, model="equidistant")


def pinhole_twin(camera: Camera, widest_deg: float | None = None) -> Camera:
    """The pinhole camera of the same image size, principal point and aspect that sees the
    same angle across the image width as `camera`, or widest_deg where that is narrower
    (itself for a pinhole)."""
    if camera.model == "pinhole":
        return camera
    angle = camera.hfov_deg if widest_deg is None else min(camera.hfov_deg, widest_deg)
    if not 0 < angle < 180:
        raise InputError(f"a pinhole sees less than 180 degrees across, not {angle:g}: give "
                         f"the widest one to resample {camera} to")
    fx = (camera.width / 2) / np.tan(np.radians(angle) / 2)
    return replace(camera, fx=float(fx), fy=float(fx * camera.fy / camera.fx), model="pinhole")


def resampling_maps(source: Camera, target: Camera) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap's (H, W) float32 maps: where in an image of `source` each pixel of `target`
    (a camera at the same place, looking the same way) finds its ray."""
    u, v, _ = source.project(target.pixel_rays().reshape(-1, 3))
    shape = (target.height, target.width)
    return u.reshape(shape).astype(np.float32), v.reshape(shape).astype(np.float32)


def resample(image: np.ndarray, maps: tuple[np.ndarray, np.ndarray],
             interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """`image` seen through the target camera of `maps`. Where the source does not reach, its
    edge is continued (so that no black bleeds into the pixels next to it): cut that part
    off with `resample_mask`."""
    return cv2.remap(image, *maps, interpolation, borderMode=cv2.BORDER_REPLICATE)


def resample_mask(mask: np.ndarray, maps: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """A (H, W) bool mask of the source seen through the target camera of `maps` (nearest
    pixel); False where the source does not reach."""
    return cv2.remap(mask.astype(np.uint8), *maps, cv2.INTER_NEAREST,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0
