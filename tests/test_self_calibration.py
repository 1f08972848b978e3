"""The focal length from structure from motion on stretches of frames (fusion.self_calibration),
on the rendered tube of tests/tube_scene.py, and its use by `c2d2 depth`, eval-depth and
`c2d2 run` (the coverage networks' field of view)."""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch
from conftest import TINY
from tube_scene import FOCAL, HEIGHT, MASK, WIDTH, pose_at, render, wall_texture
from typer.testing import CliRunner

from fusion.self_calibration import (
    FoundLens,
    SelfCalibration,
    SelfCalibrationConfig,
    Stretch,
    _turn,
    contrast_enhanced,
    eval_records,
    half_angle,
    highlight_free,
    self_calibrate,
    stretch_starts,
)
from fusion.sfm_baseline import CAMERA_MODEL, FISHEYE_MODEL, run_sfm
from hybrid.cli import app
from hybrid.pipeline import LensNotFound, Models, RunConfig, _Run, run_video, video_features
from hybrid.types import InputError
from learned.checkpoint import save_checkpoint
from learned.config import coverage_config
from learned.coverage_nets import CoverageModel
from learned.evaluate import evaluate_sequence
from learned.frames import open_sequence
from learned.model import DepthModel
from learned.view import known_view, view_values

pytestmark = pytest.mark.usefixtures("one_thread")

GREY = (MASK[..., None] * np.full(3, 128)).astype(np.uint8)
"""A frame without texture (an even grey disc): no stretch of them maps."""


@pytest.fixture(scope="module")
def tube_frames() -> list[np.ndarray]:
    texture = wall_texture()
    return [render(pose_at(i), texture) for i in range(240)]


@pytest.mark.parametrize("count, windows, length, starts", [
    (600, 5, 120, [0, 120, 240, 360, 480]),
    (6000, 5, 120, [0, 1470, 2940, 4410, 5880]),
    (300, 5, 120, [0, 180]),  # as many as fit without overlapping
    (130, 3, 120, [0]),
    (100, 5, 120, [0]),  # shorter than a stretch: the whole input once
    (600, 1, 120, [0]),
])
def test_stretches_are_evenly_spaced_and_do_not_overlap(count, windows, length, starts):
    config = SelfCalibrationConfig(windows, length, min_agreeing=1)
    assert stretch_starts(count, config) == starts


UNBOUNDED = SelfCalibrationConfig(min_field_of_view=0)


def calibration(*stretches: tuple[float, float | None],
                config: SelfCalibrationConfig = UNBOUNDED) -> SelfCalibration:
    """From (fraction placed, fx) per stretch, at 128x160 with fy = 1.25 fx (by default with no
    bound on the field of view, so that any fx can agree)."""
    return SelfCalibration(600, [Stretch(120 * i, 120, r, f)
                                 for i, (r, f) in enumerate(stretches)],
                           config, (128, 160), 1.25)


def test_K_is_the_median_of_the_largest_group_of_mapped_stretches_that_agree():
    # Mapped: 60, 62, 130, 66; 61 placed too few frames, the fourth built no model.
    found = calibration((1.0, 60.0), (0.9, 62.0), (0.6, 130.0), (0.0, None), (0.3, 61.0),
                        (0.5, 66.0))
    assert [s.fx for s in found.mapped] == [60.0, 62.0, 130.0, 66.0]
    assert [s.fx for s in found.agreeing] == [60.0, 62.0, 66.0]
    np.testing.assert_allclose(found.K, [[62.0, 0, 79.5], [0, 77.5, 63.5], [0, 0, 1]])
    record = found.record()
    assert (record["mapped"], record["agreeing"]) == ([0, 120, 240, 600], [0, 120, 600])
    assert record["K"] == found.K.tolist()
    assert found.describe().startswith("fx 62.0, fy 77.5")
    # Read back from its record, under its own rule or a stricter one.
    np.testing.assert_array_equal(SelfCalibration.from_record(record).K, found.K)
    assert SelfCalibration.from_record(record, SelfCalibrationConfig(min_agreeing=4)).K is None


def test_the_group_is_found_wherever_the_median_lies():
    """100 and 105 agree though the median of all five (200) lies far from both."""
    found = calibration(*[(1.0, f) for f in (300.0, 100.0, 400.0, 105.0, 200.0)])
    assert [s.fx for s in found.agreeing] == [100.0, 105.0]
    assert found.K[0, 0] == pytest.approx(102.5)


def test_of_equal_groups_the_tightest_agrees():
    found = calibration(*[(1.0, f) for f in (100.0, 114.0, 200.0, 201.0)])
    assert [s.fx for s in found.agreeing] == [200.0, 201.0]


@pytest.mark.parametrize("stretches", [
    [(1.0, 100.0), (1.0, 116.0)],  # 16% apart: no two agree
    [(1.0, 60.0), (0.2, 61.0)],  # one mapped stretch is no consensus
    [(0.0, None), (0.0, None)],
])
def test_no_consensus_no_K(stretches):
    found = calibration(*stretches)
    assert found.K is None and found.record()["K"] is None
    assert found.describe().startswith("no consensus")


def test_stretches_narrower_than_an_endoscope_do_not_count():
    """At 160 px wide, 620 and 621 px (15 degrees, as on the real clip) agree but are too
    narrow; 60 degrees is fx = 80 / tan(30 degrees) = 138.6 px."""
    stretches = [(1.0, 620.0), (1.0, 621.0), (1.0, 138.0), (1.0, 139.0), (0.3, 700.0)]
    found = calibration(*stretches, config=SelfCalibrationConfig())
    assert [s.fx for s in found.mapped] == [138.0]
    assert found.field_of_view(found.stretches[2]) == pytest.approx(60.2, abs=0.05)
    assert found.K is None
    # The last placed too few frames to be mapped whatever its f: it is not named.
    assert "the stretches from frames [0, 120, 360] mapped at a field of view under 60 " \
           "degrees, too narrow for an endoscope" in found.describe()
    unbounded = calibration(*stretches)
    assert unbounded.K[0, 0] == pytest.approx(620.5)
    # The wider angle counts: in frames three times as tall as wide (fy = fx), 620 px spans
    # 2 atan(240 / 620) = 42.3 degrees vertically, 138 px 120 degrees.
    tall = SelfCalibration(600, found.stretches, SelfCalibrationConfig(), (480, 160), 1.0)
    assert tall.field_of_view(tall.stretches[0]) == pytest.approx(42.3, abs=0.05)
    assert [s.fx for s in tall.mapped] == [138.0, 139.0]
    # A record made before the bound had none: read back under its own rule, it agrees.
    record = found.record()
    del record["config"]["min_field_of_view"]
    assert SelfCalibration.from_record(record).K[0, 0] == pytest.approx(620.5)


def test_eval_depth_records_are_pooled_by_name_and_a_name_in_two_is_refused(tmp_path):
    records = {name: calibration((1.0, f), (1.0, f + 1)).record()
               for name, f in (("set/proc_0000", 50.0), ("set/proc_0001", 60.0))}
    paths = []
    for k, (name, record) in enumerate(records.items()):
        paths.append(tmp_path / f"eval-{k}.json")
        paths[-1].write_text(json.dumps({"procedures": {}, "self_calibration": {name: record}}))
    assert eval_records(paths) == records
    with pytest.raises(InputError, match="set/proc_0000: in more than one of"):
        eval_records([paths[0], paths[0]])

def test_a_video_too_short_for_two_stretches_is_not_mapped():
    def never(i):
        raise AssertionError("a frame was read")

    found = self_calibrate(never, 239, np.ones((HEIGHT, WIDTH), bool), "short")
    assert found.stretches == [] and found.K is None
    assert found.describe() == "239 frames hold fewer than 2 stretches of 120: not mapped"


@pytest.mark.parametrize("fields", [dict(windows=0), dict(windows=1), dict(length=1),
                                    dict(min_registered=0), dict(min_registered=1.5),
                                    dict(agreement=0), dict(min_agreeing=0),
                                    dict(contrast=-1), dict(contrast_tiles=0),
                                    dict(min_field_of_view=-1), dict(min_field_of_view=180),
                                    dict(initial_field_of_view=-1),
                                    dict(initial_field_of_view=180),
                                    dict(camera_model="OPENCV"),
                                    dict(camera_model=FISHEYE_MODEL)])
def test_a_config_that_cannot_work_is_refused(fields):
    with pytest.raises(InputError, match="self-calibration needs"):
        SelfCalibrationConfig(**fields)


def test_focal_length_of_stretched_pixels_and_a_blank_stretch_that_does_not_count(tube_frames):
    """Three stretches of 24 frames; the middle one is blank. The frames are squeezed to 128
    columns, as the network's resize squeezes a crop, so fx = 64 and fy = 80 px."""
    columns = 128
    squeeze = columns / WIDTH
    frames = [cv2.resize(f, (columns, HEIGHT), interpolation=cv2.INTER_AREA)
              for f in tube_frames[:24] + [GREY] * 24 + tube_frames[48:72]]
    region = cv2.resize(MASK.astype(np.uint8) * 255, (columns, HEIGHT)) > 127
    found = self_calibrate(frames.__getitem__, len(frames), region, "tube", 1 / squeeze,
                           SelfCalibrationConfig(windows=3, length=24))
    assert [s.start for s in found.stretches] == [0, 24, 48]
    blank = found.stretches[1]
    assert (blank.registered, blank.fx) == (0.0, None)
    assert found.record()["agreeing"] == [0, 48]
    # Each mapped stretch gives f within a few percent (1-3% measured at full width).
    assert found.K[0, 0] == pytest.approx(FOCAL * squeeze, rel=0.05)
    assert found.K[1, 1] == pytest.approx(FOCAL, rel=0.05)
    assert found.K[1, 1] / found.K[0, 0] == pytest.approx(1 / squeeze, rel=0.01)
    np.testing.assert_allclose(found.K[:2, 2], [(columns - 1) / 2, (HEIGHT - 1) / 2])
    assert (blank.reprojection_error, blank.points, blank.turn) == (None, None, None)


def test_highlights_are_thin_bright_streaks_and_glare_not_bright_walls():
    """On a wall of lightness ~100: a 3-px streak of 220 and a patch of glare (250) are
    masked, with a margin; a broad patch of 200 (a nearer, brighter wall) is kept."""
    image = np.full((64, 80, 3), 100, np.uint8)
    image[:, 20:23] = 220  # a streak along a fold
    image[40:60, 40:76] = 200  # broad: no top-hat rise inside it
    image[5:15, 50:60] = 250  # glare
    free = highlight_free(image)
    assert not free[:, 19:24].any()
    assert free[:, :15].all() and free[:, 28:36].all()
    assert free[46:54, 46:70].all()
    assert not free[5:15, 50:60].any()
    assert free[25:35, 50:60].all()


def test_stretches_mapped_in_parallel_processes_are_those_mapped_in_one(tube_frames):
    """Two spawned workers map what one process maps, to the last digit."""
    config = SelfCalibrationConfig(windows=2, length=24)
    alone, parallel = (self_calibrate(tube_frames.__getitem__, 48, MASK, "tube", config=config,
                                      workers=workers) for workers in (1, 2))
    assert parallel.record() == alone.record()
    assert len(alone.mapped) == 2


@pytest.mark.parametrize("highlights, start, model", [(False, 0.0, CAMERA_MODEL),
                                                      (True, 120.0, FISHEYE_MODEL)])
def test_highlights_the_start_and_the_camera_reach_the_mapper(highlights, start, model,
                                                               tube_frames, monkeypatch):
    """With the option each frame's mask is the image region off its highlights; without it,
    none. (The tube's grey texture of full contrast is not tissue: the top-hat takes 45% of
    it, so this checks the masks, not the map.) A start of 0 is COLMAP's own (None)."""
    given = []

    def recorded(images, mask, work, name, frame_masks, initial_field_of_view, camera_model):
        given.append((frame_masks, initial_field_of_view, camera_model))
        return run_sfm(images, mask, work, name, frame_masks, initial_field_of_view,
                       camera_model)

    monkeypatch.setattr("fusion.self_calibration.run_sfm", recorded)
    frames = tube_frames[:12]
    config = SelfCalibrationConfig(windows=1, length=12, min_agreeing=1, highlights=highlights,
                                   initial_field_of_view=start, camera_model=model)
    self_calibrate(frames.__getitem__, 12, MASK, "tube", config=config)
    ((masks, initial, camera),) = given
    assert camera == model
    if highlights:
        np.testing.assert_array_equal(masks, [MASK & highlight_free(f) for f in frames])
        assert initial == 120.0
    else:
        assert masks is None and initial is None


def test_a_stretch_keeps_its_map_quality_and_the_true_turn_of_the_camera(tube_frames):
    """A good map gives the true trajectory's turn. (Without the contrast step: with it, this
    stretch's map drifted by up to 3 degrees of rotation in a one-off probe.)"""
    found = self_calibrate(tube_frames.__getitem__, 48, MASK, "tube",
                           config=SelfCalibrationConfig(windows=1, length=48, min_agreeing=1,
                                                        contrast=0))
    (stretch,) = found.stretches
    assert stretch.registered == 1 and stretch.reprojection_error < 1
    assert stretch.points > 100 and stretch.track_length > 3
    assert stretch.turn == pytest.approx(_turn(np.stack([pose_at(i) for i in range(48)])),
                                         abs=0.5)


def rotated(angles_deg: list[tuple[float, float, float]]) -> np.ndarray:
    """Camera-to-world poses at one spot, each rotated by a rotation vector (degrees) about
    the camera's x (pitch), y (yaw) and z (roll) axes from the world's."""
    poses = np.tile(np.eye(4), (len(angles_deg), 1, 1))
    for pose, angles in zip(poses, angles_deg, strict=True):
        pose[:3, :3] = cv2.Rodrigues(np.radians(angles))[0]
    return poses


@pytest.mark.parametrize("angles, turn", [
    ([(0, 0, 0), (0, 10, 0), (0, 25, 0)], 25),
    ([(0, 0, 0), (-5, 0, 0), (5, 0, 0)], 5),
    ([(0, 0, 0), (0, 0, 30)], 0),  # a roll about the viewing axis is no turn
    ([(0, 0, 0)], 0),
])
def test_turn_of_a_stretch(angles, turn):
    assert _turn(rotated(angles)) == pytest.approx(turn)


def test_turn_reads_the_viewing_axis_of_camera_to_world_poses():
    """A camera pitched to look down the world's vertical, then spun 20 degrees about that
    vertical, only rolls: no turn (read as world-to-camera poses, it would be 20)."""
    first, second = rotated([(90, 0, 0), (90, 0, 0)])
    second[:3, :3] = cv2.Rodrigues(np.radians([0.0, 20.0, 0.0]))[0] @ first[:3, :3]
    assert _turn(np.stack([first, second])) == pytest.approx(0, abs=1e-6)
    assert _turn(np.stack([first, second]).transpose(0, 2, 1)) == pytest.approx(20)


def dimmed(frame: np.ndarray, gain: float, rng: np.random.Generator) -> np.ndarray:
    """`frame` at `gain` times its contrast about a dark grey, with a little noise, masked."""
    dim = (frame - 128.0) * gain + 60 + rng.normal(0, 1, frame.shape)
    return (dim.clip(0, 255) * MASK[..., None]).astype(np.uint8)


def test_the_contrast_step_maps_a_dim_low_contrast_video(tube_frames):
    """At a quarter of its contrast the tube maps only with the contrast step (measured: no
    model without it; f of about 79 px, true 80, with it)."""
    rng = np.random.default_rng(0)
    frames = [dimmed(f, 0.25, rng) for f in tube_frames[:48]]
    found = {contrast: self_calibrate(frames.__getitem__, len(frames), MASK, "dim tube",
                                      config=SelfCalibrationConfig(windows=2, length=24,
                                                                   contrast=contrast))
             for contrast in (0.0, 3.0)}
    assert found[0.0].mapped == [] and found[0.0].K is None
    assert len(found[3.0].agreeing) == 2
    assert found[3.0].K[0, 0] == pytest.approx(FOCAL, rel=0.05)


def test_the_contrast_step_spreads_the_lightness_and_zero_turns_it_off():
    rng = np.random.default_rng(1)
    frame = dimmed(render(pose_at(0), wall_texture()), 0.25, rng)
    lightness = [cv2.cvtColor(im, cv2.COLOR_RGB2LAB)[..., 0][MASK].std()
                 for im in (frame, contrast_enhanced(frame, SelfCalibrationConfig()))]
    assert lightness[1] > 2 * lightness[0]
    assert contrast_enhanced(frame, SelfCalibrationConfig(contrast=0)) is frame


def test_a_record_made_before_the_contrast_step_reads_as_mapped_without_it():
    record = calibration((1.0, 50.0), (1.0, 51.0)).record()
    del record["config"]["contrast"], record["config"]["contrast_tiles"]
    assert SelfCalibration.from_record(record).config.contrast == 0.0


def test_no_stretch_maps_no_K():
    found = self_calibrate(lambda i: GREY, 12, np.ones((HEIGHT, WIDTH), bool), "grey",
                           config=SelfCalibrationConfig(windows=2, length=6))
    assert found.K is None and found.mapped == []
    assert [s.registered for s in found.stretches] == [0.0, 0.0]


@pytest.fixture(scope="module")
def tube_checkpoint(tmp_path_factory):
    """A tiny untrained depth model at the tube's own size (its depth does not matter here)."""
    config = replace(TINY, height=HEIGHT, width=WIDTH)
    torch.manual_seed(0)
    model = DepthModel(config)
    path = tmp_path_factory.mktemp("ckpt") / "tube.safetensors"
    save_checkpoint(path, {"depth": model.depth, "motion": model.motion}, config.to_dict(),
                    step=0)
    return path


def write_frames(folder, frames):
    folder.mkdir()
    for i, frame in enumerate(frames):
        cv2.imwrite(str(folder / f"{i:04d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    return folder


def test_depth_command_writes_the_self_calibrated_K_beside_the_heads(tmp_path, tube_frames,
                                                                      tube_checkpoint):
    """Square frames (the tube's middle 128 columns) that the network stretches to 160: f is
    80 px in the input and fx = 100 px at the network's size. 240 frames: two stretches."""
    left = (WIDTH - HEIGHT) // 2
    folder = write_frames(tmp_path / "tube", [f[:, left:left + HEIGHT] for f in tube_frames])
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["depth", str(folder), "--out", str(out), "--checkpoint",
                                      str(tube_checkpoint), "--self-calibrate"])
    assert result.exit_code == 0, result.output
    intrinsics = json.loads((out / "intrinsics.json").read_text())
    assert intrinsics["source"] == "self-calibration"
    assert (intrinsics["width"], intrinsics["height"]) == (HEIGHT, HEIGHT)
    assert intrinsics["fx"] == pytest.approx(FOCAL, rel=0.05)
    assert intrinsics["fy"] == pytest.approx(FOCAL, rel=0.05)
    assert (intrinsics["cx"], intrinsics["cy"]) == pytest.approx(((HEIGHT - 1) / 2,) * 2, abs=0.5)
    network = intrinsics["network"]
    assert network["fx"] / intrinsics["fx"] == pytest.approx(WIDTH / HEIGHT)
    assert network["fy"] == pytest.approx(intrinsics["fy"])
    assert intrinsics["self_calibration"]["agreeing"] == [0, 120]
    assert intrinsics["self_calibration"]["config"]["contrast"] == SelfCalibrationConfig().contrast
    # The head's own estimate is kept beside it.
    assert set(intrinsics["head"]) == {"fx", "fy", "cx", "cy", "spread", "pairs", "network"}
    assert intrinsics["head"]["pairs"] == 239
    assert len(list((out / "depth").iterdir())) == 240


def test_depth_command_without_a_mapped_stretch_keeps_the_heads_K_and_says_so(
        tmp_path, tube_checkpoint):
    folder = write_frames(tmp_path / "grey", [GREY] * 240)
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["depth", str(folder), "--out", str(out), "--checkpoint",
                                      str(tube_checkpoint), "--self-calibrate",
                                      "--contrast", "0"])
    assert result.exit_code == 0, result.output
    assert "gave no K, so the intrinsics head's is kept: no consensus" in result.output
    intrinsics = json.loads((out / "intrinsics.json").read_text())
    assert intrinsics["self_calibration"]["config"]["contrast"] == 0
    assert intrinsics["source"] == "intrinsics head" and "head" not in intrinsics
    assert intrinsics["self_calibration"]["mapped"] == []
    assert len(intrinsics["self_calibration"]["stretches"]) == 2
    assert intrinsics["fx"] == pytest.approx(intrinsics["network"]["fx"])  # crop = frame


def test_eval_depth_with_self_calibration_on_a_short_procedure_scores_the_heads_K(tmp_path,
                                                                                    clip):
    """30 frames cannot hold two stretches: the head's K is scored, and the JSON says so."""
    model = DepthModel(TINY)
    checkpoint = tmp_path / "tiny.safetensors"
    save_checkpoint(checkpoint, {"depth": model.depth, "motion": model.motion},
                    TINY.to_dict(), step=0)
    out = tmp_path / "eval.json"
    result = CliRunner().invoke(app, ["eval-depth", "--data", str(clip), "--checkpoint",
                                      str(checkpoint), "--frames", "2", "--self-calibrate",
                                      "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "30 frames hold fewer than 2 stretches" in result.output
    scored = json.loads(out.read_text())
    (metrics,) = scored["procedures"].values()
    assert metrics["self_calibrated"] == 0.0
    assert metrics["fx_rel"] == pytest.approx(metrics["fx_head_rel"])
    (record,) = scored["self_calibration"].values()
    assert (record["frames"], record["stretches"], record["K"]) == (30, [], None)


@pytest.mark.parametrize("command", [["depth", "IN", "--out", "OUT"],
                                     ["eval-depth", "--data", "IN"]])
def test_contrast_without_self_calibration_is_refused(tmp_path, clip, command):
    args = [{"IN": str(clip), "OUT": str(tmp_path / "out")}.get(a, a) for a in command]
    result = CliRunner().invoke(app, [*args, "--contrast", "2"])
    assert result.exit_code != 0
    assert "--contrast sets the self-calibration's frames: give --self-calibrate" in result.output
    assert not (tmp_path / "out").exists()


def test_eval_depth_scores_the_K_it_is_given(clip):
    """The true K scores zero error; the head's own estimate is still reported."""
    model = DepthModel(TINY).eval()
    seq = open_sequence(clip, (TINY.height, TINY.width))
    metrics = evaluate_sequence(model, seq, depth_frames=2, trajectory_frames=5,
                                K=seq.camera.K)
    assert (metrics["fx_rel"], metrics["fy_rel"], metrics["cx_rel"]) == (0, 0, 0)
    assert metrics["fx_pred"] == seq.camera.fx
    assert metrics["fx_head_rel"] == pytest.approx(
        abs(metrics["fx_head"] - seq.camera.fx) / seq.camera.fx)


def test_a_run_gives_view_hidden_networks_the_self_calibrated_field_of_view(tmp_path,
                                                                             tube_frames,
                                                                             tube_checkpoint):
    """Coverage networks trained on the true field of view with view_hidden: `c2d2 run`'s
    self-calibration stage gives them the tube's (f = 80 px) where enough stretches agree;
    without the stage, or without a consensus, they read it hidden, with a warning."""
    folder = write_frames(tmp_path / "tube", tube_frames)
    coverage = tmp_path / "view.safetensors"
    torch.manual_seed(0)
    CoverageModel(coverage_config("fast", field_of_view="true", view_hidden=0.5)).save(coverage)
    base = RunConfig(depth_checkpoint=str(tube_checkpoint), coverage_checkpoint=str(coverage),
                     segment_seconds=4.0)
    two = replace(base, self_calibrate=True,
                  self_calibration=SelfCalibrationConfig(min_agreeing=2))
    runs = {}
    for name, config in (("hidden", base), ("two", two),
                         ("three", replace(base, self_calibrate=True))):
        models = Models.load(config)
        features, _ = video_features(folder, tmp_path / name, config, models, progress=False)
        run = _Run(folder, tmp_path / name, config, models, None, False)
        runs[name] = features, run.cues(len(features))[:, -3:], run.self_calibration_record()
        run.learned()
        assert json.loads((tmp_path / name / "learned.json").read_text())["field_of_view"] == (
            {"source": "hidden"} if runs[name][2] is None or runs[name][2].K is None else
            {"source": "self-calibration", "fx": runs[name][2].K[0, 0],
             "fy": runs[name][2].K[1, 1]})
    # 240 frames hold two stretches: both map and agree on f, the tube's.
    (features, view, found), crop = runs["two"], json.loads(
        (tmp_path / "two" / "ingest.json").read_text())["crop"]
    assert found.record()["agreeing"] == [0, 120]
    # (Measured: 76.7 and 73.7 px, so 75.2, 6% short, on these frames as ingested; the
    # mapper's own accuracy is the subject of the tests above.)
    assert found.K[0, 0] == pytest.approx(FOCAL * WIDTH / crop["width"], rel=0.1)
    np.testing.assert_allclose(view, known_view(view_values(found.K, WIDTH, HEIGHT, len(view))))
    # Under the run's own rule (3 agreeing) they are too few, and not mapped at all; the run,
    # completed, says so in a note (not a warning: its results are whole).
    assert runs["three"][2].K is None and runs["three"][2].stretches == []
    config, notes = replace(base, self_calibrate=True), []
    result = run_video(folder, tmp_path / "three", config, Models.load(config), progress=False,
                       echo=notes.append)
    assert "note: self-calibration found no field of view, so the coverage networks ran " \
           "without it: 240 frames hold fewer than 3 stretches of 120: not mapped" in notes
    assert not any("field of view" in w for w in result["warnings"])
    # The folder of a run without it is not resumed with it.
    with pytest.raises(InputError, match=r"differs in self_calibrate; self_calibration, which "
                                         r"it does not record"):
        run_video(folder, tmp_path / "hidden", config, Models.load(config), progress=False)
    for name in ("hidden", "three"):
        assert not runs[name][1].any()
        np.testing.assert_array_equal(runs[name][0], runs["hidden"][0])
    assert np.abs(features - runs["hidden"][0]).max() > 1e-3  # the input reaches the network
    assert runs["hidden"][2] is None
    assert not (tmp_path / "hidden" / "self_calibration.json").exists()


LENS_SEARCH = SelfCalibrationConfig(min_field_of_view=0, camera_model=FISHEYE_MODEL,
                                    initial_field_of_view=120)


def lens_search(*stretches: tuple[float, float | None, float | None],
                config: SelfCalibrationConfig = LENS_SEARCH) -> SelfCalibration:
    """From (fraction placed, f, k) per stretch, mapped with the fisheye camera, at 128x160
    with square pixels."""
    return SelfCalibration(600, [Stretch(120 * i, 120, r, f, k=k)
                                 for i, (r, f, k) in enumerate(stretches)],
                           config, (128, 160), 1.0)


@pytest.mark.parametrize("model, ratio, k, angle", [
    (CAMERA_MODEL, 1.0, 0.0, np.pi / 4),
    (FISHEYE_MODEL, 1.2, 0.0, 1.2),  # equidistant: r = f θ
    (FISHEYE_MODEL, np.tan(0.5), 1 / 3, 0.5037),  # tan θ = θ + θ³/3 + 2θ⁵/15 + ...
    (FISHEYE_MODEL, 3.0, -0.2, float("nan")),  # θ - 0.2 θ³ never reaches 3 (at most 0.86)
])
def test_the_angle_of_a_ray_through_either_camera(model, ratio, k, angle):
    assert half_angle(model, ratio, k) == pytest.approx(angle, abs=1e-4, nan_ok=True)


def test_the_lens_is_the_largest_group_of_one_lens_whose_angles_agree():
    """At 160 px wide, f = 80, 84, 88 px with k near 0 see 2 (80 / f) radians: 114.6, 109.1
    and 104.2 degrees, within 15%; a pinhole-like stretch (k 0.5) and one placing too few
    frames do not join them."""
    found = lens_search((1.0, 80.0, 0.01), (1.0, 50.0, 0.5), (0.9, 84.0, -0.02), (0.2, 84.0, 0.0),
                        (1.0, 88.0, 0.03))
    assert found.record()["agreeing"] == [0, 240, 480]
    # The median of the three angles, each from its own f and k.
    middle = np.degrees(2 * half_angle(FISHEYE_MODEL, 80 / 84, -0.02))
    assert found.lens == FoundLens("equidistant", pytest.approx(middle))
    assert found.describe().startswith(f"equidistant, {middle:.0f} degrees across the width")
    record = found.record()
    assert "K" not in record and record["lens"] == {"model": "equidistant",
                                                    "width_deg": found.lens.width_deg}
    assert SelfCalibration.from_record(record).lens == found.lens
    with pytest.raises(ValueError, match="give a lens, not a K"):
        _ = found.K
    with pytest.raises(ValueError, match="give a K, not a lens"):
        _ = calibration((1.0, 60.0), (1.0, 61.0)).lens
    with pytest.raises(ValueError, match="mapped with SIMPLE_RADIAL_FISHEYE read as mapped with "
                                         "SIMPLE_PINHOLE"):
        SelfCalibration.from_record(record, SelfCalibrationConfig())


def test_a_stretch_whose_k_reaches_no_edge_does_not_count_and_is_named():
    """With k = -0.39 (as a CVC sequence mapped) θ - 0.39 θ³ never exceeds 0.616: at f = 80 px
    no ray lands at the edge of the 160-px width, so the stretch gives no angle."""
    found = lens_search((1.0, 80.0, -0.39), (1.0, 80.0, 0.0), (1.0, 82.0, 0.01),
                        config=replace(LENS_SEARCH, min_field_of_view=60))
    assert [s.start for s in found.mapped] == [120, 240]
    assert found.lens.model == "equidistant"
    assert ("the stretches from frames [0] mapped with a k that sends no ray to the frames' "
            "edge, and do not count (per stretch: first frame, fraction placed, k, degrees "
            "across the width: [(0, 1.0, -0.39, None), ") in found.describe()
    assert "too narrow" not in found.describe()


def test_a_pinhole_is_told_whatever_its_angles_and_equal_groups_of_the_two_lenses_tell_none():
    """The run reads a pinhole as it is: its stretches need not agree on the angle (here 116.7
    and 85.8 degrees)."""
    pinhole = lens_search((1.0, 50.0, 0.55), (1.0, 80.0, 0.6), (1.0, 80.0, 0.0))
    assert pinhole.lens.model == "pinhole"
    assert [s.start for s in pinhole.agreeing] == [0, 120]
    tie = lens_search((1.0, 50.0, 0.55), (1.0, 52.0, 0.6), (1.0, 80.0, 0.0), (1.0, 81.0, 0.0))
    assert tie.agreeing == [] and tie.lens is None
    assert tie.describe().startswith("no consensus (per stretch: first frame, fraction placed, "
                                     "k, degrees across the width: [(0, 1.0, 0.55, ")


@pytest.mark.parametrize("lens", ["equidistant", "pinhole"])
def test_the_lens_of_the_tube_is_told_from_its_frames(lens):
    """Two stretches of the tube filmed through an equidistant lens of f = 80 px, which sees
    2 (80 / 80) radians = 114.6 degrees across the 160-px width, or through a pinhole."""
    texture = wall_texture()
    frames = [render(pose_at(i), texture, lens) for i in range(48)]
    config = replace(LENS_SEARCH, windows=2, length=24, min_agreeing=2)
    found = self_calibrate(frames.__getitem__, len(frames), MASK, "tube", config=config)
    assert found.lens.model == lens
    assert all(s.k is not None for s in found.stretches)
    if lens == "equidistant":
        assert found.lens.width_deg == pytest.approx(np.degrees(2.0), rel=0.05)


def test_a_run_that_tells_the_lens_resamples_a_fisheye_and_refuses_a_video_it_cannot_tell(
        tmp_path, tube_checkpoint):
    """`RunConfig.find_lens` on 72 frames of the tube (three stretches of 24, two of which
    must agree; the coverage networks' travel cue needs more than 64 frames):
    through the equidistant lens the ingestion resamples at the angle found (114.6 degrees
    across the width, the crop being the whole frame); through a pinhole it reads the frames
    as they are; on blank frames it refuses before ingesting, and again on resuming."""
    coverage = tmp_path / "coverage.safetensors"
    torch.manual_seed(0)
    CoverageModel(coverage_config("fast")).save(coverage)
    search = replace(LENS_SEARCH, windows=3, length=24, min_agreeing=2)
    config = RunConfig(depth_checkpoint=str(tube_checkpoint), coverage_checkpoint=str(coverage),
                       segment_seconds=1.0, find_lens=True, lens_search=search)
    models = Models.load(config)
    texture = wall_texture()
    for lens in ("equidistant", "pinhole"):
        folder = write_frames(tmp_path / lens, [render(pose_at(i), texture, lens)
                                                for i in range(72)])
        work, notes = tmp_path / f"{lens}-run", []
        if lens == "equidistant":  # the whole run, which says what it found
            run_video(folder, work, config, models, progress=False, echo=notes.append)
            assert (work / "report.html").is_file()
        else:
            video_features(folder, work, config, models, progress=False)
        ingested = json.loads((work / "ingest.json").read_text())
        found = json.loads((work / "lens.json").read_text())["lens"]
        assert found["model"] == lens
        if lens == "equidistant":
            assert f"note: the lens from the video: equidistant, " \
                   f"{found['width_deg']:.0f} degrees across the width" in "\n".join(notes)
            assert ingested["fisheye_fov_deg"] == found["width_deg"]
            assert found["width_deg"] == pytest.approx(np.degrees(2.0), rel=0.05)
            intrinsics = json.loads((work / "intrinsics.json").read_text())
            assert intrinsics["resampled_from_fisheye_fov_deg"] == found["width_deg"]
        else:
            assert ingested["fisheye_fov_deg"] is None
    folder = write_frames(tmp_path / "grey", [GREY] * 72)
    for _ in range(2):
        with pytest.raises(LensNotFound, match=r"grey: its lens could not be told from the "
                                               r"video \(no consensus .*\); give --fisheye-fov"):
            video_features(folder, tmp_path / "grey-run", config, models, progress=False)
        assert (tmp_path / "grey-run" / "lens.json").is_file()
        assert not (tmp_path / "grey-run" / "frames.npy").exists()
    with pytest.raises(InputError, match="either the fisheye's field of view or --find-lens"):
        RunConfig(find_lens=True, fisheye_fov_deg=120.0)
    with pytest.raises(InputError, match="the lens is told by the fisheye camera"):
        RunConfig(find_lens=True, lens_search=SelfCalibrationConfig())
    with pytest.raises(InputError, match="the self-calibration's K is a pinhole's"):
        RunConfig(self_calibrate=True, self_calibration=LENS_SEARCH)
