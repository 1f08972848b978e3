"""pycolmap structure from motion inside an analytically rendered, textured tube
(tests/tube_scene.py), seen through a disc-shaped mask with a black border."""

from __future__ import annotations

import numpy as np
import pycolmap
import pytest
from tube_scene import (
    FOCAL,
    FRAMES,
    HEIGHT,
    MASK,
    WIDTH,
    K,
    depth,
    pose_at,
    render,
    wall_texture,
)

from fusion.sfm_baseline import FISHEYE_MODEL, run_sfm
from hybrid.types import InputError
from learned.metrics import trajectory_errors


def test_sfm_recovers_focal_length_and_trajectory(tmp_path):
    poses = np.stack([pose_at(i) for i in range(FRAMES)])
    texture = wall_texture()
    result = run_sfm([render(p, texture) for p in poses], MASK, tmp_path)
    assert result.registered.all()
    assert np.isfinite(result.poses).all()
    # The principal point stays at the image centre (OpenCV convention), as rendered.
    np.testing.assert_allclose(result.K[:2, 2], K[:2, 2])
    # 24 frames with a 2.3 cm baseline at 128x160 give f within a few percent (2.2% measured).
    assert abs(result.K[0, 0] - FOCAL) / FOCAL < 0.05
    errors = trajectory_errors(result.poses, poses)
    assert errors["ate"] < 0.02  # cm: under 1% of the path
    assert errors["rpe_rotation_deg"] < 0.2
    # The sparse depth, in the model's unit, is the wall's depth at its pixels up to that scale.
    for frame in (0, FRAMES // 2, FRAMES - 1):
        x, y, z = result.observations[frame].T
        true = depth(poses[frame])[y.round().astype(int), x.round().astype(int)]
        assert len(z) > 50
        assert np.median(np.abs(errors["sim3_scale"] * z / true - 1)) < 0.03
    # The camera mask reached COLMAP: every keypoint lies inside it.
    database = pycolmap.Database.open(tmp_path / "database.db")
    for image in database.read_all_images():
        x, y = database.read_keypoints(image.image_id)[:, :2].T.astype(int)
        assert MASK[y, x].all()


def test_frame_masks_keep_features_off_masked_pixels(tmp_path):
    """A mask per frame: its right half kept, so no keypoint lies in the left half."""
    poses = [pose_at(i) for i in range(12)]
    texture = wall_texture()
    right = np.zeros(MASK.shape, bool)
    right[:, MASK.shape[1] // 2:] = True
    run_sfm([render(p, texture) for p in poses], MASK, tmp_path, frame_masks=[right] * 12)
    database = pycolmap.Database.open(tmp_path / "database.db")
    columns = np.concatenate([database.read_keypoints(image.image_id)[:, 0]
                              for image in database.read_all_images()])
    assert len(columns) > 100 and columns.min() >= MASK.shape[1] // 2 - 0.5


def test_the_mapper_starts_from_the_given_field_of_view_and_refines_f(tmp_path):
    """Started from a 150-degree camera (f = 80 / tan 75 = 21.4 px; the truth is 80 px, 90
    degrees across the 160-px width), bundle adjustment still finds the true f."""
    poses = np.stack([pose_at(i) for i in range(FRAMES)])
    texture = wall_texture()
    result = run_sfm([render(p, texture) for p in poses], MASK, tmp_path,
                     initial_field_of_view=150)
    (camera,) = pycolmap.Database.open(tmp_path / "database.db").read_all_cameras()
    assert camera.params[0] == pytest.approx(80 / np.tan(np.radians(75)))
    assert result.registered.all()
    assert abs(result.K[0, 0] - FOCAL) / FOCAL < 0.05


def test_sfm_without_texture_raises(tmp_path):
    with pytest.raises(InputError, match="no model"):
        run_sfm([np.full((64, 80, 3), 128, np.uint8)] * 4, None, tmp_path, name="grey")


@pytest.mark.parametrize("images, mask, match", [
    ([np.zeros((8, 8, 3), np.uint8)], None, "at least 2 frames"),
    ([np.zeros((8, 8, 3), np.uint8), np.zeros((8, 9, 3), np.uint8)], None, "one size"),
    ([np.zeros((8, 8), np.uint8)] * 2, None, "RGB uint8"),
    ([np.zeros((8, 8, 3), np.float32)] * 2, None, "RGB uint8"),
    ([np.zeros((8, 8, 3), np.uint8)] * 2, np.ones((4, 4), bool), "mask"),
    ([np.zeros((8, 8, 3), np.uint8)] * 2, np.zeros((8, 8), bool), "mask"),
])
def test_bad_input_is_named(images, mask, match, tmp_path):
    with pytest.raises(InputError, match=match):
        run_sfm(images, mask, tmp_path)


@pytest.mark.parametrize("frame_masks", [[np.ones((8, 8), bool)], [np.ones((4, 8), bool)] * 2,
                                         [np.ones((8, 8), np.float32)] * 2])
def test_frame_masks_of_the_wrong_count_or_size_are_refused(frame_masks, tmp_path):
    with pytest.raises(InputError, match="frame_masks"):
        run_sfm([np.zeros((8, 8, 3), np.uint8)] * 2, None, tmp_path, frame_masks=frame_masks)


@pytest.mark.parametrize("degrees", [0, 180, -10])
def test_a_start_that_is_not_a_field_of_view_is_refused(degrees, tmp_path):
    with pytest.raises(InputError, match="initial_field_of_view"):
        run_sfm([np.zeros((8, 8, 3), np.uint8)] * 2, None, tmp_path, initial_field_of_view=degrees)


@pytest.mark.parametrize("lens", ["equidistant", "pinhole"])
def test_the_fisheye_model_tells_an_equidistant_lens_from_a_pinhole(lens, tmp_path):
    """The tube filmed through an equidistant lens of f = 80 px (r = f θ) and through a
    pinhole of the same f, each mapped with COLMAP's one-coefficient fisheye, r = f (θ + k θ³),
    started from a 120-degree prior: the lens gives k near 0 and f near 80; the pinhole a k
    well above 0 (tan θ = θ + θ³/3 + ..., so k = 1/3 at the same f over small angles)."""
    poses = np.stack([pose_at(i) for i in range(FRAMES)])
    texture = wall_texture()
    result = run_sfm([render(p, texture, lens) for p in poses], MASK, tmp_path,
                     initial_field_of_view=120, camera_model=FISHEYE_MODEL)
    f, cx, cy, k = result.camera_params
    assert result.registered.all()
    assert (cx, cy) == (WIDTH / 2, HEIGHT / 2)  # COLMAP's pixel centres at +0.5
    if lens == "equidistant":
        assert abs(f - FOCAL) / FOCAL < 0.05 and abs(k) < 0.05
    else:
        assert k > 0.25


def test_the_fisheye_model_needs_a_prior_and_other_models_are_refused(tmp_path):
    images = [np.zeros((8, 8, 3), np.uint8)] * 2
    for model, start, match in ((FISHEYE_MODEL, None, "needs an initial_field_of_view"),
                                ("OPENCV", 90.0, "camera_model must be")):
        with pytest.raises(InputError, match=match):
            run_sfm(images, None, tmp_path, initial_field_of_view=start, camera_model=model)
