"""The optical-flow term: DIS flow recovers a known shift; the Cauchy distance to the rigid
flow is zero at agreement, analytic off it, and ignores flow that leaves the image."""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch
from conftest import TINY

from learned.flow import batch_flows, dis_flow
from learned.losses import flow_error, view_synthesis_loss
from learned.model import DepthModel


def texture(height: int = 96, width: int = 128, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.integers(0, 255, (height, width, 3), dtype=np.uint8)
    return cv2.normalize(cv2.GaussianBlur(noise, (0, 0), 2), None, 0, 255, cv2.NORM_MINMAX)


def test_dis_flow_recovers_a_known_shift():
    image = texture(120, 160)
    target, source = image[10:106, 10:138], image[13:109, 5:133]  # source = target moved
    flow, trusted = dis_flow(target, source)
    # target pixel (x, y) shows what source shows at (x + 5, y - 3)
    inner = (slice(12, -12), slice(12, -12))
    assert trusted[inner].mean() > 0.9
    error = np.linalg.norm(flow[inner] - np.array([5.0, -3.0]), axis=-1)
    assert np.median(error[trusted[inner]]) < 0.25


def test_flow_error_is_zero_at_agreement_and_cauchy_off_it():
    height, width = 6, 8
    flow = torch.full((1, height, width, 2), 1.0)
    pixels = torch.stack(torch.meshgrid(torch.arange(width), torch.arange(height),
                                        indexing="xy"), -1).float()[None]
    trusted = torch.ones(1, height, width, dtype=torch.bool)
    assert float(flow_error(pixels + flow, flow, trusted, 2.0)) == pytest.approx(0.0, abs=1e-7)
    off = pixels + flow + torch.tensor([3.0, 4.0])  # 5 pixels away everywhere
    # only pixels whose flow lands inside count; their cost is log(1 + (5/2)^2)
    assert float(flow_error(off, flow, trusted, 2.0)) == pytest.approx(math.log1p(6.25))
    # pixels whose flow leaves the image (last row and column) do not count at all
    off[:, -1, :] += 100.0
    off[:, :, -1] += 100.0
    assert float(flow_error(off, flow, trusted, 2.0)) == pytest.approx(math.log1p(6.25))
    # nor do untrusted ones
    trusted[:, :2] = False
    off[:, :2] += 50.0
    assert float(flow_error(off, flow, trusted, 2.0)) == pytest.approx(math.log1p(6.25))


def test_batch_flows_match_dis_flow_per_pair():
    """b is a moved 2 pixels left: a pixel of a shows what b shows 2 to its left, and the
    reverse; each pair's flow is DIS flow's on that pair."""
    a, b = texture(seed=1), texture(seed=1)[:, list(range(2, 128)) + [127, 127]]
    images = [torch.from_numpy(x).permute(2, 0, 1)[None].float() / 255 for x in (a, b)]
    flows, trusted = batch_flows(torch.cat([images[0], images[1]]),
                                 torch.cat([images[1], images[0]]))
    assert flows.shape == (2, 96, 128, 2) and trusted.dtype == torch.bool
    for k, pair in enumerate([(a, b), (b, a)]):
        expected, ok = dis_flow(*pair)
        np.testing.assert_array_equal(flows[k].numpy(), expected)
        np.testing.assert_array_equal(trusted[k].numpy(), ok)
    inner = (slice(12, -12), slice(12, -12))
    for k, shift in enumerate([(-2.0, 0.0), (2.0, 0.0)]):
        error = np.linalg.norm(flows[k].numpy()[inner] - shift, axis=-1)
        assert np.median(error[trusted[k].numpy()[inner]]) < 0.25


def test_the_flow_term_needs_flows_and_enters_the_total():
    config = replace(TINY, w_flow=0.5)
    torch.manual_seed(0)
    model = DepthModel(config)
    frames = torch.from_numpy(np.stack([texture(64, 96, seed=k) for k in range(3)])
                              ).permute(0, 3, 1, 2)[None].float() / 255
    region = torch.ones(1, 1, 64, 96, dtype=torch.bool)
    torch.manual_seed(1)  # the auto-mask's tie-breaking noise
    terms = model.loss(frames, region).as_floats()
    assert terms["flow"] > 0
    without = DepthModel(replace(config, w_flow=0.0))
    without.load_state_dict(model.state_dict())
    torch.manual_seed(1)
    plain = without.loss(frames, region).as_floats()
    assert plain["flow"] == 0.0
    assert terms["total"] == pytest.approx(plain["total"] + 0.5 * terms["flow"], rel=1e-4)
    depth = torch.ones(1, 1, 64, 96)
    motion = (torch.zeros(1, 3),) * 4
    with pytest.raises(ValueError, match="optical flows"):
        view_synthesis_loss(frames[:, 1], [frames[:, 0]], depth, [depth], [motion],
                            torch.eye(3)[None], region, config)
