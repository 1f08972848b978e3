"""Depth, intrinsics and trajectory metrics (paper section 5.1, design.md).

Depth from monocular video is known up to scale. MRE and DR-MRE use the scale that minimises
them (the paper's definition); the literature's abs_rel & co. use median scaling.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-6


def _valid(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    pred, gt = np.asarray(pred, dtype=np.float64), np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape:
        raise ValueError(f"prediction shape {pred.shape} differs from ground truth {gt.shape}")
    valid = np.isfinite(pred) & np.isfinite(gt) & (pred > 0) & (gt > 0)
    if mask is not None:
        valid &= np.asarray(mask, dtype=bool)
    if not valid.any():
        raise ValueError("no pixel has both a valid prediction and a valid ground truth")
    return valid


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """A minimiser of sum(weights * |x - values|)."""
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def mre_scale(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """The σ minimising mean |σ·pred − gt| / gt: a weighted median of gt/pred, weights pred/gt."""
    valid = _valid(pred, gt, mask)
    p, g = pred[valid].astype(np.float64), gt[valid].astype(np.float64)
    return weighted_median(g / p, p / np.maximum(g, _EPS))


def mre(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Scale-invariant mean relative error: min over σ of mean |σ·pred − gt| / max(gt, ε)."""
    valid = _valid(pred, gt, mask)
    sigma = mre_scale(pred, gt, valid)
    p, g = pred[valid].astype(np.float64), gt[valid].astype(np.float64)
    return float(np.mean(np.abs(sigma * p - g) / np.maximum(g, _EPS)))


def dr_mre(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Discontinuity-robust MRE: each pixel takes the best ground truth in its 3x3 neighbourhood.

    min over σ of mean_i min_{j in N(i)} |σ·d̂_i − d_j| / max(d_j, ε); neighbours without ground
    truth are skipped. The objective is piecewise linear in σ: it is minimised by a log-spaced
    search around the MRE scale, then golden-section refinement to a relative 1e-7.
    """
    valid = _valid(pred, gt, mask)
    gt = np.asarray(gt, dtype=np.float64)
    padded = np.pad(np.where(np.isfinite(gt) & (gt > 0), gt, np.nan), 1, constant_values=np.nan)
    h, w = gt.shape
    neighbours = np.stack([padded[dy:dy + h, dx:dx + w][valid]
                           for dy in range(3) for dx in range(3)], axis=1)  # (n, 9)
    p = np.asarray(pred, dtype=np.float64)[valid][:, None]

    def objective(sigma: float) -> float:
        error = np.abs(sigma * p - neighbours) / np.maximum(neighbours, _EPS)
        return float(np.mean(np.nanmin(error, axis=1)))

    centre = mre_scale(pred, gt, valid)
    grid = centre * np.exp(np.linspace(-0.7, 0.7, 141))
    values = [objective(s) for s in grid]
    k = int(np.argmin(values))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    ratio = (np.sqrt(5) - 1) / 2
    while b - a > 1e-7 * b:
        c, d = b - ratio * (b - a), a + ratio * (b - a)
        if objective(c) <= objective(d):
            b = d
        else:
            a = c
    return min(objective(0.5 * (a + b)), values[k])


def order_agreement(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None,
                    pairs: int = 20_000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Sampled pixel pairs with distinct true depths: the ratio of the larger true depth to the
    smaller, and whether the predicted order agrees with the true one."""
    valid = _valid(pred, gt, mask)
    p, g = pred[valid], gt[valid]
    if p.size < 2:
        raise ValueError("depth order needs at least 2 valid pixels")
    rng = np.random.default_rng(seed)
    i = rng.integers(0, p.size, pairs)
    j = (i + rng.integers(1, p.size, pairs)) % p.size  # never a pixel with itself
    keep = g[i] != g[j]  # ties in the ground truth have no order
    i, j = i[keep], j[keep]
    ratio = np.maximum(g[i], g[j]) / np.minimum(g[i], g[j])
    return ratio, np.sign(g[i] - g[j]) == np.sign(p[i] - p[j])


def dom(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None,
        pairs: int = 20_000, seed: int = 0) -> float:
    """Depth order measure: fraction of sampled pixel pairs whose depth order agrees."""
    return float(np.mean(order_agreement(pred, gt, mask, pairs, seed)[1]))


def median_scaled_metrics(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None
                          ) -> dict[str, float]:
    """abs_rel, sq_rel, rmse, rmse_log, δ<1.25ⁿ after scaling pred by median(gt)/median(pred)."""
    valid = _valid(pred, gt, mask)
    p, g = pred[valid].astype(np.float64), gt[valid].astype(np.float64)
    p = p * np.median(g) / np.median(p)
    ratio = np.maximum(p / g, g / p)
    return {
        "abs_rel": float(np.mean(np.abs(p - g) / g)),
        "sq_rel": float(np.mean((p - g) ** 2 / g)),
        "rmse": float(np.sqrt(np.mean((p - g) ** 2))),
        "rmse_log": float(np.sqrt(np.mean((np.log(p) - np.log(g)) ** 2))),
        "delta1": float(np.mean(ratio < 1.25)),
        "delta2": float(np.mean(ratio < 1.25**2)),
        "delta3": float(np.mean(ratio < 1.25**3)),
    }


def intrinsics_error(K_pred: np.ndarray, K_true: np.ndarray, width: int, height: int
                     ) -> dict[str, float]:
    """Relative errors of fx, fy (by the focal length) and cx, cy (by the image size)."""
    return {
        "fx_rel": float(abs(K_pred[0, 0] - K_true[0, 0]) / K_true[0, 0]),
        "fy_rel": float(abs(K_pred[1, 1] - K_true[1, 1]) / K_true[1, 1]),
        "cx_rel": float(abs(K_pred[0, 2] - K_true[0, 2]) / width),
        "cy_rel": float(abs(K_pred[1, 2] - K_true[1, 2]) / height),
    }


def umeyama_sim3(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Scale s, rotation R, translation t minimising |s·R·source + t − target|² (N, 3)."""
    mu_s, mu_t = source.mean(0), target.mean(0)
    xs, xt = source - mu_s, target - mu_t
    cov = xt.T @ xs / len(source)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    var_s = (xs**2).sum() / len(source)
    scale = float(np.trace(np.diag(D) @ S) / max(var_s, 1e-12))
    return scale, R, mu_t - scale * R @ mu_s


def trajectory_errors(poses_pred: np.ndarray, poses_true: np.ndarray) -> dict[str, float]:
    """ATE (RMSE of positions after Sim(3) alignment) and RPE between consecutive frames.

    Poses are (N, 4, 4) camera-to-world. RPE translation is in the true trajectory's units after
    the same alignment scale; RPE rotation in degrees.
    """
    if len(poses_pred) != len(poses_true) or len(poses_true) < 3:
        raise ValueError("trajectories must have the same length, at least 3 poses")
    s, R, t = umeyama_sim3(poses_pred[:, :3, 3], poses_true[:, :3, 3])
    aligned = s * poses_pred[:, :3, 3] @ R.T + t
    ate = float(np.sqrt(np.mean(np.sum((aligned - poses_true[:, :3, 3]) ** 2, axis=1))))
    rel_pred = np.linalg.inv(poses_pred[:-1]) @ poses_pred[1:]
    rel_true = np.linalg.inv(poses_true[:-1]) @ poses_true[1:]
    t_err = np.linalg.norm(s * rel_pred[:, :3, 3] - rel_true[:, :3, 3], axis=1)
    r_delta = np.linalg.inv(rel_true[:, :3, :3]) @ rel_pred[:, :3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(r_delta, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    return {"ate": ate, "rpe_translation": float(np.sqrt(np.mean(t_err**2))),
            "rpe_rotation_deg": float(np.sqrt(np.mean(angle**2))), "sim3_scale": s}
