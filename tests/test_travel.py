"""The direction-of-travel input of the coverage networks, against trajectories of known shape."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hybrid.types import InputError
from learned.travel import MAX_LOG_SPEED, chain_relative, travel_features


def relative_from(poses: np.ndarray, gap: int) -> np.ndarray:
    """(N-g, 4, 4) transforms mapping camera t's points into camera t+g's, from c2w poses."""
    return np.linalg.inv(poses[gap:]) @ poses[:-gap]


def straight_path(frames: int, view: Rotation, speeds: np.ndarray) -> np.ndarray:
    """Cameras moving along world -z at the given per-frame speeds, all with one orientation."""
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, :3, :3] = view.as_matrix()
    poses[:, 2, 3] = -np.concatenate([[0.0], np.cumsum(speeds[:-1])])
    return poses


def test_looking_ahead_and_looking_back_travel_in_opposite_directions():
    # A withdrawal along world -z: a camera looking along +z looks ahead, down the lumen it
    # leaves; one turned 180° about y looks back at where it is going.
    speeds = np.full(40, 0.1)
    ahead = travel_features(relative_from(straight_path(40, Rotation.identity(), speeds), 4), 40)
    back_view = Rotation.from_euler("y", 180, degrees=True)
    back = travel_features(relative_from(straight_path(40, back_view, speeds), 4), 40)
    assert ahead.shape == back.shape == (40, 4) and ahead.dtype == np.float32
    assert np.allclose(ahead[:, :3], [0, 0, -1], atol=1e-6)
    assert np.allclose(back[:, :3], [0, 0, 1], atol=1e-6)
    # Sideways (turned 90° about y): the motion lies along the camera's x axis.
    side = travel_features(relative_from(
        straight_path(40, Rotation.from_euler("y", 90, degrees=True), speeds), 4), 40)
    assert np.allclose(np.abs(side[:, :3]), [1, 0, 0], atol=1e-6)


def test_the_direction_is_in_the_first_camera_s_axes_on_a_turning_path():
    """A camera yawing 3° per frame while it moves: the displacement to t+g, seen in camera
    t's axes (R_t^T (c_{t+g} - c_t)), not in the world's or in camera t+g's."""
    frames, gap = 30, 5
    poses = np.tile(np.eye(4), (frames, 1, 1))
    yaw = Rotation.from_euler("y", 3.0 * np.arange(frames)[:, None], degrees=True)
    poses[:, :3, :3] = yaw.as_matrix()
    poses[:, :3, 3] = np.column_stack([0.05 * np.arange(frames) ** 1.5, np.zeros(frames),
                                       -0.1 * np.arange(frames)])
    out = travel_features(relative_from(poses, gap), frames)
    moved = poses[gap:, :3, 3] - poses[:-gap, :3, 3]
    expected = np.einsum("nji,nj->ni", poses[:-gap, :3, :3], moved)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(out[:-gap, :3], expected, atol=1e-6)
    world = moved / np.linalg.norm(moved, axis=1, keepdims=True)
    assert np.abs(out[:-gap, :3] - world).max() > 0.1  # the rotation matters here


def test_an_insertion_flips_the_direction_so_that_looking_ahead_means_the_same():
    poses = straight_path(30, Rotation.from_euler("y", 180, degrees=True), np.full(30, 0.1))
    relative = relative_from(poses, 2)
    withdrawal = travel_features(relative, 30)
    insertion = travel_features(relative, 30, withdrawal=False)
    assert np.allclose(insertion[:, :3], -withdrawal[:, :3])
    assert np.allclose(insertion[:, 3], withdrawal[:, 3])


def test_speed_is_log_length_over_the_median_clipped_and_the_last_frames_repeat():
    speeds = np.full(30, 0.2)
    speeds[10:14] = 0.0   # a pause
    speeds[20:22] = 0.4   # twice as fast
    gap = 1
    out = travel_features(relative_from(straight_path(30, Rotation.identity(), speeds), gap), 30)
    assert out[5, 3] == pytest.approx(0.0, abs=1e-6)
    assert out[20, 3] == pytest.approx(np.log(2.0), abs=1e-6)
    assert out[11, 3] == pytest.approx(-MAX_LOG_SPEED)
    assert np.array_equal(out[-1], out[-2])  # frame N-1 has no pair: the last pair's values
    # A scale common to depth and translation changes nothing.
    scaled = relative_from(straight_path(30, Rotation.identity(), 7.0 * speeds), gap)
    assert np.allclose(travel_features(scaled, 30), out, atol=1e-6)


def test_bad_relative_poses_are_input_errors():
    relative = relative_from(straight_path(10, Rotation.identity(), np.full(10, 0.1)), 2)
    with pytest.raises(InputError, match="1 <= M < 8"):
        travel_features(relative, 8)
    with pytest.raises(InputError, match=r"got \(8, 3, 4\)"):
        travel_features(relative[:, :3], 10)
    bad = relative.copy()
    bad[3, 0, 3] = np.nan
    with pytest.raises(InputError, match="clip.mp4: NaN"):
        travel_features(bad, 10, name="clip.mp4")


def test_chained_relative_poses_are_those_of_the_long_pairs():
    """Chaining hops of gap-g pairs on a turning path gives the relative poses of the pairs
    (t, t + hops g) that the true poses give directly."""
    frames, gap, hops = 60, 4, 5
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("yx", np.column_stack(
        [2.0 * np.arange(frames), np.sin(np.arange(frames) / 5)]), degrees=True).as_matrix()
    poses[:, :3, 3] = np.column_stack([0.03 * np.arange(frames) ** 1.3,
                                       np.sin(np.arange(frames) / 7), -0.1 * np.arange(frames)])
    chained = chain_relative(relative_from(poses, gap), gap, hops)
    assert chained.shape == (frames - gap * hops, 4, 4)
    np.testing.assert_allclose(chained, relative_from(poses, gap * hops), atol=1e-9)
    np.testing.assert_allclose(chain_relative(relative_from(poses, gap), gap, 1),
                               relative_from(poses, gap))
    with pytest.raises(InputError, match=r"5 hops of 4 frame\(s\)"):
        chain_relative(relative_from(poses[:20], gap), gap, hops)
