"""fusion.sfm_maps and learned.map_triplets: real pycolmap maps of a textured tube
(tests/tube_scene.py) as the training signal of `train-depth --maps`."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch
from conftest import TINY, bn_running_statistics
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from tube_scene import FOCAL, FRAMES, HEIGHT, WIDTH, depth, pose_at, render, wall_texture
from typer.testing import CliRunner

from fusion.self_calibration import SquarePixels
from fusion.sfm_maps import fingerprint, map_inputs, map_path
from hybrid.cli import app
from hybrid.types import InputError
from learned.config import DepthConfig
from learned.frames import open_sequence
from learned.map_triplets import (
    MapTriplets,
    map_motion_errors,
    map_view_loss,
    relative_motion,
    with_map_terms,
)
from learned.model import DepthModel
from learned.train import TripletSampler, train_depth
from learned.zoom import zoom_pairs, zoomed_intrinsics

pytestmark = pytest.mark.usefixtures("one_thread")
CONFIG = replace(TINY, height=HEIGHT, width=WIDTH, pair_gap_s=0.1)
"""The tube's own size; gaps of 3 frames (image folders play at 30 frames/s)."""
LENGTH = FRAMES // 2
POSES = np.stack([pose_at(i) for i in range(FRAMES)])


@pytest.fixture(scope="module")
def tube(tmp_path_factory):
    """The tube as an image folder, and its maps in two stretches of 12 frames."""
    root = tmp_path_factory.mktemp("tube")
    folder = root / "tube"
    folder.mkdir()
    texture = wall_texture()
    for i, pose in enumerate(POSES):
        cv2.imwrite(str(folder / f"{i:04d}.png"), render(pose, texture))
    lines = list(map_inputs([folder], root / "maps", (HEIGHT, WIDTH), LENGTH))
    return folder, root / "maps", lines


@pytest.fixture(scope="module")
def triplets(tube):
    folder, maps, _ = tube
    sampler = TripletSampler([open_sequence(folder, (HEIGHT, WIDTH))], CONFIG.pair_gap_s)
    return MapTriplets(sampler.sequences, sampler.gaps, maps, CONFIG.map_min_points)


def test_each_stretch_is_mapped_with_its_focal_length_poses_and_sparse_depth(tube):
    folder, maps, lines = tube
    assert lines == [f"{folder}: 2 of 2 stretches mapped, {FRAMES} frames placed"]
    found = np.load(map_path(maps, folder))
    assert tuple(found["size"]) == (HEIGHT, WIDTH) and int(found["length"]) == LENGTH
    np.testing.assert_array_equal(found["starts"], [0, LENGTH])
    np.testing.assert_array_equal(found["stretch"], np.repeat([0, 1], LENGTH))
    assert np.all(np.abs(found["fx"] / FOCAL - 1) < 0.1)
    observations = found["observations"]
    assert np.all(np.diff(observations[:, 0]) >= 0)  # sorted by frame
    for k in (0, 1):  # each stretch has its own unit: the truth up to one factor per stretch
        mine = observations[(observations[:, 0] // LENGTH) == k]
        true = np.array([depth(POSES[int(i)])[round(y), round(x)] for i, x, y, _ in mine])
        ratio = mine[:, 3] / true
        assert np.median(np.abs(ratio / np.median(ratio) - 1)) < 0.03
    # A finished input is not mapped again.
    assert list(map_inputs([folder], maps, (HEIGHT, WIDTH), LENGTH)) == [
        f"{folder}: already mapped in {map_path(maps, folder)}"]


def test_triplets_lie_in_one_stretch_and_carry_its_motion(triplets):
    gap = triplets.gaps[0]
    targets = [t for _, t in triplets.triplets]
    assert targets == [t for t in range(gap, FRAMES - gap) if (t - gap) // LENGTH ==
                       (t + gap) // LENGTH]
    batch = triplets.batch(4, np.random.default_rng(0))
    assert batch.frames.shape == (4, 3, 3, HEIGHT, WIDTH)
    assert torch.allclose(batch.K[:, 0, 0], batch.K[:, 1, 1])
    for side, motion in zip((-gap, gap), batch.motions, strict=True):
        for j, pick in enumerate(np.random.default_rng(0).choice(len(targets), 4)):
            t = targets[pick]
            rotation, translation, *_ = relative_motion(POSES, t, t + side)
            error = axis_angle_to_rotation_matrix(motion[0][j:j + 1]).mT @ \
                axis_angle_to_rotation_matrix(rotation)
            assert math.degrees(math.acos(min(1.0, (error[0].trace() - 1) / 2))) < 0.3
            cosine = torch.cosine_similarity(motion[1][j], translation[0], dim=0)
            assert cosine > math.cos(math.radians(3))


def test_map_view_loss_does_not_depend_on_the_depths_unit(triplets):
    batch = triplets.batch(2, np.random.default_rng(1))
    picks = [triplets.triplets[p][1] for p in np.random.default_rng(1).choice(
        len(triplets.triplets), 2)]
    gap = triplets.gaps[0]
    true = torch.tensor(np.stack([np.stack([depth(POSES[i]) for i in (t - gap, t, t + gap)])
                                  for t in picks]), dtype=torch.float32)[:, :, None]

    def loss(depths):
        torch.manual_seed(0)  # the same auto-mask tie-breaking noise each time
        terms, sparse = map_view_loss(depths, batch, CONFIG)
        return float(terms.photometric), float(sparse)

    at_truth, sparse = loss(true)
    assert loss(3.7 * true) == pytest.approx((at_truth, sparse), rel=1e-4)
    assert sparse < 0.03  # the map's depth is the truth's up to its unit
    flat = torch.full_like(true, float(true.median()))
    assert loss(flat)[0] > 1.2 * at_truth


def test_map_motion_errors_against_hand_computed_cases(triplets):
    batch = triplets.batch(3, np.random.default_rng(2))
    assert [float(e) for e in map_motion_errors(batch.motions, batch.K, batch.motions,
                                                batch.K)] == \
        pytest.approx([0, 0, 0], abs=1e-6)
    turned = [(r + torch.tensor([0.01, -0.02, 0.0]), -t, rb, tb)
              for r, t, rb, tb in batch.motions]
    K = batch.K.clone()
    K[:, 0, 0] *= 2
    rotation, direction, focal = map_motion_errors(turned, K, batch.motions, batch.K)
    assert float(rotation) == pytest.approx(0.03)
    assert float(direction) == pytest.approx(2.0)
    assert float(focal) == pytest.approx(0.5 * math.log(2))


def test_training_steps_on_the_maps_lower_their_terms(triplets):
    torch.manual_seed(0)
    config = replace(CONFIG, maps="given", w_map=1.0, w_map_motion=1.0)
    model = DepthModel(config)
    batch = triplets.batch(2, np.random.default_rng(3))
    plain = model.loss(batch.frames, batch.regions)

    def terms():
        torch.manual_seed(1)
        with torch.no_grad():
            return with_map_terms(plain, model, batch).as_floats()

    before = terms()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    for step in range(30):
        torch.manual_seed(100 + step)
        loss = with_map_terms(model.loss(batch.frames, batch.regions), model, batch).total
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    after = terms()
    for term in ("map_view", "map_rotation", "map_direction", "map_focal"):
        assert after[term] < before[term], (term, before, after)
    # The total adds each term at its weight.
    model.config = replace(config, w_map=2.0, w_map_motion=0.5)
    torch.manual_seed(1)
    with torch.no_grad():
        both = with_map_terms(plain, model, batch)
    motion = both.map_rotation + both.map_direction + both.map_focal
    assert float(both.total) == pytest.approx(
        float(plain.total.detach() + 2 * both.map_view + 0.5 * motion), rel=1e-6)


@pytest.mark.parametrize("weights, idle", [({"w_map": 1.0}, "pair_motion"),
                                           ({"w_map_motion": 1.0}, "depth")])
def test_a_map_term_of_weight_zero_is_not_computed(triplets, monkeypatch, weights, idle):
    batch = triplets.batch(2, np.random.default_rng(5))
    model = DepthModel(replace(CONFIG, maps="given", **weights))
    plain = model.loss(batch.frames, batch.regions)

    def refuse(*args):
        raise AssertionError(f"{idle} ran for a term of weight 0")

    monkeypatch.setattr(model.depth if idle == "depth" else model,
                        "forward" if idle == "depth" else idle, refuse)
    terms = with_map_terms(plain, model, batch)
    assert (float(terms.map_view.detach()) > 0) == ("w_map" in weights)
    assert (float(terms.map_focal.detach()) > 0) == ("w_map_motion" in weights)


def test_the_motion_network_is_pulled_towards_the_maps_motion_target_to_source(triplets,
                                                                                  monkeypatch):
    """A motion network that returns the map's own motion for (target, source) meets the maps
    exactly; asked the other way round it would return the motion back."""
    batch = triplets.batch(2, np.random.default_rng(4))
    model = DepthModel(replace(CONFIG, maps="given", w_map_motion=1.0))
    frames = batch.frames

    def pair_motion(a, b):
        side = 0 if torch.equal(b, frames[:, 0]) else 1
        r, t, r_back, t_back = batch.motions[side]
        motion = (r, t, r_back, t_back) if torch.equal(a, frames[:, 1]) else \
            (r_back, t_back, r, t)
        return (*motion, batch.K)

    monkeypatch.setattr(model, "pair_motion", pair_motion)
    terms = with_map_terms(model.loss(frames, batch.regions), model, batch)
    assert [float(terms.map_rotation), float(terms.map_direction), float(terms.map_focal)] == \
        pytest.approx([0, 0, 0], abs=1e-6)


def test_train_depth_with_maps_logs_their_terms(tube, tmp_path):
    folder, maps, _ = tube
    config = replace(CONFIG, steps=2, maps=str(maps), w_map=1.0, w_map_motion=0.5)
    train_depth([folder], tmp_path / "run", config, log_every=1, progress=False)
    records = [json.loads(line) for line in (tmp_path / "run/metrics.jsonl").open()]
    assert [r["step"] for r in records] == [1, 2]
    for r in records:
        assert r["map_view"] > 0 and r["map_focal"] > 0
        assert r["total"] > r["photometric"] + r["map_view"]
    saved = DepthConfig.from_dict(json.loads((tmp_path / "run/config.json").read_text()))
    assert saved.maps == str(maps) and saved.w_map_motion == 0.5


def test_bad_maps_are_named(tube, tmp_path):
    folder, maps, _ = tube
    seq = open_sequence(folder, (HEIGHT, WIDTH))
    with pytest.raises(InputError, match="c2d2 sfm-maps"):
        MapTriplets([seq], [3], tmp_path, 20)
    small = open_sequence(folder, (64, 80))
    with pytest.raises(InputError,
                       match=r"24 frames of 128x160 \(fy / fx 1.000\), but .* 24 of 64x80"):
        MapTriplets([small], [3], maps, 20)
    with pytest.raises(InputError, match="too rarely"):
        train_depth([folder], tmp_path / "run", replace(
            CONFIG, steps=1, maps=str(maps), w_map=1.0, map_min_points=10**6), progress=False)
    for fields in ({"maps": str(maps)}, {"w_map": 1.0}, {"w_map_motion": 1.0},
                   {"maps": str(maps), "w_map": -1.0}):
        with pytest.raises(ValueError, match="need w_map"):
            replace(CONFIG, **fields)
    with pytest.raises(ValueError, match="map_zoom needs w_map_motion"):
        replace(CONFIG, maps=str(maps), w_map=1.0, map_zoom=True)


def test_the_commands_take_the_maps(tube, tmp_path):
    folder, maps, _ = tube
    runner = CliRunner()
    result = runner.invoke(app, ["sfm-maps", "--data", str(folder), "--out", str(maps)])
    assert result.exit_code == 0 and "already mapped" in result.output
    assert runner.invoke(app, ["sfm-maps", "--help"]).exit_code == 0
    result = runner.invoke(app, ["sfm-maps", "--data", str(folder), "--out", str(tmp_path),
                                 "--preset", "huge"])
    assert result.exit_code == 2 and result.stderr.startswith("error: ") and \
        "huge" in result.stderr, result.output
    train = ["train-depth", "--data", str(folder), "--out", str(tmp_path / "run"), "--steps",
             "1", "--device", "cpu"]
    for extra, names in (
            (["--maps", str(tmp_path), "--set", "w_map=1"], ["no map", "c2d2 sfm-maps"]),
            (["--maps", str(maps)], ["need w_map", "--set w_map=1"]),
            (["--set", "w_map=1"], ["weights need maps"])):
        result = runner.invoke(app, [*train, *extra])
        assert result.exit_code == 2 and result.stderr.startswith("error: "), result.output
        assert all(name in result.stderr for name in names), result.stderr


def write_truth_map(folder, maps, fx, length, other=False):
    """A map file of the tube in the format of fusion.sfm_maps, from its true poses and depth:
    stretches of `length` frames with focal lengths `fx`, 40 points a frame (with `other`, of
    other frames: its fingerprint brighter)."""
    rng = np.random.default_rng(0)
    rows = []
    for i, pose in enumerate(POSES):
        x, y = rng.uniform(10, WIDTH - 10, 40), rng.uniform(10, HEIGHT - 10, 40)
        z = depth(pose)[y.round().astype(int), x.round().astype(int)]
        rows.append(np.column_stack([np.full(40, i), x, y, z]))
    maps.mkdir(exist_ok=True)
    seq = open_sequence(folder, (HEIGHT, WIDTH))
    np.savez(map_path(maps, folder), source=str(folder.resolve()),
             fingerprint=fingerprint(seq) + (100 if other else 0),
             size=np.array([HEIGHT, WIDTH]), fy_over_fx=1.0, length=length,
             starts=np.arange(0, FRAMES, length), fx=np.array(fx, float),
             registered=np.ones(len(fx)), stretch=np.arange(FRAMES) // length, poses=POSES,
             observations=np.concatenate(rows).astype(np.float32))


def test_only_stretches_that_agree_give_triplets(tube, tmp_path):
    folder = tube[0]
    seq = open_sequence(folder, (HEIGHT, WIDTH))
    write_truth_map(folder, tmp_path / "a", [80, 82, 120], 8)  # the third is 46% off
    triplets = MapTriplets([seq], [3], tmp_path / "a", 20)
    assert [t for _, t in triplets.triplets] == [3, 4, 11, 12]
    write_truth_map(folder, tmp_path / "b", [80, 82, 120], 8, other=True)
    with pytest.raises(InputError, match="a map of other frames"):
        MapTriplets([seq], [3], tmp_path / "b", 20)
    (tmp_path / "c").mkdir()
    np.savez(map_path(tmp_path / "c", folder), stretch=np.zeros(FRAMES))
    with pytest.raises(InputError, match="earlier version"):
        MapTriplets([seq], [3], tmp_path / "c", 20)


def test_two_inputs_of_one_name_are_refused(tmp_path):
    with pytest.raises(InputError, match="share the map"):
        list(map_inputs([tmp_path / "a/train/x", tmp_path / "b/train/x"], tmp_path,
                        (HEIGHT, WIDTH)))
    assert not any(tmp_path.iterdir())  # refused before anything was made


@pytest.mark.parametrize("aspect, shape, scale", [(0.8, (160, 160), (1.0, 0.8)),
                                                  (1.25, (128, 200), (0.8, 1.0)),
                                                  (1.0, (128, 160), (1.0, 1.0))])
def test_square_pixels(aspect, shape, scale):
    square = SquarePixels((HEIGHT, WIDTH), aspect)
    assert square.shape == shape and square.scale == pytest.approx(scale)
    assert square.fy_over_fx == pytest.approx(aspect)
    assert square.mask(np.ones((HEIGHT, WIDTH), bool)).shape == shape


@pytest.mark.parametrize("rows, columns", [((0, HEIGHT), (16, 144)), ((14, 114), (0, WIDTH))],
                         ids=["square-crop", "wide-crop"])
def test_frames_with_pixels_that_are_not_square_are_mapped(tmp_path, rows, columns):
    """The tube cropped (square pixels, f = 80) and taken at 128 x 160, which stretches the
    crop's axes by kx and ky: the network's frames have fx = 80 kx and fy = 80 ky."""
    (r0, r1), (c0, c1) = rows, columns
    kx, ky = WIDTH / (c1 - c0), HEIGHT / (r1 - r0)
    folder = tmp_path / "crop"
    folder.mkdir()
    texture = wall_texture()
    for i, pose in enumerate(POSES):
        cv2.imwrite(str(folder / f"{i:04d}.png"), render(pose, texture)[r0:r1, c0:c1])
    (line,) = map_inputs([folder], tmp_path / "maps", (HEIGHT, WIDTH), LENGTH)
    assert line.endswith(f"2 of 2 stretches mapped, {FRAMES} frames placed"), line
    found = np.load(map_path(tmp_path / "maps", folder))
    assert float(found["fy_over_fx"]) == pytest.approx(ky / kx, rel=0.01)
    assert np.all(np.abs(found["fx"] / (FOCAL * kx) - 1) < 0.1)
    for k in (0, 1):  # the points' pixels are the network's: back in the render by 1 / k
        mine = found["observations"][(found["observations"][:, 0] // LENGTH) == k]
        true = np.array([depth(POSES[int(i)])[round((y + 0.5) / ky - 0.5 + r0),
                                              round((x + 0.5) / kx - 0.5 + c0)]
                         for i, x, y, _ in mine])
        ratio = mine[:, 3] / true
        assert np.median(np.abs(ratio / np.median(ratio) - 1)) < 0.03


def test_map_zoom_scores_crops_against_the_maps_focal_length_carried_through_the_zoom(
        triplets, monkeypatch):
    """With map_zoom the motion network reads crops of the map triplets and the whole triplets
    at their detail, in one batch; a head that reads each crop's focal length as the map's
    times the zoom meets the targets, one that reads the map's whole-frame K misses by it."""
    batch = triplets.batch(3, np.random.default_rng(6))
    model = DepthModel(replace(CONFIG, maps="given", w_map_motion=1.0, map_zoom=True,
                               zoom_max=2.0))
    plain = model.loss(batch.frames, batch.regions)
    torch.manual_seed(7)
    views = zoom_pairs(batch.frames, 2.0)
    zoom = torch.stack([WIDTH / views.boxes[:, 2], HEIGHT / views.boxes[:, 3]])
    assert float(zoom.min()) > 1.1  # the draws do zoom
    zoomed_K = zoomed_intrinsics(batch.K, views.boxes, (HEIGHT, WIDTH))
    seen = []
    for K, focal in ((torch.cat([zoomed_K, batch.K]), 0.0),
                     (torch.cat([batch.K, batch.K]), float(torch.log(zoom).mean()) / 2)):
        def triplet_motion(frames, K=K):
            seen.append(frames)
            return [tuple(torch.cat([part, part]) for part in side)
                    for side in batch.motions], K

        monkeypatch.setattr(model, "triplet_motion", triplet_motion)
        torch.manual_seed(7)
        terms = with_map_terms(plain, model, batch)
        assert torch.equal(seen[-1], torch.cat([views.zoomed, views.whole]))
        assert [float(terms.map_rotation), float(terms.map_direction),
                float(terms.map_focal)] == pytest.approx([0, 0, focal], abs=1e-6)


@pytest.mark.parametrize("updates", [True, False])
def test_map_zoom_updates_batch_norm_statistics_only_when_asked(triplets, updates):
    batch = triplets.batch(2, np.random.default_rng(8))
    model = DepthModel(replace(CONFIG, maps="given", w_map_motion=1.0, map_zoom=True,
                               zoom_updates_bn=updates))
    model.train()
    with torch.no_grad():
        plain = model.loss(batch.frames, batch.regions)
        before = bn_running_statistics(model.motion)
        with_map_terms(plain, model, batch)
    assert torch.equal(before, bn_running_statistics(model.motion)) != updates


def test_photo_blur_on_maps_blurs_only_the_maps_view_synthesis(triplets):
    """With photo_blur_on="maps" the ordinary loss is the sharp one, bit for bit, and the map
    batch's view term is the blurred one (which differs from the sharp one)."""
    batch = triplets.batch(2, np.random.default_rng(6))
    torch.manual_seed(0)
    blurred = DepthModel(replace(CONFIG, maps="given", w_map=1.0, photo_blur=1.5,
                                 photo_blur_on="maps"))
    sharp = DepthModel(replace(blurred.config, photo_blur=0.0))
    sharp.load_state_dict(blurred.state_dict())

    def terms(model):
        torch.manual_seed(1)
        with torch.no_grad():
            return with_map_terms(model.loss(batch.frames, batch.regions), model, batch)

    on_maps = terms(blurred)
    plain = terms(sharp)
    assert float(on_maps.photometric) == float(plain.photometric)
    blurred.config = replace(blurred.config, photo_blur_on="all")
    everywhere = terms(blurred)
    assert float(on_maps.map_view) == pytest.approx(float(everywhere.map_view), rel=1e-6)
    assert float(everywhere.photometric) != pytest.approx(float(plain.photometric), rel=0.05)
    assert float(on_maps.map_view) != pytest.approx(float(plain.map_view), rel=0.05)


@pytest.mark.parametrize("settings", [{"photo_blur_on": "ordinary"},
                                      {"photo_blur_on": "maps", "maps": "given",
                                       "w_map_motion": 1.0}])
def test_photo_blur_on_is_checked(settings):
    with pytest.raises(ValueError, match="photo_blur_on must be 'all' or 'maps'"):
        replace(CONFIG, photo_blur=1.5, **settings)
