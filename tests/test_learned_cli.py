"""The depth commands of the CLI (`depth`, `eval-depth`, `train-depth`) on bad input, loading
checkpoints of the wrong preset or shape, and the input side of learned.frames: the detected
image region and the crop that maps intrinsics back to the input's pixels."""

from __future__ import annotations

import gc
import json
import math
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from conftest import TINY, write_video
from typer.testing import CliRunner

from hybrid.cli import app
from hybrid.types import Camera, InputError
from learned.checkpoint import read_checkpoint, save_checkpoint
from learned.config import DEPTH_PRESETS
from learned.evaluate import evaluate_sequence
from learned.frames import FrameSequence, detect_region, open_sequence
from learned.infer import DepthFiles, infer_sequence
from learned.metrics import trajectory_errors
from learned.model import DepthModel, load_depth_model

runner = CliRunner()

pytestmark = pytest.mark.usefixtures("one_thread")


def save_model(path: Path, model: DepthModel, config: dict) -> Path:
    save_checkpoint(path, {"depth": model.depth, "motion": model.motion}, config, step=0)
    return path


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory) -> Path:
    torch.manual_seed(0)
    return save_model(tmp_path_factory.mktemp("ckpt") / "tiny.safetensors", DepthModel(TINY),
                      TINY.to_dict())


def disc_frame(height: int = 100, width: int = 120, centre=(64, 47), radius: int = 38,
               seed: int = 0) -> np.ndarray:
    """RGB uint8: a textured bright disc (grey ≥ 60) with a dark lumen inside it, a black
    border, and a small bright overlay in a corner (like burnt-in text)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[:height, :width]
    frame = np.zeros((height, width, 3), np.uint8)
    inside = (x - centre[0]) ** 2 + (y - centre[1]) ** 2 <= radius**2
    frame[inside] = rng.integers(60, 230, (int(inside.sum()), 3))
    lumen = (x - centre[0] - 8) ** 2 + (y - centre[1] + 5) ** 2 <= 7**2
    frame[lumen] = 5
    frame[2:5, 2:14] = 255
    return frame


def write_images(folder: Path, frames: list[np.ndarray]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, frame in enumerate(frames):
        channels = frame.shape[2]
        code = cv2.COLOR_RGB2BGR if channels == 3 else cv2.COLOR_RGBA2BGRA
        assert cv2.imwrite(str(folder / f"frame_{i:03d}.png"), cv2.cvtColor(frame, code))
    return folder


def run_depth(source: Path, out: Path, checkpoint: Path, *extra: str):
    return runner.invoke(app, ["depth", str(source), "--out", str(out),
                               "--checkpoint", str(checkpoint), *extra])


def assert_clean_error(result, *names: str) -> str:
    """Non-zero exit, one 'error:' message (no traceback) naming each of `names`."""
    assert result.exit_code != 0, result.output
    message = result.stderr
    assert message.startswith("error: "), result.output
    assert "Traceback" not in result.output
    for name in names:
        assert name in message, message
    return message


# --- image region and crop -----------------------------------------------------------------

def test_detect_region_is_the_disc_minus_a_thin_rim():
    """Erosion by a 5x5 square keeps a pixel iff its 25 neighbours are all in the disc: every
    pixel within r − 2√2 of the centre stays, and a kept pixel p at distance d has an axis
    neighbour 2 px further out along (at least) 45° of the radius, at distance
    ≥ √(d² + 2√2·d + 4) > d + √2, so d < r − √2. The dark lumen is filled; the overlay in the
    corner (a separate, smaller component) is dropped."""
    centre, radius = (64, 47), 38
    frames = [disc_frame(seed=s) for s in range(3)]
    region = detect_region(frames)
    y, x = np.mgrid[:100, :120]
    distance = np.hypot(x - centre[0], y - centre[1])
    assert region.shape == (100, 120) and region.dtype == bool
    assert region[distance <= radius - 2 * math.sqrt(2)].all()
    assert not region[distance >= radius - math.sqrt(2)].any()
    assert not region[:10, :20].any()  # the overlay


def test_detect_region_of_black_frames_is_an_input_error():
    with pytest.raises(InputError, match="black"):
        detect_region([np.full((20, 30, 3), 10, np.uint8)] * 2)


def test_the_region_is_resized_by_pixel_centres_like_the_frames():
    """A disc centred in its 4.5 times larger bounding box keeps its mirror symmetry at the
    network's size (sampling each cell's top-left pixel, it moved by about 0.4 px right and
    down against the frames)."""
    y, x = np.mgrid[:576, :720]
    region = ((x - 359.5) / 360) ** 2 + ((y - 287.5) / 288) ** 2 <= 1
    frames = [np.repeat(np.where(region[..., None], 150, 0).astype(np.uint8), 3, axis=2)] * 2
    small = FrameSequence("disc", 30.0, (128, 160), frames.__getitem__, 2, region=region).region
    assert small.any() and not small.all()
    np.testing.assert_array_equal(small, small[:, ::-1])
    np.testing.assert_array_equal(small, small[::-1])


def test_the_networks_read_the_border_filled_from_inside_and_nothing_of_it(tmp_path):
    """network_frame: inside the region the frame itself, outside it the colour of the nearest
    pixel inside; so what the border holds (black, or noise beyond the few pixels that the
    resize blends into the region's edge) never reaches the depth and motion networks, and a
    frame without border is read as it is."""
    frames = [disc_frame(seed=s) for s in range(3)]
    region = detect_region(frames)
    near = cv2.dilate(region.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    noisy = [np.where(near[..., None], f, np.random.default_rng(9).integers(0, 255, f.shape))
             .astype(np.uint8) for f in frames]
    seqs = [FrameSequence(name, 30.0, (64, 96), images.__getitem__, 3, region=region)
            for name, images in (("black", frames), ("noisy", noisy))]
    black, other = seqs
    image, small = black.network_frame(1), black.region
    np.testing.assert_array_equal(image[small], black.frame(1)[small])
    np.testing.assert_array_equal(image, other.network_frame(1))
    assert not np.array_equal(black.frame(1), other.frame(1))
    inside = np.argwhere(small)
    for row, column in np.argwhere(~small)[::50]:
        nearest = np.hypot(*(inside - (row, column)).T)
        assert any((image[row, column] == image[r, c]).all()
                   for r, c in inside[nearest == nearest.min()]), (row, column)
    model = DepthModel(TINY).eval()
    first, second = (infer_sequence(model, seq, (1,)) for seq in seqs)
    np.testing.assert_array_equal(first.depth, second.depth)
    np.testing.assert_array_equal(first.relative[1], second.relative[1])
    whole = FrameSequence("whole", 30.0, (64, 96), frames.__getitem__, 3,
                          region=np.ones((100, 120), bool))
    np.testing.assert_array_equal(whole.network_frame(2), whole.frame(2))


def test_crop_maps_network_intrinsics_back_to_the_input(tmp_path):
    folder = write_images(tmp_path / "frames", [disc_frame(seed=s) for s in range(3)])
    seq = open_sequence(folder, (64, 96))
    region = detect_region([disc_frame(seed=s) for s in range(3)])
    ys, xs = np.nonzero(region)
    crop = seq.crop
    assert (crop.x0, crop.y0) == (xs.min(), ys.min())
    assert (crop.width, crop.height) == (xs.max() - xs.min() + 1, ys.max() - ys.min() + 1)
    assert (crop.input_width, crop.input_height) == (120, 100)
    assert seq.region.shape == (64, 96) and seq.frame(0).shape == (64, 96, 3)

    net = Camera(96, 64, 40.0, 42.0, 47.0, 30.0, fps=25.0)
    got = crop.camera_to_input(net)
    # By hand: the crop is resized by (w/96, h/64); pixel centres map as
    # x_in = x0 + (u + 0.5)·w/96 − 0.5.
    sx, sy = crop.width / 96, crop.height / 64
    assert (got.width, got.height, got.fps) == (120, 100, 25.0)
    assert got.fx == pytest.approx(40.0 * sx, rel=1e-12)
    assert got.fy == pytest.approx(42.0 * sy, rel=1e-12)
    assert got.cx == pytest.approx(crop.x0 + 47.5 * sx - 0.5, rel=1e-12)
    assert got.cy == pytest.approx(crop.y0 + 30.5 * sy - 0.5, rel=1e-12)
    # A 3-D point projects, in the input, where its network pixel maps to.
    point = np.array([0.3, -0.2, 2.0])
    u, v = (net.K @ point)[:2] / point[2]
    x_in, y_in = (got.K @ point)[:2] / point[2]
    assert x_in == pytest.approx(crop.x0 + (u + 0.5) * sx - 0.5, rel=1e-12)
    assert y_in == pytest.approx(crop.y0 + (v + 0.5) * sy - 0.5, rel=1e-12)


def test_a_video_is_streamed_into_network_sized_frames(tmp_path, monkeypatch):
    """A video is read into a file of frames at the network's size, not held at its own size;
    each frame is the decoded one cut to the detected region and resized."""
    frames = [disc_frame(seed=s) for s in range(4)]
    video = write_video(tmp_path / "clip.avi", frames, 25.0)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))  # no other run's folders
    (tmp_path / "tmp").mkdir()
    temporary = Path(tempfile.gettempdir())
    before = set(temporary.glob("c2d2-frames-*"))
    seq = open_sequence(video, (64, 96))
    assert len(set(temporary.glob("c2d2-frames-*")) - before) == 1
    assert (seq.num_frames, seq.fps) == (4, pytest.approx(25.0))
    assert seq._load(0).shape == (64, 96, 3)  # what the sequence keeps is network-sized

    images = open_sequence(write_images(tmp_path / "frames", frames), (64, 96))
    c, d = seq.crop, images.crop
    assert (c.input_width, c.input_height) == (120, 100)
    assert max(abs(c.x0 - d.x0), abs(c.y0 - d.y0), abs(c.width - d.width),
               abs(c.height - d.height)) <= 1  # the same region, up to JPEG's ringing
    capture = cv2.VideoCapture(str(video))
    for index in range(4):
        ok, decoded = capture.read()
        assert ok
        cut = cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB)[c.y0:c.y0 + c.height, c.x0:c.x0 + c.width]
        assert np.array_equal(seq.frame(index), cv2.resize(cut, (96, 64),
                                                           interpolation=cv2.INTER_AREA))
    capture.release()
    del seq
    gc.collect()
    assert set(temporary.glob("c2d2-frames-*")) == before  # the frames' file went with it


# --- `c2d2 depth` --------------------------------------------------------------------------

def test_depth_runs_on_a_folder_of_images(tmp_path, tiny_checkpoint):
    """Control for the bad-input cases below: the same checkpoint on good input works."""
    folder = write_images(tmp_path / "good", [disc_frame(seed=s) for s in range(3)])
    out = tmp_path / "out"
    result = run_depth(folder, out, tiny_checkpoint)
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (out / "depth").iterdir()) == [
        "000000.npy", "000001.npy", "000002.npy"]
    assert np.load(out / "depth" / "000000.npy").shape == (64, 96)
    relative = np.load(out / "relative_poses.npy")
    poses = np.load(out / "poses.npy")
    assert relative.shape == (2, 4, 4) and poses.shape == (3, 4, 4)
    # relative[t] maps camera t's points into camera t+1: P[t+1] @ relative[t] = P[t]
    assert np.array_equal(poses[0], np.eye(4))
    np.testing.assert_allclose(poses[1:] @ relative, poses[:-1], atol=1e-9)
    intrinsics = json.loads((out / "intrinsics.json").read_text())
    assert (intrinsics["width"], intrinsics["height"], intrinsics["pairs"]) == (120, 100, 2)
    assert sorted(p.name for p in out.iterdir()) == [
        "depth", "intrinsics.json", "poses.npy", "region.png", "relative_poses.npy"]


def test_depth_into_a_folder_of_an_earlier_run_leaves_none_of_its_maps(tmp_path,
                                                                       tiny_checkpoint):
    """A longer earlier run's maps, and an interrupted one's, do not stay beside the new ones
    (the folder would look like a run of more frames)."""
    out = tmp_path / "out"
    run_depth(write_images(tmp_path / "long", [disc_frame(seed=s) for s in range(5)]), out,
              tiny_checkpoint)
    (out / "depth.partial").mkdir()
    (out / "depth.partial" / "000007.npy").write_bytes(b"interrupted")
    result = run_depth(write_images(tmp_path / "short", [disc_frame(seed=s) for s in range(3)]),
                       out, tiny_checkpoint)
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (out / "depth").iterdir()) == [
        "000000.npy", "000001.npy", "000002.npy"]
    assert not (out / "depth.partial").exists()
    assert np.load(out / "poses.npy").shape == (3, 4, 4)


def test_depth_written_frame_by_frame_equals_the_depth_in_memory(tmp_path, tiny_checkpoint):
    """20 frames span two inference batches of 16: each file holds its own frame's depth."""
    folder = write_images(tmp_path / "frames", [disc_frame(seed=s) for s in range(20)])
    result = run_depth(folder, tmp_path / "out", tiny_checkpoint)
    assert result.exit_code == 0, result.output
    model = load_depth_model(tiny_checkpoint)
    expected = infer_sequence(model, open_sequence(folder, (TINY.height, TINY.width)))
    written = np.stack([np.load(tmp_path / "out" / "depth" / f"{i:06d}.npy") for i in range(20)])
    np.testing.assert_allclose(written, expected.depth, rtol=1e-5)
    np.testing.assert_allclose(np.load(tmp_path / "out" / "relative_poses.npy"),
                               expected.relative[1], atol=1e-6)


def test_depth_files_of_a_range_count_from_its_first_frame(tmp_path, tiny_checkpoint):
    folder = write_images(tmp_path / "frames", [disc_frame(seed=s) for s in range(20)])
    model = load_depth_model(tiny_checkpoint)
    seq = open_sequence(folder, (TINY.height, TINY.width))
    expected = infer_sequence(model, seq, frames=range(3, 20))
    infer_sequence(model, seq, frames=range(3, 20), depth_out=DepthFiles(tmp_path / "depth"))
    assert len(list((tmp_path / "depth").iterdir())) == 17
    for i in (0, 16):
        np.testing.assert_allclose(np.load(tmp_path / "depth" / f"{i:06d}.npy"),
                                   expected.depth[i], rtol=1e-5)


@pytest.mark.parametrize("extra, fps", [((), 25.0), (("--fps", "12.5"), 12.5)])
def test_depth_on_a_video_takes_its_frame_rate_or_the_one_given(tmp_path, tiny_checkpoint,
                                                                 extra, fps):
    video = write_video(tmp_path / "clip.avi", [disc_frame(seed=s) for s in range(3)], 25.0)
    out = tmp_path / "out"
    result = run_depth(video, out, tiny_checkpoint, *extra)
    assert result.exit_code == 0, result.output
    assert json.loads((out / "intrinsics.json").read_text())["fps"] == pytest.approx(fps)
    assert len(list((out / "depth").iterdir())) == 3


@pytest.mark.parametrize("command, fps", [("depth", "0"), ("train-depth", "0"),
                                          ("depth", "inf")])
def test_a_frame_rate_that_is_not_a_positive_number_is_refused(tmp_path, tiny_checkpoint,
                                                               command, fps):
    folder = write_images(tmp_path / "frames", [disc_frame(seed=s) for s in range(3)])
    args = [str(folder), "--checkpoint", str(tiny_checkpoint)] if command == "depth" else \
        ["--data", str(folder), "--steps", "1"]
    result = runner.invoke(app, [command, *args, "--out", str(tmp_path / "out"), "--fps", fps])
    assert_clean_error(result, "--fps must be a positive number")
    assert not (tmp_path / "out" / "checkpoint.safetensors").exists()


def test_depth_refuses_a_frame_rate_for_a_simulated_procedure(tmp_path, tiny_checkpoint,
                                                               simulated):
    result = run_depth(simulated, tmp_path / "out", tiny_checkpoint, "--fps", "12")
    assert_clean_error(result, simulated.name, "--fps")
    assert not (tmp_path / "out").exists()


def test_depth_on_an_unreadable_video(tmp_path, tiny_checkpoint):
    fake = tmp_path / "not_a_video.mp4"
    fake.write_text("this is plain text, not an MPEG-4 file\n" * 20)
    result = run_depth(fake, tmp_path / "out", tiny_checkpoint)
    assert_clean_error(result, "not_a_video.mp4")
    assert not (tmp_path / "out" / "depth").exists()


def test_depth_on_a_folder_with_a_single_image(tmp_path, tiny_checkpoint):
    folder = write_images(tmp_path / "lonely_frame", [disc_frame()])
    message = assert_clean_error(run_depth(folder, tmp_path / "out", tiny_checkpoint),
                                 "lonely_frame")
    assert "2 frames" in message


def test_image_folders_are_read_as_8_bit_colour_of_one_size(tmp_path):
    """Images with an alpha channel and 16-bit images give the frames their colour gives (as
    `c2d2 run` reads them; 16-bit ones were read as they were, up to 65535), and an image of
    another size is refused by name (it was cut with the others' box)."""
    frames = [disc_frame(seed=s) for s in range(3)]
    plain = open_sequence(write_images(tmp_path / "plain", frames), (64, 96))
    alpha = write_images(tmp_path / "alpha", [np.dstack([f, np.full((100, 120), 255, np.uint8)])
                                              for f in frames])
    deep = tmp_path / "deep"
    deep.mkdir()
    for i, frame in enumerate(frames):
        cv2.imwrite(str(deep / f"frame_{i:03d}.png"),
                    cv2.cvtColor(frame, cv2.COLOR_RGB2BGR).astype(np.uint16) * 257)
    for folder in (alpha, deep):
        seq = open_sequence(folder, (64, 96))
        for i in range(3):
            assert np.array_equal(seq.frame(i), plain.frame(i)), (folder, i)
    mixed = write_images(tmp_path / "mixed", frames)
    cv2.imwrite(str(mixed / "frame_001.png"), cv2.resize(frames[1], (60, 50))[..., ::-1])
    with pytest.raises(InputError, match=r"image frame_001.png is \(50, 60, 3\), the first"):
        open_sequence(mixed, (64, 96))


def test_depth_with_a_mask_of_the_wrong_size(tmp_path, tiny_checkpoint):
    folder = write_images(tmp_path / "good", [disc_frame(seed=s) for s in range(3)])
    mask = tmp_path / "small_mask.png"
    cv2.imwrite(str(mask), np.full((50, 60), 255, np.uint8))
    message = assert_clean_error(run_depth(folder, tmp_path / "out", tiny_checkpoint,
                                           "--mask", str(mask)), "good")
    assert "(100, 120)" in message


def test_depth_with_a_checkpoint_that_is_not_one(tmp_path):
    folder = write_images(tmp_path / "good", [disc_frame(seed=s) for s in range(3)])
    bogus = tmp_path / "bogus.safetensors"
    bogus.write_bytes(b"\x00\x01 definitely not safetensors")
    assert_clean_error(run_depth(folder, tmp_path / "out", bogus), "bogus.safetensors")


def mismatched_checkpoint(path: Path) -> Path:
    """Weights of a network with other channel sizes, labelled with the TINY config."""
    torch.manual_seed(0)
    other = replace(TINY, encoder_channels=(8, 8, 16, 16, 40))
    return save_model(path, DepthModel(other), TINY.to_dict())


def test_depth_with_weights_that_do_not_fit(tmp_path):
    folder = write_images(tmp_path / "good", [disc_frame(seed=s) for s in range(3)])
    checkpoint = mismatched_checkpoint(tmp_path / "odd_weights.safetensors")
    message = assert_clean_error(run_depth(folder, tmp_path / "out", checkpoint),
                                 "odd_weights.safetensors")
    assert "do not fit" in message


def test_load_depth_model_rejects_weights_that_do_not_fit(tmp_path):
    checkpoint = mismatched_checkpoint(tmp_path / "odd_weights.safetensors")
    with pytest.raises(InputError, match="odd_weights.safetensors"):
        load_depth_model(checkpoint)


def test_load_depth_model_rejects_another_preset(tmp_path, tiny_checkpoint):
    """A fast-preset checkpoint asked for as 'paper' is refused before any weight is loaded."""
    assert load_depth_model(tiny_checkpoint, preset="fast").config == TINY
    with pytest.raises(InputError, match="tiny.safetensors") as err:
        load_depth_model(tiny_checkpoint, preset="paper")
    assert "'fast'" in str(err.value) and "'paper'" in str(err.value)


# --- `c2d2 eval-depth`, `c2d2 train-depth` -------------------------------------------------

def test_eval_depth_needs_ground_truth(tmp_path, tiny_checkpoint):
    folder = write_images(tmp_path / "real_frames", [disc_frame(seed=s) for s in range(3)])
    result = runner.invoke(app, ["eval-depth", "--data", str(folder),
                                 "--checkpoint", str(tiny_checkpoint)])
    message = assert_clean_error(result, "real_frames")
    assert "ground truth" in message


def test_eval_depth_keeps_procedures_of_the_same_name_apart(tmp_path, tiny_checkpoint,
                                                            simulated):
    """proc_0000 of two datasets: both are evaluated and reported, under their folders' names."""
    for dataset in ("a", "b"):
        shutil.copytree(simulated, tmp_path / dataset / simulated.name)
    out = tmp_path / "eval.json"
    result = runner.invoke(app, ["eval-depth", "--data", str(tmp_path / "a"), "--data",
                                 str(tmp_path / "b"), "--checkpoint", str(tiny_checkpoint),
                                 "--frames", "2", "--out", str(out)])
    assert result.exit_code == 0, result.output
    procedures = json.loads(out.read_text())["procedures"]
    assert sorted(procedures) == [f"a/{simulated.name}", f"b/{simulated.name}"]
    assert procedures[f"a/{simulated.name}"] == procedures[f"b/{simulated.name}"]


def test_eval_depth_scores_the_intrinsics_that_depth_writes(tmp_path, simulated):
    """The head's K that eval-depth scores is the one `c2d2 depth` writes for the whole input
    (the median over all consecutive pairs), not that of the trajectory window alone."""
    torch.manual_seed(0)
    model = DepthModel(TINY)
    torch.nn.init.normal_(model.motion.intrinsics.weight, std=0.5)  # K varies with the pair
    checkpoint = save_model(tmp_path / "varied.safetensors", model, TINY.to_dict())
    assert run_depth(simulated, tmp_path / "depth", checkpoint).exit_code == 0
    written = json.loads((tmp_path / "depth" / "intrinsics.json").read_text())["network"]
    model = load_depth_model(checkpoint)
    seq = open_sequence(simulated, (TINY.height, TINY.width))
    metrics = evaluate_sequence(model, seq, depth_frames=2, trajectory_frames=5)
    assert metrics["fx_head"] == pytest.approx(written["fx"], rel=1e-6)
    window = infer_sequence(model, seq, depth=False, frames=range(5))
    assert abs(float(np.median(window.K_pairs[:, 0, 0])) - written["fx"]) > 1e-6 * written["fx"]
    # The trajectory is still scored over the window alone (to float32 rounding: the frames
    # go through the network in other batches).
    assert metrics["ate"] == pytest.approx(
        trajectory_errors(window.poses, seq.poses[:5])["ate"], rel=1e-4)


def test_train_depth_with_an_unknown_preset(tmp_path):
    folder = write_images(tmp_path / "frames", [disc_frame(seed=s) for s in range(3)])
    result = runner.invoke(app, ["train-depth", "--data", str(folder), "--out",
                                 str(tmp_path / "run"), "--preset", "huge"])
    assert_clean_error(result, "huge", "fast", "paper")


def test_train_depth_with_missing_input(tmp_path):
    result = runner.invoke(app, ["train-depth", "--data", str(tmp_path / "nowhere"), "--out",
                                 str(tmp_path / "run"), "--steps", "1"])
    assert_clean_error(result, "nowhere")


def test_train_depth_takes_the_frame_rate_of_image_folders(tmp_path):
    """8 images are too few for triplets 0.3 s apart at the default 30 frames/s (9 frames),
    enough at --fps 10 (3 frames); a resumed run keeps its frame rate."""
    folder = write_images(tmp_path / "frames", [disc_frame(seed=s) for s in range(8)])
    command = ["train-depth", "--data", str(folder), "--steps", "1", "--device", "cpu"]
    assert_clean_error(runner.invoke(app, [*command, "--out", str(tmp_path / "a")]), "too short")
    result = runner.invoke(app, [*command, "--out", str(tmp_path / "b"), "--fps", "10"])
    assert result.exit_code == 0, result.output
    # the run keeps its frame rate: resumed without --fps, it goes on at 10 frames/s
    command[command.index("--steps") + 1] = "2"
    result = runner.invoke(app, [*command, "--out", str(tmp_path / "b")])
    assert result.exit_code == 0, result.output
    meta = read_checkpoint(tmp_path / "b" / "checkpoint.safetensors")[1]
    assert meta["step"] == 2 and meta["config"]["input_fps"] == 10.0


def test_train_depth_with_a_missing_init_model(tmp_path):
    result = runner.invoke(app, ["train-depth", "--data", str(tmp_path), "--out",
                                 str(tmp_path / "run"), "--init", str(tmp_path / "none.st")])
    assert_clean_error(result, "--init", "none.st")


def test_train_depth_refuses_to_resume_another_preset(tmp_path, tiny_checkpoint):
    """A run folder holding a 'fast' checkpoint, resumed with --preset paper."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "checkpoint.safetensors").write_bytes(tiny_checkpoint.read_bytes())
    # The shortest image folder (30 fps) whose triplets fit: 2 x gap + 1 frames.
    gap = max(1, round(30 * DEPTH_PRESETS["paper"].pair_gap_s))
    folder = write_images(tmp_path / "frames", [disc_frame(seed=s) for s in range(2 * gap + 1)])
    result = runner.invoke(app, ["train-depth", "--data", str(folder), "--out", str(run),
                                 "--preset", "paper", "--steps", "1"])
    assert_clean_error(result, "checkpoint.safetensors", "'fast'", "paper")


# --- every command's --out -----------------------------------------------------------------

@pytest.mark.parametrize("command", [
    ["simulate", "--procedures", "1"], ["depth", "SIM"], ["train-depth", "--data", "SIM"],
    ["sfm-maps", "--data", "SIM"], ["train-coverage", "--data", "SIM"]])
def test_an_output_folder_that_is_a_file_is_refused_and_the_file_kept(command, simulated,
                                                                      tmp_path):
    blocker = tmp_path / "notes.txt"
    blocker.write_text("not a folder")
    result = CliRunner().invoke(app, [str(simulated) if a == "SIM" else a for a in command]
                                + ["--out", str(blocker)])
    assert result.exit_code == 2 and "Traceback" not in result.output, result.output
    last = result.stderr.strip().splitlines()[-1]  # after any progress bar
    assert last.startswith(f"error: cannot make the output folder {blocker}: "), last
    assert last.endswith("; choose another --out"), last
    assert blocker.read_text() == "not a folder"
