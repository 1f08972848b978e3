"""Procedural colon: lumen centerline, smooth radius profile, haustral folds, triangle mesh.

All lengths are in centimetres. The lumen is sampled by arc length ℓ from the rectum end.
The wall is a tube swept along the centerline with rotation-minimising frames; folds are
inward ridges of the wall in three pieces between the taeniae, so they hide the wall behind them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial import cKDTree

from hybrid.sim.noise import smooth_noise

# Colon shape from the rectum end: (segment length cm, turn in the main plane, degrees).
# Rectum, sigmoid S-bend, descending, splenic flexure, transverse, hepatic flexure, ascending.
_TEMPLATE = (
    (15.0, 0.0), (10.0, 60.0), (20.0, -120.0), (10.0, 60.0), (25.0, 0.0),
    (15.0, -100.0), (12.0, 20.0), (16.0, -40.0), (12.0, 20.0), (15.0, -80.0), (15.0, 0.0),
)
_TEMPLATE_LENGTH = sum(length for length, _ in _TEMPLATE)
_SHAPE_STEP_CM = 0.1
"""Grid on which the random shape is drawn, independent of the mesh resolution."""


@dataclass(frozen=True)
class ColonConfig:
    """Shape and mesh resolution of a procedural colon."""

    length_cm: float = 120.0
    """Lumen length from rectum to cecum."""
    radius_range_cm: tuple[float, float] = (1.5, 3.5)
    """Range of the smooth base radius along the lumen."""
    fold_height_cm: tuple[float, float] = (0.3, 1.0)
    """How far a haustral fold stands into the lumen."""
    fold_spacing_cm: tuple[float, float] = (2.0, 5.0)
    """Distance between consecutive fold rings."""
    fold_sigma_cm: float = 0.15
    """Gaussian half-thickness of a fold along the lumen."""
    folds: bool = True
    """Whether to add haustral folds."""
    ring_spacing_cm: float = 0.1
    """Mesh resolution along the lumen."""
    segments_around: int = 128
    """Mesh resolution around the lumen."""
    min_bend_radius_cm: float = 8.0
    """Smallest radius of curvature of the centerline."""
    shape_noise_deg: float = 15.0
    """Amplitude of the random smooth deviation from the template shape."""


@dataclass(frozen=True)
class Colon:
    """A colon mesh with its lumen. Arrays in cm, float64."""

    centerline: np.ndarray
    """(M, 3) lumen points from the rectum end, one per mesh ring."""
    radius: np.ndarray
    """(M,) base radius (without folds) at each centerline point."""
    frames: np.ndarray
    """(M, 3, 3) rotation-minimising frames: columns tangent, normal, binormal."""
    vertices: np.ndarray
    """(M * S + 1, 3) wall vertices ring by ring, then the centre of the cecum cap."""
    triangles: np.ndarray
    """(T, 3) int32 triangle indices; open at the rectum end, capped at the cecum."""
    surface_uv: np.ndarray
    """(M * S + 1, 2) surface coordinates of each vertex: (ℓ, θ·r̄) in cm, for texturing."""
    fold_depth: np.ndarray
    """(M, S) inward displacement of the wall by folds, cm."""

    @property
    def arclength(self) -> np.ndarray:
        """(M,) cumulative arc length ℓ of the centerline points."""
        steps = np.linalg.norm(np.diff(self.centerline, axis=0), axis=1)
        return np.concatenate([[0.0], np.cumsum(steps)])


def make_colon(config: ColonConfig, rng: np.random.Generator) -> Colon:
    """Draw one colon. Deterministic for a given generator state.

    The shape (centerline, radius, folds) is drawn on a fixed 1 mm grid and then sampled at the
    mesh resolution, so the same generator state gives the same colon at any resolution.
    """
    if config.length_cm <= 0:
        raise ValueError(f"colon length must be positive, got {config.length_cm}")
    n_shape = int(round(config.length_cm / _SHAPE_STEP_CM)) + 1
    shape_ell = np.linspace(0.0, config.length_cm, n_shape)
    shape_centerline = _centerline(shape_ell, config, rng)
    shape_radius = _radius_profile(shape_ell, config, rng)
    folds = _draw_folds(config, rng) if config.folds else []

    n_rings = int(round(config.length_cm / config.ring_spacing_cm)) + 1
    ell = np.linspace(0.0, config.length_cm, n_rings)
    spline = CubicSpline(shape_ell, shape_centerline)
    centerline = spline(ell)
    radius = np.interp(ell, shape_ell, shape_radius)
    frames = _rotation_minimising_frames(centerline, spline(ell, 1))
    theta = np.linspace(0.0, 2 * np.pi, config.segments_around, endpoint=False)
    fold_depth = _fold_depth(ell, theta, folds, config.fold_sigma_cm)
    wall_radius = radius[:, None] - fold_depth
    directions = (np.cos(theta)[None, :, None] * frames[:, None, :, 1]
                  + np.sin(theta)[None, :, None] * frames[:, None, :, 2])
    vertices = centerline[:, None, :] + wall_radius[..., None] * directions
    mean_radius = float(np.mean(config.radius_range_cm))
    uv = np.stack(np.broadcast_arrays(ell[:, None], theta[None, :] * mean_radius), axis=-1)
    # A flat cap closes the cecum end, so that views down the lumen never look out of the colon.
    last_ring = (n_rings - 1) * theta.size + np.arange(theta.size)
    cap_centre = n_rings * theta.size
    cap = np.stack([np.full(theta.size, cap_centre), np.roll(last_ring, -1), last_ring], axis=1)
    return Colon(
        centerline=centerline, radius=radius, frames=frames,
        vertices=np.concatenate([vertices.reshape(-1, 3), centerline[-1:]]),
        triangles=np.concatenate([tube_triangles(n_rings, theta.size), cap]).astype(np.int32),
        surface_uv=np.concatenate([uv.reshape(-1, 2), [[ell[-1], 0.0]]]), fold_depth=fold_depth,
    )


def tube_triangles(n_rings: int, n_around: int) -> np.ndarray:
    """Triangles joining consecutive rings of n_around vertices (ring-major order)."""
    i, j = np.meshgrid(np.arange(n_rings - 1), np.arange(n_around), indexing="ij")
    a = i * n_around + j
    b = i * n_around + (j + 1) % n_around
    c, d = a + n_around, b + n_around
    quads = np.stack([a, b, c, d], axis=-1).reshape(-1, 4)
    tris = np.concatenate([quads[:, [0, 2, 1]], quads[:, [1, 2, 3]]])
    return tris.astype(np.int32)


def _centerline(ell: np.ndarray, config: ColonConfig, rng: np.random.Generator) -> np.ndarray:
    """Integrate a heading that follows the template turns plus smooth noise.

    Draws again (from the same generator) until the curvature bound holds and no two distant
    parts of the colon come close enough for their walls to touch.
    """
    step = ell[1] - ell[0]
    scale = max(1.0, config.length_cm / _TEMPLATE_LENGTH)
    bounds = np.cumsum([0.0] + [length * scale for length, _ in _TEMPLATE])
    turn_rate = np.zeros_like(ell)
    for k, (_, turn_deg) in enumerate(_TEMPLATE):
        inside = (ell >= bounds[k]) & (ell < bounds[k + 1])
        turn_rate[inside] = np.radians(turn_deg) / (bounds[k + 1] - bounds[k])
    max_curvature = 1.0 / config.min_bend_radius_cm
    clearance = 2 * config.radius_range_cm[1] + 1.0
    for _ in range(100):
        sigma = 12.0 / step  # noise varies over about 12 cm
        noise = smooth_noise(rng, ell.size, sigma, dims=2) * np.radians(config.shape_noise_deg)
        heading = np.cumsum(turn_rate) * step + noise[:, 0] + rng.uniform(0, 2 * np.pi)
        pitch = 0.5 * noise[:, 1]
        direction = np.stack([np.cos(pitch) * np.cos(heading), np.cos(pitch) * np.sin(heading),
                              np.sin(pitch)], axis=1)
        points = np.concatenate([[np.zeros(3)], np.cumsum(direction[:-1] * step, axis=0)])
        if _curvature(direction, step).max() <= max_curvature and _walls_apart(
                points, ell, clearance):
            return points
    raise RuntimeError("could not draw a colon centerline within the curvature bound")


def _curvature(direction: np.ndarray, step: float) -> np.ndarray:
    """Curvature from unit tangents, smoothed over 1 cm to ignore sampling noise."""
    turn = np.linalg.norm(np.diff(direction, axis=0), axis=1) / step
    window = max(1, int(round(1.0 / step)))
    return np.convolve(turn, np.ones(window) / window, mode="same")


def _walls_apart(points: np.ndarray, ell: np.ndarray, clearance: float) -> bool:
    """True when points farther apart along the lumen than 3·clearance are > clearance apart."""
    pairs = cKDTree(points).query_pairs(clearance, output_type="ndarray")
    return not np.any(np.abs(ell[pairs[:, 0]] - ell[pairs[:, 1]]) > 3 * clearance)


def _radius_profile(ell: np.ndarray, config: ColonConfig, rng: np.random.Generator) -> np.ndarray:
    """Smooth radius within radius_range_cm, varying over about 8 cm."""
    step = ell[1] - ell[0]
    signal = smooth_noise(rng, ell.size, 8.0 / step)[:, 0]
    signal = np.tanh(0.8 * signal)  # in (-1, 1), spends most time away from the limits
    lo, hi = config.radius_range_cm
    return 0.5 * (lo + hi) + 0.5 * (hi - lo) * signal


def _rotation_minimising_frames(points: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """(M, 3, 3) frames [tangent, normal, binormal] by the double-reflection method.

    tangents come from the shape's spline, so the first frame does not depend on the sampling.
    """
    tangents = tangents / np.linalg.norm(tangents, axis=1, keepdims=True)
    seed = np.eye(3)[np.argmin(np.abs(tangents[0]))]
    normal = np.cross(tangents[0], seed)
    normal /= np.linalg.norm(normal)
    frames = np.empty((len(points), 3, 3))
    frames[0] = np.stack([tangents[0], normal, np.cross(tangents[0], normal)], axis=1)
    for i in range(len(points) - 1):
        v1 = points[i + 1] - points[i]
        c1 = v1 @ v1
        n_l = normal - (2 / c1) * (v1 @ normal) * v1
        t_l = tangents[i] - (2 / c1) * (v1 @ tangents[i]) * v1
        v2 = tangents[i + 1] - t_l
        c2 = v2 @ v2
        normal = n_l - (2 / c2) * (v2 @ n_l) * v2 if c2 > 1e-20 else n_l
        normal /= np.linalg.norm(normal)
        frames[i + 1] = np.stack([tangents[i + 1], normal, np.cross(tangents[i + 1], normal)],
                                 axis=1)
    return frames


@dataclass(frozen=True)
class _FoldPiece:
    position_cm: float
    centre_rad: float
    half_span_rad: float
    height_cm: float


def _draw_folds(config: ColonConfig, rng: np.random.Generator) -> list[_FoldPiece]:
    """Fold rings every fold_spacing_cm, each three crescent pieces between the taeniae.

    The taeniae are 120° apart; each piece has its own height, span and offset along the lumen.
    """
    lo, hi = config.fold_spacing_cm
    taenia = rng.uniform(0, 2 * np.pi)
    pieces = []
    position = rng.uniform(lo, hi)
    while position < config.length_cm - 1.0:
        for piece in range(3):
            pieces.append(_FoldPiece(
                position_cm=position + rng.uniform(-0.3, 0.3),
                centre_rad=taenia + (piece + 0.5) * 2 * np.pi / 3,
                half_span_rad=np.radians(rng.uniform(45.0, 58.0)),
                height_cm=rng.uniform(*config.fold_height_cm),
            ))
        position += rng.uniform(lo, hi)
    return pieces


def _fold_depth(ell: np.ndarray, theta: np.ndarray, pieces: list[_FoldPiece], sigma_cm: float
                ) -> np.ndarray:
    """(M, S) inward wall displacement: Gaussian along ℓ, crescent-shaped around θ."""
    depth = np.zeros((ell.size, theta.size))
    for p in pieces:
        offset = np.angle(np.exp(1j * (theta - p.centre_rad)))
        across = np.sqrt(np.clip(1 - (offset / p.half_span_rad) ** 2, 0, None))
        along = np.exp(-0.5 * ((ell - p.position_cm) / sigma_cm) ** 2)
        depth = np.maximum(depth, p.height_cm * along[:, None] * across[None, :])
    return depth
