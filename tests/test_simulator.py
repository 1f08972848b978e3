"""Simulator (hybrid.sim): determinism by seed, colon and camera draws, analytic depth."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import make_cylinder
from scipy.ndimage import binary_dilation, binary_erosion

from hybrid.coverage import Lumen, VisibilityOracle, compute_coverage
from hybrid.dataset import Procedure, window_labels_path
from hybrid.lens import equidistant, pinhole_twin, resample, resample_mask, resampling_maps
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


def test_a_procedure_simulated_before_camera_seed_lens_and_corner_cut_existed_resumes(
        tmp_path, simulated, sim_config):
    copy = tmp_path / simulated.name
    shutil.copytree(simulated, copy)
    meta = json.loads((copy / "meta.json").read_text())
    del meta["config"]["camera_seed"], meta["config"]["lens"], meta["config"]["corner_cut"]
    (copy / "meta.json").write_text(json.dumps(meta))
    marker = '{"marker": true}\n'
    (copy / "coverage.json").write_text(marker)
    assert simulate_procedure(tmp_path, 7, 0, sim_config) == copy
    assert (copy / "coverage.json").read_text() == marker
    with pytest.raises(InputError, match="differing: camera_seed"):
        simulate_procedure(tmp_path, 7, 0, replace(sim_config, camera_seed=1))
    with pytest.raises(InputError, match="differing: lens"):
        simulate_procedure(tmp_path, 7, 0, replace(sim_config, lens="equidistant"))


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


def test_an_equidistant_camera_images_an_angle_at_f_times_it():
    """r = f θ: a point θ off the axis, in the direction φ, lands at (cx + fx θ cos φ,
    cy + fy θ sin φ) at any distance; each pixel's ray (z = 1) projects back onto it; a
    pinhole of the same K puts the same point at f tan θ."""
    fisheye = Camera(160, 128, 70.0, 72.0, 81.0, 62.0, model="equidistant")
    pinhole = replace(fisheye, model="pinhole")
    theta, phi = np.radians([0.0, 10.0, 45.0, 80.0, 95.0]), np.radians([0, 30, 150, 250, 40])
    for distance in (0.5, 7.0):
        points = distance * np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                                      np.cos(theta)], axis=1)
        u, v, in_front = fisheye.project(points)
        np.testing.assert_allclose(u[:4], 81.0 + 70.0 * theta[:4] * np.cos(phi[:4]), atol=1e-9)
        np.testing.assert_allclose(v[:4], 62.0 + 72.0 * theta[:4] * np.sin(phi[:4]), atol=1e-9)
        assert in_front.tolist() == [True, True, True, True, False]
        u, _, _ = pinhole.project(points)
        np.testing.assert_allclose(u[:4], 81.0 + 70.0 * np.tan(theta[:4]) * np.cos(phi[:4]),
                                   atol=1e-9)
    for camera in (fisheye, pinhole):
        rays = camera.pixel_rays()
        assert rays.shape == (128, 160, 3) and (rays[..., 2] == 1).all()
        u, v, in_front = camera.project(3.0 * rays.reshape(-1, 3))
        grid_v, grid_u = np.mgrid[0:128, 0:160]
        np.testing.assert_allclose(u, grid_u.ravel(), atol=1e-9)
        np.testing.assert_allclose(v, grid_v.ravel(), atol=1e-9)
        assert in_front.all()
    # the width spans 2 × 80 px / fx radians; a resize keeps the model and the angle
    assert fisheye.hfov_deg == pytest.approx(np.degrees(160 / 70.0))
    assert fisheye.resized(320, 256).model == "equidistant"
    assert fisheye.resized(320, 256).hfov_deg == pytest.approx(fisheye.hfov_deg)


def test_a_camera_keeps_its_model_on_disk_and_refuses_rays_it_cannot_render(tmp_path):
    fisheye = Camera(160, 128, 70.0, 72.0, 81.0, 62.0, fps=10.0, model="equidistant")
    fisheye.save(tmp_path / "camera.json")
    assert Camera.load(tmp_path / "camera.json") == fisheye
    older = json.loads((tmp_path / "camera.json").read_text())
    del older["model"]  # written before the model existed: a pinhole
    (tmp_path / "camera.json").write_text(json.dumps(older))
    assert Camera.load(tmp_path / "camera.json") == replace(fisheye, model="pinhole")
    with pytest.raises(InputError, match="camera model must be one of"):
        Camera(160, 128, 70.0, 72.0, 81.0, 62.0, model="fisheye")
    # a pixel 90° or more off the axis has no z-depth to render (half the diagonal: 102 px)
    with pytest.raises(InputError, match="sees 91° off its axis"):
        Camera(160, 128, 64.0, 64.0, 79.5, 63.5, model="equidistant").pixel_rays()
    assert np.isfinite(Camera(160, 128, 66.0, 66.0, 79.5, 63.5, model="equidistant").pixel_rays()
                       ).all()


def test_a_fisheye_procedure_is_its_pinhole_twin_through_another_lens(sim_config):
    """lens='equidistant': the same draws, so the same colon, withdrawal, texture, principal
    point and aspect, and the same field of view across the width."""
    fisheye_config = replace(sim_config, lens="equidistant")
    for index in (0, 3):
        pinhole, fisheye = draw_scene(sim_config, 2, index), draw_scene(fisheye_config, 2, index)
        assert (pinhole.camera.model, fisheye.camera.model) == ("pinhole", "equidistant")
        assert fisheye.camera.hfov_deg == pytest.approx(pinhole.camera.hfov_deg)
        assert fisheye.camera.fx > pinhole.camera.fx  # the centre magnified
        assert fisheye.camera == replace(pinhole.camera, model="equidistant",
                                         fx=fisheye.camera.fx, fy=fisheye.camera.fy)
        assert fisheye.camera.fy / fisheye.camera.fx == pytest.approx(
            pinhole.camera.fy / pinhole.camera.fx)
        np.testing.assert_array_equal(fisheye.poses, pinhole.poses)
        np.testing.assert_array_equal(fisheye.colon.vertices, pinhole.colon.vertices)
        np.testing.assert_array_equal(fisheye.renderer.texture, pinhole.renderer.texture)
    with pytest.raises(ValueError, match="lens must be None"):
        replace(sim_config, lens="fisheye")


def test_a_fisheye_truth_sees_the_wall_where_its_frames_show_it(tmp_path, sim_config):
    """The ground truth's camera and the renderer's agree through a fisheye: a vertex the
    oracle counts as seen projects onto a pixel whose rendered depth is its own z-depth.
    Projected as through a pinhole of the same K, the seen vertices land on pixels of
    other depths, and the coverage differs."""
    config = with_overrides(replace(sim_config, lens="equidistant"), length_cm=30.0)
    proc = Procedure.open(simulate_procedure(tmp_path, 7, 0, config))
    camera, mesh = proc.camera, proc.mesh()
    assert camera.model == "equidistant"
    oracles = {"fisheye": VisibilityOracle(mesh, camera),
               "pinhole": VisibilityOracle(mesh, replace(camera, model="pinhole"))}
    ids = np.arange(len(mesh.vertices))
    for i in (0, 20, 39):
        pose = proc.poses[i]
        xc = (mesh.vertices - pose[:3, 3]) @ pose[:3, :3]
        depth = proc.depth(i)
        errors = {}
        for name, oracle in oracles.items():
            seen = oracle.visible(pose, ids)
            u, v, _ = oracle.camera.project(xc[seen])
            column = np.clip(np.floor(u + 0.5), 0, camera.width - 1).astype(int)
            row = np.clip(np.floor(v + 0.5), 0, camera.height - 1).astype(int)
            rel = np.abs(depth[row, column] / xc[seen, 2] - 1)
            errors[name] = (np.percentile(rel, 90), seen.sum())
        # 90% within 1%; through the pinhole, whose K sees less, a tenth are off by 10% or more
        assert errors["fisheye"][0] < 0.01 and errors["pinhole"][0] > 0.1, errors
        assert errors["fisheye"][1] > errors["pinhole"][1], errors
    recomputed = compute_coverage(mesh, Lumen(proc.lumen), proc.poses, camera,
                                  sim_config.segment_frames)
    assert recomputed.to_json() == proc.coverage.to_json()
    assert compute_coverage(mesh, Lumen(proc.lumen), proc.poses, replace(camera, model="pinhole"),
                            sim_config.segment_frames).to_json() != proc.coverage.to_json()


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


def tube_renderer(camera: Camera):
    """An open straight tube of radius 2 cm along z from 0 to 10 cm, evenly grey, and its
    renderer for `camera`."""
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
    return tube, ColonRenderer(colon, texture, get_style("pink"), camera, circumference)


@pytest.mark.parametrize("camera", [Camera(160, 128, 60.0, 62.0, 83.2, 60.7),
                                    Camera(160, 128, 80.0, 82.0, 83.2, 60.7, model="equidistant")])
def test_rendered_depth_of_a_straight_tube_is_analytic(camera):
    """Camera on the axis of an open tube looking along it: the ray through pixel (u, v) at
    (a, b) = ((u - cx) / fx, (v - cy) / fy) meets the wall at z-depth R / r with r = |(a, b)|
    through a pinhole, or at R / tan r through an equidistant fisheye (r its angle off the
    axis); or it leaves the tube."""
    tube, renderer = tube_renderer(camera)
    start = 3.0
    pose = np.eye(4)
    pose[2, 3] = start
    rgb, depth = renderer.render(pose, np.random.default_rng(0))
    assert rgb.shape == (128, 160, 3) and rgb.dtype == np.uint8
    u, v = np.meshgrid(np.arange(160), np.arange(128))
    r = np.hypot((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy)
    expected = tube.radius / (np.tan(r) if camera.model == "equidistant" else r)
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


def test_a_fisheye_frame_resampled_to_its_pinhole_twin_is_the_twins_frame():
    """hybrid.lens: the pinhole twin sees the width's angle of the fisheye; the fisheye's
    rendering of the tube resampled to the twin is the twin's own rendering, wherever the
    fisheye reaches (all of the middle row; not the top and bottom middle, which the twin
    sees at wider angles than the fisheye)."""
    fisheye = Camera(160, 128, 80.0, 82.0, 79.5, 63.5, model="equidistant")
    twin = pinhole_twin(fisheye)
    assert twin.model == "pinhole" and pinhole_twin(twin) == twin
    assert twin.hfov_deg == pytest.approx(fisheye.hfov_deg)
    assert (twin.cx, twin.cy, twin.fy / twin.fx) == pytest.approx((79.5, 63.5, 82.0 / 80.0))
    # a lens wider than a pinhole can see across is resampled to the widest one asked for
    wide = equidistant(200.0, 160, 128)
    assert (wide.hfov_deg, wide.fx, wide.cx, wide.cy) == pytest.approx(
        (200.0, 80 / np.radians(100), 79.5, 63.5))
    assert pinhole_twin(wide, widest_deg=130.0).hfov_deg == pytest.approx(130.0)
    assert pinhole_twin(fisheye, widest_deg=130.0) == twin  # narrower than that: its twin
    with pytest.raises(InputError, match="a pinhole sees less than 180 degrees"):
        pinhole_twin(wide)
    pose = np.eye(4)
    pose[2, 3] = 3.0
    depth = {camera.model: tube_renderer(camera)[1].render(pose, np.random.default_rng(0))[1]
             for camera in (fisheye, twin)}
    maps = resampling_maps(fisheye, twin)
    reach = resample_mask(np.ones((128, 160), bool), maps)
    resampled = resample(depth["equidistant"], maps)
    # no black bleeds in at the lens's reach
    grey = resample(np.full((128, 160, 3), 200, np.uint8), maps)
    assert (grey[reach] == 200).all()
    assert reach[64].all() and not reach[0, 80] and not reach[-1, 80] and reach.mean() > 0.8
    # Two pixels from the open end's rim and the reach's edge, where the interpolation
    # mixes wall and nothing: a tenth of a per cent, the 256-gon's facets against a line.
    wall = binary_erosion(reach & (depth["pinhole"] > 0), iterations=2)
    assert wall.mean() > 0.6
    np.testing.assert_allclose(resampled[wall], depth["pinhole"][wall], rtol=1e-3)
