"""learned.adapt: adapting the depth model to one video lowers its own loss on that video; a
folder of another adaptation is refused, and a low frame rate's chain term fits; a video the
model reads as noisy, or explains well already, is not adapted to unless forced; the depth
read is the adapted and the starting model's together (Blend); `eval-depth` scores and
`depth` writes it when asked."""

from __future__ import annotations

import json
from dataclasses import asdict, replace

import numpy as np
import pytest
import torch
from conftest import TINY
from typer.testing import CliRunner

import learned.adapt
from hybrid.cli import app
from hybrid.types import InputError
from learned.adapt import (
    NOISY,
    Blend,
    adapt_depth_model,
    adaptation_config,
    photometric_error,
)
from learned.checkpoint import export_weights, file_tag
from learned.checkpoints import SHIPPED_DEPTH
from learned.evaluate import evaluate_sequence, scored_depths
from learned.frames import FrameSequence, open_sequence
from learned.model import load_depth_model, to_tensor
from learned.train import TripletSampler, train_depth

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def start(clip, tmp_path_factory):
    """A tiny model after 2 training steps on the clip, exported as a model file."""
    folder = tmp_path_factory.mktemp("start")
    run = train_depth([clip], folder / "run", replace(TINY, steps=2), progress=False)
    return export_weights(run, folder / "start.safetensors")


def clip_loss(model, clip) -> float:
    """The model's loss on three fixed batches of the clip, with fixed noise."""
    sampler = TripletSampler([open_sequence(clip, (TINY.height, TINY.width))], TINY.pair_gap_s)
    total = 0.0
    for k in range(3):
        frames, region = sampler.batch(4, np.random.default_rng(k))
        torch.manual_seed(k)
        with torch.no_grad():
            total += float(model.loss(frames, region).total)
    return total


def test_adapting_lowers_the_loss_on_the_video(start, clip, tmp_path):
    seq = open_sequence(clip, (TINY.height, TINY.width))
    before = clip_loss(load_depth_model(start), clip)
    adapted = adapt_depth_model(start, TINY, seq, tmp_path / "adapted", steps=15,
                                force=True).model
    after = clip_loss(adapted, clip)
    # Deterministic evaluations (fixed batches and noise), so the drop is the adaptation's.
    assert after < 0.95 * before, (before, after)
    record = json.loads((tmp_path / "adapted" / "adapted_to.json").read_text())
    assert record == {"input": str(clip.resolve()), "frames": seq.num_frames,
                      "model": file_tag(start), "steps": 15, "fps": seq.fps,
                      "crop": asdict(seq.crop), "adapted": True,
                      "photometric_error": photometric_error(load_depth_model(start), seq)}


def test_a_folder_of_another_adaptation_is_refused(start, clip, tmp_path):
    seq = open_sequence(clip, (TINY.height, TINY.width))
    adapt_depth_model(start, TINY, seq, tmp_path / "adapted", steps=1, force=True)
    other_input = FrameSequence("other", seq.fps, seq.size, seq.frame, seq.num_frames,
                                region=seq.region, crop=seq.crop)
    other_model = tmp_path / "other.safetensors"
    other_model.write_bytes(start.read_bytes() + b" ")  # another file, another hash
    slower = FrameSequence(seq.name, seq.fps / 2, seq.size, seq.frame, seq.num_frames,
                           region=seq.region, crop=seq.crop)
    for args in ((start, other_input, 1), (start, seq, 2), (other_model, seq, 1),
                 (start, slower, 1)):
        with pytest.raises(InputError, match="another number of steps"):
            adapt_depth_model(args[0], TINY, args[1], tmp_path / "adapted", steps=args[2],
                              force=True)
    # a folder made before the frame rate and crop were recorded is still taken as it is
    made = tmp_path / "adapted" / "adapted_to.json"
    made.write_text(json.dumps({k: v for k, v in json.loads(made.read_text()).items()
                                if k not in ("fps", "crop")}))
    adapt_depth_model(start, TINY, seq, tmp_path / "adapted", steps=1, force=True)
    with pytest.raises(InputError, match="at least 1 step"):
        adapt_depth_model(start, TINY, seq, tmp_path / "zero", steps=0)
    with pytest.raises(InputError, match=r"other: frames of \(64, 96\), the model takes"):
        train_depth([other_input], tmp_path / "wide", replace(TINY, width=128), progress=False)


def test_a_model_trained_with_maps_adapts_without_them(start, clip, tmp_path):
    """The video has no structure-from-motion maps: the adaptation drops the map terms and
    keeps the ordinary batches as they were (unblurred where the blur was the maps' only),
    and runs (it asked for the maps and stopped)."""
    seq = open_sequence(clip, (TINY.height, TINY.width))
    config = replace(TINY, maps=str(tmp_path / "no-maps"), w_map=1.0, w_map_motion=0.3,
                     map_zoom=True, photo_blur=1.0, photo_blur_on="maps")
    adapted = adaptation_config(config, start, 1, seq)
    assert (adapted.maps, adapted.w_map, adapted.w_map_motion, adapted.map_zoom) == (
        "", 0.0, 0.0, False)
    assert (adapted.photo_blur, adapted.photo_blur_on) == (0.0, "all")
    model = adapt_depth_model(start, config, seq, tmp_path / "adapted", steps=1,
                              force=True).model
    assert model.config.maps == ""


def test_the_chain_term_is_capped_at_a_low_frame_rate_pair_gap(start):
    config = replace(TINY, w_chain=0.3, chain_steps=9, pair_gap_s=0.3, lr_drop_step=500)
    frames = np.full((6, 64, 96, 3), 128, np.uint8)
    seq = FrameSequence("slow", 6.0, (64, 96), frames.__getitem__, 6,
                        region=np.ones((64, 96), bool))
    adapted = adaptation_config(config, start, 40, seq)
    # 0.3 s at 6 frames/s is 2 frames apart; the constant learning rate, from `start`.
    assert (adapted.chain_steps, adapted.steps, adapted.lr_drop_step) == (2, 40, 0)
    assert adapted.init == str(start) and adapted.w_chain == 0.3


def test_eval_depth_and_depth_score_and_write_the_adapted_model(start, simulated, tmp_path):
    out = tmp_path / "eval.json"
    result = CliRunner().invoke(app, [
        "eval-depth", "--data", str(simulated), "--checkpoint", str(start), "--frames", "2",
        "--adapt-steps", "3", "--adapt-dir", str(tmp_path / "runs"), "--adapt-always",
        "--out", str(out)])
    assert result.exit_code == 0, result.output
    written = json.loads(out.read_text())
    seq = open_sequence(simulated, (TINY.height, TINY.width))
    adapted = Blend(load_depth_model(tmp_path / "runs" / f"{simulated.parent.name}-"
                                     f"{simulated.name}" / "model.safetensors"),
                    load_depth_model(start), seq)
    assert written["adapt_steps"] == 3
    level = photometric_error(load_depth_model(start), seq)
    assert list(written["procedures"].values()) == [
        {**evaluate_sequence(adapted, seq, 2), "photometric_error": level, "adapted": 1.0}]
    assert evaluate_sequence(load_depth_model(start), seq, 2) != evaluate_sequence(adapted, seq,
                                                                                   2)
    result = CliRunner().invoke(app, ["depth", str(simulated), "--out", str(tmp_path / "depth"),
                                      "--checkpoint", str(start), "--adapt-steps", "3",
                                      "--adapt-always"])
    assert result.exit_code == 0, result.output
    with torch.no_grad():  # the same 3 steps, so the same model: its depth is what was written
        first = adapted.predict_depth(to_tensor(seq.frame(0)[None], "cpu"))[0, 0].numpy()
    np.testing.assert_allclose(np.load(tmp_path / "depth" / "depth" / "000000.npy"), first,
                               rtol=1e-5)


def test_the_blend_is_the_geometric_mean_in_the_adapted_unit(start, clip, tmp_path):
    seq = open_sequence(clip, (TINY.height, TINY.width))
    own = load_depth_model(start)
    adapted = adapt_depth_model(start, TINY, seq, tmp_path / "adapted", steps=3,
                                force=True).model
    alone = load_depth_model(tmp_path / "adapted" / "model.safetensors")
    frames = to_tensor(np.stack([seq.frame(t) for t in (0, 7, 29)]), "cpu")
    with torch.no_grad():
        a, s, blend = (m.predict_depth(frames).numpy() for m in (alone, own, adapted))
    unit = np.median(scored_depths(alone, seq)[1][:, seq.region]
                     / scored_depths(own, seq)[1][:, seq.region])
    assert abs(np.log(unit)) > 0.01  # the two models' units differ: the factor is needed
    np.testing.assert_allclose(blend, np.sqrt(a * s * unit), rtol=1e-5)
    # in the adapted model's unit: over the scored frames, half its depth above the blend's
    ratio = scored_depths(alone, seq)[1] / scored_depths(adapted, seq)[1]
    assert abs(np.log(np.median(ratio[:, seq.region]))) < 0.01 * abs(np.log(unit))
    # motion and K are the adapted model's own
    with torch.no_grad():
        motions = [m.pair_motion(frames[:1], frames[1:2]) for m in (adapted, alone, own)]
    for ours, theirs in zip(*motions[:2], strict=True):
        torch.testing.assert_close(ours, theirs)
    assert not torch.allclose(motions[0][1], motions[2][1])  # not the starting model's
    # a model blended with itself reads as it does
    same = Blend(own, own, seq)
    with torch.no_grad():
        np.testing.assert_allclose(same.predict_depth(frames).numpy(), s, rtol=1e-5)


@pytest.mark.parametrize("command", [
    ["eval-depth", "--data", "SIM", "--adapt-dir", "DIR"], ["eval-depth", "--data", "SIM",
                                                            "--adapt-always"],
    ["depth", "SIM", "--out", "DIR", "--adapt-always"]])
def test_adaptation_options_without_steps_are_refused(command, start, simulated, tmp_path):
    given = {"SIM": str(simulated), "DIR": str(tmp_path / "out")}
    result = CliRunner().invoke(app, [given.get(a, a) for a in command]
                                + ["--checkpoint", str(start)])
    assert result.exit_code != 0 and "give --adapt-steps too" in result.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("bound", "past", "why"), [("NOISY", -1e-6, "above"),
                                                    ("CLEAR", 1e-6, "below")])
def test_a_video_outside_the_bounds_is_not_adapted_to_unless_forced(
        bound, past, why, start, clip, tmp_path, monkeypatch, caplog):
    seq = open_sequence(clip, (TINY.height, TINY.width))
    level = photometric_error(load_depth_model(start), seq)
    assert level == photometric_error(load_depth_model(start), seq) > 0  # fixed draws
    monkeypatch.setattr(learned.adapt, "CLEAR", 0.0)
    monkeypatch.setattr(learned.adapt, "NOISY", 1.0)
    monkeypatch.setattr(learned.adapt, bound, level + past)
    kept = adapt_depth_model(start, TINY, seq, tmp_path / "adapted", steps=2)
    assert (kept.adapted, kept.photometric_error) == (False, level)
    assert f"not adapted to: the depth model's photometric error on it is {level:.4f}, {why}" \
        in caplog.text
    assert all(torch.equal(a, b) for a, b in zip(
        kept.model.state_dict().values(), load_depth_model(start).state_dict().values(),
        strict=True))
    record = tmp_path / "adapted" / "adapted_to.json"
    assert json.loads(record.read_text())["adapted"] is False
    assert not (tmp_path / "adapted" / "checkpoint.safetensors").exists()
    forced = adapt_depth_model(start, TINY, seq, tmp_path / "adapted", steps=2, force=True)
    assert forced.adapted and json.loads(record.read_text())["adapted"] is True
    assert clip_loss(forced.model, clip) != clip_loss(kept.model, clip)
    monkeypatch.setattr(learned.adapt, bound, level)  # at the bound it adapts
    assert adapt_depth_model(start, TINY, seq, tmp_path / "other", steps=2).adapted
    monkeypatch.setattr(learned.adapt, bound, level + past)  # an adaptation begun goes on
    assert adapt_depth_model(start, TINY, seq, tmp_path / "adapted", steps=2).adapted
    assert json.loads(record.read_text())["adapted"] is True


def test_the_commands_keep_a_noisy_video_unadapted_unless_told(start, simulated, tmp_path,
                                                               monkeypatch, caplog):
    seq = open_sequence(simulated, (TINY.height, TINY.width))
    model = load_depth_model(start)
    level = photometric_error(model, seq)
    monkeypatch.setattr(learned.adapt, "NOISY", level - 1e-6)
    out = tmp_path / "eval.json"
    result = CliRunner().invoke(app, [
        "eval-depth", "--data", str(simulated), "--checkpoint", str(start), "--frames", "2",
        "--adapt-steps", "2", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert list(json.loads(out.read_text())["procedures"].values()) == [
        {**evaluate_sequence(model, seq, 2), "photometric_error": level, "adapted": 0.0}]
    assert "not adapted to" in caplog.text
    result = CliRunner().invoke(app, ["depth", str(simulated), "--out", str(tmp_path / "depth"),
                                      "--checkpoint", str(start), "--adapt-steps", "2"])
    assert result.exit_code == 0, result.output
    with torch.no_grad():  # the model's own depth, not an adapted one's
        own = model.depth(to_tensor(seq.frame(0)[None], "cpu"))[0, 0].numpy()
    np.testing.assert_allclose(np.load(tmp_path / "depth" / "depth" / "000000.npy"), own,
                               rtol=1e-5)


def test_the_shipped_model_reads_dusk_video_as_noisy_and_pink_not(sim_config, tmp_path):
    """NOISY was set on the shipped model's training procedures; here a seed it never saw,
    in both styles."""
    from hybrid.sim.simulate import simulate_procedure

    model = load_depth_model(SHIPPED_DEPTH)
    levels = {style: photometric_error(model, open_sequence(
        simulate_procedure(tmp_path / style, 11, 0, replace(sim_config, style=style)),
        (model.config.height, model.config.width))) for style in ("pink", "dusk")}
    assert levels["pink"] < NOISY < levels["dusk"], levels
