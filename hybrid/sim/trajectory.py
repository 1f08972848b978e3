"""Withdrawal trajectories: camera-to-world poses (cm) from the cecum to the rectum.

The camera moves back along the lumen with a varying speed and pauses, keeps a smooth lateral
offset inside the lumen, and looks down the lumen (towards the cecum) with small smooth
jitter, a smooth roll, and excursions that turn it towards the wall for a few seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import minimum_filter1d
from scipy.spatial.transform import Rotation

from hybrid.sim.colon import Colon
from hybrid.sim.noise import smooth_noise


@dataclass(frozen=True)
class TrajectoryConfig:
    """How the endoscopist withdraws."""

    fps: float = 30.0
    """Frame rate."""
    mean_speed_cm_s: tuple[float, float] = (0.3, 1.0)
    """Range of the procedure's mean withdrawal speed."""
    speed_log_std: float = 0.6
    """Log-normal variation of the speed around its mean (over about 3 s)."""
    pauses_per_min: float = 2.0
    """Rate of pauses (the scope stops)."""
    pause_s: tuple[float, float] = (1.0, 6.0)
    """Duration of a pause."""
    start_depth_cm: float = 8.0
    """Start this far from the cecum end, so the look-ahead band lies inside the colon."""
    end_margin_cm: float = 2.0
    """Stop this far from the rectum end."""
    lookahead_cm: float = 4.0
    """The base view direction aims at the lumen this far ahead."""
    lateral_fraction: float = 0.35
    """Largest lateral offset as a fraction of the local radius."""
    wall_clearance_cm: float = 0.25
    """Smallest distance kept between the camera and the tip of a fold."""
    jitter_deg: float = 8.0
    """Amplitude of the small smooth deviations of the view direction."""
    excursions_per_min: tuple[float, float] = (0.5, 8.0)
    """Range of the procedure's rate of looks towards the wall."""
    excursion_deg: tuple[float, float] = (40.0, 150.0)
    """How far from the lumen direction an excursion turns the camera."""
    excursion_s: tuple[float, float] = (2.0, 20.0)
    """How long an excursion lasts, including a 1 s turn at each end."""
    roll_deg: float = 60.0
    """Amplitude of the smooth roll about the view axis."""
    max_frames: int | None = None
    """Stop after this many frames (None: withdraw to the rectum)."""


def make_withdrawal(colon: Colon, config: TrajectoryConfig, rng: np.random.Generator) -> np.ndarray:
    """(N, 4, 4) float64 camera-to-world poses of one withdrawal."""
    ell_rings = colon.arclength
    start = ell_rings[-1] - config.start_depth_cm
    if start <= config.end_margin_cm:
        raise ValueError(f"colon of {ell_rings[-1]:.1f} cm is too short for a withdrawal")
    ell = _withdrawal_arclength(start, config, rng)
    if config.max_frames is not None:
        ell = ell[:config.max_frames]
    n = ell.size
    fps = config.fps

    ring = np.interp(ell, ell_rings, np.arange(ell_rings.size))
    centre = _interp_rows(ring, colon.centerline)
    frames = _interp_rows(ring, colon.frames.reshape(-1, 9)).reshape(-1, 3, 3)
    normal = _unit(frames[:, :, 1])
    binormal = _unit(np.cross(frames[:, :, 0], normal))

    # Lateral offset inside the free lumen (wall minus folds, over +-0.5 cm).
    window = max(1, int(round(1.0 / (ell_rings[1] - ell_rings[0]))))
    free = minimum_filter1d((colon.radius[:, None] - colon.fold_depth).min(axis=1), window)
    limit = np.minimum(config.lateral_fraction * colon.radius, free - config.wall_clearance_cm)
    limit = np.interp(ring, np.arange(ell_rings.size), limit.clip(min=0.0))
    offset = smooth_noise(rng, n, 2.0 * fps, dims=2) * 0.5
    offset /= np.maximum(1.0, np.linalg.norm(offset, axis=1, keepdims=True))
    position = centre + limit[:, None] * (offset[:, :1] * normal + offset[:, 1:] * binormal)

    # Base orientation: z at the lumen ahead, y from the lumen's normal (OpenCV axes).
    ahead_ring = np.interp(np.minimum(ell + config.lookahead_cm, ell_rings[-1]), ell_rings,
                           np.arange(ell_rings.size))
    z = _unit(_interp_rows(ahead_ring, colon.centerline) - position)
    y = _unit(normal - np.sum(normal * z, axis=1, keepdims=True) * z)
    base = np.stack([np.cross(y, z), y, z], axis=2)

    deviation = np.radians(config.jitter_deg) * smooth_noise(rng, n, 1.5 * fps, dims=2)
    deviation += _excursions(n, config, rng)
    norm = np.linalg.norm(deviation, axis=1, keepdims=True)
    deviation *= np.minimum(1.0, np.radians(160.0) / np.maximum(norm, 1e-12))
    roll = np.radians(config.roll_deg) * smooth_noise(rng, n, 4.0 * fps)[:, 0] + rng.uniform(
        -np.pi, np.pi)
    turn = Rotation.from_euler("z", roll[:, None]) * Rotation.from_rotvec(
        np.concatenate([deviation, np.zeros((n, 1))], axis=1))

    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = base @ turn.as_matrix()
    poses[:, :3, 3] = position
    return poses


def _withdrawal_arclength(start: float, config: TrajectoryConfig, rng: np.random.Generator
                          ) -> np.ndarray:
    """ℓ of the camera per frame, decreasing from start to the end margin."""
    fps = config.fps
    mean_speed = rng.uniform(*config.mean_speed_cm_s)
    distance = start - config.end_margin_cm
    n = int(np.ceil(2 * distance / mean_speed * fps)) + 1
    while True:
        speed = mean_speed * np.exp(config.speed_log_std * smooth_noise(rng, n, 3.0 * fps)[:, 0]
                                    - 0.5 * config.speed_log_std**2)
        speed *= 1.0 - _bumps(n, config.pauses_per_min, config.pause_s, fps, rng)
        travelled = np.concatenate([[0.0], np.cumsum(speed[:-1]) / fps])
        if travelled[-1] >= distance:
            return start - travelled[:np.searchsorted(travelled, distance) + 1].clip(
                max=distance)
        n *= 2


def _excursions(n: int, config: TrajectoryConfig, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) pitch/yaw angles of looks towards the wall, smooth in and out."""
    rate = rng.uniform(*config.excursions_per_min)
    out = np.zeros((n, 2))
    t = np.arange(n)
    for centre, duration in _events(n, rate, config.excursion_s, config.fps, rng):
        angle = np.radians(rng.uniform(*config.excursion_deg))
        direction = rng.uniform(0, 2 * np.pi)
        shape = _plateau(t, centre, duration, ramp=config.fps)
        out += angle * shape[:, None] * np.array([np.cos(direction), np.sin(direction)])
    return out


def _bumps(n: int, per_min: float, duration_s: tuple[float, float], fps: float,
           rng: np.random.Generator) -> np.ndarray:
    """(n,) smooth 0..1 bumps at random times (used for pauses)."""
    out = np.zeros(n)
    t = np.arange(n)
    for centre, duration in _events(n, per_min, duration_s, fps, rng):
        out = np.maximum(out, np.clip(1.6 * _hann(t, centre, duration), 0.0, 1.0))
    return out


def _events(n: int, per_min: float, duration_s: tuple[float, float], fps: float,
            rng: np.random.Generator) -> list[tuple[float, float]]:
    """Poisson event (centre frame, duration in frames) pairs over n frames."""
    count = rng.poisson(per_min * n / fps / 60.0)
    centres = rng.uniform(0, n, count)
    durations = rng.uniform(*duration_s, count) * fps
    return list(zip(centres, durations, strict=True))


def _hann(t: np.ndarray, centre: float, duration: float) -> np.ndarray:
    x = np.clip((t - centre) / duration, -0.5, 0.5)
    return np.cos(np.pi * x) ** 2


def _plateau(t: np.ndarray, centre: float, duration: float, ramp: float) -> np.ndarray:
    """1 over the event, with smooth cosine ramps of `ramp` frames inside its ends."""
    ramp = min(ramp, duration / 2)
    inside = np.clip((duration / 2 - np.abs(t - centre)) / ramp, 0.0, 1.0)
    return np.sin(0.5 * np.pi * inside) ** 2


def _interp_rows(index: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Linear interpolation of table rows at fractional indices."""
    grid = np.arange(len(rows))
    return np.stack([np.interp(index, grid, rows[:, k]) for k in range(rows.shape[1])], axis=1)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)
