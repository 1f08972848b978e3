"""Adapting the depth model to one video before reading it (self-supervised, test time).

The model's own training loss (view synthesis, with the loss settings it was trained with) is
minimised for a number of steps on the frames of the one video it will then read: that video's
RGB only, no labels and no calibration, so it applies to any recorded procedure. The model
starts from the given checkpoint, which is also the chain term's teacher where the model's loss
has one. Not reliable, so off unless asked for: on held-out simulated procedures it lowered
the depth error of most pink videos and raised that of every dusk one (docs/depth.md,
"Adapting to the video").
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, replace
from pathlib import Path

import torch

from hybrid import workdir as W
from hybrid.types import InputError
from learned.checkpoint import file_tag
from learned.config import DepthConfig
from learned.frames import FrameSequence
from learned.model import DepthModel, load_depth_model
from learned.train import WEIGHTS, train_depth

log = logging.getLogger(__name__)
RECORD = "adapted_to.json"
"""What the run in an adaptation folder is: its input, starting model and number of steps."""


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


def adapt_depth_model(checkpoint: Path, config: DepthConfig, seq: FrameSequence, out: Path,
                      steps: int, progress: bool = False, device: torch.device | str = "cpu"
                      ) -> DepthModel:
    """The model at `checkpoint` (of this config) after `steps` training steps on `seq` alone,
    on `device`.

    The run is kept in `out` (checkpoint, config, losses) and resumes there if interrupted; a
    folder holding an adaptation of another model, to another input or for another number of
    steps is refused.
    """
    if steps < 1:
        raise InputError(f"adaptation needs at least 1 step, got {steps}")
    out = Path(out)
    record = {"input": str(Path(seq.name).resolve()), "frames": seq.num_frames,
              "model": file_tag(checkpoint), "steps": steps, "fps": seq.fps,
              "crop": asdict(seq.crop)}
    previous = out / RECORD
    if previous.is_file():
        made = json.loads(previous.read_text())  # a folder made before fps and crop were kept
        if {k: v for k, v in record.items() if k in made or k not in ("fps", "crop")} != made:
            raise InputError(f"{out} holds an adaptation of another model, to another input "
                             f"(or its frame rate or image region) or for another number of "
                             f"steps ({previous}); remove it or choose another output folder")
    config = adaptation_config(config, checkpoint, steps, seq)
    out.mkdir(parents=True, exist_ok=True)
    W.write_json(previous, record)
    train_depth([seq], out, config, progress=progress, device=device)
    return load_depth_model(out / WEIGHTS, device=device)
