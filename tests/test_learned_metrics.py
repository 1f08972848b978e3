"""learned.metrics on hand-computed cases: scale-invariant depth errors, order, intrinsics,
Sim(3) alignment and trajectory errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from learned.metrics import (
    dom,
    dr_mre,
    intrinsics_error,
    median_scaled_metrics,
    mre,
    mre_scale,
    order_agreement,
    trajectory_errors,
    umeyama_sim3,
)


def relative_error(sigma, pred, gt) -> float:
    """The MRE objective at one σ, written out."""
    return float(np.mean(np.abs(sigma * pred - gt) / gt))


def rotation(axis, angle: float) -> np.ndarray:
    n = np.asarray(axis, dtype=np.float64)
    n = n / np.linalg.norm(n)
    k = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def test_mre_hand_case_beats_median_scaling():
    """pred (1, 2, 4), gt 1: the objective is (|σ−1| + |2σ−1| + |4σ−1|)/3, which is 1 + σ
    (over 3) on [1/4, 1/2] and larger elsewhere, so σ* = 1/4 and MRE = 1.25/3. Median scaling
    takes σ = 1/2 and errs (0.5 + 0 + 1)/3 = 0.5, strictly more."""
    pred, gt = np.array([1.0, 2.0, 4.0]), np.ones(3)
    assert mre_scale(pred, gt) == pytest.approx(0.25, abs=1e-12)
    assert mre(pred, gt) == pytest.approx(1.25 / 3, abs=1e-12)
    assert median_scaled_metrics(pred, gt)["abs_rel"] == pytest.approx(0.5, abs=1e-12)


def test_mre_is_zero_and_dom_one_for_a_scaled_truth():
    rng = np.random.default_rng(0)
    gt = rng.uniform(1.0, 5.0, (12, 14))
    pred = 0.37 * gt
    # σ* = 1/0.37 exactly up to float rounding: errors of order 1e-15.
    assert mre(pred, gt) < 1e-12
    assert dr_mre(pred, gt) < 1e-12
    assert dom(pred, gt) == 1.0
    assert median_scaled_metrics(pred, gt)["abs_rel"] < 1e-12


def test_mre_equals_a_brute_force_minimum_over_sigma():
    rng = np.random.default_rng(3)
    gt = rng.uniform(1.0, 4.0, 9)
    pred = gt * rng.uniform(0.5, 2.0, 9) * 3.0
    ratios = gt / pred
    # The objective is piecewise linear in σ with kinks at the ratios: its minimum is the
    # smallest value at a ratio. On a dense grid it is above that minimum by at most
    # slope · step, slope ≤ mean(pred/gt).
    exact = min(relative_error(s, pred, gt) for s in ratios)
    grid = np.linspace(ratios.min(), ratios.max(), 200_001)
    on_grid = float(np.min(np.mean(np.abs(grid[:, None] * pred - gt) / gt, axis=1)))
    slope = float(np.mean(pred / gt))
    assert exact <= on_grid <= exact + slope * (grid[1] - grid[0])
    assert mre(pred, gt) == pytest.approx(exact, abs=1e-12)
    assert relative_error(mre_scale(pred, gt), pred, gt) == pytest.approx(exact, abs=1e-12)
    median_sigma = np.median(gt) / np.median(pred)
    assert mre(pred, gt) <= relative_error(median_sigma, pred, gt) + 1e-12


def test_mre_respects_the_mask_and_rejects_bad_input():
    gt = np.array([[1.0, 1.0], [1.0, 1.0]])
    pred = np.array([[1.0, 2.0], [4.0, 100.0]])
    mask = np.array([[True, True], [True, False]])
    assert mre(pred, gt, mask) == pytest.approx(1.25 / 3, abs=1e-12)  # the hand case above
    # Non-positive and non-finite values are not pixels with depth.
    pred_bad = np.array([[1.0, 2.0], [4.0, np.nan]])
    assert mre(pred_bad, gt) == pytest.approx(1.25 / 3, abs=1e-12)
    with pytest.raises(ValueError, match="shape"):
        mre(pred, gt[:1])
    with pytest.raises(ValueError, match="no pixel"):
        mre(pred, gt, np.zeros((2, 2), dtype=bool))


def test_dr_mre_forgives_a_one_pixel_shift():
    """pred = gt shifted one pixel: each interior pixel finds its exact value among its 3x3
    neighbours, so DR-MRE is 0 at σ = 1; plain MRE is not (the field is not constant)."""
    rng = np.random.default_rng(5)
    gt = rng.uniform(1.0, 3.0, (16, 18))
    pred = np.roll(gt, shift=(0, 1), axis=(0, 1))  # pred[i, j] = gt[i, j - 1]
    mask = np.zeros_like(gt, dtype=bool)
    mask[1:-1, 1:-1] = True
    assert mre(pred, gt, mask) > 0.1
    # The golden-section search stops at a σ-bracket of relative width 1e-7 around σ = 1,
    # and the objective rises with slope ≤ max(pred/gt) ≤ 3 from 0 there: ≤ 3e-7.
    assert dr_mre(pred, gt, mask) < 3e-7


def test_dr_mre_is_at_most_mre():
    rng = np.random.default_rng(11)
    gt = rng.uniform(1.0, 3.0, (10, 12))
    pred = gt * rng.uniform(0.7, 1.4, gt.shape)
    # Each pixel's own ground truth is among its neighbours, so at every σ the DR objective is
    # ≤ the MRE objective; the search may only stop 1e-7 (relative) away from its minimum.
    assert dr_mre(pred, gt) <= mre(pred, gt) + 1e-9
    assert dr_mre(pred, gt) < mre(pred, gt)  # random fields: some neighbour always fits better


def test_dom_of_a_reversed_order_is_zero():
    """pred = 1/gt reverses every pair's order: no sampled pair of pixels agrees."""
    gt = np.arange(1.0, 17.0).reshape(4, 4)
    assert dom(1.0 / gt, gt) == 0.0
    assert dom(gt**2, gt) == 1.0


def test_order_agreement_hand_case():
    """Two pixels at true depths 1 and 2 (ratio 2): every sampled pair is that pair, ordered
    right by a prediction that keeps the order and wrong by one that swaps it; equal true
    depths have no order and give no pair."""
    gt = np.array([1.0, 2.0])
    ratio, agree = order_agreement(np.array([3.0, 5.0]), gt, pairs=50)
    assert ratio.shape == (50,) and np.all(ratio == 2.0) and agree.all()
    assert not order_agreement(np.array([5.0, 3.0]), gt, pairs=50)[1].any()
    assert order_agreement(np.array([1.0, 2.0]), np.ones(2), pairs=50)[0].size == 0


def test_median_scaled_metrics_hand_case():
    """gt 1, pred (0.7, 0.9, 1.0, 1.4, 1.9) times 3: the median scale undoes the 3 and
    max(p/g, g/p) = (1/0.7, 1/0.9, 1, 1.4, 1.9)."""
    p = np.array([0.7, 0.9, 1.0, 1.4, 1.9])
    gt = np.ones(5)
    got = median_scaled_metrics(3.0 * p, gt)
    expected = {
        "abs_rel": (0.3 + 0.1 + 0.0 + 0.4 + 0.9) / 5,
        "sq_rel": (0.09 + 0.01 + 0.0 + 0.16 + 0.81) / 5,
        "rmse": math.sqrt((0.09 + 0.01 + 0.0 + 0.16 + 0.81) / 5),
        "rmse_log": math.sqrt(np.mean(np.log(p) ** 2)),
        "delta1": 2 / 5,  # 1/0.9 = 1.11 and 1 are < 1.25
        "delta2": 4 / 5,  # 1/0.7 = 1.43 and 1.4 are < 1.5625
        "delta3": 5 / 5,  # 1.9 < 1.953
    }
    assert got == pytest.approx(expected, abs=1e-12)


def test_intrinsics_error_hand_case():
    """A 160 x 128 camera with an off-centre principal point: cx, cy errors are divided by
    the image width and height, fx, fy errors by the true focal lengths."""
    K_true = np.array([[100.0, 0, 75.5], [0, 90.0, 66.5], [0, 0, 1]])
    K_pred = np.array([[110.0, 0, 83.5], [0, 85.5, 63.3], [0, 0, 1]])
    assert intrinsics_error(K_pred, K_true, 160, 128) == pytest.approx(
        {"fx_rel": 0.1, "fy_rel": 0.05, "cx_rel": 8 / 160, "cy_rel": 3.2 / 128}, abs=1e-12)


def test_umeyama_recovers_a_known_similarity():
    rng = np.random.default_rng(2)
    source = rng.normal(size=(10, 3))
    R = rotation([0.2, -0.4, 1.0], 2.2)
    target = 2.5 * source @ R.T + np.array([1.0, -3.0, 0.5])
    s, R_got, t_got = umeyama_sim3(source, target)
    # Exact data: recovered to rounding.
    assert s == pytest.approx(2.5, abs=1e-12)
    np.testing.assert_allclose(R_got, R, atol=1e-12)
    np.testing.assert_allclose(t_got, [1.0, -3.0, 0.5], atol=1e-12)


def test_umeyama_gives_a_rotation_for_coplanar_points():
    """Planar points leave the third singular direction's sign free: the result must still be
    the proper rotation (det +1) that maps them."""
    rng = np.random.default_rng(4)
    source = np.column_stack([rng.normal(size=(8, 2)), np.zeros(8)])
    R = rotation([1.0, 1.0, 0.0], 0.9)
    target = 0.5 * source @ R.T
    s, R_got, t_got = umeyama_sim3(source, target)
    assert np.linalg.det(R_got) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(s * source @ R_got.T + t_got, target, atol=1e-12)
    assert s == pytest.approx(0.5, abs=1e-12)


def trajectory(n: int = 7) -> np.ndarray:
    """A curving camera-to-world trajectory, turning about a tilted axis."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        poses[i, :3, :3] = rotation([0.1, 1.0, 0.3], 0.15 * i)
        poses[i, :3, 3] = [0.5 * i, 0.1 * i**2, 0.3 * np.sin(i)]
    return poses


def test_trajectory_errors_vanish_for_a_similar_copy():
    """A world similarity (s', R', t') maps camera-to-world poses to [R'R, s'R'p + t']: after
    Sim(3) alignment ATE, RPE are 0 and the alignment scale is 1/s'."""
    true = trajectory()
    s, R = 3.0, rotation([1.0, -2.0, 0.5], 1.3)
    pred = true.copy()
    pred[:, :3, :3] = R @ true[:, :3, :3]
    pred[:, :3, 3] = s * true[:, :3, 3] @ R.T + np.array([4.0, 5.0, -6.0])
    got = trajectory_errors(pred, true)
    assert got["sim3_scale"] == pytest.approx(1 / s, abs=1e-12)
    # Rounding only: positions ~10, so errors ~1e-14; rotation angles from arccos near 1
    # lose half the digits (~1e-8 rad = 6e-7 deg).
    assert got["ate"] < 1e-12 and got["rpe_translation"] < 1e-12
    assert got["rpe_rotation_deg"] < 1e-5


def test_trajectory_errors_hand_case():
    """Same positions, but the predicted camera turns by θ about its z axis each frame while the
    true one does not. Relative rotations differ by θ; the relative translation d_i (in the xy
    plane) is seen rotated by −iθ, so it errs by 2|d_i| sin(iθ/2)."""
    n, theta = 5, math.radians(3.0)
    true = np.tile(np.eye(4), (n, 1, 1))
    true[:, :3, 3] = [[0.5 * i, 0.1 * i**2, 0.0] for i in range(n)]
    pred = true.copy()
    pred[:, :3, :3] = [rotation([0, 0, 1], theta * i) for i in range(n)]
    got = trajectory_errors(pred, true)
    steps = np.diff(true[:, :3, 3], axis=0)
    t_err = [2 * np.linalg.norm(d) * math.sin(i * theta / 2) for i, d in enumerate(steps)]
    assert got["ate"] < 1e-12
    assert got["sim3_scale"] == pytest.approx(1.0, abs=1e-12)
    assert got["rpe_translation"] == pytest.approx(math.sqrt(np.mean(np.square(t_err))), abs=1e-12)
    assert got["rpe_rotation_deg"] == pytest.approx(3.0, abs=1e-6)  # arccos near 1: ~1e-8 rad
    with pytest.raises(ValueError, match="same length"):
        trajectory_errors(pred[:3], true[:4])


def test_config_overrides_parse_by_field_type():
    from learned.config import parse_overrides

    assert parse_overrides(["pair_gap_s=0.6", "ssim_window=7", "mask_out_of_view=false",
                            "encoder_channels=32,48,64,128,192"]) == {
        "pair_gap_s": 0.6, "ssim_window": 7, "mask_out_of_view": False,
        "encoder_channels": (32, 48, 64, 128, 192)}
    for bad in (["nonsense=1"], ["ssim_window=seven"], ["automask=maybe"], ["steps"],
                ["encoder_channels=1"], ["encoder_channels=32,48,x,128,192"], ["preset=paper"]):
        with pytest.raises(ValueError, match="--set"):
            parse_overrides(bad)
