"""learned.geometry: view synthesis of an analytic scene, and axis-angle transforms.

The scene is a slightly tilted plane Z = Z0 + a·X + b·Y (target camera = world frame) with a
texture made of a few sinusoids in world X, Y. Both views are rendered noise-free by per-pixel
ray-plane intersection, so the only error of warping the source into the target with the true
depth, pose and K is bilinear resampling of a smooth texture.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from learned.config import DepthConfig
from learned.geometry import Warp, transform_from, warp
from learned.losses import _coarse_error, _relit, photometric_error

H, W = 48, 64
FX, FY, CX, CY = 50.0, 52.0, 31.7, 23.4
Z0, A, B = 5.0, 0.1, -0.05
"""Plane Z = Z0 + A·X + B·Y in the target camera's frame (OpenCV: x right, y down, z ahead)."""
WAVELENGTHS = (1.6, 1.9, 2.1, 1.3, 1.7)
"""World wavelengths of the texture's sinusoids; a pixel covers about Z/f ≈ 0.1 world units."""


def texture(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(3, ...) RGB in [0.1, 0.9]: sums of sinusoids in world X, Y."""
    k = 2 * np.pi
    r = 0.5 + 0.15 * np.sin(k * x / 1.6 + 0.3) + 0.1 * np.cos(k * y / 1.9)
    g = 0.5 + 0.12 * np.sin(k * (x + y) / 2.1) + 0.1 * np.sin(k * y / 1.3 + 1.0)
    b = 0.5 + 0.15 * np.cos(k * (x - 0.5 * y) / 1.7)
    return np.stack([r, g, b])


def rotation(axis, angle: float) -> np.ndarray:
    """Rodrigues' formula, by hand."""
    n = np.asarray(axis, dtype=np.float64)
    n = n / np.linalg.norm(n)
    k = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def render(R: np.ndarray, t: np.ndarray, cx: float = CX) -> tuple[np.ndarray, np.ndarray,
                                                                   np.ndarray]:
    """Image (3, H, W), z-depth (H, W) and hit points (H, W, 3) in world of a camera with
    X_cam = R·X_world + t, by intersecting each pixel's ray with the plane."""
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    ray_cam = np.stack([(u - cx) / FX, (v - CY) / FY, np.ones_like(u)], axis=-1)  # z = 1
    centre = -R.T @ t
    ray_world = ray_cam @ R  # R^T · ray
    normal = np.array([-A, -B, 1.0])
    s = (Z0 - normal @ centre) / (ray_world @ normal)  # ray parameter = z-depth (ray z is 1)
    hit = centre + s[..., None] * ray_world
    return texture(hit[..., 0], hit[..., 1]), s, hit


R_TRUE = rotation([0.3, 1.0, 0.2], math.radians(4.0))
T_TRUE = np.array([0.25, -0.15, 0.4])
"""Target -> source: X_s = R·X_t + t (source rotated 4 degrees and moved 0.5 units)."""


def as_t(x: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(x), dtype=torch.float32)


def matrix(R: np.ndarray, t: np.ndarray) -> torch.Tensor:
    T = torch.eye(4)[None].clone()
    T[0, :3, :3], T[0, :3, 3] = as_t(R), as_t(t)
    return T


def intrinsics(scale: float = 1.0) -> torch.Tensor:
    return as_t(np.array([[FX * scale, 0, CX], [0, FY * scale, CY], [0, 0, 1.0]]))[None]


@pytest.fixture(scope="module")
def scene():
    """The rendered views, with torch on one thread for this module's tests (restored after
    them, so that the rest of the session keeps its own count)."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    target, target_depth, hit = render(np.eye(3), np.zeros(3))
    source, _, _ = render(R_TRUE, T_TRUE)
    yield {"target": as_t(target)[None], "depth": as_t(target_depth)[None, None],
           "source": as_t(source)[None], "hit": hit}
    torch.set_num_threads(previous)


def interior(valid: torch.Tensor) -> torch.Tensor:
    """Valid pixels whose 3x3 neighbourhood is valid too (SSIM's window sees only them)."""
    return -F.max_pool2d(-valid.float(), 3, 1, 1) > 0


def mean_error(scene, T: torch.Tensor, K: torch.Tensor) -> float:
    w = warp(scene["source"], scene["depth"], T, K)
    keep = interior(w.valid)
    assert keep.float().mean() > 0.7  # the views overlap on most of the image
    return float(photometric_error(w.image, scene["target"], DepthConfig())[keep].mean())


def shift_error(scene, pixels: float) -> float:
    """Reference: the photometric error of the target against itself rendered with the
    principal point moved by `pixels` (a uniform misregistration)."""
    shifted, _, _ = render(np.eye(3), np.zeros(3), cx=CX + pixels)
    error = photometric_error(as_t(shifted)[None], scene["target"], DepthConfig())
    return float(error[..., 1:-1, 1:-1].mean())


def displacement(R: np.ndarray, t: np.ndarray, scale: float) -> np.ndarray:
    """(H, W) distance in source pixels between where the target pixels project with the given
    (R, t, focal scale) and with the true ones, using the true depth; by hand."""
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    _, depth, _ = render(np.eye(3), np.zeros(3))

    def project(R, t, fx, fy):
        points = np.stack([(u - CX) / fx * depth, (v - CY) / fy * depth, depth], axis=-1)
        m = points @ R.T + t
        return np.stack([fx * m[..., 0] / m[..., 2] + CX, fy * m[..., 1] / m[..., 2] + CY], -1)

    return np.linalg.norm(project(R, t, FX * scale, FY * scale)
                          - project(R_TRUE, T_TRUE, FX, FY), axis=-1)


def test_warp_with_the_true_pose_reproduces_the_target(scene):
    w = warp(scene["source"], scene["depth"], matrix(R_TRUE, T_TRUE), intrinsics())
    keep = interior(w.valid)

    # Geometry: z of each target point in the source camera, and the ray-length ratio, equal
    # the analytic hit points moved by (R, t). float32 arithmetic on values ~5: 1e-5 relative.
    moved = scene["hit"] @ R_TRUE.T + T_TRUE
    np.testing.assert_allclose(w.depth_in_source[0, 0].numpy(), moved[..., 2], rtol=1e-5)
    ratio = np.linalg.norm(moved, axis=-1) / np.linalg.norm(scene["hit"], axis=-1)
    np.testing.assert_allclose(w.ray_ratio[0, 0].numpy(), ratio, rtol=1e-5)

    # Valid = lands inside the source image: compare with projecting the hit points by hand.
    u = FX * moved[..., 0] / moved[..., 2] + CX
    v = FY * moved[..., 1] / moved[..., 2] + CY
    inside = (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
    margin = (np.abs(u - np.clip(u, 0, W - 1)) > 1e-3) | (np.abs(v - np.clip(v, 0, H - 1)) > 1e-3)
    clear = inside | margin  # skip pixels within 1e-3 px of the edge (float32 rounding)
    assert np.array_equal(w.valid[0, 0].numpy()[clear], inside[clear])

    # Intensities: bilinear interpolation of f errs by at most (|f_uu| + |f_vv|)/8 per pixel.
    # The shortest wavelength is 1.3 world units over ≤ 0.12 units per source pixel (z ≤ 6,
    # f = 50), i.e. ≥ 10.8 px; amplitudes per channel sum to ≤ 0.25, so
    # |f''| ≤ 0.25·(2π/10.8)² and the error ≤ 2·that/8.
    bound = 2 * 0.25 * (2 * np.pi / 10.8) ** 2 / 8
    assert float(moved[..., 2].max()) < 6.0
    diff = (w.image - scene["target"]).abs()
    assert float(diff[keep.expand_as(diff)].max()) < bound

    # Photometric error: an order of magnitude below that of a half-pixel misregistration.
    error = float(photometric_error(w.image, scene["target"], DepthConfig())[keep].mean())
    assert error < 0.1 * shift_error(scene, 0.5)


@pytest.mark.parametrize("case", ["fx,fy -10%", "fx,fy +10%", "translation x1.5",
                                  "rotation +1 deg about x", "rotation +2 deg about y"])
def test_warp_error_grows_when_pose_or_intrinsics_are_wrong(scene, case):
    """Each perturbation misregisters the warp by at least half a pixel on average (checked by
    projecting by hand), so its error must exceed that of a uniform quarter-pixel shift, itself
    far above the error at the true parameters."""
    R, t, scale = R_TRUE, T_TRUE, 1.0
    if case.startswith("fx"):
        scale = 0.9 if "-" in case else 1.1
    elif case.startswith("translation"):
        t = 1.5 * T_TRUE
    elif case.endswith("about x"):
        R = rotation([1, 0, 0], math.radians(1.0)) @ R_TRUE
    else:
        R = rotation([0, 1, 0], math.radians(2.0)) @ R_TRUE
    assert displacement(R, t, scale).mean() > 0.5
    true_error = mean_error(scene, matrix(R_TRUE, T_TRUE), intrinsics())
    wrong_error = mean_error(scene, matrix(R, t), intrinsics(scale))
    assert wrong_error > shift_error(scene, 0.25) > 5 * true_error


@pytest.mark.parametrize("axis,angle", [((0, 0, 1), 0.3), ((1, 0, 0), -0.7),
                                        ((0.2, -0.5, 0.8), 1.1)])
def test_transform_from_matches_rodrigues(axis, angle):
    n = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    translation = np.array([0.5, -1.0, 2.0])
    T = transform_from(torch.tensor(n * angle)[None], torch.tensor(translation)[None])
    assert T.shape == (1, 4, 4)
    expected = np.eye(4)
    expected[:3, :3], expected[:3, 3] = rotation(n, angle), translation
    # float64 throughout: agreement to rounding.
    np.testing.assert_allclose(T[0].numpy(), expected, atol=1e-12)
    if axis == (0, 0, 1):  # the textbook matrix, written out
        c, s = math.cos(angle), math.sin(angle)
        np.testing.assert_allclose(T[0, :3, :3].numpy(), [[c, -s, 0], [s, c, 0], [0, 0, 1]],
                                   atol=1e-12)


def test_transform_from_is_batched_and_composes():
    """Rotations about one axis compose by adding angles; T(-θ) inverts T(θ) with t = 0."""
    r = torch.tensor([[0.0, 0.0, 0.2], [0.0, 0.0, 0.5], [0.0, 0.0, -0.2]], dtype=torch.float64)
    T = transform_from(r, torch.zeros(3, 3, dtype=torch.float64))
    np.testing.assert_allclose((T[0] @ T[0]).numpy(),
                               transform_from(r[:1] * 2, torch.zeros(1, 3, dtype=torch.float64)
                                              )[0].numpy(), atol=1e-12)
    np.testing.assert_allclose((T[0] @ T[2]).numpy(), np.eye(4), atol=1e-12)


def test_coarse_levels_follow_the_warp_of_the_analytic_scene(scene):
    """At 1/2 and 1/4 resolution the true pose still explains the target best: a 1.5x
    translation, which misregisters by more than half a pixel at full resolution (see above),
    at least doubles the coarse error, although that is under 1/4 of a pixel at 1/4 size."""
    mask = torch.ones(1, 1, H, W, dtype=torch.bool)

    def coarse(T: torch.Tensor, level: int) -> float:
        w = warp(scene["source"], scene["depth"], T, intrinsics())
        keep = interior(w.valid)[..., 4:-4, 4:-4]
        error = _coarse_error(scene["source"], scene["target"], w, mask, level, DepthConfig(),
                              full=torch.zeros(1, 1, H, W))
        return float(error[..., 4:-4, 4:-4][keep].mean())

    for level in (1, 2):
        true_error = coarse(matrix(R_TRUE, T_TRUE), level)
        assert coarse(matrix(R_TRUE, 1.5 * T_TRUE), level) > 2 * true_error


def test_coarse_levels_reach_further_than_full_resolution():
    """White noise shifted by s pixels while the warp assumes no motion: the full-resolution
    error is at its ceiling from 1 pixel on, but a level of block size b = 2^level keeps
    growing until s = b (correlation of block means 1 - s/b, L1 error proportional to
    sqrt(s/b): x1.41 from s = b/2 to s = b), then stays."""
    image = torch.rand(1, 3, 256, 320, generator=torch.Generator().manual_seed(1))
    config = replace(DepthConfig(), w_ssim=0.0, w_l1=1.0, brightness_match=False)
    v, u = torch.meshgrid(torch.arange(128.0), torch.arange(160.0), indexing="ij")
    still = Warp(image=None, valid=None, depth_in_source=None, sampled_source_depth=None,
                 ray_ratio=torch.ones(1, 1, 128, 160), where=torch.stack([u, v], -1)[None])
    target = image[..., 64:192, 80:240]
    mask = torch.ones(1, 1, 128, 160, dtype=torch.bool)

    def error(shift: int, level: int) -> float:
        source = image[..., 64:192, 80 + shift:240 + shift]
        if level == 0:
            e = photometric_error(source, target, config)
        else:
            e = _coarse_error(source, target, still, mask, level, config,
                              full=torch.zeros(1, 1, 128, 160))
        return float(e[..., 8:-8, 8:-8].mean())

    assert error(8, 0) == pytest.approx(error(1, 0), rel=0.02)
    for level in (1, 2):
        b = 2**level
        assert error(b, level) / error(b // 2, level) == pytest.approx(math.sqrt(2), rel=0.05)
        assert error(2 * b, level) == pytest.approx(error(b, level), rel=0.02)


def test_coarse_levels_keep_the_full_error_where_a_block_is_not_wholly_usable(scene):
    """A pixel outside the usable mask makes its whole 4x4 block fall back to the
    full-resolution error at level 2; other blocks get the coarse one."""
    w = warp(scene["source"], scene["depth"], matrix(R_TRUE, 1.5 * T_TRUE), intrinsics())
    mask = torch.ones(1, 1, H, W, dtype=torch.bool)
    mask[..., 9, 13] = False  # in the block of rows 8-11, columns 12-15
    full = torch.full((1, 1, H, W), 7.0)
    error = _coarse_error(scene["source"], scene["target"], w, mask, 2, DepthConfig(), full)
    assert (error[..., 8:12, 12:16] == 7.0).all()
    assert (error[..., :8, :] != 7.0).all() and (error[..., 12:, :] != 7.0).all()


def photometric_loss(target: torch.Tensor, source: torch.Tensor, target_depth: torch.Tensor,
                     t: np.ndarray, config: DepthConfig,
                     region: torch.Tensor | None = None) -> float:
    """The photometric term of the whole loss, one source seen with the true rotation and
    translation t (both orders), the true K and the source's true depth; region: the image
    region (None: the whole image)."""
    from kornia.geometry.conversions import rotation_matrix_to_axis_angle

    from learned.losses import view_synthesis_loss

    _, source_depth, _ = render(R_TRUE, T_TRUE)
    T = matrix(R_TRUE, t)
    back = torch.linalg.inv(T)
    motion = (rotation_matrix_to_axis_angle(T[:, :3, :3]), T[:, :3, 3],
              rotation_matrix_to_axis_angle(back[:, :3, :3]), back[:, :3, 3])
    torch.manual_seed(0)  # the auto-mask's tie-breaking noise
    return float(view_synthesis_loss(
        target, [source], target_depth, [as_t(source_depth)[None, None]], [motion],
        intrinsics(), torch.ones(1, 1, H, W) if region is None else region, config).photometric)


def test_view_synthesis_loss_with_coarse_levels_prefers_the_true_motion(scene):
    """The whole loss, one source, with coarse_levels = 2: the true pose beats a 1.5x
    translation (the coarse path runs inside the per-pixel minimum and auto-masking)."""
    config = replace(DepthConfig(), height=H, width=W, coarse_levels=2)

    def loss(t: np.ndarray, config: DepthConfig = config) -> float:
        return photometric_loss(scene["target"], scene["source"], scene["depth"], t, config)

    assert loss(1.5 * T_TRUE) > 2 * loss(T_TRUE)
    # ... and the coarse levels are in it: the same loss at full resolution only differs.
    assert loss(T_TRUE) != pytest.approx(loss(T_TRUE, replace(config, coarse_levels=0)),
                                         rel=0.05)


def test_the_black_border_outside_the_image_region_is_not_compared(scene):
    """An endoscope's round image region, the frames black outside it: with the true depth,
    pose and K the photometric term is what it is when the border holds the scene: no pixel
    whose SSIM window reads the target's border or the source's is compared (both were:
    0.0208 against 0.0004)."""
    rows, columns = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    region = (((columns - CX) / (W / 2)) ** 2 + ((rows - CY) / (H / 2)) ** 2 <= 1)[None, None]
    config = replace(DepthConfig(), height=H, width=W)
    black, filled = (photometric_loss(target, source, scene["depth"], T_TRUE, config, region)
                     for target, source in ((scene["target"] * region, scene["source"] * region),
                                            (scene["target"], scene["source"])))
    assert black == pytest.approx(filled, rel=1e-6)


def test_photo_blur_lifts_the_truth_out_of_sensor_noise(scene):
    """Independent noise on both views fills the error at the truth; blurred before the
    comparison (photo_blur), the true pose stands out against a 1.5x translation by much more.
    A small highlight in the source is masked with all the pixels its blurred light reaches:
    how bright it is changes nothing."""
    generator = torch.Generator().manual_seed(0)
    target, source = (x + 0.05 * torch.randn(x.shape, generator=generator)
                      for x in (scene["target"], scene["source"]))

    def loss(t: np.ndarray, blur: float, source: torch.Tensor = source) -> float:
        config = replace(DepthConfig(), height=H, width=W, photo_blur=blur, automask=False)
        return photometric_loss(target, source, scene["depth"], t, config)

    sharp = loss(1.5 * T_TRUE, 0.0) / loss(T_TRUE, 0.0)
    blurred = loss(1.5 * T_TRUE, 1.5) / loss(T_TRUE, 1.5)
    assert sharp > 1.0 and blurred > 1.5 * sharp
    highlights = [source.clone(), source.clone()]
    highlights[0][..., 19:22, 29:32], highlights[1][..., 19:22, 29:32] = 0.97, 1.0
    assert loss(T_TRUE, 1.5, highlights[0]) == pytest.approx(loss(T_TRUE, 1.5, highlights[1]),
                                                             rel=1e-4)
    assert loss(T_TRUE, 1.5, highlights[0]) != pytest.approx(loss(T_TRUE, 1.5), rel=1e-3)


def test_photo_blur_must_not_be_negative():
    with pytest.raises(ValueError, match="photo_blur must be >= 0"):
        replace(DepthConfig(), photo_blur=-1.0)


def test_coarse_levels_need_a_size_they_divide():
    assert replace(DepthConfig(), coarse_levels=3).coarse_levels == 3  # 128x160
    with pytest.raises(ValueError, match="divisible by 64"):
        replace(DepthConfig(), coarse_levels=6)
    with pytest.raises(ValueError, match="coarse_levels=-1"):
        replace(DepthConfig(), coarse_levels=-1)


def test_inverse_square_relighting_undoes_the_light_at_the_camera(scene):
    """Both views lit by a point light at their own camera, gamma-encoded: relit, the warped
    source matches the target as closely as the unlit views match; not relit, it does not.
    The relighting passes gradients to the depth (the shading cue)."""
    config = replace(DepthConfig(), inverse_square=True)

    def lit(image: np.ndarray, hit: np.ndarray, centre: np.ndarray) -> torch.Tensor:
        distance = np.linalg.norm(hit - centre, axis=-1)
        return as_t(image * (Z0 / distance) ** (2 / config.display_gamma))[None]

    image, _, hit = render(np.eye(3), np.zeros(3))
    target = lit(image, hit, np.zeros(3))
    image, _, hit = render(R_TRUE, T_TRUE)
    source = lit(image, hit, -R_TRUE.T @ T_TRUE)
    depth = scene["depth"].clone().requires_grad_()
    w = warp(source, depth, matrix(R_TRUE, T_TRUE), intrinsics())
    keep = interior(w.valid)
    relit = photometric_error(_relit(w.image, w.ray_ratio, config), target, config)[keep].mean()
    plain = float(photometric_error(w.image.detach(), target, config)[keep].mean())
    unlit = mean_error(scene, matrix(R_TRUE, T_TRUE), intrinsics())
    assert float(relit.detach()) < 1.5 * unlit and plain > 5 * unlit
    assert torch.equal(_relit(w.image, w.ray_ratio, DepthConfig()), w.image)  # off by default
    # Through the relighting alone (the sampled image held fixed), gradients reach the depth.
    _relit(w.image.detach(), w.ray_ratio, config).sum().backward()
    assert float(depth.grad.abs().sum()) > 0
