"""Inputs and labels of the coverage networks, per simulated procedure, cached on disk.

The per-frame input is the depth network's output on the procedure's RGB (what inference sees),
or the simulator's depth for the ablation, normalised by `normalise_depth`, and the cues beside
it: the direction of travel from the motion network (learned.travel; the procedures are
withdrawals) and, if asked for, the field of view of the motion network's intrinsics or of the
simulator's camera (learned.view) and each frame's depth scale against the procedure's
(`relative_scale`, from the per-frame medians of the same depth). Labels: the
per-frame coverage of coverage.json for the three Δ pairs, the default-pair coverage of
overlapping training windows (the exact ground truth: written by the simulator, or computed
here) and of the back-to-back segments of coverage.json (used for evaluation).

Cache files sit in the procedure's `cache/` folder, named by what they depend on, and are
written atomically.
"""

from __future__ import annotations

import functools
import hashlib
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hybrid.coverage import Lumen, compute_coverage, pair_key
from hybrid.dataset import Procedure, window_labels_path
from hybrid.types import InputError
from learned.config import CoverageConfig
from learned.coverage_nets import normalise_depth, region_medians, relative_scale
from learned.frames import NETWORK_INPUT, FrameSequence, open_sequence
from learned.infer import DepthOutput, infer_sequence
from learned.model import DepthModel
from learned.train import input_name
from learned.travel import chain_relative, no_travel, travel_features
from learned.view import known_view, view_values


@dataclass
class ProcedureSamples:
    """Everything the coverage networks train and evaluate on, for one procedure."""

    name: str
    inputs: np.ndarray
    """(N, 1, h, w) float16 normalised depth."""
    travel: np.ndarray
    """(N, travel_size) float32 direction of travel and log relative speed."""
    view: np.ndarray
    """(N, 2 or 0) float32 field-of-view values (learned.view), the same for every frame."""
    scale: np.ndarray
    """(N, 1 or 0) float32 depth scale against the procedure's (relative_scale)."""
    frame_labels: np.ndarray
    """(N, 3) float32 per-frame coverage per Δ pair, NaN where undefined."""
    window_starts: np.ndarray
    """(W,) first frames of the overlapping training windows."""
    window_labels: np.ndarray
    """(W,) their default-pair coverage (NaN where undefined)."""
    segment_starts: np.ndarray
    """(S,) first frames of the back-to-back segments of coverage.json."""
    segment_labels: np.ndarray
    """(S,) their default-pair coverage."""

    @property
    def cues(self) -> np.ndarray:
        """(N, cue_size) per-frame network values beside the depth: travel, view, scale."""
        return np.concatenate([self.travel, self.view, self.scale], axis=1)


_BORDER_TAG = hashlib.sha256(NETWORK_INPUT.encode()).hexdigest()[:8]
"""How the networks read an image region's border (`NETWORK_INPUT`), in a bordered procedure's
cache names: caches made while they read it otherwise are not taken."""


def procedure_samples(path: Path, config: CoverageConfig, depth_model: DepthModel | None,
                      depth_tag: str, progress: bool = False,
                      frames_only: bool = False) -> ProcedureSamples:
    """Inputs and labels of one simulated procedure (from its cache when present).

    depth_tag names the depth model (e.g. a hash of its checkpoint) in the cache file name.
    frames_only: samples for the per-frame network alone, with no windows or segments; the
    procedure may then keep every k-th frame (`c2d2 simulate --frame-step k`, k dividing the
    travel gap), its travel then read over the same time as at the full rate.
    """
    proc = Procedure.open(path)
    if config.field_of_view == "true" and proc.camera.model != "pinhole":
        raise InputError(f"{proc.path}: the true field-of-view input is a pinhole camera's; "
                         f"this procedure's is {proc.camera.model} (field_of_view 'none' or "
                         f"'predicted' read it)")
    truth = proc.coverage
    T, stride = config.segment_frames, config.segment_stride
    step = config.frame_rate / proc.camera.fps  # frames of the training rate per frame here
    if frames_only and not (step.is_integer() and step >= 1 and config.travel_gap % step == 0):
        raise InputError(f"{proc.path}: {proc.camera.fps:g} fps; per-frame samples need "
                         f"{config.frame_rate:g} fps divided by a whole number that divides "
                         f"the travel gap of {config.travel_gap} frames")
    if not frames_only and proc.camera.fps != config.frame_rate:
        raise InputError(f"{proc.path}: {proc.camera.fps:g} fps, the coverage networks train "
                         f"on {config.frame_rate:g} fps")
    if not frames_only and truth.segment_frames != T:
        raise InputError(f"{proc.path}: its segments are {truth.segment_frames} frames, the "
                         f"coverage networks' are {T}")
    gap = config.travel_frames(proc.camera.fps)
    cache = proc.path / "cache"
    size = f"{config.height}x{config.width}" + ("" if config.median_normalise else "-log")
    predicted = config.input_depth != "true"
    # A bordered procedure's caches also name how the networks read the border (the depth
    # network's frames since the fifty-fifth session, the coverage input since the fifty-seventh)
    border = "" if proc.region.all() else f"-border{_BORDER_TAG}"
    depth_name = (depth_tag if predicted else "true") + border
    inputs_path = cache / f"input-{depth_name}-{size}.npy"
    medians_path = cache / f"medians-{depth_name}.npy"
    relative_path = cache / f"relative-{depth_tag}{border}-{gap}.npy"
    view_path = cache / f"view-{depth_tag}{border}.npy"
    # One pass of the depth model for whichever of its caches are missing: the travel's pairs,
    # and consecutive pairs for the view (their median K, as `c2d2 run`'s intrinsics.json).
    missing_depth = predicted and not (inputs_path.is_file() and (
        medians_path.is_file() or not config.depth_scale))
    gaps = {gap} if gap and not relative_path.is_file() else set()
    if config.field_of_view == "predicted" and not view_path.is_file():
        gaps.add(1)
    network = functools.cache(lambda: _network_outputs(proc, depth_model, missing_depth,
                                                       tuple(gaps), progress))
    depth = functools.cache(lambda: _predicted_depth(*network()) if predicted
                            else true_depth(proc))
    inputs = _cached(inputs_path, lambda: normalise_depth(
        *depth(), (config.height, config.width), name=str(proc.path),
        by_median=config.median_normalise).astype(np.float16))
    if config.depth_scale:
        scale = relative_scale(_cached(medians_path, lambda: region_medians(*depth())),
                               name=str(proc.path))
    else:
        scale = np.zeros((len(inputs), 0), dtype=np.float32)
    if gap:
        relative = _cached(relative_path, lambda: network()[1].relative[gap])
        travel = travel_features(relative, len(inputs), name=str(proc.path))
        if config.travel_hops:
            chained = chain_relative(relative, gap, config.travel_hops, name=str(proc.path))
            travel = np.concatenate([travel, travel_features(chained, len(inputs),
                                                             name=str(proc.path))], axis=1)
    else:
        travel = no_travel(len(inputs))
    if config.field_of_view == "none":
        view = np.zeros((len(inputs), 0), dtype=np.float32)
    else:
        camera = proc.camera
        values = (_cached(view_path, lambda: _predicted_view(*network()))
                  if config.field_of_view == "predicted"
                  else view_values(camera.K, camera.width, camera.height, 1, str(proc.path))[0])
        view = np.tile(values, (len(inputs), 1))
        if config.view_hidden:
            view = known_view(view)
    labels = np.array([[np.nan if v is None else v for v in truth.per_frame[pair_key(p)]]
                       for p in truth.delta_pairs], dtype=np.float32).T
    if frames_only:
        windows, segment_starts, segment_labels = np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    else:
        windows = window_labels(proc, T, stride, progress)
        segment_starts = np.array([s.start for s in truth.segments])
        segment_labels = truth.segment_labels()
    return ProcedureSamples(
        name=input_name(proc.path), inputs=inputs, travel=travel,
        view=view, scale=scale, frame_labels=labels,
        window_starts=windows[:, 0].astype(int), window_labels=windows[:, 1],
        segment_starts=segment_starts.astype(int), segment_labels=segment_labels)


def true_depth(proc: Procedure, frames: Sequence[int] | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's depth (N, H, W) of all frames, or of the given ones, and the
    procedure's image region (the ablation)."""
    frames = range(proc.num_frames) if frames is None else frames
    depth = np.stack([proc.depth(i) for i in frames])
    # No surface (looking out of the open rectum end): as far as the frame's farthest wall.
    depth = np.where(depth > 0, depth, depth.max(axis=(1, 2), keepdims=True))
    return depth, proc.region


def _network_outputs(proc: Procedure, depth_model: DepthModel | None, depth: bool,
                     gaps: tuple[int, ...], progress: bool) -> tuple[FrameSequence, DepthOutput]:
    """The procedure's frames and, in one pass, the depth model's depth (if `depth`) and
    relative poses of the frame pairs (t, t + g) for each gap g, with the intrinsics of the
    smallest gap's pairs."""
    if depth_model is None:
        raise InputError("predicted-depth inputs and the travel and predicted field-of-view "
                         "inputs need a depth model")
    seq = open_sequence(proc.path, (depth_model.config.height, depth_model.config.width))
    return seq, infer_sequence(depth_model, seq, gaps, depth=depth, progress=progress)


def _predicted_depth(seq: FrameSequence, output: DepthOutput) -> tuple[np.ndarray, np.ndarray]:
    """The depth model's depth (N, H, W) and the frames' image region."""
    return output.depth, seq.region


def _predicted_view(seq: FrameSequence, output: DepthOutput) -> np.ndarray:
    """(2,) field-of-view values of the median K of the depth model's pairs."""
    return view_values(np.median(output.K_pairs, axis=0), seq.size[1], seq.size[0], 1,
                       seq.name)[0]


def window_labels(proc: Procedure, frames: int, stride: int, progress: bool = False
                  ) -> np.ndarray:
    """(W, 2): start frame and default-pair coverage of every window of `frames` frames
    starting every `stride`, from the exact ground truth (cached; `c2d2 simulate` writes
    them for the coverage networks' windows)."""
    return _cached(window_labels_path(proc.path, frames, stride), lambda: compute_coverage(
        proc.mesh(), Lumen(proc.lumen), proc.poses, proc.camera, frames, progress=progress,
        segment_stride=stride, region=proc.region).window_table())


def _cached(path: Path, make) -> np.ndarray:
    if path.is_file():
        return np.load(path)
    array = make()
    path.parent.mkdir(exist_ok=True)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp.npy")  # one per process filling it
    np.save(tmp, array)
    os.replace(tmp, path)
    return array
