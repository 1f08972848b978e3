"""Shared fixtures: a hand-made open cylinder, analytic field-of-view fractions, a simulated
procedure, a video writer.

The cylinder is built here, not by the simulator, so that coverage is checked against geometry
whose visible area can be integrated by hand: wall point (R cos θ, R sin θ, z), lumen = the
z axis from z = 0 to z = L (so ℓ* of any point is its z, clipped to [0, L]).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from hybrid.types import Camera
from learned.config import DEPTH_PRESETS

os.environ["C2D2_DEVICE"] = "cpu"
"""Commands under test run their networks on the CPU whatever the machine, so that results
compare with CPU references; tests/test_device.py asks for the GPU itself."""


@dataclass(frozen=True)
class Cylinder:
    """An open straight tube of S vertices per ring, rings `spacing` apart along +z."""

    radius: float
    length: float
    spacing: float
    segments: int
    vertices: np.ndarray
    triangles: np.ndarray

    @property
    def lumen(self) -> np.ndarray:
        """(2, 3) centerline: the axis from z = 0 to z = L."""
        return np.array([[0.0, 0.0, 0.0], [0.0, 0.0, self.length]])

    @property
    def ring_z(self) -> np.ndarray:
        """z of each vertex."""
        return self.vertices[:, 2]


def make_cylinder(radius: float = 2.0, length: float = 10.0, spacing: float = 0.04,
                  segments: int = 1024) -> Cylinder:
    """Open cylinder (no caps) around the z axis; vertices on the circle of radius R.

    Coordinates are rounded to float32 (moving them < 1e-6 cm) so that a PLY file, which
    trimesh writes in float32, holds exactly these vertices.
    """
    n_rings = int(round(length / spacing)) + 1
    z = np.linspace(0.0, length, n_rings)
    theta = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    zz, tt = np.meshgrid(z, theta, indexing="ij")
    vertices = np.stack([radius * np.cos(tt), radius * np.sin(tt), zz], axis=-1).reshape(-1, 3)
    vertices = vertices.astype(np.float32).astype(np.float64)
    i, j = np.meshgrid(np.arange(n_rings - 1), np.arange(segments), indexing="ij")
    a = i * segments + j
    b = i * segments + (j + 1) % segments
    c, d = a + segments, b + segments
    triangles = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3),
                                np.stack([b, c, d], -1).reshape(-1, 3)]).astype(np.int64)
    return Cylinder(radius, length, spacing, segments, vertices, triangles)


def pose(rotation_columns: tuple, position: tuple) -> np.ndarray:
    """4x4 camera-to-world pose from the camera's x, y, z axes in world coordinates."""
    T = np.eye(4)
    T[:3, :3] = np.stack([np.asarray(c, dtype=np.float64) for c in rotation_columns], axis=1)
    T[:3, 3] = position
    assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3)) and np.linalg.det(T[:3, :3]) > 0
    return T


def in_image(camera: Camera, pose_c2w: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Whether world points project inside the image extent [-0.5, W-0.5] x [-0.5, H-0.5]
    and lie in front of the camera (the definition in README/design.md)."""
    R, p = pose_c2w[:3, :3], pose_c2w[:3, 3]
    xc = (points - p) @ R
    z = xc[..., 2]
    front = z > 0
    zs = np.where(front, z, 1.0)
    u = camera.fx * xc[..., 0] / zs + camera.cx
    v = camera.fy * xc[..., 1] / zs + camera.cy
    return front & (u >= -0.5) & (u <= camera.width - 0.5) & (v >= -0.5) & (
        v <= camera.height - 0.5)


@dataclass(frozen=True)
class WallFraction:
    """Analytic visible fraction of the wall band z in [z0, z1], by a midpoint grid."""

    value: float
    """Visible area / band area."""
    total_variation: float
    """Total variation over the band of f(z), the visible fraction of the ring at z."""
    grid_error: float
    """Bound on this reference's own quadrature error (see wall_fraction)."""


def wall_fraction(camera: Camera, poses: list[np.ndarray], radius: float, z0: float, z1: float,
                  n_arcs: int, nz: int = 400, ntheta: int = 4096) -> WallFraction:
    """Fraction of the wall area of the band seen by at least one of the cameras.

    The wall element R dθ dz is uniform, so the fraction is the mean over a midpoint grid in
    (z, θ). Its own error is at most TV/nz (midpoint rule in z: each cell is off by at most
    the oscillation of f over it) plus n_arcs/ntheta (each visible arc of a ring gains or
    loses at most one θ sample).
    """
    z = z0 + (np.arange(nz) + 0.5) * (z1 - z0) / nz
    theta = (np.arange(ntheta) + 0.5) * 2 * np.pi / ntheta
    points = np.stack(np.broadcast_arrays(radius * np.cos(theta)[None, :],
                                          radius * np.sin(theta)[None, :], z[:, None]), axis=-1)
    seen = np.zeros(points.shape[:2], dtype=bool)
    for p in poses:
        seen |= in_image(camera, p, points)
    f = seen.mean(axis=1)
    tv = float(np.abs(np.diff(f)).sum())
    return WallFraction(float(f.mean()), tv, tv / nz + n_arcs / ntheta)


def mesh_tolerance(cylinder: Cylinder, band: float, total_variation: float, n_arcs: int
                   ) -> float:
    """How far the mesh's area-weighted vertex fraction may be from the continuous one.

    z: the rings of the band tile it exactly, so the vertex sum is a midpoint rule with cells
    one ring spacing h long; each cell is off by at most h times the oscillation of f over it,
    in all h·TV, i.e. h·TV/band as a fraction. θ: the S vertices of a ring count each visible
    arc to within one vertex, so at most n_arcs/S.
    """
    return cylinder.spacing * total_variation / band + n_arcs / cylinder.segments


@pytest.fixture(scope="session")
def cylinder() -> Cylinder:
    """R = 2 cm, L = 10 cm, rings 0.04 cm apart, 1024 vertices around.

    The spacing is a multiple of the lumen's 0.02 cm resampling, so each ring's ℓ* is its z
    exactly; cameras at ℓ = 0.02 + 0.04 k put every band edge ℓ + Δ mid-way between two rings,
    so the rings of a band tile it exactly.
    """
    return make_cylinder()


@pytest.fixture(scope="session")
def sim_config():
    """A short, fast procedure: 14 cm colon, 40 frames, 20-frame segments."""
    from hybrid.sim.simulate import SimConfig, with_overrides

    return replace(with_overrides(SimConfig(), length_cm=14.0, max_frames=40), segment_frames=20)


@pytest.fixture(scope="session")
def simulated(tmp_path_factory, sim_config) -> Path:
    """Procedure 0 of seed 7 written by simulate_procedure."""
    from hybrid.sim.simulate import simulate_procedure

    return simulate_procedure(tmp_path_factory.mktemp("sim_a"), 7, 0, sim_config)


TINY = replace(DEPTH_PRESETS["fast"], height=64, width=96, batch_size=2, learning_rate=1e-3,
               encoder_channels=(8, 8, 16, 16, 32), decoder_channels=(8, 8, 8, 16, 16),
               motion_channels=(8, 8, 16, 16, 32))
"""The fast depth preset shrunk for tests (its preset name stays 'fast')."""


@pytest.fixture(scope="session")
def clip(tmp_path_factory) -> Path:
    """A 30-frame simulated procedure of a 14 cm colon."""
    from hybrid.sim.simulate import SimConfig, simulate_procedure, with_overrides

    return simulate_procedure(tmp_path_factory.mktemp("clip"), 3, 0,
                              with_overrides(SimConfig(), length_cm=14, max_frames=30))


def bn_running_statistics(module: torch.nn.Module) -> torch.Tensor:
    """A copy of every batch-norm layer's running mean and variance in `module`, in one tensor."""
    return torch.cat([t.clone() for m in module.modules() if isinstance(m, torch.nn.BatchNorm2d)
                      for t in (m.running_mean, m.running_var)])


@pytest.fixture
def one_thread():
    """Keep torch on one thread: the machine is shared, and results stay deterministic."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def write_video(path: Path, frames: list[np.ndarray], fps: float) -> Path:
    """MJPG .avi (lossy but decodable everywhere) of RGB frames."""
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (width, height))
    assert writer.isOpened()
    for frame in frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()
    return path


def unboxed(text: str) -> str:
    """A command's error output as one line: the frame Typer draws around a usage error and
    its line breaks removed."""
    return " ".join(re.sub("[│╭╮╰╯─]", " ", text).split())
