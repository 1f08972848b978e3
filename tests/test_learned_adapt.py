"""learned.adapt: adapting the depth model to one video lowers its own loss on that video; the
run resumes, refuses a folder of another adaptation, and fits a low frame rate's chain term;
the `eval-depth` and `depth` commands adapt per input when asked."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from conftest import TINY
from typer.testing import CliRunner

from hybrid.cli import app
from hybrid.types import InputError
from learned.adapt import adapt_depth_model, adaptation_config
from learned.checkpoint import export_weights
from learned.frames import FrameSequence, open_sequence
from learned.model import load_depth_model
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


def test_adapting_lowers_the_loss_on_the_video_and_resumes(start, clip, tmp_path):
    seq = open_sequence(clip, (TINY.height, TINY.width))
    before = clip_loss(load_depth_model(start), clip)
    adapted = adapt_depth_model(start, seq, tmp_path / "adapted", steps=15)
    after = clip_loss(adapted, clip)
    # Deterministic evaluations (fixed batches and noise), so the drop is the adaptation's.
    assert after < 0.95 * before, (before, after)
    record = json.loads((tmp_path / "adapted" / "adapted_to.json").read_text())
    assert record["input"] == seq.name and record["frames"] == seq.num_frames
    again = adapt_depth_model(start, seq, tmp_path / "adapted", steps=15)  # nothing left to do
    assert all(torch.equal(a, b) for a, b in zip(again.parameters(), adapted.parameters(),
                                                 strict=True))


def test_a_folder_adapted_to_another_input_is_refused(start, clip, tmp_path):
    seq = open_sequence(clip, (TINY.height, TINY.width))
    adapt_depth_model(start, seq, tmp_path / "adapted", steps=1)
    shorter = FrameSequence("other", seq.fps, seq.size, seq.frame, seq.num_frames - 1,
                            region=seq.region, crop=seq.crop)
    with pytest.raises(InputError, match="another input"):
        adapt_depth_model(start, shorter, tmp_path / "adapted", steps=1)
    with pytest.raises(InputError, match="at least 1 step"):
        adapt_depth_model(start, seq, tmp_path / "zero", steps=0)


def test_the_chain_term_is_capped_at_a_low_frame_rate_pair_gap(start):
    config = replace(TINY, w_chain=0.3, chain_steps=9, pair_gap_s=0.3, lr_drop_step=500)
    frames = np.full((6, 64, 96, 3), 128, np.uint8)
    seq = FrameSequence("slow", 6.0, (64, 96), frames.__getitem__, 6,
                        region=np.ones((64, 96), bool))
    adapted = adaptation_config(config, start, 40, seq)
    # 0.3 s at 6 frames/s is 2 frames apart; the constant learning rate, from `start`.
    assert (adapted.chain_steps, adapted.steps, adapted.lr_drop_step) == (2, 40, 0)
    assert adapted.init == str(start) and adapted.w_chain == 0.3


def test_eval_depth_and_depth_adapt_each_input_when_asked(start, simulated, tmp_path):
    out = tmp_path / "eval.json"
    result = CliRunner().invoke(app, [
        "eval-depth", "--data", str(simulated), "--checkpoint", str(start), "--frames", "2",
        "--adapt-steps", "3", "--adapt-dir", str(tmp_path / "runs"), "--out", str(out)])
    assert result.exit_code == 0, result.output
    name = f"{simulated.parent.name}-{simulated.name}"
    adapted = load_depth_model(tmp_path / "runs" / name / "model.safetensors")
    assert json.loads(out.read_text())["adapt_steps"] == 3
    # The weights scored are the adapted ones: 3 steps away from the start's.
    assert not all(torch.equal(a, b) for a, b in zip(
        adapted.parameters(), load_depth_model(start).parameters(), strict=True))
    result = CliRunner().invoke(app, ["depth", str(simulated), "--out", str(tmp_path / "depth"),
                                      "--checkpoint", str(start), "--adapt-steps", "2"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "depth" / "adapted" / "model.safetensors").is_file()
    assert len(list((tmp_path / "depth" / "depth").glob("*.npy"))) > 0
