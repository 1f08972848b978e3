"""Unsupervised training of depth, ego-motion and intrinsics by view synthesis, on RGB only.

Reads simulated procedures, folders of images or videos (and, with config.maps, their
structure-from-motion maps: learned.map_triplets); writes into the output folder
`checkpoint.safetensors` (weights, optimiser, step, config), `model.safetensors` (the weights
alone, when the run completes), `config.json` and
`metrics.jsonl` (training losses; validation metrics where ground truth exists, which is used
for nothing else). Rerunning with the same folder resumes from the last checkpoint.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from hybrid import workdir as W
from hybrid.types import InputError
from learned.checkpoint import (
    export_weights,
    file_tag,
    load_modules,
    load_optimizer,
    read_checkpoint,
    save_checkpoint,
)
from learned.config import DEPTH_PRESETS, DepthConfig
from learned.device import device_of
from learned.frames import VIDEO_SUFFIXES, FrameSequence, open_sequence
from learned.map_triplets import MapTriplets, with_map_terms
from learned.metrics import intrinsics_error, mre
from learned.model import (
    DepthModel,
    bn_momentum,
    chained_rotation,
    load_depth_model,
    to_tensor,
)

log = logging.getLogger(__name__)
CHECKPOINT = "checkpoint.safetensors"
WEIGHTS = "model.safetensors"
"""Written when a run completes: the weights alone, as shipped."""


def expand_inputs(paths: list[Path]) -> list[Path]:
    """Each path is one input, or a folder holding simulated procedures or videos (not a
    procedure still being simulated, `*.partial`)."""
    out: list[Path] = []
    for path in map(Path, paths):
        if not path.exists():
            raise InputError(f"training input not found: {path}")
        children = sorted(path.iterdir()) if path.is_dir() else []
        procedures = [c for c in children if (c / "camera.json").is_file()
                      and (c / "rgb").is_dir() and not c.name.endswith(".partial")]
        videos = [c for c in children if c.suffix.lower() in VIDEO_SUFFIXES]
        out += procedures or videos or [path]
    return out


def input_name(path: Path) -> str:
    """How runs name an input: its folder's name and its own (proc_0000 of two datasets
    differ)."""
    return f"{path.parent.name}/{path.name}"


@dataclass
class TripletSampler:
    """Random (previous, target, next) frame triplets, `gap` frames apart, from sequences."""

    sequences: list[FrameSequence]
    pair_gap_s: float
    chain_steps: int = 0
    """Also the frames between previous and target for a chain of this many steps (0: none;
    DepthModel.loss)."""

    def __post_init__(self) -> None:
        self.gaps = [max(1, round(s.fps * self.pair_gap_s)) for s in self.sequences]
        self.counts = np.array([max(0, s.num_frames - 2 * g)
                                for s, g in zip(self.sequences, self.gaps, strict=True)])
        if self.chain_steps and min(self.gaps) < self.chain_steps:
            short = self.sequences[int(np.argmin(self.gaps))]
            raise InputError(f"{short.name}: its pair gap is {min(self.gaps)} frames, fewer than "
                             f"the chain term's {self.chain_steps} steps; set chain_steps to at "
                             f"most {min(self.gaps)} (--set chain_steps=N)")
        if self.counts.sum() == 0:
            raise InputError("inputs are too short: each needs more than 2 x pair gap frames "
                             "(image folders are taken at 30 frames/s unless --fps says "
                             "otherwise)")

    def draw(self, size: int, rng: np.random.Generator) -> list[tuple[int, int, int]]:
        """`size` triplets drawn uniformly over all targets: (sequence index, target frame,
        gap)."""
        bounds = np.cumsum(self.counts)
        drawn = []
        for pick in rng.choice(bounds[-1], size):
            k = int(np.searchsorted(bounds, pick, side="right"))
            drawn.append((k, int(pick - (bounds[k] - self.counts[k])) + self.gaps[k],
                          self.gaps[k]))
        return drawn

    def batch(self, size: int, rng: np.random.Generator, device: torch.device | str = "cpu"
              ) -> tuple[torch.Tensor, torch.Tensor]:
        """Frames (B, 3 + n, 3, H, W) in [0, 1] (previous, target, next, then the n =
        chain_steps - 1 frames between previous and target, if chain_steps) and image regions
        (B, 1, H, W), on `device`."""
        frames, regions = [], []
        for k, t, gap in self.draw(size, rng):
            seq = self.sequences[k]
            between = [t - gap + round(j * gap / self.chain_steps)
                       for j in range(1, self.chain_steps)]
            frames.append(np.stack([seq.network_frame(i) for i in (t - gap, t, t + gap, *between)]))
            regions.append(seq.region)
        return (to_tensor(np.stack(frames), device),
                torch.from_numpy(np.stack(regions))[:, None].to(device))


def mirror_flips(size: int, rng: np.random.Generator) -> torch.Tensor:
    """(size, 2) bool: mirror left-right, mirror up-down, each with chance 1/2."""
    return torch.from_numpy(rng.random((size, 2)) < 0.5)


def mirror_images(images: torch.Tensor, flips: torch.Tensor) -> torch.Tensor:
    """Images (B, ..., H, W), each mirrored left-right where flips[:, 0] and up-down where
    flips[:, 1]."""
    shape = (-1,) + (1,) * (images.dim() - 1)
    for axis, dim in enumerate((-1, -2)):
        chosen = flips[:, axis].to(images.device).view(shape)
        images = torch.where(chosen, images.flip(dim), images)
    return images


def recompute_motion_statistics(model: DepthModel, sampler: TripletSampler, batches: int,
                                seed: int, device: torch.device | str = "cpu") -> None:
    """Reset the motion network's batch-norm running statistics and average them anew, each
    batch weighed alike, over `batches` batches of the sampler's triplets (those a run of this
    seed draws at its first steps, unmirrored), read as DepthModel.loss reads them: no zoom
    crops, no map batches. The model keeps its mode and the layers their momentum."""
    training = model.motion.training
    model.motion.train()
    try:
        with bn_momentum(model.motion, None) as norms, torch.no_grad():
            for norm in norms:
                norm.reset_running_stats()
            for index in range(batches):
                frames, _ = sampler.batch(model.config.batch_size,
                                          np.random.default_rng([seed, index]), device)
                model.triplet_motion(frames)
    finally:
        model.motion.train(training)


def validate(model: DepthModel, sequences: list[FrameSequence], frames_per_sequence: int = 8
             ) -> dict[str, float]:
    """Median MRE over sampled frames and focal errors, on sequences with ground truth."""
    errors, focal = [], []
    model.eval()
    with torch.no_grad():
        for seq in sequences:
            gap = max(1, round(seq.fps * model.config.pair_gap_s))
            picks = np.linspace(gap, seq.num_frames - 1, frames_per_sequence).round().astype(int)
            images = to_tensor(np.stack([seq.network_frame(t) for t in picks]), device_of(model))
            depth = model.depth(images)[:, 0].cpu().numpy()  # the network's own, one view
            errors += [mre(d, seq.depth(t), seq.region) for d, t in zip(depth, picks, strict=True)]
            previous = to_tensor(np.stack([seq.network_frame(t - gap) for t in picks]),
                                 device_of(model))
            K = model.pair_motion(previous, images)[-1].mean(0).cpu().numpy()
            err = intrinsics_error(K, seq.camera.K, seq.camera.width, seq.camera.height)
            focal.append(0.5 * (err["fx_rel"] + err["fy_rel"]))
    model.train()
    return {"val_mre": float(np.median(errors)), "val_focal_rel": float(np.mean(focal))}


def train_depth(data: list[Path | FrameSequence], out: Path, config: DepthConfig,
                val: list[Path] = (), log_every: int = 50, val_every: int = 500,
                save_every: int = 250, progress: bool = True,
                device: torch.device | str = "cpu") -> Path:
    """Train (or resume) on `device` and return the checkpoint path. `data`: inputs as
    `expand_inputs` takes them, or sequences already opened at the config's size."""
    out = Path(out)
    path = out / CHECKPOINT
    if not path.is_file() and config.init and not Path(config.init).is_file():
        raise InputError(f"--init: no depth model at {config.init}")
    W.make_folder(out)
    step, tensors, meta, elapsed = 0, None, None, 0.0
    if path.is_file():  # resume with the run's own config, see _resumed_config
        tensors, meta = read_checkpoint(path)
        step = meta["step"]
        config = _resumed_config(DepthConfig.from_dict(meta["config"]), config, step, path)
        log.info("resuming %s at step %d", path, step)
        elapsed = _drop_records_after(out / "metrics.jsonl", step)
    size = (config.height, config.width)
    fps = config.input_fps or None
    opened = [d for d in data if isinstance(d, FrameSequence)]
    for seq in opened:
        if tuple(seq.size) != size:
            raise InputError(f"{seq.name}: frames of {tuple(seq.size)}, the model takes {size}")
    paths = expand_inputs([d for d in data if not isinstance(d, FrameSequence)])
    sampler = TripletSampler(opened + [open_sequence(p, size, fps=fps) for p in paths],
                             config.pair_gap_s, config.chain_steps if config.w_chain else 0)
    maps = MapTriplets(sampler.sequences, sampler.gaps, Path(config.maps),
                       config.map_min_points) if config.maps else None
    if maps is not None and not maps.triplets:
        raise InputError(f"{config.maps}: no triplet of frames lies in an agreeing stretch of "
                         f"the maps with {config.map_min_points} map points; the inputs map "
                         f"too rarely to train on (train without --maps)")
    val_paths = expand_inputs(list(val))
    val_sequences = [open_sequence(p, size) for p in val_paths]
    if untrue := [s.name for s in val_sequences if s.camera is None]:
        raise InputError(f"--val {untrue[0]}: not a simulated procedure; validation scores depth "
                         f"against the simulator's truth, so it takes simulated procedures only")
    _check_inputs(out / "inputs.json", {
        "data": [str(Path(p).resolve()) for p in [s.name for s in opened] + paths],
        "val": [str(p.resolve()) for p in val_paths],
        "maps": config.maps and str(Path(config.maps).resolve())})
    if tensors is not None and step < config.steps:  # an extended run's export is stale
        (out / WEIGHTS).unlink(missing_ok=True)
    torch.manual_seed(config.seed)
    model = DepthModel(config).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    teacher = model
    if config.w_chain and config.chain_teacher == "init":
        teacher = _frozen_teacher(config, out, device)
    if tensors is not None:
        load_modules(tensors, {"depth": model.depth, "motion": model.motion}, path)
        load_optimizer(tensors, meta, optimizer)
    elif config.init:
        init = teacher if teacher is not model else \
            load_depth_model(Path(config.init), config.preset, device)
        model.load_state_dict(init.state_dict())
    W.write_json(out / "config.json", config.to_dict())
    model.train()
    running: dict[str, float] = {}
    started = time.time() - elapsed  # seconds in the log count the whole run
    first_step = step
    with (out / "metrics.jsonl").open("a") as metrics_log, \
            tqdm(total=config.steps, initial=step, desc="train-depth", unit="step",
                 disable=not progress) as bar:
        while step < config.steps:
            rng = np.random.default_rng([config.seed, step])  # resumable sampling
            torch.manual_seed(config.seed * 1_000_003 + step)  # and resumable noise in the loss
            frames, regions = sampler.batch(config.batch_size, rng, device)
            if config.mirror:
                flips = mirror_flips(len(frames), rng)
                frames, regions = mirror_images(frames, flips), mirror_images(regions, flips)
            terms = model.loss(frames, regions, chain_target=chained_rotation(teacher, frames)
                               if config.w_chain else None)
            if maps is not None:
                terms = with_map_terms(terms, model, maps.batch(
                    config.batch_size, np.random.default_rng([config.seed, step, 1]), device))
            if not torch.isfinite(terms.total):
                raise InputError(
                    f"{out}: the loss is not finite at step {step + 1} ({terms.as_floats()}); "
                    f"that step was not taken, and the checkpoint, if any, holds the last step "
                    f"saved. Train again in a new folder with another seed or a lower learning "
                    f"rate (train-depth --seed, --set learning_rate=...), or, adapting to a "
                    f"video, with fewer steps")
            optimizer.zero_grad()
            terms.total.backward()
            for group in optimizer.param_groups:
                group["lr"] = config.lr_at(step)
            torch.nn.utils.clip_grad_norm_(model.parameters(), config.grad_clip)
            optimizer.step()
            step += 1
            bar.update(1)
            for k, v in terms.as_floats().items():
                running[k] = running.get(k, 0.0) + v
            record: dict[str, float] = {}
            if step % log_every == 0:
                record = {k: v / log_every for k, v in running.items()}
                running = {}
                bar.set_postfix(loss=f"{record['total']:.4f}")
            if val_sequences and (step % val_every == 0 or step == config.steps):
                record.update(validate(model, val_sequences))
            if record:
                record.update(step=step, seconds=round(time.time() - started, 1))
                metrics_log.write(json.dumps(record) + "\n")
                metrics_log.flush()
            if record.get("smoothness") == 0.0:  # a mean of terms >= 0: every depth map was flat
                raise InputError(
                    f"{out}: the depth network collapsed by step {step}: each of its depth maps "
                    f"over the last {log_every} steps was one constant (most likely its output "
                    f"saturated, where no gradient reaches it). Train again in a new folder with "
                    f"another seed (train-depth --seed), or, adapting to a video, with fewer "
                    f"steps (docs/depth.md, \"Blurred images in the photometric error\")")
            if step % save_every == 0 or step == config.steps:
                save_checkpoint(path, {"depth": model.depth, "motion": model.motion},
                                config.to_dict(), step, optimizer)
    if config.bn_recompute_batches:  # resets first, so a rerun of a finished run agrees
        recompute_motion_statistics(model, sampler, config.bn_recompute_batches, config.seed,
                                    device)
    if config.bn_recompute_batches or step == first_step:
        # the recomputed statistics, or a finished run's depth_views (nothing was trained)
        save_checkpoint(path, {"depth": model.depth, "motion": model.motion},
                        config.to_dict(), step, optimizer)
    export_weights(path, out / WEIGHTS)
    return path


def _frozen_teacher(config: DepthConfig, out: Path, device: torch.device | str) -> DepthModel:
    """The init model as the chain term's teacher. Its file's SHA-256 prefix is kept in the run
    folder, and a resumed run refuses a teacher that changed since."""
    if not Path(config.init).is_file():
        raise InputError(f"{config.init}: no such model, and it is the chain term's teacher of "
                         f"the run in {out}")
    tag, record = file_tag(config.init), out / "teacher.json"
    if record.is_file() and json.loads(record.read_text())["sha256_12"] != tag:
        raise InputError(f"{config.init} changed since the run in {out} began (it is the chain "
                         f"term's teacher); restore it or start a new run")
    W.write_json(record, {"init": config.init, "sha256_12": tag})
    return load_depth_model(Path(config.init), config.preset, device)


def _resumed_config(saved: DepthConfig, asked: DepthConfig, step: int, path: Path
                    ) -> DepthConfig:
    """The config a run resumed at `step` goes on with: its own, except --steps and a
    learning-rate drop asked for (one that differs from the preset's) that has not happened
    yet, so that the resumed run trains exactly as a fresh run with the final config would,
    and a depth_views asked for (one that differs from the preset's), which training never
    reads."""
    if saved.preset != asked.preset:
        raise InputError(f"{path} holds a {saved.preset!r} run; use another --out for the "
                         f"{asked.preset!r} preset")
    default = DEPTH_PRESETS[asked.preset]
    config = replace(saved, steps=asked.steps, depth_views=saved.depth_views
                     if asked.depth_views == default.depth_views else asked.depth_views)
    drop = (asked.lr_drop_step, asked.lr_drop_factor)
    if drop not in ((default.lr_drop_step, default.lr_drop_factor),
                    (saved.lr_drop_step, saved.lr_drop_factor)):
        if 0 < saved.lr_drop_step < step or 0 < asked.lr_drop_step < step:
            raise InputError(
                f"{path}: cannot change the learning-rate drop (x{saved.lr_drop_factor} from "
                f"step {saved.lr_drop_step} -> x{asked.lr_drop_factor} from step "
                f"{asked.lr_drop_step}) at step {step}: the drop must lie at or after the "
                "step the run resumes from")
        config = replace(config, lr_drop_step=asked.lr_drop_step,
                         lr_drop_factor=asked.lr_drop_factor)
    if replace(asked, steps=config.steps, lr_drop_step=config.lr_drop_step,
               lr_drop_factor=config.lr_drop_factor, depth_views=config.depth_views) != config:
        log.warning("%s: resuming with the run's own config; only --steps, a future "
                    "learning-rate drop and depth_views are taken from the command line", path)
    return config


def _check_inputs(path: Path, inputs: dict) -> None:
    """Record a run's inputs, or refuse to resume it on others (runs made before this record
    are taken as they are)."""
    if path.is_file() and (before := json.loads(path.read_text())) != inputs:
        raise InputError(f"{path.parent} holds a run on other inputs ({before}); resume it on "
                         f"the same inputs, or train into another folder")
    W.write_json(path, inputs)


def _drop_records_after(metrics: Path, step: int) -> float:
    """Forget log lines written after the checkpoint a run resumes from (and a last line cut
    short by a kill); return its seconds."""
    if not metrics.is_file():
        return 0.0
    lines = metrics.read_text().splitlines()
    records = []
    for number, line in enumerate(lines, 1):
        if not line:
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            if number < len(lines):
                raise InputError(f"{metrics}: line {number} is not a record; the run's log "
                                 f"is damaged: use another --out") from None
    records = [r for r in records if r["step"] <= step]
    W.write_text(metrics, "".join(json.dumps(r) + "\n" for r in records))
    return float(records[-1]["seconds"]) if records else 0.0
