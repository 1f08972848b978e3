"""The two-stage coverage networks: structure, the input rule, training, CORAL, the fold split,
the commands, and bad input."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import TINY
from coverage_toys import SMALL, frame_loss, segment_loss, toy_samples, toy_travel
from test_learned_cli import assert_clean_error, runner, save_model
from torch import nn

from hybrid.cli import app
from hybrid.dataset import Procedure
from hybrid.pipeline import Models, RunConfig
from hybrid.types import InputError
from learned.calibration import fit_table, identity_table
from learned.checkpoint import file_tag, save_checkpoint
from learned.config import COVERAGE_PRESETS, CoverageConfig, coverage_config, parse_overrides
from learned.coral import adapt, coral_transform, set_source
from learned.coverage_data import procedure_samples
from learned.coverage_eval import (
    Predictions,
    coverage_metrics,
    procedure_segments,
    segment_mae_interval,
)
from learned.coverage_nets import (
    MIRRORS,
    CoverageModel,
    SegmentNet,
    count_parameters,
    load_coverage_model,
    mirrored,
    normalise_depth,
    relative_scale,
    resample_features,
)
from learned.coverage_train import (
    evaluate,
    fold_predictions,
    fold_split,
    load_run,
    load_samples,
    powered,
    regression_loss,
    run_samples,
    train_frame_net,
    train_segment_net,
)
from learned.frames import open_sequence
from learned.infer import infer_sequence
from learned.model import DepthModel
from learned.travel import travel_features
from learned.view import hidden_view, known_view, view_values

pytestmark = pytest.mark.usefixtures("one_thread")

# --- structure ----------------------------------------------------------------------------


def test_segment_net_has_six_convolutions_pooling_and_one_output():
    config = COVERAGE_PRESETS["paper"]
    net = SegmentNet(config)
    convs = [m for m in net.convs if isinstance(m, nn.Conv1d)]
    assert len(convs) == 6
    assert convs[0].in_channels == 2048
    assert [c.out_channels for c in convs] == list(config.segment_channels)
    assert isinstance(net.fc, nn.Linear) and net.fc.out_features == 1
    # Parameter count from the layer sizes (weights + biases), about 20K as in the paper.
    cin, expected = 2048, 0
    for cout, kernel in zip(config.segment_channels, config.segment_kernels, strict=True):
        expected += cin * cout * kernel + cout
        cin = cout
    expected += cin + 1
    assert count_parameters(net) == expected == 22_249
    out = net(torch.randn(3, 300, 2048))
    assert out.shape == (3,) and bool(((out > 0) & (out < 1)).all())


def test_paper_per_frame_net_is_resnet50_with_2048_features():
    config = COVERAGE_PRESETS["paper"]
    model = CoverageModel(config)
    # ResNet-50 without its classifier has 23,508,032 parameters; ours takes the depth and
    # 8 travel planes, short and chained (7x7x9x64 stem weights instead of 7x7x3x64), and
    # ends in 3 outputs.
    assert count_parameters(model.frame.encoder) == 23_508_032 + 7 * 7 * 6 * 64
    assert model.frame.head.in_features == 2048 and model.frame.head.out_features == 3
    travel = torch.tensor([[0.0, 0.6, -0.8, 0.5] * 2, [0.0, 0.6, 0.8, 0.5] * 2])
    features = model.frame.eval().features(torch.zeros(2, 1, 64, 64), travel)
    assert features.shape == (2, 2048) and not torch.allclose(features[0], features[1])
    depth_only = CoverageModel(replace(config, travel_gap=0))  # the paper's: depth alone
    assert count_parameters(depth_only.frame.encoder) == 23_508_032 - 7 * 7 * 2 * 64


def test_normalised_input_is_log_depth_over_its_median():
    depth = np.full((1, 8, 10), 2.0, np.float32)
    depth[0, :, 5:] = 8.0
    region = np.ones((8, 10), bool)
    region[0, 0] = False  # border pixel: its depth is not in the median
    depth[0, 0, 0] = 1e6
    out = normalise_depth(depth, region, (8, 10))
    median = np.median(depth[0][region])
    assert out.shape == (1, 1, 8, 10)
    assert out[0, 0, 0, 0] == pytest.approx(np.log(1e6 / median))  # its own value
    assert np.allclose(out[0, 0, 4, :5], np.log(2.0 / median))
    assert np.allclose(out[0, 0, 4, 5:], np.log(8.0 / median))
    # Scale invariance: depth known up to scale gives the same input.
    assert np.allclose(normalise_depth(depth * 7.5, region, (8, 10)), out, atol=1e-6)
    # Without the median: log depth, so a scale shows as a shift.
    own = normalise_depth(depth, region, (8, 10), by_median=False)
    assert np.allclose(own, out + np.log(median), atol=1e-6)
    assert np.allclose(normalise_depth(depth * 7.5, region, (8, 10), by_median=False),
                       own + np.log(7.5), atol=1e-6)


def test_outside_the_region_the_input_keeps_the_depth_over_the_median_inside():
    """Outside the region (here the image's corners cut off) the input is the depth's own
    log(depth / median) too, the median taken inside only; the region changes nothing but the
    median."""
    from hybrid.sim.simulate import octagon_region

    rng = np.random.default_rng(3)
    depth = rng.uniform(0.5, 6.0, (2, 12, 16)).astype(np.float32)
    region = octagon_region(12, 16, 4)
    median = np.median(depth[:, region], axis=1)[:, None, None]
    assert not np.allclose(median, np.median(depth, axis=(1, 2))[:, None, None])
    np.testing.assert_allclose(normalise_depth(depth, region, (12, 16))[:, 0],
                               np.log(depth / median), rtol=1e-6)
    depth[1, 0, 0] = 0.0  # a corner's depth is read too: it must be positive
    with pytest.raises(InputError, match=r"outside the image region in frames \[1\]"):
        normalise_depth(depth, region, (12, 16))


def test_powered_input_is_that_of_the_depth_raised_to_the_power():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 6.0, (2, 9, 11)).astype(np.float32)  # 99 pixels: an odd median
    region = np.ones((9, 11), bool)
    powers = np.array([0.8, 1.25], np.float32)
    raised = normalise_depth(depth ** powers[:, None, None], region, (9, 11))
    scaled = powered(torch.from_numpy(normalise_depth(depth, region, (9, 11))),
                     torch.from_numpy(powers))
    np.testing.assert_allclose(scaled.numpy(), raised, atol=1e-5)
    with pytest.raises(ValueError, match="depth_power"):
        coverage_config("fast", depth_power=-0.1)


def test_normalised_input_rejects_nan_depth():
    depth = np.ones((3, 4, 4), np.float32)
    depth[2, 1, 1] = np.nan
    with pytest.raises(InputError, match=r"frames \[2\]"):
        normalise_depth(depth, np.ones((4, 4), bool), (4, 4), name="clip.mp4")


# --- training -----------------------------------------------------------------------------


def test_per_frame_net_learns_from_the_travel_what_depth_cannot_tell():
    """The toy labels are 0 wherever the camera moves forwards, whatever its depth: only the
    travel input tells those frames apart."""
    samples = toy_samples(count=4, seed=3)
    forward = np.concatenate([s.travel[:, 2] > 0 for s in samples])
    assert forward.mean() > 0.15  # both kinds of frame are there
    means = {}
    for gap in (8, 0):
        torch.manual_seed(0)
        model = CoverageModel(replace(SMALL, travel_gap=gap))
        given = [replace(s, travel=s.travel[:, :model.config.travel_size]) for s in samples]
        train_frame_net(model, given, lambda e: None)
        pred = np.concatenate([model.frame_outputs(s.inputs, s.cues)[0][:, 0] for s in given])
        means[gap] = pred[forward].mean(), pred[~forward].mean()
    (fwd, back), (fwd_depth_only, back_depth_only) = means[8], means[0]
    # With the travel, the forward frames fall towards their label 0 and apart from the rest.
    assert fwd < 0.5 * fwd_depth_only
    assert back - fwd > 2 * (back_depth_only - fwd_depth_only)


def test_per_frame_net_learns_from_the_field_of_view_what_depth_cannot_tell():
    """The toy labels of each procedure are scaled by its camera's width: only the
    field-of-view input tells the procedures apart."""
    samples = toy_samples(count=4, seed=5)
    widths = np.log(np.tan(np.radians([45.0, 55.0, 60.0, 65.0])))  # 90-130 degree cameras
    scaled = []
    for s, w in zip(samples, widths, strict=True):
        view = np.tile(np.float32([w, w - 0.2]), (len(s.inputs), 1))
        scaled.append(replace(s, view=view, frame_labels=s.frame_labels * (0.5 + 0.6 * w)))
    errors = {}
    for field_of_view in ("true", "none"):
        torch.manual_seed(0)
        model = CoverageModel(replace(SMALL, field_of_view=field_of_view))
        given = [replace(s, view=s.view[:, :model.config.cue_size - model.config.travel_size])
                 for s in scaled]
        train_frame_net(model, given, lambda e: None)
        errors[field_of_view] = frame_loss(model, given)
    assert errors["true"] < 0.5 * errors["none"], errors


def test_a_net_trained_with_the_field_of_view_sometimes_hidden_serves_both_cases():
    """The toy labels of the test above. Trained with view_hidden, the network reads the field
    of view where it is given (nearly as well as one that always has it) and, where it is
    hidden, errs about as much as one that never had it, not as a network given a wrong one."""
    samples = toy_samples(count=4, seed=5)
    widths = np.log(np.tan(np.radians([45.0, 55.0, 60.0, 65.0])))
    scaled = [replace(s, view=known_view(np.tile(np.float32([w, w - 0.2]), (len(s.inputs), 1))),
                      frame_labels=s.frame_labels * (0.5 + 0.6 * w))
              for s, w in zip(samples, widths, strict=True)]
    errors = {}
    for hidden in (0.0, 0.5):
        torch.manual_seed(0)
        config = replace(SMALL, field_of_view="true", view_hidden=hidden)
        model = CoverageModel(config)
        given = [replace(s, view=s.view[:, :config.view_size]) for s in scaled]
        train_frame_net(model, given, lambda e: None)
        errors[hidden, "known"] = frame_loss(model, given)
        errors[hidden, "hidden"] = frame_loss(model, [
            replace(s, view=hidden_view(len(s.view))[:, :config.view_size]) for s in given])
    torch.manual_seed(0)
    none = CoverageModel(SMALL)
    train_frame_net(none, [replace(s, view=s.view[:, :0]) for s in scaled], lambda e: None)
    errors["none"] = frame_loss(none, [replace(s, view=s.view[:, :0]) for s in scaled])
    assert errors[0.5, "known"] < 0.5 * errors["none"], errors
    assert errors[0.5, "hidden"] < 1.3 * errors["none"], errors
    assert errors[0.0, "hidden"] > 2 * errors[0.5, "hidden"], errors


def test_the_true_field_of_view_of_a_fisheye_procedure_is_refused(tmp_path, sim_config):
    """The true field-of-view input is log(W / 2 fx), a pinhole's half-angle tangent."""
    from hybrid.sim.simulate import simulate_procedure, with_overrides

    path = simulate_procedure(tmp_path, 7, 0, replace(with_overrides(sim_config, max_frames=4),
                                                      lens="equidistant"))
    with pytest.raises(InputError, match="true field-of-view input is a pinhole camera's"):
        procedure_samples(path, replace(SMALL, field_of_view="true"), None, "none")


def test_view_hidden_needs_a_field_of_view_and_adds_the_known_value():
    assert replace(SMALL, field_of_view="true", view_hidden=0.5).cue_size == \
        replace(SMALL, field_of_view="true").cue_size + 1
    for bad in ({"view_hidden": 0.5}, {"field_of_view": "true", "view_hidden": 1.0},
                {"field_of_view": "true", "view_hidden": -0.1}):
        with pytest.raises(ValueError, match="view_hidden"):
            replace(SMALL, **bad)
    view = known_view(view_values(np.diag([80.0, 32.0, 1.0]), 160, 128, 2))
    assert view.shape == (2, 3) and view[:, 2].tolist() == [1.0, 1.0]
    assert hidden_view(2).tolist() == [[0.0, 0.0, 0.0]] * 2


def test_per_frame_net_learns_from_the_depth_scale_what_normalised_depth_cannot_tell():
    """The toy labels fall as the frame's depth scale grows (a wider stretch of colon, whose
    wall lies farther outside the band's view), which the median-normalised input hides: only
    the scale cue tells the frames apart."""
    rng = np.random.default_rng(7)
    scaled = []
    for s in toy_samples(count=4, seed=7):
        scale = relative_scale(np.exp(np.cumsum(rng.normal(0, 0.1, len(s.inputs)))))
        scaled.append(replace(s, scale=scale,
                              frame_labels=s.frame_labels / (1 + np.exp(2 * scale))))
    errors = {}
    for depth_scale in (True, False):
        torch.manual_seed(0)
        model = CoverageModel(replace(SMALL, depth_scale=depth_scale))
        given = [replace(s, scale=s.scale[:, :int(depth_scale)]) for s in scaled]
        train_frame_net(model, given, lambda e: None)
        errors[depth_scale] = frame_loss(model, given)
    assert errors[True] < 0.5 * errors[False], errors


def test_relative_scale_is_log_depth_scale_over_the_videos_median():
    medians = np.array([1.0, 2.0, 4.0, 8.0, 0.5])
    scale = relative_scale(medians)
    assert scale.shape == (5, 1)
    np.testing.assert_allclose(scale[:, 0], np.log(medians / 2.0), atol=1e-6)
    np.testing.assert_allclose(relative_scale(medians * 30.0), scale, atol=1e-6)
    for bad in (np.array([1.0, 0.0]), np.array([1.0, np.nan]), np.zeros(0)):
        with pytest.raises(InputError, match="clip.mp4"):
            relative_scale(bad, name="clip.mp4")


def test_field_of_view_values_are_log_tangents_of_the_half_angles():
    K = np.array([[80.0, 0, 79.5], [0, 32.0, 63.5], [0, 0, 1]])  # 160 x 128: 90 deg across
    values = view_values(K, 160, 128, frames=3)
    assert values.shape == (3, 2) and values.dtype == np.float32
    assert values[0] == pytest.approx([0.0, np.log(2.0)])
    # The same camera at another resolution gives the same values.
    assert view_values(K * [[0.5], [0.5], [1]], 80, 64, 1)[0] == pytest.approx(values[0])
    with pytest.raises(InputError, match="positive focal lengths"):
        view_values(np.diag([0.0, 32.0, 1.0]), 160, 128, 1, name="intrinsics.json")


def test_mirroring_negates_the_travel_along_the_flipped_axis():
    depth = torch.arange(6.0).reshape(1, 1, 2, 3).repeat(3, 1, 1, 1)
    cues = torch.tensor([[0.6, 0.3, -0.7, 0.3, 0.2, 0.1]]).repeat(3, 1)  # travel, then view
    flips = torch.tensor([[True, False], [False, True], [False, False]])
    x, m = mirrored(depth, cues, flips, travel=4)
    assert torch.equal(x[0, 0], depth[0, 0].flip(-1)) and torch.equal(x[1, 0], depth[1, 0].flip(-2))
    assert torch.equal(x[2], depth[2])
    assert m[0].tolist() == pytest.approx([-0.6, 0.3, -0.7, 0.3, 0.2, 0.1])
    assert m[1].tolist() == pytest.approx([0.6, -0.3, -0.7, 0.3, 0.2, 0.1])
    assert torch.equal(m[2], cues[2])
    # Two travel blocks (the short and the chained travel): both are mirrored.
    two = torch.cat([cues[:, :4], cues], dim=1)
    m = mirrored(depth, two, flips, travel=8)[1]
    assert m[0].tolist() == pytest.approx([-0.6, 0.3, -0.7, 0.3, -0.6, 0.3, -0.7, 0.3, 0.2, 0.1])
    assert m[1].tolist() == pytest.approx([0.6, -0.3, -0.7, 0.3, 0.6, -0.3, -0.7, 0.3, 0.2, 0.1])
    # Without travel columns the field of view is left as it is.
    assert torch.equal(mirrored(depth, cues[:, 4:], flips, travel=0)[1], cues[:, 4:])
    assert mirrored(depth, torch.zeros(3, 0), flips, travel=0)[1].shape == (3, 0)


def test_a_mirrored_video_gets_the_same_coverage():
    torch.manual_seed(0)
    model = CoverageModel(SMALL)
    rng = np.random.default_rng(0)
    inputs = rng.normal(size=(30, 1, 16, 20)).astype(np.float32)
    cues = toy_travel(30, rng)
    coverage, features = model.frame_outputs(inputs, cues)
    assert features.shape == (30, len(MIRRORS), SMALL.feature_size)
    x, m = torch.from_numpy(inputs), torch.from_numpy(cues)
    with torch.no_grad():  # the first view is the frame as it is; coverage is the views' mean
        np.testing.assert_allclose(features[:, 0], model.frame.features(x, m), atol=1e-5)
        views = [model.frame(*mirrored(x, m, torch.tensor(f).expand(30, 2), travel=4))
                 for f in MIRRORS]
    np.testing.assert_allclose(coverage, torch.stack(views).mean(0), atol=1e-6)
    assert np.abs(coverage - views[0].numpy()).max() > 1e-4
    # Mirrored left-right, each view becomes another one; the predictions stay.
    lr = mirrored(x, m, torch.tensor([[True, False]]).expand(30, 2), travel=4)
    coverage_lr, features_lr = model.frame_outputs(lr[0].numpy(), lr[1].numpy())
    np.testing.assert_allclose(coverage_lr, coverage, atol=1e-6)
    np.testing.assert_allclose(features_lr[:, [1, 0, 3, 2]], features, atol=1e-5)
    np.testing.assert_allclose(model.segment_outputs(features_lr, [0, 10]),
                               model.segment_outputs(features, [0, 10]), atol=1e-6)
    assert model.segment_outputs(features, []).shape == (0,)
    # A segment's coverage goes through the model's calibration table.
    raw = model.segment_outputs(features, [0, 10], calibrated=False)
    with torch.no_grad():
        model.segment.calibration.copy_(torch.linspace(0.2, 0.6, 101, dtype=torch.float64))
    np.testing.assert_allclose(model.segment_outputs(features, [0, 10]), 0.2 + 0.4 * raw)
    # Adapted by CORAL onto the training windows' statistics, the table does not apply; onto
    # held-out ones, it does.
    with torch.no_grad():
        model.segment.coral_offset.fill_(0.5)
    adapted = model.segment_outputs(features, [0, 10], calibrated=False)
    assert np.abs(adapted - raw).max() > 1e-4
    np.testing.assert_array_equal(model.segment_outputs(features, [0, 10]), adapted)
    with torch.no_grad():
        model.segment.held_out_source.fill_(1.0)
    np.testing.assert_allclose(model.segment_outputs(features, [0, 10]), 0.2 + 0.4 * adapted)


def test_training_reduces_both_losses_on_a_tiny_set():
    samples = toy_samples()
    torch.manual_seed(0)
    model = CoverageModel(SMALL)
    before = frame_loss(model, samples)
    log: list[dict] = []
    train_frame_net(model, samples, log.append)
    after = frame_loss(model, samples)
    assert after < 0.5 * before, (before, after)
    features = [model.frame_outputs(s.inputs, s.cues)[1] for s in samples]
    seg_before = segment_loss(model, samples)
    train_segment_net(model, samples, features, log.append)
    seg_after = segment_loss(model, samples)
    assert seg_after < 0.5 * seg_before, (seg_before, seg_after)
    assert {e["stage"] for e in log} == {1, 2}
    assert all(np.isfinite(e["loss"]) for e in log)


def test_stage_one_in_bfloat16_trains_float32_weights_through_bfloat16_passes():
    samples = toy_samples()
    torch.manual_seed(0)
    model = CoverageModel(replace(SMALL, frame_precision="bfloat16"))
    before = frame_loss(model, samples)
    passes: set[torch.dtype] = set()
    model.frame.encoder.stem.register_forward_hook(lambda m, i, out: passes.add(out.dtype))
    train_frame_net(model, samples, lambda entry: None)
    assert passes == {torch.bfloat16}
    assert {p.dtype for p in model.parameters()} == {torch.float32}
    after = frame_loss(model, samples)
    assert after < 0.5 * before, (before, after)
    passes.clear()
    model.frame_outputs(samples[0].inputs, samples[0].cues)  # prediction stays float32
    assert passes == {torch.float32}


@pytest.mark.parametrize(("kind", "fit"), [("l2", 0.18), ("l1", 0.0)])
def test_l2_loss_fits_the_mean_and_l1_the_median(kind, fit):
    """Seven frames covered 0 and three 0.6: one constant fits 0.18 under L2, 0 under L1."""
    target = torch.tensor([0.0] * 7 + [0.6] * 3)
    constant = nn.Parameter(torch.tensor(0.3))
    optimizer = torch.optim.Adam([constant], lr=0.01)
    for _ in range(500):
        optimizer.zero_grad()
        regression_loss(kind, constant.expand(10), target).backward()
        optimizer.step()
    assert abs(constant.item() - fit) < 0.02, constant.item()
    assert float(regression_loss(kind, torch.full((10,), 0.18), target)) == pytest.approx(
        0.7 * 0.18**2 + 0.3 * 0.42**2 if kind == "l2" else 0.7 * 0.18 + 0.3 * 0.42)


def test_source_statistics_are_those_of_every_training_window_in_every_view():
    samples = toy_samples()
    torch.manual_seed(0)
    model = CoverageModel(replace(SMALL, segment_epochs=2))
    features = [model.frame_outputs(s.inputs, s.cues)[1] for s in samples]
    train_segment_net(model, samples, features, lambda entry: None)
    T = SMALL.segment_frames
    windows = [torch.from_numpy(f[start:start + T, view].astype(np.float32))
               for s, f in zip(samples, features, strict=True)
               for start, label in zip(s.window_starts, s.window_labels, strict=True)
               if np.isfinite(label) for view in range(len(MIRRORS))]
    with torch.no_grad():
        embedded = model.segment.embed(torch.stack(windows)).double()
    assert torch.allclose(model.segment.source_mean.double(), embedded.mean(0), atol=1e-5)
    assert torch.allclose(model.segment.source_cov.double(), torch.cov(embedded.T), atol=1e-5)


def test_a_feature_constant_in_training_is_ignored_in_a_new_video():
    """A feature that never varied over the training frames (a dead unit) is standardised to
    0 whatever it reads later, not multiplied by a millionth's inverse."""
    samples = toy_samples()
    torch.manual_seed(0)
    model = CoverageModel(replace(SMALL, segment_epochs=2))
    features = [model.frame_outputs(s.inputs, s.cues)[1] for s in samples]
    for f in features:
        f[..., 3] = 0.5  # as a unit that never fires would be
    train_segment_net(model, samples, features, lambda entry: None)
    spread = np.concatenate(features).reshape(-1, SMALL.feature_size).std(0)
    assert torch.isinf(model.segment.feature_std[3])
    assert torch.equal(torch.isinf(model.segment.feature_std),
                       torch.from_numpy(spread <= 1e-3 * np.median(spread)))
    woken = features[0].copy()
    woken[..., 3] = 40.0
    np.testing.assert_array_equal(model.segment_outputs(woken, [0]),
                                  model.segment_outputs(features[0], [0]))


def test_fold_split_never_mixes_procedures():
    folds = fold_split(11, 5, seed=3)
    assert len(folds) == 5
    held = np.concatenate(folds)
    assert sorted(held.tolist()) == list(range(11))  # each procedure held out exactly once
    for k, test in enumerate(folds):
        train = set(range(11)) - set(test.tolist())
        assert not train & set(test.tolist())
        assert len(test) in (2, 3)
        assert all(not set(test.tolist()) & set(other.tolist())
                   for j, other in enumerate(folds) if j != k)
    assert [f.tolist() for f in fold_split(11, 5, seed=3)] == [f.tolist() for f in folds]
    with pytest.raises(InputError, match="at least 5 procedures"):
        fold_split(3, 5, seed=0)


# --- CORAL --------------------------------------------------------------------------------


def test_coral_transform_matches_mean_and_covariance():
    rng = np.random.default_rng(0)
    d = 6
    source = rng.normal(size=(500, d)) @ rng.normal(size=(d, d)) + rng.normal(size=d)
    target = rng.normal(size=(300, d)) @ rng.normal(size=(d, d)) * 3 - 5
    mean, cov = source.mean(0), np.cov(source, rowvar=False)
    A, b = coral_transform(mean, cov, target)
    moved = target @ A.T + b
    assert np.allclose(moved.mean(0), mean, atol=1e-9)
    tolerance = 1e-3 * np.abs(cov).max()  # the ridge (RIDGE of the mean variance) moves it
    assert np.abs(np.cov(moved, rowvar=False) - cov).max() < tolerance
    # Before adaptation the statistics were far apart.
    assert np.abs(np.cov(target, rowvar=False) - cov).max() > 100 * tolerance
    # As many rows as dimensions span at most d - 1 of them: the gain would blow up.
    coral_transform(mean, cov, target[:d + 1])
    with pytest.raises(InputError, match="more target samples than their 6 dimensions"):
        coral_transform(mean, cov, target[:d])


def test_adapt_makes_target_features_look_like_the_source():
    torch.manual_seed(0)
    model = CoverageModel(SMALL)
    rng = np.random.default_rng(1)
    F = SMALL.feature_size
    def walks() -> list[np.ndarray]:  # features drifting over time, so that windows differ
        return [np.cumsum(rng.normal(size=(200, len(MIRRORS), F)), 0).astype(np.float32)
                for _ in range(3)]

    source = walks()
    starts = list(range(0, 200 - SMALL.segment_frames + 1, 3))
    assert set_source(model, source, stride=3) == 3 * len(starts)
    embedded = torch.cat([model.segment_embeddings(f, starts).flatten(0, 1)
                          for f in source]).double()
    assert torch.allclose(model.segment.source_mean.double(), embedded.mean(0), atol=1e-5)
    assert torch.allclose(model.segment.source_cov.double(), torch.cov(embedded.T), atol=1e-4)
    # The target domain: the same kind of features, rescaled and shifted.
    target = [2.5 * f + 1.0 for f in walks()]
    used = adapt(model, target, stride=3)
    assert used == 3 * len(starts)
    net = model.segment
    z = torch.cat([model.segment_embeddings(f, starts).flatten(0, 1) for f in target]).double()
    moved = z @ net.coral_matrix.double().T + net.coral_offset.double()
    scale = float(net.source_cov.abs().max())
    assert scale > 1e-5  # windows differ: a real covariance to match
    assert (moved.mean(0) - net.source_mean.double()).abs().max() < 1e-4 * scale ** 0.5
    assert (torch.cov(moved.T) - net.source_cov.double()).abs().max() < 1e-3 * scale


def test_adapt_needs_a_video_of_one_segment_and_more_segments_than_dimensions():
    """Overlapping windows and mirror views are not independent samples: CORAL asks for more
    segments' worth of target video (20 frames each here) than the 4 dimensions it aligns."""
    model = CoverageModel(SMALL)
    with pytest.raises(InputError, match="at least 20 frames"):
        adapt(model, [np.zeros((19, 4, SMALL.feature_size), np.float32)], stride=5)
    dims = SMALL.segment_channels[-1]  # the pooled layer CORAL aligns
    rng = np.random.default_rng(0)
    video = rng.normal(size=(20 * (dims + 1), 4, SMALL.feature_size)).astype(np.float32)
    assert adapt(model, [video], stride=5) == (len(video) - 20) // 5 + 1
    assert adapt(model, [video[:60], video[60:]], stride=5) == 9 + 5  # 3 and 2 segments
    fitted = model.segment.coral_matrix.clone()
    # as `c2d2 adapt` gives them: computed one video at a time, with one too short for a window
    assert adapt(model, (v for v in (video[:60], video[:10], video[60:])), stride=5) == 9 + 5
    torch.testing.assert_close(model.segment.coral_matrix, fitted, rtol=0, atol=0)
    with pytest.raises(InputError, match=f"more target video than {dims} segments of 20 frames"
                                         f".* got {dims}"):
        adapt(model, [video[:-1]], stride=5)


# --- bad input ----------------------------------------------------------------------------


def test_segment_shorter_than_the_window_is_an_input_error():
    model = CoverageModel(SMALL)
    with pytest.raises(InputError, match="needs 20 frames"):
        model.segment_outputs(np.zeros((19, 4, SMALL.feature_size), np.float32), [0])


def test_features_of_the_wrong_size_are_an_input_error():
    model = CoverageModel(SMALL)
    with pytest.raises(InputError, match=r"\(N, 4, 8\)"):
        model.segment_outputs(np.zeros((40, 4, 2048), np.float32), [0])
    with pytest.raises(InputError, match=r"\(N, 4, 8\)"):
        model.segment_outputs(np.zeros((40, SMALL.feature_size), np.float32), [0])
    with pytest.raises(InputError, match="normalised depth"):
        model.frame_outputs(np.zeros((2, 1, 64, 80), np.float32), np.zeros((2, 4), np.float32))
    with pytest.raises(InputError, match=r"cues must be \(N, 4\)"):
        model.frame_outputs(np.zeros((2, 1, 16, 20), np.float32), np.zeros((2, 0), np.float32))


def test_a_model_of_another_preset_is_an_input_error(tmp_path):
    path = tmp_path / "small.safetensors"
    CoverageModel(SMALL).save(path)
    assert load_coverage_model(path, preset="fast").config == SMALL
    with pytest.raises(InputError, match="'fast'-preset coverage model"):
        load_coverage_model(path, preset="paper")
    depth = save_model(tmp_path / "depth.safetensors", DepthModel(TINY), TINY.to_dict())
    with pytest.raises(InputError, match="'depth' checkpoint, not a 'coverage'"):
        load_coverage_model(depth)


def test_a_run_refuses_networks_that_read_the_true_field_of_view(tmp_path):
    path = tmp_path / "true-view.safetensors"
    CoverageModel(replace(SMALL, field_of_view="true")).save(path)
    with pytest.raises(InputError, match="always read the simulator's true field of view"):
        Models.load(RunConfig(coverage_checkpoint=str(path)))


def test_a_run_refuses_networks_that_read_the_simulators_depth(tmp_path):
    """Trained on the true depth (in cm, with median_normalise off), such networks would be
    fed the depth network's output in its own units."""
    path = tmp_path / "true-depth.safetensors"
    CoverageModel(replace(SMALL, input_depth="true", median_normalise=False)).save(path)
    with pytest.raises(InputError, match=f"^{path}: these coverage networks read the "
                                         f"simulator's depth"):
        Models.load(RunConfig(coverage_checkpoint=str(path)))


def test_a_run_refuses_to_self_calibrate_for_networks_without_the_field_of_view(tmp_path):
    for view in ("none", "predicted"):
        path = tmp_path / f"{view}.safetensors"
        CoverageModel(replace(SMALL, field_of_view=view)).save(path)
        with pytest.raises(InputError, match=f"do not take it \\(field_of_view '{view}'\\)"):
            Models.load(RunConfig(coverage_checkpoint=str(path), self_calibrate=True))


def test_coverage_config_overrides():
    assert parse_overrides(["input_depth=true", "frame_epochs=2"], COVERAGE_PRESETS["fast"]) \
        == {"input_depth": "true", "frame_epochs": 2}
    with pytest.raises(ValueError, match="input_depth"):
        coverage_config("fast", input_depth="lidar")
    with pytest.raises(ValueError, match="field_of_view"):
        coverage_config("fast", field_of_view="wide")
    with pytest.raises(ValueError, match="segment_loss"):
        coverage_config("fast", segment_loss="huber")
    with pytest.raises(ValueError, match="frame_precision"):
        coverage_config("fast", frame_precision="float16")
    assert coverage_config("paper").frame_loss == "l2"  # the paper's loss
    with pytest.raises(ValueError, match="unknown preset"):
        coverage_config("huge")


def test_a_setting_given_by_option_and_by_set_is_a_clear_error(tmp_path):
    for args in (["train-coverage", "--folds", "2", "--set", "folds=0"],
                 ["train-depth", "--seed", "1", "--set", "seed=2"]):
        result = runner.invoke(app, [*args, "--data", str(tmp_path), "--out", str(tmp_path / "o")])
        assert_clean_error(result, f"--set {args[-1].split('=')[0]}=", args[1])
    assert not (tmp_path / "o").exists()


# --- commands on simulated procedures -----------------------------------------------------


@pytest.fixture(scope="module")
def two_procedures(tmp_path_factory, sim_config) -> Path:
    from hybrid.sim.simulate import simulate_procedure

    root = tmp_path_factory.mktemp("cov_data")
    for index in (0, 1):
        simulate_procedure(root, 11, index, sim_config)
    return root


def test_procedures_shorter_than_the_chained_travel_are_a_clear_error(tmp_path,
                                                                     two_procedures):
    """The presets chain 8 hops of 8 frames; 40-frame procedures cannot give that travel."""
    depth = save_model(tmp_path / "depth.safetensors", DepthModel(TINY), TINY.to_dict())
    result = runner.invoke(app, ["train-coverage", "--data", str(two_procedures), "--out",
                                 str(tmp_path / "run"), "--depth-checkpoint", str(depth),
                                 "--set", "segment_frames=20"])
    assert result.exit_code != 0 and "Traceback" not in result.output, result.output
    error = result.stderr[result.stderr.index("error: "):]  # after the progress bar
    for name in (str(two_procedures / "proc_0000"), "8 hops of 8 frame(s)",
                 "needs more than 64 frames, got 40", "travel_hops"):
        assert name in error, error


def test_train_eval_and_adapt_commands(tmp_path, two_procedures):
    depth = save_model(tmp_path / "depth.safetensors", DepthModel(TINY), TINY.to_dict())
    run = tmp_path / "run"
    sets = ["segment_frames=20", "segment_stride=5", "frame_epochs=1", "segment_epochs=2",
            "frame_batch=16", "travel_hops=2",  # 40-frame procedures: 2 hops of 8 frames
            "segment_channels=8,8,8,8,8,2",  # CORAL below: 4 segments of video > 2 dimensions
            "calibrate=true"]  # last: dropped below
    args = ["train-coverage", "--data", str(two_procedures), "--out", str(run), "--folds", "2",
            "--depth-checkpoint", str(depth)] + [x for s in sets for x in ("--set", s)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert {p.name for p in run.iterdir()} >= {"fold-0.safetensors", "fold-1.safetensors",
                                               "model.safetensors", "cv_metrics.json",
                                               "cv_scatter.png", "record.json"}
    import json

    cv = json.loads((run / "cv_metrics.json").read_text())
    assert cv["segments"] == 4 and cv["frames"] == 80  # 2 procedures x (40 frames, 2 segments)
    assert 0 <= cv["segment_mae"] <= 1 and 0 <= cv["frame_mae_1-4"] <= 1
    # The same command again resumes: nothing is retrained (no new lines in the log).
    log = (run / "train_log.jsonl").read_text()
    assert runner.invoke(app, args).exit_code == 0
    assert (run / "train_log.jsonl").read_text() == log
    # A run recorded before the `calibrate` field resumes as the calibrated run it was.
    legacy = json.loads((run / "record.json").read_text())
    del legacy["config"]["calibrate"]
    (run / "record.json").write_text(json.dumps(legacy))
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    # The benchmarks read the run back with its fold split; a changed record is refused.
    record, config, samples, folds = load_run(run)
    assert config.travel_hops == 2 and [s.name for s in samples] == record["procedures"]
    assert [f.tolist() for f in folds] == [f.tolist() for f in fold_split(2, 2, 0)]
    _, _, no_samples, same_folds = load_run(run, with_samples=False)
    assert no_samples == [] and [f.tolist() for f in same_folds] == [f.tolist() for f in folds]
    assert [s.name for s in run_samples(run, record, config)] == record["procedures"]
    # The cross-validation's segments are calibrated fold by fold on the other fold's held-out
    # windows, and the shipped model on both folds' windows.
    held = [fold_predictions(load_coverage_model(run / f"fold-{k}.safetensors"),
                             [samples[i] for i in f]) for k, f in enumerate(folds)]
    raw = [np.concatenate(h.predictions.segment_pred) for h in held]
    true = np.concatenate([np.concatenate(h.predictions.segment_true) for h in held])
    calibrated = np.concatenate([
        np.interp(raw[k], np.linspace(0, 1, 101), fit_table(held[1 - k].window_pred,
                                                            held[1 - k].window_true))
        for k in (0, 1)])
    assert cv["segment_mae"] == pytest.approx(np.abs(calibrated - true).mean())
    assert cv["uncalibrated"]["segment_mae"] == pytest.approx(
        np.abs(np.concatenate(raw) - true).mean())
    assert cv["segment_mae"] != cv["uncalibrated"]["segment_mae"]
    table = fit_table(np.concatenate([h.window_pred for h in held]),
                      np.concatenate([h.window_true for h in held]))
    final = load_coverage_model(run / "model.safetensors").segment.calibration.numpy()
    np.testing.assert_allclose(final, table, atol=1e-12)
    assert np.abs(final - identity_table()).max() > 0.01
    # Uncalibrated (the default), the same folds give the same figures the other way round,
    # and the final model's table is the identity.
    plain = tmp_path / "plain"
    plain.mkdir()
    for k in (0, 1):
        shutil.copy(run / f"fold-{k}.safetensors", plain)
    shutil.copy(run / "model.safetensors", plain)
    result = runner.invoke(app, [str(plain) if a == str(run) else a
                                 for a in args[:-2]])  # without --set calibrate=true
    assert result.exit_code == 0, result.output
    cv_plain = json.loads((plain / "cv_metrics.json").read_text())
    assert cv_plain["segment_mae"] == cv["uncalibrated"]["segment_mae"]
    assert cv_plain["calibrated"]["segment_mae"] == cv["segment_mae"]
    uncalibrated = load_coverage_model(plain / "model.safetensors").segment
    np.testing.assert_array_equal(uncalibrated.calibration.numpy(), identity_table())
    assert not uncalibrated.holds_table()
    assert load_coverage_model(run / "model.safetensors").segment.holds_table()
    (run / "record.json").write_text(json.dumps({**record, "procedures": ["other/proc"] * 2}))
    with pytest.raises(InputError, match="no longer those of"):
        load_run(run)
    (run / "record.json").write_text(json.dumps(record))

    evaluation = tmp_path / "eval"
    result = runner.invoke(app, ["eval-coverage", "--data", str(two_procedures), "--out",
                                 str(evaluation), "--model", str(run / "model.safetensors"),
                                 "--depth-checkpoint", str(depth)])
    assert result.exit_code == 0, result.output
    metrics = json.loads((evaluation / "metrics.json").read_text())
    assert metrics["segments"] == 4 and (evaluation / "scatter.png").stat().st_size > 0
    # Each procedure's segments give the MAE again; with two procedures the interval runs
    # from the one's MAE to the other's (a draw of both from one has probability 1/4).
    procedures = metrics["procedures"]
    assert sorted(procedures) == [f"{two_procedures.name}/proc_000{i}" for i in (0, 1)]
    errors = [abs(p - t) for r in procedures.values()
              for p, t in zip(r["learned"]["pred"], r["truth"], strict=True)]
    assert np.mean(errors) == pytest.approx(metrics["segment_mae"])
    per_procedure = [np.mean([abs(p - t) for p, t in zip(r["learned"]["pred"], r["truth"],
                                                          strict=True)])
                     for r in procedures.values()]
    assert metrics["segment_mae_interval"] == pytest.approx(sorted(per_procedure))

    adapted = tmp_path / "adapted.safetensors"
    # The target: one of the two training procedures, whose windows' statistics are not
    # those of both, in segments of 10 frames (4 of them), each resampled to the network's 20.
    result = runner.invoke(app, ["adapt", "--target", str(two_procedures / "proc_0001"),
                                 "--out", str(adapted), "--model", str(run / "model.safetensors"),
                                 "--depth-checkpoint", str(depth),
                                 "--segment-seconds", str(10 / 30)])
    assert result.exit_code == 0, result.output
    assert "CORAL fitted on 13 target windows" in result.output  # (80 - 20) / 5 + 1
    assert load_coverage_model(adapted).depth_tag == file_tag(depth)  # kept for its users
    net = load_coverage_model(adapted).segment
    assert not torch.allclose(net.coral_matrix, torch.eye(len(net.coral_matrix)))
    trained_source = net.source_mean.clone()
    # Mapped onto the training windows' statistics, the table is kept but not applied.
    assert "calibration is not applied" in result.output
    np.testing.assert_array_equal(net.calibration.numpy(), final)
    assert load_coverage_model(run / "model.safetensors").segment.calibrates()
    assert not net.calibrates()

    result = runner.invoke(app, ["adapt", "--target", str(two_procedures / "proc_0001"),
                                 "--out", str(adapted),
                                 "--source", str(two_procedures / "proc_0000"),
                                 "--model", str(run / "model.safetensors"),
                                 "--depth-checkpoint", str(depth),
                                 "--segment-seconds", str(10 / 30)])
    assert result.exit_code == 0, result.output
    assert "source statistics from 13 held-out windows" in result.output  # (80 - 20) / 5 + 1
    assert not torch.allclose(load_coverage_model(adapted).segment.source_mean, trained_source)
    # Mapped onto held-out statistics, the calibration fitted on held-out windows applies, and
    # still applies when that model is adapted again without --source.
    assert "calibration is not applied" not in result.output
    assert load_coverage_model(adapted).segment.calibrates()
    # Adapted for insertion videos, whose travel cues read the other way: another transform.
    inserted = tmp_path / "inserted.safetensors"
    result = runner.invoke(app, ["adapt", "--target", str(two_procedures / "proc_0001"),
                                 "--out", str(inserted), "--insertion",
                                 "--source", str(two_procedures / "proc_0000"),
                                 "--model", str(run / "model.safetensors"),
                                 "--depth-checkpoint", str(depth),
                                 "--segment-seconds", str(10 / 30)])
    assert result.exit_code == 0, result.output
    assert not torch.allclose(load_coverage_model(inserted).segment.coral_offset,
                              load_coverage_model(adapted).segment.coral_offset)
    # ... while the simulated source videos are withdrawals still: the same statistics.
    for key in ("source_mean", "source_cov"):
        assert torch.equal(getattr(load_coverage_model(inserted).segment, key),
                           getattr(load_coverage_model(adapted).segment, key))
    again = tmp_path / "again.safetensors"
    result = runner.invoke(app, ["adapt", "--target", str(two_procedures), "--out", str(again),
                                 "--model", str(adapted), "--depth-checkpoint", str(depth),
                                 "--segment-seconds", str(20 / 30)])
    assert result.exit_code == 0 and "calibration is not applied" not in result.output
    assert load_coverage_model(again).segment.calibrates()
    # An uncalibrated model has no calibration to speak of.
    result = runner.invoke(app, ["adapt", "--target", str(two_procedures), "--out",
                                 str(tmp_path / "plain-adapted.safetensors"), "--model",
                                 str(plain / "model.safetensors"), "--depth-checkpoint",
                                 str(depth), "--segment-seconds", str(20 / 30)])
    assert result.exit_code == 0 and "calibration" not in result.output, result.output


def test_field_of_view_inputs_of_a_simulated_procedure(tmp_path, two_procedures):
    """'true': the simulator's camera; 'predicted': the median K of the motion network's
    consecutive pairs (as `c2d2 run` takes it), cached beside the procedure's other inputs."""
    torch.manual_seed(0)
    depth_model = DepthModel(TINY).eval()
    path = two_procedures / "proc_0000"
    config = replace(SMALL, field_of_view="true")
    true = procedure_samples(path, config, depth_model, "tiny")
    camera = Procedure.open(path).camera
    assert true.cues.shape == (len(true.inputs), 6)
    assert true.view[0] == pytest.approx([np.log(camera.width / 2 / camera.fx),
                                          np.log(camera.height / 2 / camera.fy)])
    predicted = procedure_samples(path, replace(config, field_of_view="predicted"), depth_model,
                                  "tiny")
    seq = open_sequence(path, (TINY.height, TINY.width))
    K = np.median(infer_sequence(depth_model, seq, (1,), depth=False).K_pairs, 0)  # as a run
    assert predicted.view[0] == pytest.approx(view_values(K, TINY.width, TINY.height, 1)[0],
                                              abs=1e-5)
    assert (predicted.view == predicted.view[0]).all()
    assert (path / "cache" / "view-tiny.npy").is_file()
    # Read back from the caches, without the depth model.
    again = procedure_samples(path, replace(config, field_of_view="predicted"), None, "tiny")
    assert np.array_equal(again.view, predicted.view)


def test_depth_scale_input_of_a_simulated_procedure(two_procedures):
    """The scale cue of each frame: the median of its depth (the simulator's, or the depth
    network's over the image region) against the procedure's median of those medians, the
    medians cached beside the other inputs."""
    torch.manual_seed(0)
    depth_model = DepthModel(TINY).eval()
    path = two_procedures / "proc_0000"
    proc = Procedure.open(path)
    config = replace(SMALL, depth_scale=True, input_depth="true")
    true = procedure_samples(path, config, depth_model, "tiny")
    assert true.cues.shape == (len(true.inputs), 5)
    filled = (np.where(d > 0, d, d.max()) for d in map(proc.depth, range(proc.num_frames)))
    medians = np.array([np.median(d) for d in filled])  # no surface: the farthest wall
    np.testing.assert_allclose(true.scale[:, 0], np.log(medians / np.median(medians)),
                               atol=1e-5)
    assert true.scale.std() > 0.01  # the frames' depth scales differ
    predicted = procedure_samples(path, replace(config, input_depth="predicted"), depth_model,
                                  "tiny")
    seq = open_sequence(path, (TINY.height, TINY.width))
    depth = infer_sequence(depth_model, seq, (), depth=True).depth
    frame_medians = np.median(depth[:, seq.region], axis=1)
    np.testing.assert_allclose(predicted.scale[:, 0],
                               np.log(frame_medians / np.median(frame_medians)), atol=1e-5)
    assert (path / "cache" / "medians-tiny.npy").is_file()
    again = procedure_samples(path, replace(config, input_depth="predicted"), None, "tiny")
    assert np.array_equal(again.scale, predicted.scale)


def test_a_bordered_procedure_does_not_take_caches_of_another_border_reading(tmp_path,
                                                                            two_procedures):
    """A procedure with a border caches its inputs under a name telling how the networks
    read the border; an input cached without it (by a c2d2 that read the border otherwise)
    is not taken, while a whole-image procedure keeps its caches' names."""
    import shutil

    from hybrid.dataset import REGION_FILE, write_region
    from hybrid.sim.simulate import octagon_region

    torch.manual_seed(0)
    depth_model = DepthModel(TINY).eval()
    path = tmp_path / "proc_0000"
    shutil.copytree(two_procedures / "proc_0000", path, ignore=shutil.ignore_patterns("cache"))
    camera = Procedure.open(path).camera
    write_region(path / REGION_FILE, octagon_region(camera.height, camera.width, 6))
    size = f"{SMALL.height}x{SMALL.width}"
    stale = path / "cache" / f"input-tiny-{size}.npy"
    stale.parent.mkdir()
    seq = open_sequence(path, (TINY.height, TINY.width))
    np.save(stale, np.ones((seq.num_frames, 1, SMALL.height, SMALL.width), np.float16))
    samples = procedure_samples(path, SMALL, depth_model, "tiny")
    depth = infer_sequence(depth_model, seq, (), depth=True).depth
    expected = normalise_depth(depth, seq.region, (SMALL.height, SMALL.width))
    np.testing.assert_allclose(samples.inputs, expected, atol=2e-3)  # float16
    assert not np.allclose(samples.inputs, 1)  # not the stale input
    assert [p.name for p in (path / "cache").glob(f"input-tiny-border*-{size}.npy")]
    procedure_samples(two_procedures / "proc_0001", SMALL, depth_model, "tiny")
    assert (two_procedures / "proc_0001" / "cache" / f"input-tiny-{size}.npy").is_file()


def test_chained_travel_input_of_a_simulated_procedure(two_procedures):
    """travel_hops adds the travel over that many travel gaps, chained from the cached pairs."""
    torch.manual_seed(0)
    depth_model = DepthModel(TINY).eval()
    path = two_procedures / "proc_0000"
    config = replace(SMALL, travel_gap=2, travel_hops=3)
    samples = procedure_samples(path, config, depth_model, "tiny")
    assert samples.travel.shape == (len(samples.inputs), 8) and config.cue_size == 8
    relative = np.load(path / "cache" / "relative-tiny-2.npy")
    np.testing.assert_allclose(samples.travel[:, :4], travel_features(relative, len(relative) + 2))
    np.testing.assert_allclose(samples.travel[:, 4:], travel_features(
        relative[4:] @ relative[2:-2] @ relative[:-4], len(relative) + 2), atol=1e-6)


@pytest.fixture(scope="module")
def sparse_procedures(tmp_path_factory, sim_config) -> Path:
    """Every 4th frame of procedure 0 of seed 11 (the colon of two_procedures' first) and of
    seed 12; every 5th of seed 12's."""
    from hybrid.sim.simulate import simulate_procedure

    root = tmp_path_factory.mktemp("sparse")
    simulate_procedure(root / "same-colon", 11, 0, replace(sim_config, frame_step=4))
    simulate_procedure(root / "step4", 12, 0, replace(sim_config, frame_step=4))
    simulate_procedure(root / "step5", 12, 0, replace(sim_config, frame_step=5))
    return root


def test_per_frame_samples_of_a_procedure_at_every_kth_frame(two_procedures, sparse_procedures):
    """frames_only: the per-frame labels of the kept frames, the travel over the same time
    (a gap of 8 / 4 frames), no windows; a step that does not divide the gap is refused."""
    torch.manual_seed(0)
    depth_model = DepthModel(TINY).eval()
    config = replace(SMALL, travel_gap=8, travel_hops=2)
    path = sparse_procedures / "same-colon" / "proc_0000"
    samples = procedure_samples(path, config, depth_model, "tiny", frames_only=True)
    full = procedure_samples(two_procedures / "proc_0000", replace(config, travel_hops=0),
                             depth_model, "tiny")
    np.testing.assert_array_equal(samples.frame_labels, full.frame_labels[::4])
    relative = np.load(path / "cache" / "relative-tiny-2.npy")
    assert len(relative) == 10 - 2
    np.testing.assert_allclose(samples.travel, np.concatenate(
        [travel_features(relative, 10), travel_features(relative[2:] @ relative[:-2], 10)],
        axis=1), atol=1e-6)
    assert len(samples.inputs) == 10
    assert samples.window_starts.size == samples.segment_starts.size == 0
    with pytest.raises(InputError, match=r"7.5 fps, the coverage networks train on 30 fps"):
        procedure_samples(path, config, depth_model, "tiny")
    with pytest.raises(InputError, match=r"6 fps; .*divides the travel gap of 8"):
        procedure_samples(sparse_procedures / "step5" / "proc_0000", config, depth_model,
                          "tiny", frames_only=True)


def test_one_colon_twice_in_the_training_data_is_refused(two_procedures, sparse_procedures):
    """Within --data too: the same colon at another frame step (or style) could fall on both
    sides of a fold, and so could a procedure given twice."""
    from learned.coverage_train import check_no_shared_colon

    check_no_shared_colon([two_procedures], [sparse_procedures / "step4"])  # other colons
    same = sparse_procedures / "same-colon" / "proc_0000"
    for data in ([two_procedures, same], [two_procedures, two_procedures / "proc_0001"]):
        with pytest.raises(InputError, match="has the colon of .* give each procedure once"):
            check_no_shared_colon(data, [])


def test_train_coverage_with_per_frame_procedures(tmp_path, two_procedures, sparse_procedures):
    """--frame-data: stage 1 of every model (each fold's and the final) also reads those
    frames; a procedure with the colon of a training one is refused before anything is
    trained, and so is a resume with other per-frame procedures."""
    depth = save_model(tmp_path / "depth.safetensors", DepthModel(TINY), TINY.to_dict())
    sets = ["segment_frames=20", "segment_stride=5", "frame_epochs=1", "segment_epochs=1",
            "frame_batch=4", "travel_hops=2"]
    args = ["train-coverage", "--data", str(two_procedures), "--folds", "2",
            "--depth-checkpoint", str(depth)] + [x for s in sets for x in ("--set", s)]
    frame_data = ["--frame-data", str(sparse_procedures / "step4")]
    result = runner.invoke(app, args + ["--out", str(tmp_path / "leak"), "--frame-data",
                                        str(sparse_procedures / "same-colon")])
    assert_clean_error(result, str(sparse_procedures / "same-colon" / "proc_0000"),
                       str(two_procedures / "proc_0000"), "same seed, index and colon")
    assert not (tmp_path / "leak" / "fold-0.safetensors").exists()
    import json

    def labelled(path: Path) -> int:  # frames with a per-frame label (stage 1 trains on them)
        per_frame = Procedure.open(path).coverage.per_frame.values()
        return sum(any(v is not None for v in frame) for frame in zip(*per_frame, strict=True))

    steps = {}
    for name, extra in (("plain", []), ("frames", frame_data)):
        result = runner.invoke(app, args + ["--out", str(tmp_path / name)] + extra)
        assert result.exit_code == 0, result.output
        log = [json.loads(line) for line in (tmp_path / name / "train_log.jsonl").open()]
        steps[name] = {fold: max(e["step"] for e in log if e["stage"] == 1 and e["fold"] == fold)
                       for fold in ("0", "1", "all")}
    record = json.loads((tmp_path / "frames" / "record.json").read_text())
    assert record["frame_procedures"] == ["step4/proc_0000"]
    assert record["procedures"] == [f"{two_procedures.name}/proc_{i:04d}" for i in (0, 1)]
    extra = labelled(sparse_procedures / "step4" / "proc_0000")
    assert extra >= 4
    for fold, held in enumerate(fold_split(2, 2, 0)):  # each fold model trains on the other
        plain = labelled(two_procedures / f"proc_{1 - held[0]:04d}")
        assert (steps["plain"][str(fold)], steps["frames"][str(fold)]) == (
            plain // 4, (plain + extra) // 4), fold
    plain = sum(labelled(p) for p in sorted(two_procedures.glob("proc_*")))
    assert (steps["plain"]["all"], steps["frames"]["all"]) == (plain // 4, (plain + extra) // 4)
    result = runner.invoke(app, args + ["--out", str(tmp_path / "frames")])  # without them
    assert result.exit_code != 0 and "Traceback" not in result.output, result.output
    error = result.stderr[result.stderr.index("error: "):]  # after the progress bar
    assert f"{tmp_path / 'frames'} holds a run on other procedures" in error, error
    # The networks know the depth model they learned on, and refuse another's depth maps.
    from learned.checkpoint import checkpoint_metadata
    from learned.checkpoints import SHIPPED_DEPTH

    final = tmp_path / "frames" / "model.safetensors"
    assert checkpoint_metadata(final)["depth_model"] == file_tag(depth)
    assert checkpoint_metadata(tmp_path / "frames" / "fold-0.safetensors")["depth_model"] == \
        file_tag(depth)
    result = runner.invoke(app, ["eval-coverage", "--data", str(two_procedures), "--model",
                                 str(final), "--out", str(tmp_path / "eval")])
    assert_clean_error(result, str(final), str(SHIPPED_DEPTH), file_tag(depth))
    assert not (tmp_path / "eval").exists()
    missing = tmp_path / "no-such-depth.safetensors"
    result = runner.invoke(app, ["eval-coverage", "--data", str(two_procedures), "--model",
                                 str(final), "--depth-checkpoint", str(missing), "--out",
                                 str(tmp_path / "eval")])
    assert_clean_error(result, f"not found: {missing}")
    from hybrid.pipeline import Models, RunConfig  # c2d2 run, batch, eval and adapt load so

    with pytest.raises(InputError, match=f"learned on the output of the depth model "
                                         f"{file_tag(depth)}"):
        Models.load(RunConfig(coverage_checkpoint=str(final)))
    Models.load(RunConfig(depth_checkpoint=str(depth), coverage_checkpoint=str(final)))


def test_eval_coverage_with_a_depth_checkpoint_as_model(tmp_path, two_procedures):
    depth = save_model(tmp_path / "depth.safetensors", DepthModel(TINY), TINY.to_dict())
    result = runner.invoke(app, ["eval-coverage", "--data", str(two_procedures), "--out",
                                 str(tmp_path / "e"), "--model", str(depth)])
    assert_clean_error(result, "depth.safetensors", "not a 'coverage'")


def test_eval_coverage_refuses_a_procedure_given_twice(tmp_path, two_procedures):
    """Its segments would be counted twice, and the per-procedure records could not tell the
    two apart: refused before anything is computed or written."""
    out = tmp_path / "e"
    result = runner.invoke(app, ["eval-coverage", "--data", str(two_procedures), "--data",
                                 str(two_procedures / "proc_0001"), "--out", str(out)])
    assert_clean_error(result, f"{two_procedures.name}/proc_0001", "more than once")
    assert not out.exists()


def test_eval_coverage_scores_view_hidden_networks_with_the_field_of_view_hidden(
        tmp_path, two_procedures):
    """The default reads the simulator's field of view; --view-hidden scores what a run
    without a self-calibrated one gives (the 'known' value 0 too); a network not trained
    with view_hidden cannot take it."""
    import json

    depth = save_model(tmp_path / "depth.safetensors", DepthModel(TINY), TINY.to_dict())
    torch.manual_seed(0)
    model = CoverageModel(replace(SMALL, field_of_view="true", view_hidden=0.5))
    path = tmp_path / "view.safetensors"
    model.save(path)
    samples = load_samples([two_procedures], model.config, depth)
    expected = {
        hidden: coverage_metrics(evaluate(model, [
            replace(s, view=hidden_view(len(s.view))) if hidden else s for s in samples]))
        for hidden in (False, True)}
    assert samples[0].view[:, 2].tolist() == [1.0] * len(samples[0].view)
    scored = {}
    for hidden in (False, True):
        out = tmp_path / f"eval-{hidden}"
        result = runner.invoke(app, ["eval-coverage", "--data", str(two_procedures), "--out",
                                     str(out), "--model", str(path), "--depth-checkpoint",
                                     str(depth)] + ["--view-hidden"] * hidden)
        assert result.exit_code == 0, result.output
        scored[hidden] = json.loads((out / "metrics.json").read_text())
        assert scored[hidden]["view_hidden"] is hidden
        for key in ("frame_mae_1-3", "frame_mae_1-4", "frame_mae_1-6", "segment_mae"):
            assert scored[hidden][key] == pytest.approx(expected[hidden][key]), key
    assert scored[True]["frame_mae_1-4"] != scored[False]["frame_mae_1-4"]
    plain = tmp_path / "plain.safetensors"
    CoverageModel(SMALL).save(plain)
    result = runner.invoke(app, ["eval-coverage", "--data", str(two_procedures), "--out",
                                 str(tmp_path / "e"), "--model", str(plain), "--view-hidden"])
    assert_clean_error(result, "--view-hidden", "plain.safetensors",
                       "not trained with field_of_view 'true' and view_hidden")


def test_segment_mae_interval_and_procedure_records():
    """Two procedures erring 0.1 and 0.3 on every segment: a draw of both from one has
    probability 1/4, so the 95% bootstrap interval is [0.1, 0.3]; an undefined truth is left
    out of the MAE and written as None."""
    predictions = Predictions()
    for error in (0.1, 0.3):
        truth = np.array([0.2, 0.5, np.nan])
        predictions.add(np.zeros((3, 3)), np.zeros((3, 3)), truth + error, truth)
    assert segment_mae_interval(predictions) == pytest.approx([0.1, 0.3])
    records = procedure_segments(predictions, ["a/proc_0000", "b/proc_0000"])
    assert records["b/proc_0000"]["truth"] == [0.2, 0.5, None]
    assert records["b/proc_0000"]["learned"]["pred"][:2] == pytest.approx([0.5, 0.8])
    with pytest.raises(ValueError, match="distinct names"):
        procedure_segments(predictions, ["a/proc_0000", "a/proc_0000"])
    alone = Predictions()
    alone.add(np.zeros((1, 3)), np.zeros((1, 3)), np.array([0.5]), np.array([0.4]))
    assert segment_mae_interval(alone) is None  # no interval from one procedure
    alone.add(np.zeros((1, 3)), np.zeros((1, 3)), np.array([0.5]), np.array([np.nan]))
    assert segment_mae_interval(alone) is None  # nor with a second that has no defined truth


def test_segments_of_another_frame_rate_are_resampled_to_the_window():
    """A 6-fps video: a 10-s segment is 60 frames; the network's window is 300 (30 fps)."""
    features = np.arange(150, dtype=np.float32)[:, None]  # frame index as the feature
    resampled = resample_features(features, segment_frames=60, window=300)
    assert len(resampled) == 750  # 2.5 segments
    first, second = resampled[:300, 0], resampled[300:600, 0]
    assert first.min() == 0 and first.max() == 59 and np.all(np.diff(first) >= 0)
    assert second.min() == 60 and second.max() == 119
    assert np.bincount(first.astype(int)).tolist() == [5] * 60  # each frame 5 times
    # At the network's own rate nothing changes.
    assert np.array_equal(resample_features(features, 300, 300), features)


def test_a_depth_only_model_from_before_the_travel_input_still_loads(tmp_path):
    old = replace(SMALL, travel_gap=0)
    model = CoverageModel(old)
    saved = old.to_dict()
    del saved["travel_gap"], saved["frame_rate"]  # configs written before the fields existed
    path = tmp_path / "old.safetensors"
    save_checkpoint(path, {"frame": model.frame, "segment": model.segment}, saved, 0,
                    kind="coverage")
    loaded = load_coverage_model(path)
    assert loaded.config == old
    assert loaded.config.travel_size == 0 and loaded.frame.encoder.stem[0].in_channels == 1


def test_a_model_from_before_the_longer_travel_still_loads(tmp_path):
    """Networks saved before travel_hops existed read the short travel only (4 cues)."""
    old = SMALL  # travel_hops 0
    model = CoverageModel(old)
    saved = old.to_dict()
    del saved["travel_hops"]
    path = tmp_path / "old.safetensors"
    save_checkpoint(path, {"frame": model.frame, "segment": model.segment}, saved, 0,
                    kind="coverage")
    loaded = load_coverage_model(path)
    assert loaded.config == old and COVERAGE_PRESETS["fast"].travel_hops == 8
    assert loaded.config.travel_size == 4 and loaded.frame.encoder.stem[0].in_channels == 5


def test_a_config_from_before_the_loss_settings_reads_as_l2():
    """Networks saved before frame_loss and segment_loss existed were trained with L2."""
    saved = replace(SMALL, frame_loss="l1", segment_loss="l1").to_dict()
    del saved["frame_loss"], saved["segment_loss"]
    loaded = CoverageConfig.from_dict(saved)
    assert (loaded.frame_loss, loaded.segment_loss) == ("l2", "l2")
