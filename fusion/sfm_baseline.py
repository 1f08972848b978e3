"""Classical baseline: intrinsics and camera poses from pycolmap structure from motion.

Writes the frames (and the camera mask) as PNGs under a work directory, extracts SIFT, matches
sequentially and runs COLMAP's incremental mapper with the settings that register a camera
moving along a tube (method-notes, "pycolmap 4.2"). Returns one shared K and camera-to-world
poses for the registered frames of the largest model, to compare with the learned branch after a
Sim(3) alignment (monocular scale is free).
"""

from __future__ import annotations

import logging
import shutil
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pycolmap

from hybrid.types import InputError

log = logging.getLogger(__name__)

CAMERA_MODEL = "SIMPLE_PINHOLE"
"""One focal length and a principal point, no distortion: the model of the simulator and of the
learned branch's K. The principal point stays at the image centre (COLMAP's default: refining it
from one sequence is ill-posed); the focal length is refined by bundle adjustment."""

FISHEYE_MODEL = "SIMPLE_RADIAL_FISHEYE"
"""COLMAP's fisheye of one focal length f and one coefficient k: a ray θ off the axis lands
f (θ + k θ³) from the principal point (k = 0: the equidistant lens of `hybrid.types.Camera`)."""


class NoModel(InputError):
    """The mapper built no model from the frames (too little texture or motion)."""


@dataclass
class SfmResult:
    """What the mapper recovered for N input frames."""

    K: np.ndarray
    """(3, 3) float64 intrinsics in the input images' pixels (OpenCV pixel centres)."""
    poses: np.ndarray
    """(N, 4, 4) float64 camera-to-world; NaN for frames that were not registered."""
    registered: np.ndarray
    """(N,) bool, frames placed by the mapper."""
    seconds: float
    """Wall time of extraction, matching and mapping."""
    reprojection_error: float
    """Mean reprojection error of the model's 3D points (px of the input images)."""
    points: int
    """3D points in the model."""
    track_length: float
    """Mean number of images that observe a 3D point."""
    observations: list[np.ndarray]
    """Per input frame, (M, 3) float32: the pixel (x, y, OpenCV centres) and the depth along
    the camera's axis of each 3D point of the model the frame observes, in the model's unit
    (sparse depth, up to the model's scale); (0, 3) for frames not registered."""
    camera_params: np.ndarray
    """The camera model's parameters as COLMAP orders them (SIMPLE_PINHOLE: f, cx, cy;
    SIMPLE_RADIAL_FISHEYE: f, cx, cy, k), in COLMAP's pixels (centres at +0.5)."""


def mapping_options() -> pycolmap.IncrementalPipelineOptions:
    """Incremental mapping that initialises on a forward-moving camera: the default asks for a
    16° triangulation angle and mostly sideways motion between the first two frames."""
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = 0
    options.mapper.init_min_tri_angle = 4.0
    options.mapper.init_max_forward_motion = 0.99
    options.mapper.init_min_num_inliers = 50
    return options


def verification_options() -> pycolmap.TwoViewGeometryOptions:
    """Two-view verification that calls a pair planar only when a homography explains 95% of the
    inliers (default 80%). With COLMAP's defaults the mapper placed 2 of 30 frames in a textured
    tube; it placed all 30 with this and `mapping_options` together."""
    options = pycolmap.TwoViewGeometryOptions()
    options.max_H_inlier_ratio = 0.95
    options.ransac.random_seed = 0
    return options


def run_sfm(images: list[np.ndarray], mask: np.ndarray | None, work_dir: Path,
            name: str = "frames", frame_masks: list[np.ndarray] | None = None,
            initial_field_of_view: float | None = None,
            camera_model: str = CAMERA_MODEL) -> SfmResult:
    """Structure from motion on consecutive RGB uint8 frames (H, W, 3) of one camera.

    mask: (H, W) bool, True where the image shows the scene (False on a black border), or None.
    frame_masks: one (H, W) bool per frame, True where its features may be kept (e.g. off
    specular highlights), or None.
    initial_field_of_view: degrees across the frames' longer side of the camera the mapper
    starts from (bundle adjustment then refines its f), or None for COLMAP's default start,
    f = 1.2 x the longer side (45 degrees).
    camera_model: `CAMERA_MODEL`, or `FISHEYE_MODEL` (K's fx = fy = its f; k only in
    `SfmResult.camera_params`), which needs initial_field_of_view, through an equidistant
    lens, as a prior: COLMAP cannot verify fisheye pairs without one.
    work_dir is emptied of a previous run's database and model.
    """
    _check_images(images, mask, name)
    if frame_masks is not None and (len(frame_masks) != len(images) or any(
            np.shape(m) != np.shape(images[0])[:2] or np.asarray(m).dtype != bool
            for m in frame_masks)):
        raise InputError(f"{name}: frame_masks must hold one (H, W) bool per frame, "
                         f"{len(images)} of {np.shape(images[0])[:2]}")
    if initial_field_of_view is not None and not 0 < initial_field_of_view < 180:
        raise InputError(f"{name}: initial_field_of_view must lie in (0, 180) degrees, "
                         f"got {initial_field_of_view}")
    if camera_model not in (CAMERA_MODEL, FISHEYE_MODEL):
        raise InputError(f"{name}: camera_model must be {CAMERA_MODEL} or {FISHEYE_MODEL}, "
                         f"got {camera_model}")
    if camera_model == FISHEYE_MODEL and initial_field_of_view is None:
        raise InputError(f"{name}: {FISHEYE_MODEL} needs an initial_field_of_view, the prior "
                         f"without which COLMAP verifies no fisheye pair")
    work_dir = Path(work_dir)
    image_dir, model_dir = work_dir / "images", work_dir / "sparse"
    mask_dir = work_dir / "masks"
    database = work_dir / "database.db"
    for old in (image_dir, model_dir, mask_dir):
        shutil.rmtree(old, ignore_errors=True)
    database.unlink(missing_ok=True)
    image_dir.mkdir(parents=True)
    model_dir.mkdir()
    names = [f"{i:06d}.png" for i in range(len(images))]
    for file, image in zip(names, images, strict=True):
        cv2.imwrite(str(image_dir / file), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    if camera_model == FISHEYE_MODEL:  # a prior f (COLMAP's pixel centres at +0.5)
        height, width = np.shape(images[0])[:2]
        f = max(height, width) / np.radians(initial_field_of_view)
        reader.camera_params = f"{f},{width / 2},{height / 2},0"
    elif initial_field_of_view is not None:
        reader.default_focal_length_factor = 0.5 / np.tan(np.radians(initial_field_of_view) / 2)
    if mask is not None:
        reader.camera_mask_path = str(work_dir / "mask.png")
        cv2.imwrite(reader.camera_mask_path, mask.astype(np.uint8) * 255)
    if frame_masks is not None:  # COLMAP reads image NAME's mask from NAME.png
        mask_dir.mkdir()
        reader.mask_path = str(mask_dir)
        for file, keep in zip(names, frame_masks, strict=True):
            cv2.imwrite(str(mask_dir / f"{file}.png"), np.asarray(keep, np.uint8) * 255)

    start = time.perf_counter()
    with _colmap_errors_only():
        models = _map(database, image_dir, model_dir, reader)
    seconds = time.perf_counter() - start
    if not models:
        raise NoModel(f"{name}: structure from motion reconstructed no model from "
                         f"{len(images)} frames (too little texture or motion); try more frames "
                         f"or a larger image size")
    model = max(models.values(), key=lambda m: m.num_reg_images())
    return _result(model, names, seconds, name)


def _map(database: Path, image_dir: Path, model_dir: Path,
         reader: pycolmap.ImageReaderOptions) -> dict[int, pycolmap.Reconstruction]:
    """SIFT, sequential matching and incremental mapping, each on one thread; the models found.

    With COLMAP's threads the result is not repeatable, seeds or not: one 120-frame stretch of
    a simulated procedure mapped fully at f = 85, 47 and 47 px in three runs; on one thread, at
    51 px every time (`docs/depth.md`, "The contrast step, and one thread"). Two such runs at
    once in threads of one process are not repeatable either."""
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = 1
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = 1
    mapping = mapping_options()
    mapping.num_threads = 1
    pycolmap.extract_features(database, image_dir, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extraction,
                              device=pycolmap.Device.cpu)
    pycolmap.match_sequential(database, matching_options=matching,
                              verification_options=verification_options(),
                              device=pycolmap.Device.cpu)
    return pycolmap.incremental_mapping(database, image_dir, model_dir, options=mapping)


@contextmanager
def _colmap_errors_only():
    """COLMAP logs every matched image to stderr; keep its errors only while it runs (this
    module logs its own summary)."""
    previous = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = int(pycolmap.logging.ERROR)
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = previous


def _result(model: pycolmap.Reconstruction, names: list[str], seconds: float,
            name: str) -> SfmResult:
    (camera,) = model.cameras.values()
    K = camera.calibration_matrix().astype(np.float64)
    K[:2, 2] -= 0.5  # COLMAP puts pixel centres at +0.5, OpenCV at integers
    index = {file: i for i, file in enumerate(names)}
    poses = np.full((len(names), 4, 4), np.nan)
    observations = [np.zeros((0, 3), np.float32) for _ in names]
    for image in model.images.values():
        if image.has_pose:
            cam_to_world = image.cam_from_world().inverse().matrix()
            poses[index[image.name]] = np.vstack([cam_to_world, [0, 0, 0, 1]])
            observations[index[image.name]] = _observed(model, image)
    registered = np.isfinite(poses).all(axis=(1, 2))
    log.info("%s: SfM registered %d of %d frames, f = %.1f px, in %.1f s", name,
             registered.sum(), len(names), K[0, 0], seconds)
    return SfmResult(K, poses, registered, seconds, float(model.compute_mean_reprojection_error()),
                     int(model.num_points3D()), float(model.compute_mean_track_length()),
                     observations, np.array(camera.params, dtype=np.float64))


def _observed(model: pycolmap.Reconstruction, image: pycolmap.Image) -> np.ndarray:
    """SfmResult.observations of one registered image."""
    seen = [p for p in image.points2D if p.has_point3D()]
    if not seen:
        return np.zeros((0, 3), np.float32)
    world = np.array([model.points3D[p.point3D_id].xyz for p in seen])
    cam_from_world = image.cam_from_world().matrix()
    depth = world @ cam_from_world[2, :3] + cam_from_world[2, 3]
    xy = np.array([p.xy for p in seen]) - 0.5  # COLMAP's pixel centres to OpenCV's
    return np.column_stack([xy, depth]).astype(np.float32)


def _check_images(images: list[np.ndarray], mask: np.ndarray | None, name: str) -> None:
    if len(images) < 2:
        raise InputError(f"{name}: structure from motion needs at least 2 frames, got "
                         f"{len(images)}")
    shape = np.shape(images[0])
    bad = [i for i, im in enumerate(images)
           if np.shape(im) != shape or np.asarray(im).dtype != np.uint8]
    if len(shape) != 3 or shape[2] != 3 or bad:
        raise InputError(f"{name}: frames must be RGB uint8 (H, W, 3) of one size {shape}; "
                         f"frames {bad[:10]} differ")
    if mask is not None and (np.shape(mask) != shape[:2] or not np.any(mask)):
        raise InputError(f"{name}: mask must be a non-empty (H, W) bool image of the frames' "
                         f"size {shape[:2]}, got shape {np.shape(mask)}")
