"""--device: names that are refused, and (where torch sees a GPU) the networks giving on CUDA
what they give on the CPU, training there and resuming on the CPU."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch
from conftest import TINY
from coverage_toys import SMALL, frame_loss, segment_loss, toy_samples
from typer.testing import CliRunner

from hybrid.cli import app
from hybrid.types import InputError
from learned.checkpoint import read_checkpoint
from learned.coverage_nets import CoverageModel
from learned.coverage_train import fit_model
from learned.device import device_of, pick_device
from learned.frames import open_sequence
from learned.infer import infer_sequence
from learned.model import DepthModel, chained_rotation, load_depth_model
from learned.train import train_depth

gpu = pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no CUDA device")
ABSENT_GPU = f"cuda:{torch.cuda.device_count()}"
"""A CUDA device index this machine does not have."""


def test_pick_device_names():
    assert pick_device("cpu") == torch.device("cpu")
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert pick_device("auto").type == expected
    for bad in ("tpu", "gpu0", ABSENT_GPU):
        with pytest.raises(InputError, match="--device"):
            pick_device(bad)


def test_cli_refuses_a_missing_gpu_before_doing_any_work(tmp_path):
    result = CliRunner().invoke(app, ["depth", str(tmp_path / "absent.mp4"), "--out",
                                      str(tmp_path / "out"), "--device", ABSENT_GPU])
    assert result.exit_code == 2
    assert "--device" in result.output and "CUDA device" in result.output
    assert not (tmp_path / "out").exists()


@pytest.fixture(scope="module")
def moving_texture(tmp_path_factory):
    """A folder of 24 frames of a smooth random texture sliding 2 pixels a frame."""
    folder = tmp_path_factory.mktemp("frames")
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.integers(0, 255, (160, 260, 3), dtype=np.uint8), (0, 0), 3)
    texture = cv2.normalize(texture, None, 20, 235, cv2.NORM_MINMAX)
    for k in range(24):
        cv2.imwrite(str(folder / f"{k:04d}.png"), texture[20:84, 2 * k:2 * k + 96])
    return folder


@gpu
def test_networks_give_the_same_on_cuda_as_on_the_cpu(moving_texture):
    torch.manual_seed(0)
    model = DepthModel(TINY).eval()
    seq = open_sequence(moving_texture, (TINY.height, TINY.width))
    on_cpu = infer_sequence(model, seq)
    on_gpu = infer_sequence(model.to("cuda"), seq)
    assert device_of(model).type == "cuda"
    np.testing.assert_allclose(on_gpu.depth, on_cpu.depth, rtol=1e-3)
    np.testing.assert_allclose(on_gpu.relative[1], on_cpu.relative[1], atol=1e-4)
    np.testing.assert_allclose(on_gpu.K_pairs, on_cpu.K_pairs, rtol=1e-4)


@gpu
def test_training_on_cuda_resumes_on_the_cpu(tmp_path, moving_texture):
    """A run trained on the GPU writes a checkpoint that the CPU reads and resumes from, with
    Adam's state carried over; the loss is finite throughout."""
    config = replace(TINY, steps=3)
    path = train_depth([moving_texture], tmp_path, config, log_every=1, progress=False,
                       device="cuda")
    train_depth([moving_texture], tmp_path, replace(config, steps=5), log_every=1,
                progress=False, device="cpu")
    tensors, meta = read_checkpoint(path)
    assert meta["step"] == 5
    counters = [v for k, v in tensors.items() if k.startswith("optimizer.") and k.endswith(".step")]
    assert counters and all(float(c) == 5 for c in counters)
    log = (tmp_path / "metrics.jsonl").read_text().splitlines()
    assert len(log) == 5 and "NaN" not in "".join(log)
    model = load_depth_model(tmp_path / "model.safetensors", device="cuda")
    assert device_of(model).type == "cuda"


@gpu
def test_coverage_networks_train_on_cuda_and_predict_alike_on_the_cpu():
    samples = toy_samples()
    torch.manual_seed(0)
    untrained = (frame_loss(CoverageModel(SMALL), samples),
                 segment_loss(CoverageModel(SMALL), samples))
    model = fit_model(samples, SMALL, log=lambda entry: None, device="cuda")
    assert device_of(model).type == "cuda"
    trained = (frame_loss(model, samples), segment_loss(model, samples))
    assert trained[0] < 0.5 * untrained[0] and trained[1] < 0.5 * untrained[1]
    on_cpu = (frame_loss(model.cpu(), samples), segment_loss(model, samples))
    np.testing.assert_allclose(on_cpu, trained, rtol=1e-3)


@gpu
def test_the_flow_term_gives_the_same_on_cuda(moving_texture):
    config = replace(TINY, w_flow=0.5)
    seq = open_sequence(moving_texture, (TINY.height, TINY.width))
    frames = torch.stack([torch.from_numpy(seq.frame(t)).permute(2, 0, 1) for t in (0, 3, 6)]
                         )[None].float() / 255
    region = torch.from_numpy(seq.region)[None, None]
    torch.manual_seed(0)
    model = DepthModel(config).eval()
    values = []
    for device in ("cpu", "cuda"):
        torch.manual_seed(1)  # the auto-mask's tie-breaking noise
        values.append(model.to(device).loss(frames.to(device), region.to(device)).as_floats())
    assert values[0]["flow"] > 0
    assert values[1]["flow"] == pytest.approx(values[0]["flow"], rel=1e-3)


@gpu
def test_the_fine_tune_terms_give_the_same_on_cuda(moving_texture):
    """The chain term, the shading prior on the intrinsics and the zoom consistency (the
    shipped fine-tune's terms and the zoom candidate's) give on CUDA what they give on the
    CPU. The zoom boxes are drawn from the CPU's generator, which the auto-mask's noise also
    draws from on the CPU only: the zoom term is therefore taken on its own, after a seed."""
    config = replace(TINY, w_chain=0.3, w_shading=0.1, shading_steers="intrinsics")
    seq = open_sequence(moving_texture, (TINY.height, TINY.width))
    # previous, target, next, then the chain's frames between previous and target
    frames = torch.stack([torch.from_numpy(seq.frame(t)).permute(2, 0, 1)
                          for t in (0, 6, 12, 2, 4)])[None].float() / 255
    region = torch.from_numpy(seq.region)[None, None]
    torch.manual_seed(0)
    model = DepthModel(config).eval()
    values = []
    for device in ("cpu", "cuda"):
        model.to(device)
        torch.manual_seed(1)  # the auto-mask's tie-breaking noise
        target = chained_rotation(model, frames.to(device))
        terms = model.loss(frames.to(device), region.to(device), chain_target=target)
        torch.manual_seed(2)  # the zoom boxes
        zoom = model.zoom_loss(frames[:, :2].to(device))
        values.append(terms.as_floats() | {"zoom": zoom.item()})
    for term in ("chain", "shading", "zoom", "total"):
        assert values[0][term] > 0
        assert values[1][term] == pytest.approx(values[0][term], rel=1e-3), term
