"""Training of the coverage networks: stage 1 (per frame), then stage 2 (per segment), with
k-fold cross-validation split by procedure.

Writes into the run folder: `fold-K.safetensors` (one model per fold, uncalibrated, so an
interrupted run resumes at the next fold), `cv_metrics.json` and `cv_scatter.png` (predictions on
each fold's held-out procedures, pooled, read as the final model reads; with `calibrate` each
fold's segments are calibrated on the other folds' held-out windows; the other reading is
under the key `uncalibrated` or `calibrated`), `model.safetensors` (trained on every
procedure, the model that ships; with `calibrate` its segment coverage is calibrated on all
the folds' held-out windows), `train_log.jsonl` (losses) and `record.json` (config, data,
depth model, times).
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
from hybrid.dataset import Procedure
from hybrid.types import InputError
from learned.calibration import cross_fitted, fit_table, identity_table
from learned.checkpoint import file_tag
from learned.config import CoverageConfig
from learned.coverage_data import ProcedureSamples, procedure_samples
from learned.coverage_eval import Predictions, coverage_metrics, format_table, scatter_plots
from learned.coverage_nets import MIRRORS, CoverageModel, load_coverage_model, mirrored
from learned.device import device_of
from learned.model import load_depth_model
from learned.train import expand_inputs
from learned.view import hidden_view

logger = logging.getLogger(__name__)


def fold_split(count: int, folds: int, seed: int) -> list[np.ndarray]:
    """Procedure indices of each fold's held-out set: a seeded shuffle cut into `folds` parts."""
    if folds < 2:
        return []
    if count < folds:
        raise InputError(f"{folds}-fold cross-validation needs at least {folds} procedures, "
                         f"got {count}")
    order = np.random.default_rng(seed).permutation(count)
    return [np.sort(part) for part in np.array_split(order, folds)]


def regression_loss(kind: str, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared ('l2') or absolute ('l1') error."""
    error = pred - target
    return (error.square() if kind == "l2" else error.abs()).mean()


def _optimise(loss: torch.Tensor, optimizer: torch.optim.Optimizer, schedule) -> float:
    """One optimiser and schedule step on the loss; returns its value. A loss that is not
    finite stops the training before it reaches the weights."""
    if not torch.isfinite(loss):
        raise InputError(f"the coverage networks' training loss is {loss.item()}: their inputs "
                         f"or the learning rate are out of range; check the procedures' depth "
                         f"and labels, or train with a lower learning rate")
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    schedule.step()
    return loss.item()


def powered(depth: torch.Tensor, powers: torch.Tensor) -> torch.Tensor:
    """Normalised depth (B, 1, h, w) of the maps raised to powers (B,): log(d^p / median^p) is
    p log(d / median)."""
    return depth * powers[:, None, None, None]


def train_frame_net(model: CoverageModel, samples: list[ProcedureSamples], log,
                    progress: bool = False) -> None:
    """Stage 1: the frame_loss (L2 or L1) on the per-frame coverage of the three Δ pairs
    (undefined ones masked).

    Depth maps are flipped left-right and up-down at random, the travel direction's x and y
    with them: a mirrored colon is covered alike. With `depth_power`, each map is also raised
    to a random power (its normalised input scaled), as the depth network's maps are
    compressed or stretched. With `view_hidden`, each frame's field of view is hidden at that
    chance.
    """
    config, device = model.config, device_of(model)
    inputs = np.concatenate([s.inputs for s in samples])
    cues = np.concatenate([s.cues for s in samples])
    if cues.shape[1] != config.cue_size:
        raise InputError(f"the samples carry {cues.shape[1]} cues per frame, the model takes "
                         f"{config.cue_size} (travel_gap {config.travel_gap}, field_of_view "
                         f"{config.field_of_view!r})")
    labels = np.concatenate([s.frame_labels for s in samples])
    keep = np.isfinite(labels).any(axis=1)
    inputs, cues, labels = inputs[keep], cues[keep], labels[keep]
    steps_per_epoch = max(1, len(inputs) // config.frame_batch)
    total = steps_per_epoch * config.frame_epochs
    optimizer = torch.optim.AdamW(model.frame.parameters(), config.frame_lr,
                                  weight_decay=config.weight_decay)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, total)
    rng = np.random.default_rng([config.seed, 1])
    model.frame.train()
    running, bar = [], tqdm(total=total, desc="stage 1 (per frame)", disable=not progress)
    for step in range(total):
        if step % steps_per_epoch == 0:
            order = rng.permutation(len(inputs))
        ids = np.sort(order[(step % steps_per_epoch) * config.frame_batch:][:config.frame_batch])
        x, m = mirrored(torch.from_numpy(inputs[ids].astype(np.float32)).to(device),
                        torch.from_numpy(cues[ids]).to(device),
                        torch.from_numpy(rng.random((len(ids), 2)) < 0.5).to(device),
                        config.travel_size)
        if config.view_hidden:
            hide = torch.from_numpy(rng.random(len(ids)) < config.view_hidden).to(device)
            view = slice(config.travel_size, config.travel_size + config.view_size)
            m[:, view] = torch.where(hide[:, None], 0.0, m[:, view])
        if config.depth_power:
            u = rng.uniform(-config.depth_power, config.depth_power, len(ids))
            x = powered(x, torch.from_numpy(np.exp(u).astype(np.float32)).to(device))
        y = torch.from_numpy(labels[ids]).to(device)
        ok = torch.isfinite(y)
        with torch.autocast(device.type, torch.bfloat16,
                            enabled=config.frame_precision == "bfloat16"):
            predicted = model.frame(x, m).float()
        error = regression_loss(config.frame_loss, predicted[ok], y[ok])
        running.append(_optimise(error, optimizer, schedule))
        bar.update(1)
        if (step + 1) % 100 == 0 or step + 1 == total:
            log({"stage": 1, "step": step + 1, "loss": float(np.mean(running))})
            bar.set_postfix(loss=f"{np.mean(running):.4f}")
            running = []
    bar.close()
    model.frame.eval()


def train_segment_net(model: CoverageModel, samples: list[ProcedureSamples],
                      features: list[np.ndarray], log, progress: bool = False) -> None:
    """Stage 2: the segment_loss (L2 or L1) on the coverage of overlapping windows of frozen
    per-frame features ((N, len(MIRRORS), F) per procedure).

    Each window is taken in one of its mirror views and reversed in time at random (coverage
    depends on neither). Sets the feature standardisation from every frame of the training
    procedures and the CORAL source statistics from the training windows (all mirror
    views).
    """
    config, net, device = model.config, model.segment, device_of(model)
    every = np.concatenate(features).reshape(-1, config.feature_size)
    net.feature_mean.copy_(torch.from_numpy(every.mean(0)))
    # A feature (nearly) constant in training taught the network nothing, and one that varies
    # in a new video would be multiplied by up to 1e6: an infinite std makes it read 0.
    std = every.std(0)
    constant = std <= 1e-3 * np.median(std)
    net.feature_std.copy_(torch.from_numpy(np.where(constant, np.inf, std + 1e-6)))
    windows = [(k, int(start), float(label)) for k, s in enumerate(samples)
               for start, label in zip(s.window_starts, s.window_labels, strict=True)
               if np.isfinite(label)]
    if not windows:
        raise InputError(f"no {config.segment_frames}-frame training windows with a label; "
                         f"the procedures are too short")
    T = config.segment_frames

    def stack(picks, views) -> torch.Tensor:
        """(B, T, F): window picks[b] in mirror view views[b]."""
        return torch.from_numpy(np.stack([features[windows[i][0]][windows[i][1]:][:T, v]
                                          for i, v in zip(picks, views, strict=True)])
                                .astype(np.float32)).to(device)

    steps_per_epoch = max(1, len(windows) // config.segment_batch)
    total = steps_per_epoch * config.segment_epochs
    optimizer = torch.optim.AdamW(net.parameters(), config.segment_lr,
                                  weight_decay=config.weight_decay)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, total)
    rng = np.random.default_rng([config.seed, 2])
    targets = torch.tensor([w[2] for w in windows], dtype=torch.float32, device=device)
    net.train()
    running, bar = [], tqdm(total=total, desc="stage 2 (per segment)", disable=not progress)
    for step in range(total):
        if step % steps_per_epoch == 0:
            order = rng.permutation(len(windows))
        picks = order[(step % steps_per_epoch) * config.segment_batch:][:config.segment_batch]
        x = stack(picks, rng.integers(len(MIRRORS), size=len(picks)))
        reverse = torch.from_numpy(rng.random(len(picks)) < 0.5).to(device)
        x = torch.where(reverse[:, None, None], x.flip(1), x)
        error = regression_loss(config.segment_loss, net(x), targets[picks])
        running.append(_optimise(error, optimizer, schedule))
        bar.update(1)
        if (step + 1) % 200 == 0 or step + 1 == total:
            log({"stage": 2, "step": step + 1, "loss": float(np.mean(running))})
            running = []
    bar.close()
    net.eval()
    starts = [[start for j, start, _ in windows if j == k] for k in range(len(samples))]
    embedded = torch.cat([model.segment_embeddings(f, ss).flatten(0, 1)
                          for f, ss in zip(features, starts, strict=True) if ss]).double()
    net.source_mean.copy_(embedded.mean(0).float())
    net.source_cov.copy_(torch.atleast_2d(torch.cov(embedded.T)).float())


def fit_model(samples: list[ProcedureSamples], config: CoverageConfig, log,
              progress: bool = False, device: torch.device | str = "cpu",
              frame_samples: list[ProcedureSamples] = ()) -> CoverageModel:
    """Both stages on the given procedures, on `device`; stage 1 also on frame_samples. With
    `view_hidden`, stage 2 sees each procedure's field of view hidden at that chance."""
    torch.manual_seed(config.seed)
    model = CoverageModel(config).to(device)
    train_frame_net(model, [*samples, *frame_samples], log, progress)
    hide = np.random.default_rng([config.seed, 3]).random(len(samples)) < config.view_hidden
    samples = [replace(s, view=hidden_view(len(s.view))) if h else s
               for s, h in zip(samples, hide, strict=True)]
    features = [model.frame_outputs(s.inputs, s.cues)[1] for s in samples]
    train_segment_net(model, samples, features, log, progress)
    return model


def predict(model: CoverageModel, samples: ProcedureSamples) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame coverage (N, 3) and coverage of the procedure's back-to-back segments (S,)."""
    frame, features = model.frame_outputs(samples.inputs, samples.cues)
    return frame, model.segment_outputs(features, samples.segment_starts.tolist())


@dataclass
class FoldPredictions:
    """A model's uncalibrated predictions on some procedures, and on their windows every
    `segment_stride` frames (predictions, labels: what the calibration is fitted on)."""

    predictions: Predictions
    window_pred: np.ndarray
    window_true: np.ndarray


def fold_predictions(model: CoverageModel, samples: list[ProcedureSamples],
                     progress: bool = False) -> FoldPredictions:
    """`model`'s uncalibrated predictions on the procedures (for a fold model, its held-out
    ones)."""
    predictions, window_pred, window_true = Predictions(), [], []
    for s in tqdm(samples, desc="predictions", disable=not progress):
        frame, features = model.frame_outputs(s.inputs, s.cues)
        predictions.add(frame, s.frame_labels, model.segment_outputs(
            features, s.segment_starts.tolist(), calibrated=False), s.segment_labels)
        labelled = np.isfinite(s.window_labels)
        window_pred.append(model.segment_outputs(features, s.window_starts[labelled].tolist(),
                                                 calibrated=False))
        window_true.append(s.window_labels[labelled])
    return FoldPredictions(predictions, np.concatenate(window_pred), np.concatenate(window_true))


def calibrated_cv(folds: list[FoldPredictions]) -> Predictions:
    """The folds' predictions pooled, each fold's segments calibrated on the other folds'
    windows."""
    segments = cross_fitted([np.concatenate(f.predictions.segment_pred) for f in folds],
                            [(f.window_pred, f.window_true) for f in folds])
    pooled = Predictions()
    for fold, calibrated in zip(folds, segments, strict=True):
        p = fold.predictions
        pooled.add(np.concatenate(p.frame_pred), np.concatenate(p.frame_true), calibrated,
                   np.concatenate(p.segment_true))
    return pooled


def evaluate(model: CoverageModel, samples: list[ProcedureSamples],
             predictions: Predictions | None = None) -> Predictions:
    """Predictions with their truth on each procedure (appended to `predictions` if given)."""
    predictions = Predictions() if predictions is None else predictions
    for s in samples:
        frame, segment = predict(model, s)
        predictions.add(frame, s.frame_labels, segment, s.segment_labels)
    return predictions


def load_samples(data: list[Path], config: CoverageConfig, depth_checkpoint: Path,
                 progress: bool = False, device: torch.device | str = "cpu",
                 frames_only: bool = False) -> list[ProcedureSamples]:
    """Samples of every simulated procedure under the given paths (the depth network on
    `device`); frames_only: for the per-frame network alone (procedure_samples)."""
    paths = expand_inputs(data)
    depth_model = None
    if config.input_depth == "predicted" or config.travel_gap or \
            config.field_of_view == "predicted":
        depth_model = load_depth_model(depth_checkpoint, device=device)
    tag = file_tag(depth_checkpoint)
    return [procedure_samples(p, config, depth_model, tag, progress, frames_only)
            for p in tqdm(paths, desc="inputs and labels", disable=not progress)]


def check_no_shared_colon(data: list[Path], frame_data: list[Path]) -> None:
    """Refuse two procedures drawn from the same seed, index and colon settings: the same
    colon (whatever the style or frame step), so that one colon could lie on both sides of a
    fold of `data`, or a held-out one of `data` among the per-frame procedures `frame_data`
    that every model trains on. A procedure given twice is refused as well."""
    seen: dict[str, Path] = {}
    for path in expand_inputs(data) + expand_inputs(frame_data):
        meta = Procedure.open(path).meta
        key = json.dumps([meta.get("seed"), meta.get("index"), meta.get("config", {}).get("colon")],
                         sort_keys=True)
        if key in seen:
            raise InputError(f"{path} has the colon of {seen[key]} (same seed, index and colon "
                             f"settings): give each procedure once, and simulate procedures of "
                             f"other styles or frame steps with another --seed")
        seen[key] = path


def recorded_config(record: dict) -> CoverageConfig:
    """The config of a run's record. Runs recorded before the `calibrate` field calibrated
    exactly when their CV metrics hold an `uncalibrated` entry."""
    fields = dict(record["config"])
    fields.setdefault("calibrate", "uncalibrated" in record.get("cv_metrics", {}))
    return CoverageConfig.from_dict(fields)


def load_run(run: Path, progress: bool = False, with_samples: bool = True
             ) -> tuple[dict, CoverageConfig, list[ProcedureSamples], list[np.ndarray]]:
    """A `train_coverage` run's record, config, samples and fold split (held-out indices), its
    depth model checked against the record; with_samples=False loads no samples (an empty
    list; `run_samples` loads them later)."""
    record = json.loads((Path(run) / "record.json").read_text())
    config = recorded_config(record)
    folds = fold_split(len(record["procedures"]), config.folds, config.seed)
    depth = Path(record["depth_checkpoint"]["path"])
    if file_tag(depth) != record["depth_checkpoint"]["sha256_12"]:
        raise InputError(f"{depth} is no longer the depth model {run} was trained on")
    samples = run_samples(run, record, config, progress) if with_samples else []
    return record, config, samples, folds


def run_samples(run: Path, record: dict, config: CoverageConfig, progress: bool = False
                ) -> list[ProcedureSamples]:
    """The samples of the procedures a run's record names, checked against it."""
    samples = load_samples([Path(p) for p in record["data"]], config,
                           Path(record["depth_checkpoint"]["path"]), progress)
    if [s.name for s in samples] != record["procedures"]:
        raise InputError(f"the procedures under {record['data']} are no longer those of {run}")
    return samples


def train_coverage(data: list[Path], out: Path, config: CoverageConfig,
                   depth_checkpoint: Path, progress: bool = True,
                   device: torch.device | str = "cpu", frame_data: list[Path] = ()) -> Path:
    """Cross-validate, then train on everything, on `device`; returns the final model's
    path. The procedures under frame_data train the per-frame network of every model and are
    never held out."""
    out = W.make_folder(out)
    record_path = out / "record.json"
    previous = json.loads(record_path.read_text()) if record_path.is_file() else {}
    if previous and recorded_config(previous) != config:
        raise InputError(f"{out} holds a run with another config; resume it with the same "
                         f"options or use another --out")
    started = time.time()
    check_no_shared_colon(data, frame_data)
    samples = load_samples(data, config, depth_checkpoint, progress, device)
    frame_samples = load_samples(frame_data, config, depth_checkpoint, progress, device,
                                 frames_only=True) if frame_data else []
    if previous and (previous["procedures"] != [s.name for s in samples]
                     or previous.get("frame_procedures", []) != [s.name for s in frame_samples]
                     or previous["depth_checkpoint"]["sha256_12"] != file_tag(depth_checkpoint)):
        raise InputError(f"{out} holds a run on other procedures or another depth model; use "
                         f"another --out")
    record = {"config": config.to_dict(), "data": [str(p) for p in data],
              "procedures": [s.name for s in samples],
              "frame_data": [str(p) for p in frame_data],
              "frame_procedures": [s.name for s in frame_samples],
              "depth_checkpoint": {"path": str(depth_checkpoint),
                                   "sha256_12": file_tag(depth_checkpoint)},
              "seconds": {**previous.get("seconds", {}),
                          "inputs_and_labels": round(time.time() - started, 1)}}
    W.write_json(record_path, record)
    log_file = (out / "train_log.jsonl").open("a")

    def log(entry: dict, fold: str = "all") -> None:
        log_file.write(json.dumps({"fold": fold, **entry}) + "\n")
        log_file.flush()

    folds = []
    for k, held in enumerate(fold_split(len(samples), config.folds, config.seed)):
        path = out / f"fold-{k}.safetensors"
        train = [s for i, s in enumerate(samples) if i not in set(held)]
        if path.is_file():
            model = load_coverage_model(path, device=device)
        else:
            tic = time.time()
            model = fit_model(train, config, lambda e, k=k: log(e, str(k)), progress, device,
                              frame_samples)
            model.depth_tag = record["depth_checkpoint"]["sha256_12"]
            model.save(path)
            record["seconds"][f"fold_{k}"] = round(time.time() - tic, 1)
        folds.append(fold_predictions(model, [samples[i] for i in held], progress))
    table = identity_table()
    if folds:
        raw = Predictions()
        for fold in folds:
            raw.extend(fold.predictions)
        cv, other = (calibrated_cv(folds), raw) if config.calibrate else (raw, calibrated_cv(folds))
        other_name = "uncalibrated" if config.calibrate else "calibrated"
        metrics = {**coverage_metrics(cv), other_name: coverage_metrics(other)}
        record["cv_metrics"] = metrics
        W.write_json(out / "cv_metrics.json", metrics)
        scatter_plots(cv, out / "cv_scatter.png",
                      f"{config.folds}-fold cross-validation by procedure ({len(samples)} "
                      f"procedures)")
        logger.info("\n%s", format_table({f"{config.folds}-fold CV": metrics,
                                          other_name: metrics[other_name]}))
        if config.calibrate:
            table = fit_table(np.concatenate([f.window_pred for f in folds]),
                              np.concatenate([f.window_true for f in folds]))
    elif config.calibrate:
        logger.warning("no cross-validation (folds=%d): the segment coverage is left "
                       "uncalibrated", config.folds)
    final = out / "model.safetensors"
    if final.is_file():
        model = load_coverage_model(final, device=device)
    else:
        tic = time.time()
        model = fit_model(samples, config, log, progress, device, frame_samples)
        record["seconds"]["final"] = round(time.time() - tic, 1)
    model.segment.calibration.copy_(torch.from_numpy(table))
    model.depth_tag = record["depth_checkpoint"]["sha256_12"]
    model.save(final)
    record["seconds"]["total_this_call"] = round(time.time() - started, 1)
    W.write_json(record_path, record)
    log_file.close()
    return final
