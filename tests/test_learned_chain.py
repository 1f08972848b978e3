"""The chain term (DepthConfig.w_chain): the sampler's in-between frames, the composition of the
motion net's own frame-to-frame rotations, and the term's place in the loss."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from conftest import TINY
from kornia.geometry.conversions import rotation_matrix_to_axis_angle

from hybrid.types import InputError
from learned.checkpoints import SHIPPED_DEPTH
from learned.frames import open_sequence
from learned.model import DepthModel, chained_rotation, load_depth_model, to_tensor
from learned.train import TripletSampler

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def seq(clip):
    return open_sequence(clip, (TINY.height, TINY.width))


def turning_model(config) -> DepthModel:
    """A randomly initialised model whose motion outputs are scaled up, so that its terms are
    far from zero."""
    torch.manual_seed(0)
    model = DepthModel(config)
    with torch.no_grad():
        model.motion.rotation_scale.fill_(3.0)
    return model


def sample_offsets(seq, chain_steps: int) -> list[list[int]]:
    """Per sample of a batch, the frame indices it holds relative to its previous frame."""
    frames, _ = TripletSampler([seq], TINY.pair_gap_s, chain_steps=chain_steps).batch(
        3, np.random.default_rng(1))
    all_frames = to_tensor(np.stack([seq.frame(i) for i in range(seq.num_frames)]))
    offsets = []
    for sample in frames:
        first = next(i for i in range(seq.num_frames) if torch.equal(all_frames[i], sample[0]))
        offsets.append([next(i for i in range(first, seq.num_frames)
                             if torch.equal(all_frames[i], image)) - first for image in sample])
    return offsets


def test_sampler_adds_the_frames_between_previous_and_target(seq):
    gap = round(seq.fps * TINY.pair_gap_s)
    assert gap == 9
    # One step per frame: previous, target, next, then every frame in between.
    assert sample_offsets(seq, 9) == [[0, 9, 18, *range(1, 9)]] * 3
    # Fewer steps than frames: the nearest frames, round(j * 9 / 4) for j = 1, 2, 3.
    assert sample_offsets(seq, 4) == [[0, 9, 18, 2, 4, 7]] * 3
    with pytest.raises(InputError, match="chain_steps to at most 9"):
        TripletSampler([seq], TINY.pair_gap_s, chain_steps=10)


def test_chained_rotation_composes_the_steps_from_target_back_to_previous(clip):
    model = load_depth_model(SHIPPED_DEPTH).train()  # a trained net: rotations of degrees
    seq = open_sequence(clip, (model.config.height, model.config.width))
    prev, mid, target, after = (to_tensor(seq.frame(i))[None] for i in (0, 6, 12, 18))
    frames = torch.stack([prev, target, after, mid], 1)  # previous, target, next, between
    running = model.motion.encoder.stem[1].running_mean.clone()
    chained = chained_rotation(model, frames)
    # The chain runs in eval mode and leaves the model as it was.
    assert model.motion.training
    assert torch.equal(model.motion.encoder.stem[1].running_mean, running)
    model.eval()
    with torch.no_grad():
        mid_to_prev = model.pair_transform(mid, prev)[0][0]
        target_to_mid = model.pair_transform(target, mid)[0][0]

    def angles(T):
        return rotation_matrix_to_axis_angle(T[None, :3, :3].float())[0]

    forward = angles(mid_to_prev @ target_to_mid)
    reversed_order = angles(target_to_mid @ mid_to_prev)
    assert float(chained.norm()) > np.radians(1)
    assert float((chained[0] - forward).abs().max()) < 1e-6
    assert float((forward - reversed_order).abs().max()) > 1e-5  # the order shows


def test_the_chain_term_measures_the_estimate_target_to_previous(clip):
    """The term is the L1 distance of the chain target from the rotation target -> previous
    (the direction chained_rotation composes), not from another of the loss's motions."""
    model = load_depth_model(SHIPPED_DEPTH)
    model.config = replace(model.config, w_chain=0.5)
    seq = open_sequence(clip, (model.config.height, model.config.width))
    frames = torch.stack([to_tensor(seq.frame(i))[None] for i in (0, 12, 24)], 1)
    region = torch.ones(1, 1, model.config.height, model.config.width, dtype=torch.bool)
    target = chained_rotation(model, frames)  # no frames in between: one step
    with torch.no_grad():
        chain = model.loss(frames, region, chain_target=target).chain
        r_tp, _, r_pt, _, _ = model.pair_motion(frames[:, 1], frames[:, 0])
        r_tn = model.pair_motion(frames[:, 1], frames[:, 2])[0]
    assert float(chain) == pytest.approx(float((r_tp - target).abs().sum()), rel=1e-5)
    for other in (r_pt, r_tn):  # previous -> target, target -> next: a wrong index shows
        assert abs(float((other - target).abs().sum()) - float(chain)) > 0.05


def test_chain_term_enters_the_loss_and_pulls_the_direct_rotation_towards_the_chain(seq):
    gap = round(seq.fps * TINY.pair_gap_s)
    config = replace(TINY, w_chain=0.5, chain_steps=gap)
    frames, region = TripletSampler([seq], TINY.pair_gap_s, chain_steps=gap).batch(
        2, np.random.default_rng(0))
    model = turning_model(config)
    plain = DepthModel(replace(config, w_chain=0.0))
    plain.load_state_dict(model.state_dict())
    torch.manual_seed(0)
    base = plain.loss(frames[:, :3], region)
    target = chained_rotation(model, frames)
    torch.manual_seed(0)
    terms = model.loss(frames, region, chain_target=target)
    assert float(terms.chain.detach()) > 0
    assert torch.allclose(terms.total, base.total + 0.5 * terms.chain, atol=1e-6)
    with pytest.raises(ValueError, match="chain_target"):
        model.loss(frames, region)
    # The term's gradient reaches the direct estimate: a few steps on it alone, against a
    # fixed target (a frozen teacher), shrink it.
    optimizer = torch.optim.Adam(model.motion.parameters(), lr=1e-3)
    first = float(terms.chain.detach())
    for _ in range(15):
        chain = model.loss(frames, region, chain_target=target).chain
        optimizer.zero_grad()
        chain.backward()
        optimizer.step()
    assert float(model.loss(frames, region, chain_target=target).chain.detach()) < 0.5 * first


def test_chain_settings_are_checked():
    with pytest.raises(ValueError, match="chain_steps"):
        replace(TINY, chain_steps=0)
    with pytest.raises(ValueError, match="w_chain"):
        replace(TINY, w_chain=-1.0)
    with pytest.raises(ValueError, match="chain_teacher"):
        replace(TINY, chain_teacher="init")  # no init model to take it from
    with pytest.raises(ValueError, match="chain_teacher"):
        replace(TINY, chain_teacher="other", init="model.safetensors")


def test_train_depth_logs_the_chain_term_with_either_teacher(tmp_path, clip):
    from learned.checkpoint import export_weights
    from learned.train import train_depth

    base = train_depth([clip], tmp_path / "base", replace(TINY, steps=1), progress=False)
    export_weights(base, tmp_path / "base.safetensors")
    first = None
    for teacher in ("self", "init"):
        config = replace(TINY, steps=2, w_chain=1.0, chain_steps=3, chain_teacher=teacher,
                         init=str(tmp_path / "base.safetensors"))
        train_depth([clip], tmp_path / teacher, config, log_every=1, progress=False)
        records = [json.loads(line) for line in (tmp_path / teacher / "metrics.jsonl").open()]
        assert len(records) == 2 and all(r["chain"] > 0 for r in records)
        if first is not None:  # at the first step the model is its init: the teachers agree
            assert records[0]["chain"] == pytest.approx(first[0]["chain"], rel=1e-5)
            assert records[1]["chain"] != pytest.approx(first[1]["chain"], rel=1e-5)
        first = records
    # Resuming the run with a teacher that changed since is refused.
    other = train_depth([clip], tmp_path / "other", replace(TINY, steps=1, seed=1),
                        progress=False)
    export_weights(other, tmp_path / "base.safetensors")
    with pytest.raises(InputError, match="changed since the run"):
        train_depth([clip], tmp_path / "init", replace(config, steps=3), progress=False)
    (tmp_path / "base.safetensors").unlink()
    with pytest.raises(InputError, match="no such model"):
        train_depth([clip], tmp_path / "init", replace(config, steps=3), progress=False)
