"""learned.nets / model / train / checkpoint: output shapes and ranges, a real loss reduction on a
tiny simulated clip, checkpoint round trip, and resuming a run."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch
from conftest import TINY, bn_running_statistics

from hybrid.types import InputError
from learned.checkpoint import export_weights, read_checkpoint, save_checkpoint
from learned.checkpoints import SHIPPED_DEPTH
from learned.config import DEPTH_PRESETS, DepthConfig
from learned.evaluate import scored_depths
from learned.frames import open_sequence
from learned.infer import infer_sequence
from learned.model import DepthModel, load_depth_model, to_tensor
from learned.nets import DepthNet, shift_correlation
from learned.train import (
    TripletSampler,
    mirror_flips,
    mirror_images,
    recompute_motion_statistics,
    train_depth,
)

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def batch(clip):
    """One fixed batch of 2 triplets at 64 x 96."""
    sampler = TripletSampler([open_sequence(clip, (TINY.height, TINY.width))], TINY.pair_gap_s)
    return sampler.batch(TINY.batch_size, np.random.default_rng(0))


def test_sampler_batch_shapes(batch, clip):
    frames, region = batch
    assert frames.shape == (2, 3, 3, 64, 96) and frames.dtype == torch.float32
    assert region.shape == (2, 1, 64, 96) and region.dtype == torch.bool
    assert float(frames.min()) >= 0.0 and float(frames.max()) <= 1.0
    # Triplets are gap = round(fps · pair_gap_s) ≥ 1 frames apart, so never all equal.
    assert not torch.equal(frames[:, 0], frames[:, 1])
    assert not torch.equal(frames[:, 2], frames[:, 1])


def test_mirroring_flips_each_triplet_and_its_region_alike(batch):
    frames, region = batch
    frames, region = frames.repeat(20, 1, 1, 1, 1), region.repeat(20, 1, 1, 1)
    flips = mirror_flips(len(frames), np.random.default_rng(3))
    out_frames, out_region = mirror_images(frames, flips), mirror_images(region, flips)
    for b, (left_right, up_down) in enumerate(flips.tolist()):
        dims = [d for d, chosen in ((-1, left_right), (-2, up_down)) if chosen]
        expected = frames[b].flip(dims) if dims else frames[b]
        assert torch.equal(out_frames[b], expected)
        assert torch.equal(out_region[b], region[b].flip(dims) if dims else region[b])
    # Each of the four mirror images occurs.
    assert len({tuple(f) for f in flips.tolist()}) == 4
    # Half of the triplets on average, each axis drawn apart.
    many = mirror_flips(4000, np.random.default_rng(4)).float()
    assert np.allclose(many.mean(0).numpy(), 0.5, atol=0.03)
    assert abs(float((many[:, 0] * many[:, 1]).mean()) - 0.25) < 0.03


def test_depth_net_shape_and_range():
    torch.manual_seed(0)
    config = replace(TINY, min_depth=0.5, max_depth=2.0)
    net = DepthNet(config).eval()
    images = torch.cat([torch.rand(2, 3, 64, 96), torch.zeros(1, 3, 64, 96),
                        torch.ones(1, 3, 64, 96)])
    with torch.no_grad():
        depth = net(images)
    assert depth.shape == (4, 1, 64, 96)
    assert torch.isfinite(depth).all()
    # depth = 1/(1/max + (1/min − 1/max)·sigmoid): within [min, max] up to float32 rounding.
    assert float(depth.min()) >= 0.5 * (1 - 1e-6) and float(depth.max()) <= 2.0 * (1 + 1e-6)


def test_depth_net_takes_a_size_not_divisible_by_32():
    """64 x 80 (80 = 2.5 · 32) and 50 x 70: each decoder level is resized to its skip's size,
    so the depth comes out at the input's size, finite and within [min_depth, max_depth]."""
    for height, width in ((64, 80), (50, 70)):
        config = replace(TINY, height=height, width=width)
        with torch.no_grad():
            depth = DepthNet(config).eval()(torch.rand(1, 3, height, width))
        assert depth.shape == (1, 1, height, width)
        assert torch.isfinite(depth).all()
        assert float(depth.min()) >= config.min_depth * (1 - 1e-6)
        assert float(depth.max()) <= config.max_depth * (1 + 1e-6)


@pytest.mark.parametrize("motion_net", ["stacked", "correlation"])
def test_motion_net_outputs(batch, motion_net):
    """Shapes, and K at initialisation by hand: the intrinsics head starts at zero weights, so
    fx = softplus(−0.4)·W, fy = softplus(−0.4)·H, cx = W/2 − 0.5, cy = H/2 − 0.5."""
    torch.manual_seed(0)
    model = DepthModel(replace(TINY, motion_net=motion_net))
    frames, _ = batch
    with torch.no_grad():
        rotation, translation, K = model.motion(torch.cat([frames[:, 1], frames[:, 0]], 1))
    assert rotation.shape == (2, 3) and translation.shape == (2, 3) and K.shape == (2, 3, 3)
    for x in (rotation, translation, K):
        assert torch.isfinite(x).all()
    softplus = math.log1p(math.exp(-0.4))
    expected = torch.tensor([[softplus * 96, 0, 47.5], [0, softplus * 64, 31.5], [0, 0, 1]])
    torch.testing.assert_close(K, expected.expand(2, 3, 3), rtol=1e-6, atol=1e-5)
    # Motions start small (scaled by 0.01) but are not identically zero.
    assert 0 < float(rotation.abs().max()) < 0.1 and 0 < float(translation.abs().max()) < 0.1


def test_shift_correlation_peaks_at_the_shift():
    torch.manual_seed(0)
    a = torch.randn(2, 8, 12, 14)
    dy, dx, reach = 1, -2, 3
    b = torch.roll(a, shifts=(dy, dx), dims=(-2, -1))  # b[y + dy, x + dx] = a[y, x]
    volume = shift_correlation(a, b, reach)
    assert volume.shape == (2, 49, 12, 14)
    inner = volume[..., reach:-reach, reach:-reach]
    assert (inner.argmax(1) == (dy + reach) * (2 * reach + 1) + dx + reach).all()
    torch.testing.assert_close(inner.amax(1), torch.ones_like(inner[:, 0]))


@pytest.mark.parametrize("change", [{"motion_net": "flow"}, {"motion_reach": 0}])
def test_a_bad_motion_network_setting_is_refused(change):
    with pytest.raises(ValueError, match="motion_net must be"):
        replace(TINY, **change)


def test_the_stacked_motion_network_still_reads_the_shipped_checkpoint():
    """The default motion network keeps the parameter names the shipped model was saved with."""
    shipped, _ = read_checkpoint(SHIPPED_DEPTH)
    expected = {f"motion.{k}" for k in DepthModel(DEPTH_PRESETS["fast"]).motion.state_dict()}
    assert {k for k in shipped if k.startswith("motion.")} == expected


@pytest.mark.parametrize("config", [TINY, replace(TINY, w_shading=0.1),
                                    replace(TINY, w_zoom=1.0),
                                    replace(TINY, motion_net="correlation")],
                         ids=["default", "shading", "zoom", "correlation"])
def test_optimisation_reduces_the_loss_on_a_fixed_batch(batch, config):
    torch.manual_seed(0)
    model = DepthModel(config)
    frames, region = batch

    def loss() -> dict[str, float]:
        torch.manual_seed(1)  # same auto-mask tie-breaking noise for both evaluations
        with torch.no_grad():
            return model.loss(frames, region).as_floats()

    before = loss()
    assert all(math.isfinite(v) for v in before.values())
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    for step in range(30):
        torch.manual_seed(100 + step)
        terms = model.loss(frames, region)
        optimizer.zero_grad()
        terms.total.backward()
        optimizer.step()
    after = loss()
    assert all(math.isfinite(v) for v in after.values())
    with torch.no_grad():
        *motions, K = model.pair_motion(frames[:, 1], frames[:, 0])
    assert all(m.shape == (2, 3) and torch.isfinite(m).all() for m in motions)
    assert K.shape == (2, 3, 3) and torch.isfinite(K).all()
    # Both evaluations are deterministic (same batch, same noise), so any drop is real; ask for
    # 5%, far above the 1e-5 tie-break noise, as the sign that 30 Adam steps fit the batch.
    assert after["total"] < 0.95 * before["total"], (before, after)
    for term, weight in (("shading", config.w_shading), ("zoom", config.w_zoom)):
        if weight:  # the term is in the loss, and training lowers it too
            assert after[term] < before[term], (before, after)
        else:
            assert before[term] == after[term] == 0


def test_checkpoint_round_trip_gives_identical_outputs(tmp_path, batch):
    torch.manual_seed(0)
    model = DepthModel(TINY)
    frames, _ = batch
    images = frames[:, 1]
    model.train()
    with torch.no_grad():  # move the batch-norm running statistics off their defaults
        model.depth(images)
        model.motion(torch.cat([images, frames[:, 0]], 1))
    model.eval()
    path = tmp_path / "tiny.safetensors"
    save_checkpoint(path, {"depth": model.depth, "motion": model.motion}, TINY.to_dict(), step=7)
    loaded = load_depth_model(path, preset="fast")
    assert not loaded.training
    assert loaded.config == TINY
    assert read_checkpoint(path)[1]["step"] == 7
    with torch.no_grad():
        assert torch.equal(loaded.depth(images), model.depth(images))
        for a, b in zip(loaded.pair_motion(images, frames[:, 0]),
                        model.pair_motion(images, frames[:, 0]), strict=True):
            assert torch.equal(a, b)


def test_config_dict_round_trip():
    config = replace(TINY, preset="paper", steps=3)
    assert DepthConfig.from_dict(json.loads(json.dumps(config.to_dict()))) == config


@pytest.mark.parametrize("mirror", [False, True], ids=["plain", "mirrored"])
def test_train_depth_resumes_where_it_stopped(tmp_path, clip, mirror):
    """2 steps, then the same folder with steps = 4, equals 4 steps in one go, bit for bit
    (mirrored triplets too: their flips are drawn from the step's generator). The resumed run
    keeps its own config (only the number of steps may change), and log lines written after
    the last checkpoint are forgotten."""
    config = replace(TINY, steps=2, mirror=mirror)
    resumed, straight = tmp_path / "resumed", tmp_path / "straight"
    path = train_depth([clip], resumed, config, log_every=1, progress=False)
    assert path == resumed / "checkpoint.safetensors"
    assert read_checkpoint(path)[1]["step"] == 2
    with (resumed / "metrics.jsonl").open("a") as log:  # as if killed after a later step,
        log.write(json.dumps({"step": 3, "total": -1.0}) + "\n")  # the next line cut short
        log.write('{"step": 4, "tot')
    train_depth([clip], resumed, replace(config, steps=4, pair_gap_s=0.9, learning_rate=0.1),
                log_every=1, progress=False)
    train_depth([clip], straight, replace(config, steps=4), log_every=1, progress=False)

    tensors, meta = read_checkpoint(path)
    assert meta["step"] == 4
    records = [json.loads(line) for line in (resumed / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records] == [1, 2, 3, 4]
    assert json.loads((resumed / "config.json").read_text())["steps"] == 4
    # Adam's per-parameter step counters continued from the checkpoint (4, not 2).
    counters = [v for k, v in tensors.items() if k.startswith("optimizer.") and k.endswith(".step")]
    assert counters and all(float(c) == 4 for c in counters)

    reference, _ = read_checkpoint(straight / "checkpoint.safetensors")
    assert tensors.keys() == reference.keys()
    assert all(torch.equal(tensors[k], reference[k]) for k in tensors)
    straight_records = [json.loads(line)
                        for line in (straight / "metrics.jsonl").read_text().splitlines()]
    assert [r["total"] for r in records] == [r["total"] for r in straight_records]


def test_learning_rate_drop_can_be_added_to_a_run_before_it_happens(tmp_path, clip):
    """A run resumed with a drop at a later step trains exactly as a fresh run with that drop;
    moving a drop the run has already passed is refused."""
    config = replace(TINY, steps=2, learning_rate=1e-3)
    assert [replace(config, lr_drop_step=3, lr_drop_factor=0.5).lr_at(s) for s in (0, 2, 3, 9)
            ] == [1e-3, 1e-3, 5e-4, 5e-4]
    assert config.lr_at(10**6) == 1e-3  # lr_drop_step 0: never
    resumed, straight = tmp_path / "resumed", tmp_path / "straight"
    train_depth([clip], resumed, config, progress=False)
    dropped = replace(config, steps=4, lr_drop_step=3, lr_drop_factor=0.5)
    train_depth([clip], resumed, dropped, progress=False)
    train_depth([clip], straight, dropped, progress=False)
    tensors, meta = read_checkpoint(resumed / "checkpoint.safetensors")
    reference, _ = read_checkpoint(straight / "checkpoint.safetensors")
    assert DepthConfig.from_dict(meta["config"]) == dropped
    assert all(torch.equal(tensors[k], reference[k]) for k in reference)
    # The drop is used: without it the weights differ.
    train_depth([clip], tmp_path / "no-drop", replace(config, steps=4), progress=False)
    undropped, _ = read_checkpoint(tmp_path / "no-drop" / "checkpoint.safetensors")
    assert not all(torch.equal(undropped[k], reference[k]) for k in reference)
    # A plain resume (no drop asked for) keeps the run's own drop, ahead of it or past it.
    plain = tmp_path / "plain"
    train_depth([clip], plain, replace(dropped, steps=2), progress=False)
    for steps in (3, 5):  # resumed at step 2, then at step 3
        train_depth([clip], plain, replace(config, steps=steps), progress=False)
        saved = read_checkpoint(plain / "checkpoint.safetensors")[1]["config"]
        assert DepthConfig.from_dict(saved) == replace(dropped, steps=steps)
    with pytest.raises(InputError, match="learning-rate drop"):  # the drop at 3 has happened
        train_depth([clip], resumed, replace(dropped, steps=6, lr_drop_step=5), progress=False)
    # A drop at the step a run stopped at has not happened yet: it may still move.
    train_depth([clip], tmp_path / "late", replace(dropped, lr_drop_step=4), progress=False)
    later = replace(dropped, steps=5, lr_drop_step=5)
    train_depth([clip], tmp_path / "late", later, progress=False)
    assert DepthConfig.from_dict(read_checkpoint(tmp_path / "late" / "checkpoint.safetensors")[1]
                                 ["config"]) == later


def test_a_new_run_can_start_from_a_trained_model(tmp_path, clip):
    """--init: the run's first weights are the given model's (a step at learning rate 0 keeps
    them); without it they are random."""
    base = train_depth([clip], tmp_path / "base", replace(TINY, steps=2), progress=False)
    export_weights(base, tmp_path / "base.safetensors")
    init = load_depth_model(tmp_path / "base.safetensors")
    config = replace(TINY, steps=1, learning_rate=0.0, seed=5)
    for name, start in (("tuned", str(tmp_path / "base.safetensors")), ("fresh", "")):
        train_depth([clip], tmp_path / name, replace(config, init=start), progress=False)
        export_weights(tmp_path / name / "checkpoint.safetensors", tmp_path / f"{name}.st")
        model = load_depth_model(tmp_path / f"{name}.st")
        same = all(torch.equal(a, b) for a, b in zip(model.parameters(), init.parameters(),
                                                     strict=True))
        assert same == (name == "tuned")


def test_a_collapsed_depth_network_stops_training_with_a_clear_error(tmp_path, clip, batch):
    """A depth head saturated at min_depth (as a real run's became, docs/depth.md) gives flat
    depth maps and no gradient: train-depth stops at the first log with an error saying so."""
    model = DepthModel(TINY)
    with torch.no_grad():
        model.depth.head[1].bias += 100.0
    assert torch.equal(model.depth(batch[0][:, 1]), torch.full_like(batch[0][:, 1, :1],
                                                                     TINY.min_depth))
    save_checkpoint(tmp_path / "flat.ckpt", {"depth": model.depth, "motion": model.motion},
                    TINY.to_dict(), 0)
    export_weights(tmp_path / "flat.ckpt", tmp_path / "flat.safetensors")
    config = replace(TINY, steps=6, init=str(tmp_path / "flat.safetensors"))
    with pytest.raises(InputError, match=r"collapsed by step 2: each of its depth maps over "
                                         r"the last 2 steps was one constant"):
        train_depth([clip], tmp_path / "run", config, log_every=2, save_every=2,
                    progress=False)
    records = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").open()]
    assert [(r["step"], r["smoothness"]) for r in records] == [(2, 0.0)]
    assert not (tmp_path / "run" / "checkpoint.safetensors").exists()  # stopped before saving


def test_a_loss_that_is_not_finite_stops_training_before_the_weights(tmp_path, clip,
                                                                      monkeypatch):
    """A NaN loss at step 2 stops the run with a clear error; the checkpoint of step 1 is
    left as it was (the step ran on, saved NaN weights, and crashed in the next backward)."""
    real = DepthModel.loss

    def nan_at_step_2(self, *args, **kwargs):
        terms = real(self, *args, **kwargs)
        nan_at_step_2.calls += 1
        return replace(terms, total=terms.total * float("nan")) if nan_at_step_2.calls == 2 \
            else terms

    nan_at_step_2.calls = 0
    monkeypatch.setattr(DepthModel, "loss", nan_at_step_2)
    with pytest.raises(InputError, match=r"the loss is not finite at step 2 \(\{'total': nan"):
        train_depth([clip], tmp_path / "run", replace(TINY, steps=3), save_every=1,
                    progress=False)
    tensors, meta = read_checkpoint(tmp_path / "run" / "checkpoint.safetensors")
    assert meta["step"] == 1 and all(torch.isfinite(t).all() for t in tensors.values())


def test_a_run_is_resumed_on_its_own_inputs_only(tmp_path, clip, simulated):
    """Resuming on other data would mix two runs; extending a finished run removes its export
    until the longer run ends (the export beside it was the shorter run's)."""
    run = tmp_path / "run"
    train_depth([clip], run, replace(TINY, steps=1), progress=False)
    assert (run / "model.safetensors").is_file()
    with pytest.raises(InputError, match="holds a run on other inputs"):
        train_depth([simulated], run, replace(TINY, steps=2), progress=False)

    def killed(*args, **kwargs):
        raise KeyboardInterrupt

    with pytest.MonkeyPatch.context() as patch:  # the extended run killed at its next step
        patch.setattr(DepthModel, "loss", killed)
        with pytest.raises(KeyboardInterrupt):
            train_depth([clip], run, replace(TINY, steps=2), progress=False)
    assert not (run / "model.safetensors").exists()
    train_depth([clip], run, replace(TINY, steps=2), progress=False)
    assert (run / "model.safetensors").is_file()


def test_validation_on_an_input_without_truth_is_refused(tmp_path, clip):
    """It was dropped without a word, and the run validated on nothing."""
    frames = tmp_path / "frames"
    frames.mkdir()
    seq = open_sequence(clip, (TINY.height, TINY.width))
    for i in range(3):
        cv2.imwrite(str(frames / f"{i}.png"), seq.frame(i)[..., ::-1])
    with pytest.raises(InputError, match=r"--val .*frames: not a simulated procedure"):
        train_depth([clip], tmp_path / "run", replace(TINY, steps=1), val=[frames],
                    progress=False)


@pytest.mark.parametrize("field", ["steps", "batch_size", "seed"])
def test_a_step_count_batch_or_seed_out_of_range_is_refused(field):
    with pytest.raises(ValueError, match="steps and batch_size must be >= 1 and seed >= 0"):
        replace(TINY, **{field: -1})


def test_exported_weights_drop_the_optimiser_and_predict_the_same(tmp_path, batch):
    model = DepthModel(TINY)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    frames, region = batch
    model.loss(frames, region).total.backward()
    optimizer.step()
    full = tmp_path / "checkpoint.safetensors"
    save_checkpoint(full, {"depth": model.depth, "motion": model.motion}, TINY.to_dict(), 1,
                    optimizer)
    slim = export_weights(full, tmp_path / "model.safetensors")
    tensors, meta = read_checkpoint(slim)
    assert meta["step"] == 1 and not any(k.startswith("optimizer.") for k in tensors)
    assert slim.stat().st_size < full.stat().st_size / 2  # Adam keeps two moments per weight
    loaded = load_depth_model(slim)
    model.eval()
    with torch.no_grad():
        assert torch.equal(loaded.depth(frames[:, 1]), model.depth(frames[:, 1]))


@pytest.mark.parametrize("updates", [True, False])
def test_the_zoom_batch_updates_batch_norm_statistics_only_when_asked(batch, updates):
    """With zoom_updates_bn=False a loss with the zoom term leaves the motion network's running
    statistics where the same loss without it leaves them; with True it moves them."""
    frames, region = batch
    stats = []
    for config in (replace(TINY, w_zoom=1.0, zoom_updates_bn=updates), TINY):
        torch.manual_seed(0)
        model = DepthModel(config)
        model.train()
        with torch.no_grad():
            model.loss(frames, region)
        stats.append(bn_running_statistics(model.motion))
    # the frames moved them
    assert not torch.equal(stats[1], bn_running_statistics(DepthModel(TINY).motion))
    assert torch.equal(stats[0], stats[1]) != updates


def test_recomputed_statistics_are_the_plain_average_over_ordinary_batches(clip):
    """recompute_motion_statistics forgets what training left and weighs its batches alike:
    each batch-norm layer's running mean and variance are the means of the (unbiased)
    statistics of what the layer saw in each batch."""
    sampler = TripletSampler([open_sequence(clip, (TINY.height, TINY.width))], TINY.pair_gap_s)
    torch.manual_seed(0)
    model = DepthModel(TINY).eval()
    norms = [m for m in model.motion.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    seen = {norm: [] for norm in norms}
    for norm in norms:
        norm.running_mean.fill_(5.0)  # as if training had left them far off
        norm.register_forward_hook(lambda module, inputs, _: seen[module].append(
            (inputs[0].mean((0, 2, 3)), inputs[0].transpose(0, 1).flatten(1).var(1))))
    recompute_motion_statistics(model, sampler, 3, seed=0)
    assert not model.motion.training and all(norm.momentum == 0.1 for norm in norms)
    for norm, stats in seen.items():
        assert len(stats) == 3 * 2  # two pairs a triplet batch (DepthModel.triplet_motion)
        means, variances = (torch.stack(s).mean(0) for s in zip(*stats, strict=True))
        assert torch.allclose(norm.running_mean, means, atol=1e-5)
        assert torch.allclose(norm.running_var, variances, rtol=1e-4, atol=1e-6)
    kept = [norm.running_mean.clone() for norm in norms]
    recompute_motion_statistics(model, sampler, 3, seed=0)
    assert all(torch.equal(a, norm.running_mean) for a, norm in zip(kept, norms, strict=True))


def test_train_depth_recomputes_the_statistics_at_the_end_when_asked(tmp_path, clip):
    """The run's checkpoint and exported weights hold the recomputed statistics; training
    itself is unchanged."""
    config = replace(TINY, steps=2)
    plain = train_depth([clip], tmp_path / "plain", config, progress=False)
    asked = train_depth([clip], tmp_path / "asked", replace(config, bn_recompute_batches=3),
                        progress=False)
    model = load_depth_model(plain)
    sampler = TripletSampler([open_sequence(clip, (TINY.height, TINY.width))], TINY.pair_gap_s)
    recompute_motion_statistics(model, sampler, 3, seed=0)
    tensors = read_checkpoint(asked)[0]
    shipped = load_depth_model(tmp_path / "asked" / "model.safetensors")
    for part in ("depth", "motion"):
        weights = getattr(shipped, part).state_dict()
        for name, value in getattr(model, part).state_dict().items():
            assert torch.equal(tensors[f"{part}.{name}"], value), name
            assert torch.equal(weights[name], value), name
    first = "motion.encoder.stem.1.running_mean"
    assert not torch.equal(read_checkpoint(plain)[0][first], tensors[first])  # training's own
    with pytest.raises(ValueError, match="bn_recompute_batches"):
        replace(TINY, bn_recompute_batches=-1)


def test_depth_views_average_the_mirror_images_in_log_depth(batch):
    """predict_depth with 4 views is the geometric mean of the depth of the frame and of its
    three mirror images, each mirrored back, so it mirrors with its input; 1 view is the
    network's own output."""
    torch.manual_seed(0)
    model = DepthModel(replace(TINY, depth_views=4)).eval()
    images = batch[0][:, 1]
    with torch.no_grad():
        own = model.depth(images)
        views = [own] + [model.depth(images.flip(d)).flip(d) for d in ((-1,), (-2,), (-1, -2))]
        averaged = model.predict_depth(images)
        assert torch.allclose(averaged, torch.stack(views).log().mean(0).exp(), rtol=1e-5)
        assert not torch.allclose(averaged, own, rtol=1e-3)  # the views differ
        assert not torch.allclose(averaged, torch.stack(views).mean(0), rtol=1e-5, atol=0)
        for dims in ((-1,), (-2,)):
            assert torch.allclose(model.predict_depth(images.flip(dims)), averaged.flip(dims),
                                  rtol=1e-5)
        two = DepthModel(replace(TINY, depth_views=2)).eval()
        two.load_state_dict(model.state_dict())
        assert torch.allclose(two.predict_depth(images), (own * views[1]).sqrt(), rtol=1e-5)
        one = DepthModel(TINY).eval()
        one.load_state_dict(model.state_dict())
        assert torch.equal(one.predict_depth(images), own)
    with pytest.raises(ValueError, match="depth_views"):
        replace(TINY, depth_views=3)


def test_a_finished_run_rerun_with_other_depth_views_writes_its_model_again(tmp_path, clip):
    """A depth_views asked of a finished run is written into its model, with the same weights
    and nothing trained; a rerun that asks for none keeps it. Inference (infer_sequence, and
    eval-depth's scored_depths) then reads the mirror views."""
    config = replace(TINY, steps=2)
    path = train_depth([clip], tmp_path, config, progress=False)
    before = read_checkpoint(path)[0]
    train_depth([clip], tmp_path, replace(config, depth_views=4), progress=False)
    tensors, meta = read_checkpoint(path)
    assert meta["step"] == 2 and meta["config"]["depth_views"] == 4
    assert all(torch.equal(tensors[k], before[k]) for k in before)
    train_depth([clip], tmp_path, config, progress=False)
    model = load_depth_model(tmp_path / "model.safetensors")
    assert model.config == replace(config, depth_views=4)
    seq = open_sequence(clip, (TINY.height, TINY.width))
    picks, scored = scored_depths(model, seq, count=3)
    with torch.no_grad():
        images = to_tensor(np.stack([seq.frame(t) for t in picks]))
        views, own = model.predict_depth(images)[:, 0].numpy(), model.depth(images)[:, 0].numpy()
    inferred = infer_sequence(model, seq, gaps=()).depth[picks]
    assert np.allclose(scored, views, rtol=1e-5) and np.allclose(inferred, views, rtol=1e-5)
    assert not np.allclose(views, own, rtol=1e-3)


def test_motion_noise_reaches_the_motion_network_only_while_training(batch):
    """motion_noise adds noise of one standard deviation per pair, at most motion_noise, to
    the frames the motion network reads while training; not under no_grad (the recomputed
    statistics) nor in eval mode (inference)."""
    frames, _ = batch
    a, b = frames[:, 1], frames[:, 0]
    torch.manual_seed(0)
    model = DepthModel(replace(TINY, motion_noise=0.05))
    seen = []
    model.motion.register_forward_pre_hook(lambda module, args: seen.append(args[0].detach()))
    model.train()
    model.pair_motion(a, b)
    with torch.no_grad():
        model.pair_motion(a, b)
    model.eval()
    model.pair_motion(a, b)
    clean = torch.cat([torch.cat([a, b], 1), torch.cat([b, a], 1)], 0)
    assert torch.equal(seen[1], clean) and torch.equal(seen[2], clean)
    n = a.shape[0]
    assert torch.equal(seen[0][:n, :3], seen[0][n:, 3:])  # both orders read the same frames
    noise = (seen[0] - clean)[:n]
    std_a, std_b = noise[:, :3].flatten(1).std(1), noise[:, 3:].flatten(1).std(1)
    assert bool((std_a > 0).all()) and float(std_a.max()) <= 0.05
    assert torch.allclose(std_a, std_b, rtol=0.05)  # one standard deviation per pair ...
    assert float(std_a.max() / std_a.min()) > 1.05  # ... drawn for each pair
    with pytest.raises(ValueError, match="motion_noise"):
        replace(TINY, motion_noise=-0.01)
