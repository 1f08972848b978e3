"""Adapting the depth model to one video before reading it (self-supervised, test time).

The model's own training loss (view synthesis, with the loss settings it was trained with) is
minimised for a number of steps on the frames of the one video it will then read: that video's
RGB only, no labels and no calibration, so it applies to any recorded procedure. The model
starts from the given checkpoint, which is also the chain term's teacher where the model's loss
has one. Not reliable, so off unless asked for: on held-out simulated procedures it lowered
the depth error of 5 of 12 pink videos and raised that of the others and of every dusk one
(docs/depth.md, "Adapting to the video" and the sections after it). So a video is adapted to
only where the starting model's photometric error on it lies between CLEAR and NOISY, unless
that is forced: above NOISY it is dim and noisy (the dusk style); below CLEAR the model
explains it well already. The depth then read is the geometric mean of the adapted model's
and the starting model's (Blend): on 8 held-out pink videos it took back most of the harm
the adapted model's own depth did, and kept the adapted model's focal length, better on
average (docs/depth.md, "The adapted and the starting model's depth together"); on 9 fresh
ones at or above CLEAR its depth error was lower than the model's own on 7 (docs/depth.md,
"A rule on the starting photometric error").
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from hybrid import workdir as W
from hybrid.types import InputError
from learned.checkpoint import file_tag
from learned.config import DepthConfig
from learned.device import device_of
from learned.evaluate import scored_depths
from learned.frames import FrameSequence
from learned.model import DepthModel, load_depth_model
from learned.train import WEIGHTS, TripletSampler, train_depth

log = logging.getLogger(__name__)
RECORD = "adapted_to.json"
"""What the run in an adaptation folder is: its input, starting model and number of steps;
and the starting model's photometric error on the input, and whether it was adapted to."""
NOISY = 0.11
"""The starting model's photometric error on a video (photometric_error) above which it is not
adapted to unless forced. The shipped model reads 0.050-0.066 on its 10 pink training
procedures and 0.181-0.199 on its 10 dusk ones (0.11: their geometric midpoint); adapting
made the depth of every dusk video tried worse, up to 2.6 times (docs/depth.md, "Held by its
training data, and a guard against noisy video")."""
CLEAR = 0.058
"""The starting model's photometric error on a video below which it is not adapted to unless
forced. Set on the shipped model, before it was checked, from 12 held-out pink videos: the
blend's depth was better than the model's own on all 7 at 0.059-0.074, and worse on 3 of the
5 at 0.051-0.057 (the highest 0.0558); on 9 fresh videos at or above it the blend's was
better on 7, 0.121 MRE against 0.128 (docs/depth.md, "A rule on the starting photometric
error", and docs/adapt/rule)."""


def worth_adapting(level: float) -> bool:
    """Whether a video on which the starting model's photometric error is `level` is adapted
    to without being forced: CLEAR <= level <= NOISY."""
    return CLEAR <= level <= NOISY


class Blend(DepthModel):
    """The adapted model, reading as depth the geometric mean of its own and the starting
    model's, the latter put in the adapted model's unit by one factor for the video (the median
    ratio of their depths over the image region of 24 evenly spaced frames, those eval-depth
    scores by default). Motion and K are the adapted model's. The two weigh alike: not tuned."""

    def __init__(self, adapted: DepthModel, start: DepthModel, seq: FrameSequence):
        super().__init__(adapted.config)
        self.load_state_dict(adapted.state_dict())
        self.to(device_of(adapted)).eval()
        self.start = start.eval()
        ratio = scored_depths(adapted, seq)[1] / scored_depths(start, seq)[1]
        self.unit = float(np.median(ratio[:, seq.region]))

    def predict_depth(self, rgb: torch.Tensor) -> torch.Tensor:
        return (super().predict_depth(rgb) * self.start.predict_depth(rgb) * self.unit).sqrt()


@dataclass(frozen=True)
class Adaptation:
    """The model to read the video with, and what the adaptation found."""

    model: DepthModel
    """A Blend where adapted, else the starting model."""
    photometric_error: float
    """The starting model's, on the video (photometric_error)."""
    adapted: bool
    """False where the video was not worth adapting to and the starting model is returned."""


def adaptation_config(config: DepthConfig, checkpoint: Path, steps: int, seq: FrameSequence
                      ) -> DepthConfig:
    """The model's training config, run for `steps` from `checkpoint` at its constant learning
    rate; the chain term's steps capped at the video's pair gap in frames (a low frame rate
    has fewer frames between a pair); without the structure-from-motion maps of a model
    trained with --maps (the video has none), its ordinary batches as they were."""
    gap = max(1, round(seq.fps * config.pair_gap_s))
    if config.w_chain and gap < config.chain_steps:
        log.warning("%s: the chain term takes %d steps instead of %d, the frames between a "
                    "pair at %.3g frames/s", seq.name, gap, config.chain_steps, seq.fps)
    return replace(config.ordinary_view(), photo_blur_on="all", maps="", w_map=0.0,
                   w_map_motion=0.0, map_zoom=False, init=str(checkpoint), steps=steps,
                   lr_drop_step=0, input_fps=0.0, chain_steps=min(config.chain_steps, gap))


def photometric_error(model: DepthModel, seq: FrameSequence, batches: int = 6) -> float:
    """The model's mean photometric error (its loss's term) on `batches` fixed batches of the
    video's triplets, in eval mode: the same draws and value at every call."""
    probe = DepthModel(replace(model.config, w_chain=0.0, w_zoom=0.0)).to(device_of(model))
    probe.load_state_dict(model.state_dict())
    probe.eval()
    sampler = TripletSampler([seq], model.config.pair_gap_s)
    values = []
    with torch.random.fork_rng(), torch.no_grad():  # seeds its own draws, not the caller's
        for k in range(batches):
            frames, region = sampler.batch(model.config.batch_size, np.random.default_rng(k),
                                           device_of(model))
            torch.manual_seed(k)
            values.append(float(probe.loss(frames, region).photometric))
    return float(np.mean(values))


def adapt_depth_model(checkpoint: Path, config: DepthConfig, seq: FrameSequence, out: Path,
                      steps: int, progress: bool = False, device: torch.device | str = "cpu",
                      force: bool = False) -> Adaptation:
    """The model at `checkpoint` (of this config) after `steps` training steps on `seq` alone,
    on `device`, blended with the starting model (Blend); the model as it is, with a warning,
    where its photometric error on `seq` is not worth adapting to (worth_adapting), unless
    `force` or an adaptation in `out` has begun already.

    The run is kept in `out` (checkpoint, config, losses, and the record) and resumes there if
    interrupted; a folder holding an adaptation of another model, to another input or for
    another number of steps is refused.
    """
    if steps < 1:
        raise InputError(f"adaptation needs at least 1 step, got {steps}")
    out = Path(out)
    record = {"input": str(Path(seq.name).resolve()), "frames": seq.num_frames,
              "model": file_tag(checkpoint), "steps": steps, "fps": seq.fps,
              "crop": asdict(seq.crop)}
    previous = out / RECORD
    begun = False
    if previous.is_file():
        made = json.loads(previous.read_text())
        begun = made.get("adapted", True)  # so was every one made before the guard
        made = {k: v for k, v in made.items()
                if k not in ("photometric_error", "adapted")}  # readings, not the run's identity
        # a folder made before fps and crop were kept has neither
        if {k: v for k, v in record.items() if k in made or k not in ("fps", "crop")} != made:
            raise InputError(f"{out} holds an adaptation of another model, to another input "
                             f"(or its frame rate or image region) or for another number of "
                             f"steps ({previous}); remove it or choose another output folder")
    start = load_depth_model(checkpoint, config.preset, device)
    level = photometric_error(start, seq)
    adapted = force or begun or worth_adapting(level)
    W.make_folder(out, "--adapt-dir (or --out)")
    W.write_json(previous, {**record, "photometric_error": level, "adapted": adapted})
    if not adapted:
        why = (f"above {NOISY}, where adapting made the depth of every such (dim, noisy) "
               f"simulated video worse" if level > NOISY else
               f"below {CLEAR}, where the model explains the video well already and the "
               f"adapted depth was worse on 3 of the 5 such simulated videos tried")
        log.warning("%s: not adapted to: the depth model's photometric error on it is %.4f, "
                    "%s; its depth is the model's own (force it with --adapt-always)",
                    seq.name, level, why)
        return Adaptation(start, level, False)
    train_depth([seq], out, adaptation_config(config, checkpoint, steps, seq),
                progress=progress, device=device)
    return Adaptation(Blend(load_depth_model(out / WEIGHTS, device=device), start, seq), level,
                      True)
