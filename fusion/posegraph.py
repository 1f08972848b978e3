"""Pose-graph smoothing of a monocular trajectory from network relative poses (GTSAM).

Reads relative poses `relative[g]` (N-g, 4, 4): relative[g][t] maps points of camera t into
camera t+g (learned.infer.infer_sequence). Returns camera-to-world poses (N, 4, 4), float64,
first pose = identity, that best agree with all of them under a robust (Huber) loss; the caller
saves them (np.save).

One node per frame; a between-factor per relative pose of every gap in `skips`; optionally a
constant-velocity factor per step. Batch Levenberg-Marquardt over all frames, or overlapping
windows of a fixed size, each anchored on the frames the previous one has already committed,
so that the cost grows linearly with the video's length.
"""

from __future__ import annotations

import time
from bisect import bisect_left
from dataclasses import dataclass

import gtsam
import numpy as np

from hybrid.types import InputError, chain_poses, check_poses

_MAX_STEPS = 1e6
"""Longest plausible relative translation, in median gap-1 steps."""


@dataclass(frozen=True)
class PoseGraphConfig:
    """How relative poses are weighted and the graph is optimised."""

    skips: tuple[int, ...] = (1, 2)
    """Frame gaps g whose relative poses (t -> t+g) become factors; must contain 1. With the
    relative poses refined by RGB-D odometry (fusion.odometry), (1, 2) gives the coverage
    error of (1, 2, 4, 8) for half the odometry's time; the network's own poses did better
    with (1, 2, 4, 8) (docs/posegraph.md)."""
    rotation_sigma: float = 0.02
    """Standard deviation of a gap-1 relative rotation, radians per axis."""
    translation_sigma: float = 2.0
    """Standard deviation of a gap-1 relative translation per axis, in units of the median
    length of the gap-1 translations: monocular translations have an unknown scale, so an
    absolute sigma would mean nothing."""
    gap_exponent: float = 0.5
    """Sigmas of a gap-g factor are multiplied by g ** gap_exponent (0: one sigma for all gaps;
    0.5: errors that add up like a chain of independent steps; 1: errors that grow with g)."""
    huber_k: float = 1.345
    """Huber threshold on the whitened error: residuals beyond k sigmas count linearly."""
    velocity_weight: float = 0.5
    """Constant-velocity smoothness (0 = off): a second factor on each step t -> t+1 whose
    measurement is the previous step t-1 -> t, with the gap-1 sigmas / sqrt(velocity_weight)."""
    window: int = 0
    """0: one batch optimisation over all frames. > 2 * max(skips): windows of this many
    frames, each re-using the last max(skips) committed frames as fixed anchors."""
    max_iterations: int = 100
    """Levenberg-Marquardt iterations per optimisation."""

    def __post_init__(self) -> None:
        if 1 not in self.skips or any(not isinstance(g, int) or g < 1 for g in self.skips):
            raise InputError(f"pose-graph skips must be positive integer gaps including 1, got "
                             f"{self.skips}")
        if min(self.rotation_sigma, self.translation_sigma, self.huber_k) <= 0:
            raise InputError("pose-graph rotation_sigma, translation_sigma and huber_k must be "
                             "positive")
        if self.velocity_weight < 0:
            raise InputError("pose-graph velocity_weight must be >= 0 (0 = off)")
        if not isinstance(self.max_iterations, int) or self.max_iterations < 1:
            raise InputError(f"pose-graph max_iterations must be a positive integer, got "
                             f"{self.max_iterations!r}")
        if self.window and self.window <= 2 * max(self.skips):
            raise InputError(f"pose-graph window must be 0 (batch) or more than twice the "
                             f"largest skip ({2 * max(self.skips)}), got {self.window}")


@dataclass
class PoseGraphResult:
    """Smoothed trajectory and how the optimisation went."""

    poses: np.ndarray
    """(N, 4, 4) smoothed camera-to-world poses, first = identity."""
    chained: np.ndarray
    """(N, 4, 4) the unsmoothed chain of relative[1]."""
    initial_error: float
    """Graph error (sum over windows) at the chained estimate."""
    final_error: float
    """Graph error (sum over windows) after optimisation."""
    iterations: int
    """Levenberg-Marquardt iterations, summed over windows."""
    capped: list[int]
    """First frame of each window (0 alone for a batch optimisation) whose Levenberg-Marquardt
    stopped at max_iterations rather than by converging: its poses are improved on the chain
    but may be smoothed less than the graph allows."""
    seconds: float
    """Wall time of building and optimising the graph."""


def smooth_trajectory(relative: dict[int, np.ndarray], config: PoseGraphConfig,
                      name: str = "poses") -> PoseGraphResult:
    """Camera-to-world poses (N, 4, 4) agreeing best with the relative poses of every skip.

    relative[g]: (N-g, 4, 4), relative[g][t] maps camera t's points into camera t+g, so that
    P[t+g] = P[t] @ inv(relative[g][t]). relative[1] is required; gaps g >= N are ignored.
    """
    start = time.perf_counter()
    measured = _checked(relative, config, name)
    count = len(measured[1]) + 1
    chained = chain_poses(measured[1])
    step = _median_step(measured, name)
    sigmas = np.array([config.rotation_sigma] * 3 + [config.translation_sigma * step] * 3)
    graph = _Graph(measured, config, sigmas)
    poses, initial, final, iterations, capped = graph.windowed(count, chained, name)
    poses = np.linalg.inv(poses[0]) @ poses  # the prior holds it to 1e-6: make it exact
    return PoseGraphResult(poses, chained, initial, final, iterations, capped,
                           time.perf_counter() - start)


def _checked(relative: dict[int, np.ndarray], config: PoseGraphConfig, name: str
             ) -> dict[int, np.ndarray]:
    """The used gaps' relative poses as float64, or an InputError naming what is wrong."""
    if 1 not in relative:
        raise InputError(f"{name} has no gap-1 relative poses ({name}[1]), which define the "
                         f"frames; compute relative poses for consecutive frames")
    first = np.asarray(relative[1])
    if first.ndim != 3 or first.shape[1:] != (4, 4) or len(first) < 1:
        raise InputError(f"{name}[1] must have shape (N-1, 4, 4) with N >= 2 frames, got "
                         f"{first.shape}; the pose graph needs at least 2 frames")
    count = len(first) + 1
    measured = {}
    for g in config.skips:
        if g >= count:
            continue
        if g not in relative:
            raise InputError(f"{name} has no relative poses for gap {g}; compute them or drop "
                             f"{g} from the pose-graph skips")
        shape = np.shape(relative[g])
        if shape != (count - g, 4, 4):
            raise InputError(f"{name}[{g}] must have shape ({count - g}, 4, 4) for {count} "
                             f"frames, got {shape}; relative[g][t] is the pose t -> t+g")
        measured[g] = check_poses(relative[g], f"{name}[{g}]")
    return measured


def _median_step(measured: dict[int, np.ndarray], name: str) -> float:
    """Median gap-1 translation length, after checking that every translation is plausible.

    A translation a million steps long is no camera motion, and its error would swamp the
    graph's: Levenberg-Marquardt would stop, its relative decrease below tolerance, unsmoothed.
    """
    step = float(np.median(np.linalg.norm(measured[1][:, :3, 3], axis=1)))
    if step == 0:
        raise InputError(f"{name}[1]: the camera does not move in most frames, so translation "
                         f"sigmas (relative to the median step) are undefined; smooth a stretch "
                         f"where it moves")
    for g, stack in measured.items():
        bad = np.flatnonzero(np.linalg.norm(stack[:, :3, 3], axis=1) > _MAX_STEPS * step)
        if bad.size:
            raise InputError(f"{name}[{g}] has translations over {_MAX_STEPS:.0e} times the "
                             f"median gap-1 step at frames {bad[:10].tolist()}; check the "
                             f"relative poses there")
    return step


class _Graph:
    """Factors of a pose graph over frames, built for any range of free frames."""

    def __init__(self, measured: dict[int, np.ndarray], config: PoseGraphConfig,
                 sigmas: np.ndarray):
        self.config = config
        huber = gtsam.noiseModel.mEstimator.Huber.Create(config.huber_k)

        def robust(scale: float) -> gtsam.noiseModel.Robust:
            return gtsam.noiseModel.Robust.Create(
                huber, gtsam.noiseModel.Diagonal.Sigmas(sigmas * scale))

        self.prior = gtsam.noiseModel.Diagonal.Sigmas(np.full(6, 1e-6))
        # (i, j, Z, noise) with Z the measured P_i^-1 P_j.
        self.edges = []
        for g, stack in measured.items():
            noise = robust(g ** config.gap_exponent)
            self.edges += [(t, t + g, _pose(np.linalg.inv(T)), noise) for t, T in enumerate(stack)]
        if config.velocity_weight > 0:
            velocity = robust(1 / np.sqrt(config.velocity_weight))
            self.edges += [(t + 1, t + 2, _pose(np.linalg.inv(T)), velocity)
                           for t, T in enumerate(measured[1][:-1])]
        self.edges.sort(key=lambda edge: edge[1])
        self.ends = [edge[1] for edge in self.edges]

    def optimise(self, free: range, fixed: dict[int, gtsam.Pose3], initial: np.ndarray,
                 name: str) -> tuple[np.ndarray, float, float, int]:
        """Optimise the free frames with the fixed ones held; returns (poses of the free frames,
        initial error, final error, iterations). initial holds a guess for every frame."""
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        for t in free:
            values.insert(t, _pose(initial[t]))
        if free.start == 0:
            graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), self.prior))
        first, last = bisect_left(self.ends, free.start), bisect_left(self.ends, free.stop)
        for i, j, Z, noise in self.edges[first:last]:
            if i in free:
                graph.add(gtsam.BetweenFactorPose3(i, j, Z, noise))
            else:  # i is held: Log(Z^-1 P_i^-1 P_j), the between error, is a prior P_i Z on P_j
                graph.add(gtsam.PriorFactorPose3(j, fixed[i].compose(Z), noise))
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self.config.max_iterations)
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        result = optimizer.optimize()
        poses = np.stack([result.atPose3(t).matrix() for t in free])
        before, after = graph.error(values), graph.error(result)
        check_converged(poses, before, after, name)
        return poses, before, after, optimizer.iterations()

    def windowed(self, count: int, initial: np.ndarray, name: str
                 ) -> tuple[np.ndarray, float, float, int, list[int]]:
        """Optimise windows of config.window frames in order (one window of all the frames
        when it is 0); each commits all but its last max(skips) frames, which the next window
        re-estimates with the committed frames before them held fixed. Also returns the first
        frames of the windows stopped at max_iterations."""
        lag, size = max(self.config.skips), self.config.window or count
        guess = initial.copy()
        poses = np.empty_like(initial)
        done, before, after, iterations, capped = 0, 0.0, 0.0, 0, []
        while done < count:
            stop = min(done + size - (lag if done else 0), count)
            fixed = {t: _pose(poses[t]) for t in range(max(done - lag, 0), done)}
            window, e0, e1, steps = self.optimise(range(done, stop), fixed, guess, name)
            before, after, iterations = before + e0, after + e1, iterations + steps
            if steps >= self.config.max_iterations:
                capped.append(done)
            guess[done:stop] = window
            # The next window's new frames: the chain continued from this window's last pose.
            ahead = slice(stop, stop + size)
            guess[ahead] = window[-1] @ np.linalg.inv(initial[stop - 1]) @ initial[ahead]
            commit = stop if stop == count else stop - lag
            poses[done:commit] = window[:commit - done]
            done = commit
        return poses, before, after, iterations, capped


def check_converged(poses: np.ndarray, initial_error: float, final_error: float,
                    name: str) -> None:
    """InputError unless the optimised poses are finite and the error did not grow."""
    if (not np.isfinite(poses).all() or not np.isfinite(final_error)
            or final_error > initial_error * (1 + 1e-9)):
        raise InputError(f"the pose graph of {name} did not converge (error {initial_error:.4g} "
                         f"-> {final_error:.4g}); check the relative poses for absurd values, "
                         f"or raise rotation_sigma / translation_sigma")


def _pose(T: np.ndarray) -> gtsam.Pose3:
    """gtsam.Pose3 from a 4x4, its rotation projected onto SO(3)."""
    return gtsam.Pose3(gtsam.Rot3.ClosestTo(T[:3, :3]), T[:3, 3])
