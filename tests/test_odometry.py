"""fusion.odometry: relative poses given with a wrong rotation are pulled back to the truth by
RGB-D odometry on a simulated procedure's frames, true depth and K; bad input."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

from fusion import odometry
from fusion.odometry import OdometryConfig, median_depth, refine_relative_poses
from hybrid.dataset import Procedure
from hybrid.types import InputError


def rotation_error_deg(estimated: np.ndarray, truth: np.ndarray) -> np.ndarray:
    wrong = np.linalg.inv(estimated[:, :3, :3]) @ truth[:, :3, :3]
    return np.degrees(np.linalg.norm(Rotation.from_matrix(wrong).as_rotvec(), axis=1))


@pytest.fixture(scope="module")
def procedure(simulated):
    proc = Procedure.open(simulated)
    frames = range(proc.num_frames)
    return ([proc.depth(i) for i in frames], [proc.rgb(i) for i in frames], proc.camera.K,
            proc.poses)


def truth_at(poses: np.ndarray, gap: int) -> np.ndarray:
    """Entry t maps camera t's points into camera t + gap."""
    return np.linalg.inv(poses[gap:]) @ poses[:-gap]


@pytest.mark.parametrize("method", ["hybrid", "point-to-plane"])
def test_odometry_recovers_the_rotation_from_a_wrong_start(procedure, method):
    depth, rgb, K, poses = procedure
    threads = o3d.utility.get_max_threads()
    rng = np.random.default_rng(0)
    truth = {g: truth_at(poses, g) for g in (1, 2)}
    start = {}
    for g, rel in truth.items():  # 1.5° about a random axis on every pair
        axes = rng.normal(size=(len(rel), 3))
        axes *= np.radians(1.5) / np.linalg.norm(axes, axis=1, keepdims=True)
        start[g] = rel.copy()
        start[g][:, :3, :3] = Rotation.from_rotvec(axes).as_matrix() @ rel[:, :3, :3]
    refined = refine_relative_poses(start, depth, rgb, K, method=method)
    for g in truth:
        before = rotation_error_deg(start[g], truth[g]).mean()
        after = rotation_error_deg(refined.relative[g], truth[g]).mean()
        assert before == pytest.approx(1.5)
        assert after < 0.3, (g, after)
        assert refined.kept[g] == 0
        assert np.all((refined.fitness[g] > 0) & (refined.fitness[g] <= 1))  # all refined
        moved = np.linalg.norm(refined.relative[g][:, :3, 3] - truth[g][:, :3, 3], axis=1)
        step = np.linalg.norm(truth[g][:, :3, 3], axis=1)
        assert np.median(moved / step) < 0.5
    assert o3d.utility.get_max_threads() == threads  # one thread only while refining


def test_threads_and_blocks_do_not_change_the_result(procedure, monkeypatch):
    """Pairs run on threads, each pair on one, a block of frames at a time: the same bytes
    whatever the threads and however the 40 frames fall into blocks (gap 9 spans blocks of 7
    and 1 frames; gap 45 is longer than the clip and has no pair)."""
    depth, rgb, K, poses = procedure
    start = {g: truth_at(poses, g) for g in (1, 2, 9)}
    start[45] = np.zeros((0, 4, 4))
    first = refine_relative_poses(start, depth, rgb, K, threads=1)
    assert first.kept[45] == 0 and first.relative[45].shape == (0, 4, 4)
    for count, block in ((3, 64), (2, 7), (3, 1)):
        monkeypatch.setattr(odometry, "_BLOCK", block)
        again = refine_relative_poses(start, depth, rgb, K, threads=count)
        assert again.kept == first.kept
        for g in start:
            np.testing.assert_array_equal(again.relative[g], first.relative[g])
            np.testing.assert_array_equal(again.fitness[g], first.fitness[g])


def test_a_region_keeps_the_odometry_to_the_image(procedure):
    """Pixels outside the region are never read: any content there gives the same result. With
    a black border, as in a real video, the wrong start is still mostly corrected (this clip
    turns 5.5° a frame, and a narrower view tells rotation from translation less well:
    measured 1.15° -> 0.44° with this 4-pixel border, 0.89° with 16 pixels, 0.10° with none)."""
    depth, rgb, K, poses = procedure
    region = np.zeros(depth[0].shape, bool)
    region[4:-4, 4:-4] = True
    truth = {1: truth_at(poses, 1)}
    start = {1: truth[1].copy()}
    start[1][:, :3, :3] = Rotation.from_rotvec([0.0, 0.02, 0.0]).as_matrix() @ truth[1][:, :3, :3]
    black = [np.where(region[..., None], f, 0).astype(np.uint8) for f in rgb]
    refined = refine_relative_poses(start, depth, black, K, region).relative[1]
    assert rotation_error_deg(refined, truth[1]).mean() < 0.5 * np.degrees(0.02)
    scrambled = [np.where(region[..., None], f, 255 - f).astype(np.uint8) for f in rgb]
    noisy = [np.where(region, d, 99.0) for d in depth]
    np.testing.assert_array_equal(refine_relative_poses(start, noisy, scrambled, K, region
                                                        ).relative[1], refined)


def test_odometry_keeps_the_estimate_of_a_pair_it_cannot_align(procedure):
    depth, rgb, K, poses = procedure
    blank = [np.zeros_like(d) for d in depth]
    blank[0] = depth[0]  # one valid frame: the thresholds have a unit, no pair has depth
    start = {1: truth_at(poses, 1)}
    refined = refine_relative_poses(start, blank, rgb, K)
    assert refined.kept[1] == len(start[1])
    np.testing.assert_array_equal(refined.relative[1], start[1])
    assert np.isnan(refined.fitness[1]).all()


def test_depth_max_leaves_deeper_pixels_out(procedure):
    """depth_max counts in median depths: above every pixel it changes nothing; below every
    pixel no pair has points left, and each keeps its start."""
    depth, rgb, K, poses = procedure
    depth, rgb, poses = depth[:21], rgb[:21], poses[:21]
    start = {1: truth_at(poses, 1)}
    valid = np.concatenate([d[d > 0] for d in depth])
    median = median_depth(depth, None, "test")  # the unit of the odometry's thresholds
    everything = refine_relative_poses(start, depth, rgb, K)
    np.testing.assert_array_equal(
        refine_relative_poses(start, depth, rgb, K, depth_max=1.01 * valid.max() / median
                              ).relative[1], everything.relative[1])
    nothing = refine_relative_poses(start, depth, rgb, K, depth_max=0.99 * valid.min() / median)
    assert everything.kept[1] == 0 and nothing.kept[1] == len(start[1])
    np.testing.assert_array_equal(nothing.relative[1], start[1])


def test_median_makes_the_poses_independent_of_the_depth_unit(procedure):
    """With `median` the pairs are aligned in one unit whatever the depth's own: depth and
    translations ten times larger give the same rotations and ten times the translations.
    Without it the hybrid method weighs depth against colour by the depth's unit, and the
    poses move with it."""
    depth, rgb, K, poses = procedure
    depth, rgb, poses = depth[:21], rgb[:21], poses[:21]
    start = truth_at(poses, 1)
    tenfold = start.copy()
    tenfold[:, :3, 3] *= 10
    inputs = (({1: start}, depth), ({1: tenfold}, [10 * d for d in depth]))
    fixed = [refine_relative_poses(s, d, rgb, K, median=0.3).relative[1] for s, d in inputs]
    assert rotation_error_deg(fixed[1], fixed[0]).max() < 0.01  # float32 rounding: 0.002°
    lengths = [np.linalg.norm(f[:, :3, 3], axis=1) for f in fixed]
    np.testing.assert_allclose(lengths[1], 10 * lengths[0], rtol=0.02)
    own = [refine_relative_poses(s, d, rgb, K).relative[1] for s, d in inputs]
    assert rotation_error_deg(own[1], own[0]).mean() > 0.1


def test_the_diagnostics_leave_the_default_alone_and_change_what_they_name(procedure):
    """`median` at the depth's own median and `light_power` 0 give the default poses bit for
    bit; a light power or another method moves them."""
    depth, rgb, K, poses = procedure
    depth, rgb, poses = depth[:11], rgb[:11], poses[:11]
    start = {1: truth_at(poses, 1)}
    default = refine_relative_poses(start, depth, rgb, K).relative[1]
    same = refine_relative_poses(start, depth, rgb, K, light_power=0.0, method="hybrid",
                                 median=median_depth(depth, None, "test")).relative[1]
    np.testing.assert_array_equal(same, default)
    for changed in ({"light_power": 1.0}, {"method": "intensity"}):
        moved = refine_relative_poses(start, depth, rgb, K, **changed).relative[1]
        assert np.abs(moved - default).max() > 1e-6, changed


def test_bad_input_is_refused(procedure):
    depth, rgb, K, poses = procedure
    rel = {1: truth_at(poses, 1)}
    with pytest.raises(InputError, match="depth maps but"):
        refine_relative_poses(rel, depth, rgb[:-1], K)
    nan = rel[1].copy()
    nan[3, 0, 3] = np.nan
    with pytest.raises(InputError, match="finite"):
        refine_relative_poses({1: nan}, depth, rgb, K)
    with pytest.raises(InputError, match="no valid"):
        refine_relative_poses(rel, [np.zeros_like(d) for d in depth], rgb, K)
    holed = [d.copy() for d in depth]
    holed[2][5, 7] = np.nan
    with pytest.raises(InputError, match="frame 2: depth has NaN"):
        refine_relative_poses(rel, holed, rgb, K)
    with pytest.raises(InputError, match=r"frame 1: depth must be a non-empty \(H, W\) map of"):
        refine_relative_poses(rel, [depth[0], depth[1][:-1], *depth[2:]], rgb, K)
    with pytest.raises(InputError, match="no relative poses"):
        refine_relative_poses({}, depth, rgb, K)
    with pytest.raises(InputError, match="positive integers"):
        refine_relative_poses({0: np.tile(np.eye(4), (len(depth), 1, 1))}, depth, rgb, K)
    with pytest.raises(InputError, match="frame 0: expected a uint8"):
        refine_relative_poses(rel, depth, [np.repeat(np.repeat(f, 2, 0), 2, 1) for f in rgb], K)
    with pytest.raises(InputError, match="3x3"):
        refine_relative_poses(rel, depth, rgb, np.eye(4))
    with pytest.raises(InputError, match="boolean"):
        refine_relative_poses(rel, depth, rgb, K, np.ones((4, 4), bool))
    with pytest.raises(InputError, match="positive"):
        OdometryConfig(depth_huber=0.0)
    with pytest.raises(InputError, match="method must be one of"):
        refine_relative_poses(rel, depth, rgb, K, method="icp")
    with pytest.raises(InputError, match="median must be positive"):
        refine_relative_poses(rel, depth, rgb, K, median=0.0)
    for power in (-1.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match="light_power must be finite"):
            refine_relative_poses(rel, depth, rgb, K, light_power=power)
    with pytest.raises(InputError, match="depth_max must be positive"):
        refine_relative_poses(rel, depth, rgb, K, depth_max=float("nan"))
    with pytest.raises(InputError, match="per pyramid level"):
        OdometryConfig(iterations=())
    with pytest.raises(InputError, match="threads"):
        refine_relative_poses(rel, depth, rgb, K, threads=0)


class _CountedDepth:
    """A long video's depth maps, made when read (each frame's value its index + 1)."""

    def __init__(self, frames: int):
        self.frames, self.read = frames, 0

    def __len__(self) -> int:
        return self.frames

    def __getitem__(self, index: int) -> np.ndarray:
        self.read += 1
        return np.full((4, 5), index + 1.0, np.float32)


def test_the_depth_unit_of_a_long_video_reads_a_bounded_number_of_frames():
    """Every 10th frame of a short video; evenly spaced frames, at most SAMPLED_FRAMES of them,
    of a long one, so that the memory does not grow with its length."""
    from hybrid.types import SAMPLED_FRAMES, sampling_stride

    short, long = _CountedDepth(1000), _CountedDepth(60_000)
    assert median_depth(short, None, "short") == np.median(np.arange(1, 1001, 10))
    assert short.read == 100
    assert median_depth(long, None, "long") == np.median(np.arange(1, 60_001, 120))
    assert long.read == SAMPLED_FRAMES == 60_000 // sampling_stride(60_000, 10)
