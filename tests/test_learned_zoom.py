"""learned.zoom: a crop of an analytic pinhole image, enlarged, is the image of the zoomed
camera, and the zoom consistency is zero exactly for a head that follows the zoom."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import TINY

from learned.model import DepthModel
from learned.zoom import zoom_consistency, zoom_pairs, zoomed_intrinsics

H, W = 48, 64
K0 = torch.tensor([[40.0, 0.0, 31.0], [0.0, 42.0, 24.5], [0.0, 0.0, 1.0]])


def render(K: torch.Tensor) -> torch.Tensor:
    """(3, H, W) image of a scene that depends on the ray's direction only (the sky seen by a
    pinhole camera), smooth enough for bilinear interpolation to be nearly exact."""
    v, u = torch.meshgrid(torch.arange(H, dtype=torch.float64),
                          torch.arange(W, dtype=torch.float64), indexing="ij")
    x, y = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    channels = [torch.sin(5.0 * x) * torch.cos(4.0 * y), torch.cos(4.0 * x + 3.0 * y), x * y]
    return 0.5 + 0.25 * torch.stack(channels).float()


@pytest.fixture(scope="module")
def views():
    frames = render(K0)[None, None].repeat(6, 2, 1, 1, 1)  # 6 samples of 2 frames
    return zoom_pairs(frames, zoom_max=1.6, generator=torch.Generator().manual_seed(0))


def test_the_enlarged_crop_is_the_image_of_the_zoomed_camera(views):
    boxes = views.boxes
    assert (boxes[:, 2] < W).any() and (boxes[:, 2] >= W / 1.6 - 1).all()
    told_apart = 0
    for zoomed, K in zip(views.zoomed, zoomed_intrinsics(K0.expand(6, 3, 3), boxes, (H, W)),
                         strict=True):
        inner = (slice(None), slice(None), slice(2, -2), slice(2, -2))  # bilinear edge rows
        assert float((zoomed - render(K)[None])[inner].abs().max()) < 2e-3
        wrong = K.clone()
        wrong[0, 0] = K0[0, 0]  # the crop's focal length left unscaled
        if wrong[0, 0] < 0.9 * K[0, 0]:
            assert float((zoomed - render(wrong)[None])[inner].abs().max()) > 0.1
            told_apart += 1
    assert told_apart > 0  # the unscaled focal length was checked on some box


def test_the_whole_frames_keep_their_camera(views):
    inner = (slice(None), slice(None), slice(None), slice(2, -2), slice(2, -2))
    assert float((views.whole - render(K0)[None, None])[inner].abs().max()) < 5e-3


def test_the_whole_frames_lose_the_detail_that_the_crops_lack():
    """Pixel-scale detail (white noise) is gone from the whole frames as from the enlarged
    crops, so that blur does not tell the two apart; only the scene's scale does."""
    noise = torch.rand(3, H, W, generator=torch.Generator().manual_seed(1))
    views = zoom_pairs(noise[None, None].repeat(6, 2, 1, 1, 1), zoom_max=1.6,
                       generator=torch.Generator().manual_seed(0))

    def detail(x: torch.Tensor) -> torch.Tensor:  # mean squared difference of neighbours
        return (x.diff(dim=-1).pow(2).mean((-3, -2, -1)) + x.diff(dim=-2).pow(2).mean((-3, -2, -1)))

    assert (detail(views.zoomed) < 0.4 * detail(noise)).all()
    assert (detail(views.whole) < 0.4 * detail(noise)).all()


def test_consistency_is_zero_for_a_head_that_follows_the_zoom_and_log_s_for_one_that_does_not(
        views):
    K_whole = K0.expand(6, 3, 3).clone()
    K_zoomed = zoomed_intrinsics(K_whole, views.boxes, (H, W))
    assert float(zoom_consistency(K_zoomed, K_whole, views.boxes, (H, W))) < 1e-6
    # A head that reads one K whatever the zoom is off by log s on each focal length and by
    # the principal point's shift.
    s = np.array([W / views.boxes[:, 2].numpy(), H / views.boxes[:, 3].numpy()])
    centre = ((K_zoomed[:, 0, 2] - K0[0, 2]).abs() / W
              + (K_zoomed[:, 1, 2] - K0[1, 2]).abs() / H).numpy()
    expected = float(np.mean(np.log(s).sum(0) + centre))
    got = float(zoom_consistency(K_whole, K_whole, views.boxes, (H, W)))
    assert got == pytest.approx(expected, rel=1e-5) and got > 0.1


def test_zoom_of_one_or_less_is_refused():
    with pytest.raises(ValueError, match="zoom_max"):
        zoom_pairs(torch.zeros(1, 2, 3, H, W), zoom_max=1.0)


def test_the_model_compares_the_zoomed_k_with_the_whole_k_carried_through_the_zoom():
    """DepthModel.zoom_loss pairs the K of the crops and of the whole frames in that order
    (a swap would score the whole K against the crops' K zoomed once more)."""
    torch.manual_seed(0)
    model = DepthModel(TINY).eval()  # batch norm on running statistics: batching is moot
    torch.nn.init.normal_(model.motion.intrinsics.weight, std=0.5)  # K varies with the image
    pairs = torch.rand(3, 2, 3, TINY.height, TINY.width)
    torch.manual_seed(1)
    with torch.no_grad():
        loss = model.zoom_loss(pairs)
    torch.manual_seed(1)
    views = zoom_pairs(pairs, TINY.zoom_max)
    with torch.no_grad():
        K_zoomed = model.pair_motion(views.zoomed[:, 1], views.zoomed[:, 0])[-1]
        K_whole = model.pair_motion(views.whole[:, 1], views.whole[:, 0])[-1]
    size = (TINY.height, TINY.width)
    assert float(loss) == pytest.approx(float(zoom_consistency(K_zoomed, K_whole, views.boxes,
                                                               size)), rel=1e-5)
    assert abs(float(loss) - float(zoom_consistency(K_whole, K_zoomed, views.boxes, size))
               ) > 1e-3
