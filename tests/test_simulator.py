"""Simulator (hybrid.sim): determinism by seed, colon and camera draws, analytic depth."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import make_cylinder
from scipy.ndimage import binary_dilation

from hybrid.coverage import Lumen, compute_coverage
from hybrid.dataset import Procedure, window_labels_path
from hybrid.sim.appearance import TEXELS_PER_CM, get_style
from hybrid.sim.colon import Colon, ColonConfig, make_colon
from hybrid.sim.render import ColonRenderer
from hybrid.sim.simulate import (
    SimConfig,
    draw_camera,
    draw_scene,
    octagon_region,
    simulate_dataset,
    simulate_procedure,
    with_overrides,
)
from hybrid.sim.trajectory import TrajectoryConfig, make_withdrawal
from hybrid.types import Camera, InputError, check_poses


def tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


@pytest.fixture(scope="module")
def same_seed_again(tmp_path_factory, sim_config) -> Path:
    return simulate_procedure(tmp_path_factory.mktemp("sim_b"), 7, 0, sim_config)


def test_same_seed_gives_byte_identical_files(simulated, same_seed_again, sim_config):
    a, b = tree_bytes(simulated), tree_bytes(same_seed_again)
    n = sim_config.trajectory.max_frames
    expected = {"camera.json", "poses.npy", "colon.ply", "lumen.npy", "coverage.json",
                "meta.json"} | {f"{kind}/{i:06d}.png" for kind in ("rgb", "depth")
                                for i in range(n)}
    assert set(a) == expected
    assert set(b) == expected
    different = [name for name in a if a[name] != b[name]]
    assert different == []
    assert not simulated.with_name(simulated.name + ".partial").exists()


def test_different_seed_differs(tmp_path, simulated, sim_config):
    other = simulate_procedure(tmp_path, 8, 0, sim_config)
    a, b = tree_bytes(simulated), tree_bytes(other)
    for name in ("poses.npy", "colon.ply", "lumen.npy", "camera.json", "coverage.json",
                 "rgb/000000.png", "depth/000000.png"):
        assert a[name] != b[name], name
    # The index is part of the seed too.
    third = simulate_procedure(tmp_path, 7, 1, sim_config)
    assert tree_bytes(third)["poses.npy"] != a["poses.npy"]


def test_complete_procedure_is_skipped(tmp_path, simulated, sim_config):
    copy = tmp_path / simulated.name
    shutil.copytree(simulated, copy)
    marker = '{"marker": true}\n'
    (copy / "coverage.json").write_text(marker)
    assert simulate_procedure(tmp_path, 7, 0, sim_config) == copy
    assert (copy / "coverage.json").read_text() == marker


def test_a_complete_procedure_of_other_settings_is_refused(tmp_path, simulated, sim_config):
    """Not silently reused: a folder simulated with another seed or config is an error."""
    copy = tmp_path / simulated.name
    shutil.copytree(simulated, copy)
    kept = (copy / "coverage.json").read_text()
    for seed, config, key in ((8, sim_config, "seed"),
                              (7, replace(sim_config, style="dusk"), "style")):
        with pytest.raises(InputError, match=f"other settings .*differing: {key}\\)"):
            simulate_procedure(tmp_path, seed, 0, config)
    # a dataset run checks every folder before rendering any: procedure 1 is not written
    with pytest.raises(InputError, match="differing: seed"):
        simulate_dataset(tmp_path, 2, 8, sim_config, workers=2)
    assert not (tmp_path / "proc_0001").exists() and not (tmp_path / "proc_0001.partial").exists()
    shutil.copytree(copy, tmp_path / "proc_0001")  # procedure 0 under the name of 1
    with pytest.raises(InputError, match="differing: index"):
        simulate_procedure(tmp_path, 7, 1, sim_config)
    assert (copy / "coverage.json").read_text() == kept


def test_a_procedure_simulated_before_camera_seed_and_corner_cut_existed_resumes(
        tmp_path, simulated, sim_config):
    copy = tmp_path / simulated.name
    shutil.copytree(simulated, copy)
    meta = json.loads((copy / "meta.json").read_text())
    del meta["config"]["camera_seed"], meta["config"]["corner_cut"]
    (copy / "meta.json").write_text(json.dumps(meta))
    marker = '{"marker": true}\n'
    (copy / "coverage.json").write_text(marker)
    assert simulate_procedure(tmp_path, 7, 0, sim_config) == copy
    assert (copy / "coverage.json").read_text() == marker
    with pytest.raises(InputError, match="differing: camera_seed"):
        simulate_procedure(tmp_path, 7, 0, replace(sim_config, camera_seed=1))


def test_frame_step_keeps_every_kth_frame_with_its_truth(tmp_path, simulated, sim_config):
    """frame_step k: the same withdrawal's every k-th frame, a camera at fps / k, segments of
    segment_frames / k frames (the same time), and those frames' own per-frame truth."""
    k = 4
    sparse = simulate_procedure(tmp_path, 7, 0, replace(sim_config, frame_step=k))
    full, part = Procedure.open(simulated), Procedure.open(sparse)
    assert part.num_frames == 10 and part.meta["config"]["frame_step"] == k
    np.testing.assert_array_equal(part.poses, full.poses[::k])
    assert part.camera == replace(full.camera, fps=full.camera.fps / k)
    assert np.array_equal(part.depth(3), full.depth(3 * k))  # depth has no noise
    assert part.coverage.segment_frames == sim_config.segment_frames // k
    assert part.coverage.per_frame.keys() == full.coverage.per_frame.keys()
    for key, values in full.coverage.per_frame.items():
        assert part.coverage.per_frame[key] == pytest.approx(values[::k], nan_ok=True), key
    assert len(part.coverage.segments) == len(full.coverage.segments) == 2
    for bad in (0, 3):  # not a divisor of the 20-frame segments
        with pytest.raises(ValueError, match="frame_step must be a positive divisor"):
            replace(sim_config, frame_step=bad)


def test_an_octagon_blacks_out_the_corners_and_hides_them_from_the_truth(tmp_path, sim_config):
    """corner_cut: the same procedure, its frames black outside an octagon of the drawn cut
    (region.png), its depth unchanged, and a truth that counts only the wall shown inside.
    (A 30 cm colon: the 14 cm one's camera starts too near the cecum to see any of V.)"""
    cut, config = 0.25, with_overrides(sim_config, length_cm=30.0)
    full = Procedure.open(simulate_procedure(tmp_path / "full", 7, 0, config))
    octagon = Procedure.open(simulate_procedure(tmp_path / "octagon", 7, 0,
                                                replace(config, corner_cut=(cut, cut))))
    region = octagon.region
    height, width = region.shape
    legs = cut * min(height, width)
    assert region.sum() == pytest.approx(height * width - 2 * legs**2, rel=0.03)  # 4 triangles
    assert not region[0, 0] and not region[-1, -1] and region[height // 2].all()
    assert np.array_equal(region, octagon_region(height, width, legs))
    assert np.array_equal(full.region, np.ones_like(region))  # no region.png: the whole image
    for i in (0, 20, 39):
        assert np.array_equal(octagon.rgb(i)[region], full.rgb(i)[region])
        assert octagon.rgb(i)[~region].max() == 0 < full.rgb(i)[~region].max()
        assert np.array_equal(octagon.depth(i), full.depth(i))
    fewer = 0
    for key, values in full.coverage.per_frame.items():
        shown = np.array(octagon.coverage.per_frame[key], dtype=float)
        assert (shown <= np.array(values, dtype=float) + 1e-12).all(), key
        fewer += int((shown < np.array(values, dtype=float) - 1e-3).sum())
    assert fewer > 0
    recomputed = compute_coverage(octagon.mesh(), Lumen(octagon.lumen), octagon.poses,
                                  octagon.camera, sim_config.segment_frames, region=region)
    assert recomputed.to_json() == octagon.coverage.to_json()
    for bad in ((0.3, 0.2), (0.1, 0.5)):
        with pytest.raises(ValueError, match="corner_cut must be"):
            replace(sim_config, corner_cut=bad)


def test_window_labels_come_with_the_truth(tmp_path, simulated, sim_config):
    """With a window stride the simulator writes the training windows' labels in the same
    pass: coverage.json stays byte for byte what it is without, and the labels are what the
    coverage networks' data would compute from the written files."""
    from learned.coverage_data import window_labels

    folder = simulate_procedure(tmp_path, 7, 0, sim_config, window_stride=5)
    assert (folder / "coverage.json").read_bytes() == (simulated / "coverage.json").read_bytes()
    written = np.load(window_labels_path(folder, 20, 5))
    assert written.shape == (5, 2)
    plain = shutil.copytree(simulated, tmp_path / "plain")  # labelled without windows
    computed = window_labels(Procedure.open(plain), 20, 5)
    assert window_labels_path(plain, 20, 5).is_file()
    np.testing.assert_array_equal(written, computed)
    for bad in (0, 3, 40):  # not a divisor of the 20-frame segments
        with pytest.raises(InputError, match="window stride must be a positive divisor"):
            simulate_procedure(tmp_path / "bad", 7, 0, sim_config, window_stride=bad)
    assert not (tmp_path / "bad").exists()


def test_meta_records_seed_and_config(simulated, sim_config):
    meta = json.loads((simulated / "meta.json").read_text())
    assert (meta["seed"], meta["index"], meta["num_frames"]) == (7, 0, 40)
    assert meta["config"]["colon"]["length_cm"] == 14.0
    assert meta["config"]["trajectory"]["max_frames"] == 40
    assert meta["config"]["segment_frames"] == sim_config.segment_frames
    assert Procedure.open(simulated).style == sim_config.style == meta["config"]["style"]


def test_colon_lumen_length_and_folds():
    config = ColonConfig(length_cm=16.0)
    colon = make_colon(config, np.random.default_rng(1))
    # The centerline is integrated from unit steps: its arc length is the configured length.
    assert colon.arclength[-1] == pytest.approx(16.0, rel=1e-9)
    assert colon.centerline.shape == (161, 3)
    lo, hi = config.radius_range_cm
    assert lo <= colon.radius.min() and colon.radius.max() <= hi
    assert colon.fold_depth.min() >= 0.0 and colon.fold_depth.max() <= config.fold_height_cm[1]
    # Folds only move the wall inwards, by exactly fold_depth (ring-major vertices, then cap).
    S = config.segments_around
    wall = colon.vertices[:-1].reshape(-1, S, 3)
    distance = np.linalg.norm(wall - colon.centerline[:, None], axis=2)
    np.testing.assert_allclose(distance, colon.radius[:, None] - colon.fold_depth, atol=1e-9)
    # The cap centre closes the cecum end.
    np.testing.assert_array_equal(colon.vertices[-1], colon.centerline[-1])


def test_withdrawal_moves_back_inside_the_lumen():
    colon = make_colon(ColonConfig(length_cm=20.0), np.random.default_rng(2))
    config = TrajectoryConfig(max_frames=200)
    poses = check_poses(make_withdrawal(colon, config, np.random.default_rng(3)))
    assert poses.shape == (200, 4, 4)
    ell, nearest = Lumen(colon.centerline).project(poses[:, :3, 3])
    # Starts start_depth_cm from the cecum end; the offset camera's ℓ* is within the lumen
    # resampling (0.01 cm) plus the frame interpolation between rings 0.1 cm apart (the
    # lateral offset <= 0.35 * 3.5 cm turned by <= 0.1 cm / 8 cm bend radius: 0.015 cm).
    assert ell[0] == pytest.approx(20.0 - config.start_depth_cm, abs=0.01 + 0.015)
    assert ell[-1] < ell[0]
    # The camera is at most lateral_fraction * radius from a point of the centerline polyline;
    # the lumen's samples along it are 0.02 cm apart, so the nearest is <= 0.01 cm further.
    lateral = np.linalg.norm(poses[:, :3, 3] - nearest, axis=1)
    assert lateral.max() <= config.lateral_fraction * colon.radius.max() + 0.01 + 1e-9


def test_camera_draw_within_configured_lens():
    config = SimConfig()
    for seed in range(5):
        camera = draw_camera(config, np.random.default_rng(seed))
        hfov = np.degrees(2 * np.arctan(camera.width / 2 / camera.fx))
        assert (camera.height, camera.width) == (128, 160)
        assert config.hfov_deg[0] <= hfov <= config.hfov_deg[1]
        assert abs(camera.fy / camera.fx - 1) <= config.aspect_jitter
        assert abs(camera.cx - 79.5) <= config.principal_jitter * 160
        assert abs(camera.cy - 63.5) <= config.principal_jitter * 128


def test_camera_field_of_view_is_the_angle_across_the_image():
    assert Camera(160, 128, 80.0, 80.0, 79.5, 63.5).hfov_deg == pytest.approx(90.0)
    assert Camera(160, 128, 80.0 / np.sqrt(3), 80.0, 79.5, 63.5).hfov_deg == pytest.approx(120.0)
    # resizing the image keeps the angle
    assert Camera(160, 128, 50.0, 50.0, 79.5, 63.5).resized(320, 256).hfov_deg == pytest.approx(
        Camera(160, 128, 50.0, 50.0, 79.5, 63.5).hfov_deg)


def test_camera_seed_takes_that_seeds_camera_and_nothing_else(sim_config):
    pink = replace(sim_config, style="pink")
    dusk = replace(sim_config, style="dusk")
    for index in (0, 3):
        own = draw_scene(dusk, 2, index)
        shared = draw_scene(replace(dusk, camera_seed=1), 2, index)
        assert shared.camera == draw_scene(pink, 1, index).camera != own.camera
        np.testing.assert_array_equal(shared.poses, own.poses)
        np.testing.assert_array_equal(shared.colon.vertices, own.colon.vertices)
        np.testing.assert_array_equal(shared.renderer.texture, own.renderer.texture)
    # the endoscope's image region goes with its camera
    cut = (0.15, 0.25)
    regions = [draw_scene(replace(config, corner_cut=cut), seed, 0).region
               for config, seed in ((replace(dusk, camera_seed=1), 2), (pink, 1), (dusk, 2))]
    np.testing.assert_array_equal(regions[0], regions[1])
    assert not np.array_equal(regions[0], regions[2])


def test_rendered_depth_of_a_straight_tube_is_analytic():
    """Camera on the axis of an open tube looking along it: the ray through pixel (u, v) with
    direction (a, b, 1) meets the wall at z-depth R / sqrt(a² + b²), or leaves the tube."""
    tube = make_cylinder(radius=2.0, length=10.0, spacing=0.1, segments=256)
    n_rings = int(round(tube.length / tube.spacing)) + 1
    z = np.linspace(0.0, tube.length, n_rings)
    theta = np.linspace(0.0, 2 * np.pi, tube.segments, endpoint=False)
    frames = np.tile(np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]]), (n_rings, 1, 1))
    uv = np.stack(np.broadcast_arrays(z[:, None], theta[None, :] * tube.radius), -1)
    colon = Colon(centerline=np.stack([0 * z, 0 * z, z], 1), radius=np.full(n_rings, 2.0),
                  frames=frames, vertices=tube.vertices, triangles=tube.triangles.astype(np.int32),
                  surface_uv=uv.reshape(-1, 2), fold_depth=np.zeros((n_rings, tube.segments)))
    circumference = 2 * np.pi * tube.radius
    texture = np.full((int(tube.length * TEXELS_PER_CM) + 2,
                       int(circumference * TEXELS_PER_CM), 3), 0.5, np.float32)
    camera = Camera(160, 128, 60.0, 62.0, 83.2, 60.7)
    renderer = ColonRenderer(colon, texture, get_style("pink"), camera, circumference)
    start = 3.0
    pose = np.eye(4)
    pose[2, 3] = start
    rgb, depth = renderer.render(pose, np.random.default_rng(0))
    assert rgb.shape == (128, 160, 3) and rgb.dtype == np.uint8
    u, v = np.meshgrid(np.arange(160), np.arange(128))
    r = np.hypot((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy)
    expected = tube.radius / r
    # The mesh is the inscribed 256-gon: its wall is between R cos(π/S) and R from the axis.
    # Float32 ray casting adds ~1e-6 relative.
    rel = 1 - np.cos(np.pi / tube.segments) + 1e-5
    far = tube.length - start
    hits = expected < far * (1 - rel)
    misses = expected > far * (1 + rel)
    assert hits.mean() > 0.5 and misses.any()
    np.testing.assert_allclose(depth[hits], expected[hits], rtol=rel)
    assert (depth[misses] == 0).all()
    # Nothing hit, nothing lit: the open end is black apart from sensor noise. Two pixels
    # from any hit the blur (0.5 px) leaves nothing, and the noise N(0, noise_std), clipped
    # at 0, averages noise_std / sqrt(2π) (1.0 grey level) and stays within 5 of its sigmas.
    dark = misses & ~binary_dilation(~misses, iterations=2)
    noise = get_style("pink").noise_std * 255
    assert dark.sum() > 100
    assert rgb[dark].max() <= 5 * noise
    assert rgb[dark].mean() == pytest.approx(noise / np.sqrt(2 * np.pi), abs=0.5)
