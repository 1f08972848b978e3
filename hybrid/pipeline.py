"""The whole C2D2 pipeline on one recorded video, stage by stage, in a work directory.

[lens] -> ingest -> depth (learned depth, K, relative poses) -> [self-calibration] -> pose
graph (the relative poses refined by RGB-D odometry, then smoothed) -> reconstruction (scale,
TSDF mesh, lumen) -> geometric coverage (+ unrolled maps) -> learned coverage -> cross-check
and report. The lens and self-calibration stages run only when asked for
(`RunConfig.find_lens`, `RunConfig.self_calibrate`). Each stage writes
its files (hybrid.workdir) atomically and is skipped when they exist, so an interrupted run
resumes where it stopped. Long arrays (frames, depth) are written
and read in blocks (hybrid.npyio), so memory does not grow with the video's length.

Segments are cut by time (`segment_seconds`) at the video's own frame rate; the per-segment
network, trained on 300 frames at 30 fps, reads each segment's per-frame features resampled to
300 by nearest frame. When the geometric branch cannot run on a video (no surface, no lumen),
its error is recorded and the learned branch still reports.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from fusion.odometry import OdometryConfig, refine_relative_poses
from fusion.posegraph import PoseGraphConfig, smooth_trajectory
from fusion.self_calibration import (
    FIELDS_ADDED,
    SelfCalibration,
    SelfCalibrationConfig,
    calibrate_sequence,
    stretch_spans,
)
from fusion.sfm_baseline import CAMERA_MODEL, FISHEYE_MODEL
from hybrid import __version__
from hybrid import workdir as W
from hybrid.coverage import DELTA_PAIRS_CM, Lumen
from hybrid.crosscheck import cross_check
from hybrid.geometric_coverage import GeometricConfig
from hybrid.ingest import Ingested, ingest, sampled, scan
from hybrid.lens import check_fisheye_fov
from hybrid.lumen_fit import FittedLumen
from hybrid.npyio import NpyRows, NpyWriter
from hybrid.reconstruction import ReconstructionConfig, reconstruct
from hybrid.segment_geometry import LocalSegment, local_segment_coverage, save_maps
from hybrid.types import Camera, InputError, failure_reason, read_mask
from learned.checkpoint import file_tag
from learned.coverage_eval import CLASS_EDGES
from learned.coverage_nets import (
    CoverageModel,
    load_coverage_model,
    normalise_depth,
    region_medians,
    relative_scale,
    resample_features,
)
from learned.frames import (
    NETWORK_INPUT,
    FrameSequence,
    check_fps,
    image_files,
    is_procedure,
)
from learned.infer import aggregate_intrinsics, infer_sequence
from learned.model import DepthModel, load_depth_model
from learned.travel import chain_relative, no_travel, travel_features
from learned.view import hidden_view, known_view, view_values

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunConfig:
    """Everything a run depends on besides the video."""

    depth_checkpoint: str | None = None
    """Depth + motion + intrinsics model (None: the shipped fast one)."""
    coverage_checkpoint: str | None = None
    """Coverage networks (None: the shipped fast ones)."""
    fps: float | None = None
    """Override the video's frame rate (image folders default to 30)."""
    segment_seconds: float = 10.0
    """Segment length."""
    fisheye_fov_deg: float | None = None
    """The video comes through an equidistant fisheye lens that sees this many degrees
    across the image region's width (the endoscope's specification): ingestion resamples
    its frames to a pinhole camera (hybrid.ingest). None: a pinhole video, or one whose lens
    `find_lens` tells."""
    find_lens: bool = False
    """Tell the lens from the video before ingesting it: stretches of it as recorded are mapped
    by structure from motion with a fisheye camera (`lens_search`, minutes a video). A fisheye
    is then resampled as with fisheye_fov_deg, at the angle its stretches agree on, a pinhole
    read as it is, and a video whose stretches do not agree is refused (`LensNotFound`)."""
    lens_search: SelfCalibrationConfig = field(default_factory=lambda: SelfCalibrationConfig(
        min_agreeing=3, camera_model=FISHEYE_MODEL, initial_field_of_view=120.0))
    """Its stretches and the consensus it needs: 3 agreeing, as the self-calibration's, the
    mapper starting from 120 degrees through an equidistant lens."""
    min_usable_fraction: float = 0.5
    """A segment is assessable when at least this fraction of its frames is usable."""
    deficient_below: float = CLASS_EDGES[0]
    """A segment is deficient when its coverage (the branches that ran, combined by
    hybrid.crosscheck.combined_coverage) is below this: the 'mostly not covered' class of the
    3-class bins."""
    geometric_weight: float = 0.5
    """The geometric coverage's weight against the learned one's in the combined coverage, at
    full support (hybrid.crosscheck.combined_coverage): chosen on data/heldout and checked on
    data/heldout2 (docs/pipeline.md, "The branches' weights in the combined coverage")."""
    self_calibrate: bool = False
    """Map stretches of the video by structure from motion (fusion.self_calibration, minutes
    a video) for the field of view of coverage networks trained with field_of_view 'true' and
    view_hidden, which otherwise run with it hidden. The geometric branch keeps the
    intrinsics head's K."""
    self_calibration: SelfCalibrationConfig = field(
        default_factory=lambda: SelfCalibrationConfig(min_agreeing=3))
    """Its stretches, and the consensus it needs: 3 agreeing stretches, the bound chosen on the
    training procedures' self-calibration (docs/coverage.md, "Reading the field of view at
    inference"), where `c2d2 depth --self-calibrate` takes 2, each at a field of view of 60
    degrees or more."""
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    posegraph: PoseGraphConfig = field(default_factory=PoseGraphConfig)
    reconstruction: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    geometric: GeometricConfig = field(default_factory=GeometricConfig)

    def __post_init__(self) -> None:
        check_fps(self.fps)
        if not 0 < self.segment_seconds < math.inf:
            raise InputError(f"segments must last a positive, finite time, got "
                             f"{self.segment_seconds}")
        if self.fisheye_fov_deg is not None:
            check_fisheye_fov(self.fisheye_fov_deg)
            if self.find_lens:
                raise InputError("give either the fisheye's field of view or --find-lens, not "
                                 "both")
        if self.lens_search.camera_model != FISHEYE_MODEL:
            raise InputError(f"the lens is told by the fisheye camera ({FISHEYE_MODEL}), not "
                             f"by {self.lens_search.camera_model}")
        if self.self_calibration.camera_model != CAMERA_MODEL:
            raise InputError(f"the self-calibration's K is a pinhole's ({CAMERA_MODEL}), not "
                             f"{self.self_calibration.camera_model}'s")
        if not (math.isfinite(self.geometric_weight) and self.geometric_weight >= 0):
            raise InputError(f"the geometric coverage's weight must be a finite number, 0 or "
                             f"more, got {self.geometric_weight}")


class LensNotFound(InputError):
    """The lens stage's stretches agree on no lens."""


@dataclass
class Models:
    depth: DepthModel
    coverage: CoverageModel
    tags: dict[str, str]
    """SHA-256 prefixes of the files they were read from: a file replaced at the same path is
    another model, so a work folder records them."""

    @classmethod
    def load(cls, config: RunConfig, device: torch.device | str = "cpu") -> Models:
        """The run's networks, on `device`."""
        from learned.checkpoints import SHIPPED_COVERAGE, SHIPPED_DEPTH

        depth = Path(config.depth_checkpoint or SHIPPED_DEPTH)
        coverage = Path(config.coverage_checkpoint or SHIPPED_COVERAGE)
        coverage_model = load_coverage_model(coverage, device=device)
        if coverage_model.config.input_depth == "true":
            raise InputError(f"{coverage}: these coverage networks read the simulator's depth "
                             f"(an ablation), which a video does not have; use networks "
                             f"trained on the depth network's output (input_depth 'predicted')")
        reads_view = coverage_model.config.field_of_view == "true"
        if reads_view and not coverage_model.config.view_hidden:
            raise InputError(f"{coverage}: these coverage networks always read the simulator's "
                             f"true field of view (an ablation), which a video does not have; "
                             f"use networks trained with field_of_view 'predicted' or 'none', "
                             f"or 'true' with view_hidden")
        if config.self_calibrate and not reads_view:
            raise InputError(f"{coverage}: self-calibration gives the coverage networks the "
                             f"video's field of view, and these networks do not take it "
                             f"(field_of_view {coverage_model.config.field_of_view!r}); use "
                             f"networks trained with field_of_view 'true' and view_hidden, or "
                             f"run without self-calibration")
        coverage_model.check_depth(depth, str(coverage))
        return cls(load_depth_model(depth, device=device), coverage_model,
                   {"depth": file_tag(depth), "coverage": file_tag(coverage)})


def read_region(out: Path) -> np.ndarray:
    """(H, W) bool: the image region a work folder's ingest stage wrote."""
    return read_mask(out / W.REGION, "region")


def read_network_K(out: Path, height: int, width: int) -> np.ndarray:
    """The network's K from a work folder's intrinsics.json, in pixels of its depth maps."""
    data = json.loads((out / W.INTRINSICS).read_text())
    return Camera(width, height, **data["network"]).K


def segment_frame_count(config: RunConfig, fps: float) -> int:
    """Frames per segment at the video's rate (at least 2)."""
    return max(2, round(config.segment_seconds * fps))


class _Run:
    """One video's work directory and what its stages share."""

    def __init__(self, source: Path, out: Path, config: RunConfig, models: Models,
                 region: np.ndarray | None, progress: bool):
        self.source, self.out, self.config, self.models = source, out, config, models
        self.region_input, self.progress = region, progress
        self.size = (models.depth.config.height, models.depth.config.width)

    def path(self, name: str) -> Path:
        return self.out / name

    @property
    def ingested(self) -> Ingested:
        return Ingested.load(self.path(W.INGEST))

    @property
    def region(self) -> np.ndarray:
        return read_region(self.out)

    def frames(self) -> NpyRows:
        return NpyRows(self.path(W.FRAMES))

    def depth(self) -> NpyRows:
        return NpyRows(self.path(W.DEPTH))

    def sequence(self) -> FrameSequence:
        """The ingested frames (already cut to the image region and resized)."""
        return FrameSequence.ingested(self.source.name, self.ingested, self.path(W.FRAMES),
                                      self.region)

    @property
    def segment_frames(self) -> int:
        return segment_frame_count(self.config, self.ingested.fps)

    @property
    def travel_gap(self) -> int:
        """The coverage model's travel gap in this video's frames (0: no travel input)."""
        return self.models.coverage.config.travel_frames(self.ingested.fps)

    # --- stages ---------------------------------------------------------------------------

    def lens(self) -> None:
        """`tell_lens` with as many mapping processes as this one has torch threads."""
        found = tell_lens(self.source, self.size, self.config, self.region_input,
                          self.progress, torch.get_num_threads())
        W.write_json(self.path(W.LENS), found.record())

    def lens_found(self) -> SelfCalibration:
        """The lens stage's stretches under the run's rule."""
        return SelfCalibration.from_record(json.loads(self.path(W.LENS).read_text()),
                                           self.config.lens_search)

    def fisheye_fov(self) -> float | None:
        """The fisheye angle across the width that ingestion resamples: the one given, or the
        lens stage's (None for a pinhole; `LensNotFound` without a consensus)."""
        if not self.config.find_lens:
            return self.config.fisheye_fov_deg
        found = self.lens_found()
        if found.lens is None:
            raise LensNotFound(f"{self.source}: its lens could not be told from the video "
                               f"({found.describe()}); give --fisheye-fov DEGREES for a fisheye "
                               f"of known angle, or run without --find-lens to read it as a "
                               f"pinhole, into another --out")
        return found.lens.width_deg if found.lens.model == "equidistant" else None

    def ingest(self) -> None:
        record, region = ingest(self.source, self.size, self.path(W.FRAMES), self.region_input,
                                self.config.fps, self.progress, self.fisheye_fov())
        W.write_png(self.path(W.REGION), region.astype(np.uint8) * 255)
        record.save(self.path(W.INGEST))  # last: its presence marks the stage complete

    def check_length(self) -> None:
        record = self.ingested
        if record.frames < self.segment_frames:
            raise InputError(f"{self.source}: {record.frames} frames at {record.fps:g} fps "
                             f"({record.frames / record.fps:.1f} s) is shorter than one "
                             f"{self.config.segment_seconds:g}-s segment")

    def short_segments(self) -> str | None:
        """A warning where a segment holds no more frames than the coverage model's travel
        input spans: each frame's travel is then read mostly outside its segment."""
        hops = max(1, self.models.coverage.config.travel_hops)
        if self.segment_frames > self.travel_gap * hops:
            return None
        return (f"a {self.config.segment_seconds:g}-s segment holds {self.segment_frames} "
                f"frames at {self.ingested.fps:g} fps, no more than the coverage model's travel "
                f"input spans ({hops} hops of {self.travel_gap} frames), so each segment's "
                f"learned coverage reads its neighbours' motion; if the frame rate is wrong, "
                f"give the true one (`c2d2 run --fps`), else longer segments")

    def depth_stage(self) -> None:
        seq = self.sequence()
        depth = NpyWriter(self.path(W.DEPTH), (seq.num_frames, *self.size), np.float16)
        gaps = tuple(g for g in sorted({1, *self.config.posegraph.skips, self.travel_gap} - {0})
                     if g < seq.num_frames)
        result = infer_sequence(self.models.depth, seq, gaps, depth_out=depth,
                                progress=self.progress)
        np.savez(self.path(W.RELATIVE + ".partial.npz"),
                 **{f"gap{g}": r for g, r in result.relative.items()})
        self.path(W.RELATIVE + ".partial.npz").replace(self.path(W.RELATIVE))
        intrinsics = aggregate_intrinsics(result.K_pairs, self.size, seq.crop, seq.fps)
        if self.ingested.fisheye_fov_deg is not None:  # K is the resampled frames' pinhole's
            intrinsics["resampled_from_fisheye_fov_deg"] = self.ingested.fisheye_fov_deg
        W.write_json(self.path(W.INTRINSICS), intrinsics)
        depth.close()  # last: its presence marks the stage complete

    def self_calibration(self) -> None:
        """The stretches mapped by as many processes as this one has torch threads (its share
        of the cores in a batch)."""
        found = calibrate_sequence(self.sequence(), self.config.self_calibration, self.progress,
                                   torch.get_num_threads())
        W.write_json(self.path(W.SELF_CALIBRATION), found.record())

    def posegraph(self) -> None:
        with np.load(self.path(W.RELATIVE)) as data:
            relative = {int(k[3:]): data[k] for k in data.files
                        if int(k[3:]) in self.config.posegraph.skips}
        if self.config.odometry.enabled:
            refined = refine_relative_poses(relative, self.depth(), self.frames(),
                                            self.network_K(), self.region, self.config.odometry,
                                            name=str(self.source), progress=self.progress)
            relative = refined.relative
            W.write_json(self.path(W.ODOMETRY), {
                "pairs_kept_unrefined": refined.kept,
                "fitness_p5_median": {g: _percentiles(f, (5, 50))
                                      for g, f in refined.fitness.items()}})
        result = smooth_trajectory(relative, self.config.posegraph, name=str(self.source))
        W.write_json(self.path(W.POSEGRAPH), {
            "initial_error": result.initial_error, "final_error": result.final_error,
            "iterations": result.iterations, "max_iterations": self.config.posegraph.max_iterations,
            "capped_windows_first_frames": result.capped})
        for name, poses in ((W.POSES_RAW, result.chained), (W.POSES, result.poses)):
            W.write_npy(self.path(name), poses)

    def reconstruction(self) -> None:
        frames = self.frames()
        rec = reconstruct(self.depth(), self.network_K(), np.load(self.path(W.POSES)),
                          rgb=frames, region=self.region, config=self.config.reconstruction,
                          fps=self.ingested.fps, name=self.source.name, progress=self.progress)
        rec.mesh.save(self.path(W.MESH))
        rec.lumen.save(self.path(W.LUMEN))
        W.write_json(self.path(W.RECONSTRUCTION), {"scale_cm_per_unit": rec.scale,
                                                   "typical_radius_cm":
                                                       self.config.reconstruction
                                                       .typical_radius_cm})

    def geometric(self) -> None:
        segments = work_segments(self.out, self.config, name=self.source.name)
        if all(s.result is None for s in segments):
            raise InputError(f"no segment could be reconstructed: {segments[0].error}")
        save_maps(segments, self.path(W.MAPS), f"{self.source.name}: wall seen (green) and "
                  f"missed (red) in each segment's V")
        W.write_json(self.path(W.GEOMETRIC), {
            "segments": [{**vars(s.segment), "support": s.support} for s in segments],
            "errors": {str(s.segment.index): s.error for s in segments if s.error}})

    def travel(self, count: int) -> np.ndarray:
        """(N, travel_size): each of the N frames' direction of travel, the coverage model's
        input (and that over `travel_hops` gaps chained, if it reads it)."""
        gap = self.travel_gap
        if not gap:
            return no_travel(count)
        with np.load(self.path(W.RELATIVE)) as data:
            relative = data[f"gap{gap}"] if f"gap{gap}" in data.files else None
        if relative is None:  # a depth stage run for a model without this gap
            relative = infer_sequence(self.models.depth, self.sequence(), (gap,), depth=False,
                                      progress=self.progress).relative[gap]
        withdrawal, name = self.config.reconstruction.lumen.withdrawal, str(self.path(W.RELATIVE))
        travel = [travel_features(relative, count, withdrawal, name=name)]
        if hops := self.models.coverage.config.travel_hops:
            travel.append(travel_features(chain_relative(relative, gap, hops, name), count,
                                          withdrawal, name=name))
        return np.concatenate(travel, axis=1)

    def cues(self, count: int) -> np.ndarray:
        """(N, cue_size): the coverage model's values beside each frame's depth, the travel
        and (if it reads them) the field of view (of the network's intrinsics, or
        `self_calibrated_K` for networks trained on the true one) and the frames' depth scale
        against the video's."""
        config = self.models.coverage.config
        cues = [self.travel(count)]
        if config.field_of_view == "predicted":
            view = view_values(self.network_K(), self.size[1], self.size[0], count,
                               name=str(self.path(W.INTRINSICS)))
            cues.append(known_view(view) if config.view_hidden else view)
        elif config.field_of_view == "true":
            K = self.self_calibrated_K()
            cues.append(hidden_view(count) if K is None else known_view(view_values(
                K, self.size[1], self.size[0], count, name=str(self.path(W.SELF_CALIBRATION)))))
        if config.depth_scale:
            depth = self.depth()
            medians = np.concatenate([
                region_medians(np.asarray(depth[start:start + 512], np.float32), self.region,
                               name=self.source.name)
                for start in range(0, len(depth), 512)])
            cues.append(relative_scale(medians, name=self.source.name))
        return np.concatenate(cues, axis=1)

    def frame_outputs(self, cues: np.ndarray, start: int, stop: int
                      ) -> tuple[np.ndarray, np.ndarray]:
        """Per-frame coverage (n, 3) and features (n, 4, F) of the mirror views of frames
        [start, stop), computed in chunks; cues: every frame's (self.cues)."""
        model = self.models.coverage
        depth = self.depth()
        size = (model.config.height, model.config.width)
        outputs = [model.frame_outputs(normalise_depth(
            np.asarray(depth[first:min(first + 512, stop)], np.float32), self.region, size,
            name=self.source.name, by_median=model.config.median_normalise),
            cues[first:min(first + 512, stop)])
            for first in range(start, stop, 512)]
        return (np.concatenate([o[0] for o in outputs]),
                np.concatenate([o[1] for o in outputs]))

    def learned(self) -> None:
        """Per-frame coverage of every frame, and each full segment's from its own frames'
        features, read one segment at a time: the features of a whole video (a 30-minute one's
        110 MB at the fast preset, 1.8 GB at the paper's) are never held at once."""
        model = self.models.coverage
        count = len(self.depth())
        cues = self.cues(count)
        L, T = self.segment_frames, model.config.segment_frames
        per_frame, segments = [], []
        for start in range(0, count, L):
            stop = min(start + L, count)
            coverage, features = self.frame_outputs(cues, start, stop)
            per_frame.append(coverage)
            if stop - start == L:  # trailing frames get per-frame values only
                value = model.segment_outputs(resample_features(features, L, T), [0])[0]
                segments.append({"index": start // L, "start": start, "stop": stop,
                                 "coverage": float(value)})
        record = {"delta_pairs_cm": [list(p) for p in DELTA_PAIRS_CM],
                  "per_frame": np.concatenate(per_frame).round(5).tolist(),
                  "segments": segments}
        if model.config.field_of_view == "true":
            K = self.self_calibrated_K()
            record["field_of_view"] = {"source": "hidden"} if K is None else {
                "source": "self-calibration", "fx": float(K[0, 0]), "fy": float(K[1, 1])}
        W.write_json(self.path(W.LEARNED), record)

    def report(self) -> None:
        from hybrid.report import write_report

        table = cross_check(self.out, self.ingested, self.config)
        table.save(self.path(W.COVERAGE_JSON), self.path(W.COVERAGE_CSV))
        write_report(self.out, table, self.ingested)

    def network_K(self) -> np.ndarray:
        return read_network_K(self.out, *self.size)

    def self_calibration_record(self) -> SelfCalibration | None:
        """The self-calibration stage's stretches under the run's rule (None when it is off)."""
        if not self.config.self_calibrate:
            return None
        record = json.loads(self.path(W.SELF_CALIBRATION).read_text())
        return SelfCalibration.from_record(record, self.config.self_calibration)

    def view_note(self) -> str:
        """Which field of view networks trained on the true one read in this run, and why."""
        found = self.self_calibration_record()
        if found is None:
            return ("the coverage networks ran without the field of view (--self-calibrate "
                    "gives it them)")
        if found.K is None:
            return (f"self-calibration found no field of view, so the coverage networks ran "
                    f"without it: {found.describe()}")
        return "the coverage networks read the self-calibrated field of view"

    def self_calibrated_K(self) -> np.ndarray | None:
        """K at the networks' size where the self-calibration's stretches agree, else None."""
        found = self.self_calibration_record()
        return None if found is None else found.K


def tell_lens(source: Path, size: tuple[int, int], config: RunConfig,
              region: np.ndarray | None = None, progress: bool = False, workers: int = 1
              ) -> SelfCalibration:
    """The lens stage: the stretches of `config.lens_search` of an input as recorded (read
    once to find its image region, or given it in input pixels, then as far as the last
    stretch), at the networks' `size`, mapped with the fisheye camera."""
    scanned = scan(source, region, config.fps, progress)
    search = config.lens_search
    frames = sampled(scanned, size, [i for span in stretch_spans(scanned.count, search)
                                     for i in span])
    return calibrate_sequence(frames, search, progress, workers)


def _percentiles(values: np.ndarray, q: tuple[float, ...]) -> list[float] | None:
    """The q-th percentiles of the finite values, rounded (None if there are none)."""
    values = values[np.isfinite(values)]
    return np.percentile(values, q).round(4).tolist() if values.size else None


def video_features(source: Path, work: Path, config: RunConfig, models: Models,
                   progress: bool = True) -> tuple[np.ndarray, int]:
    """The lens (if on), ingest, depth and self-calibration (if on) stages of `run_video`
    (resumable, in `work`), then the per-frame coverage features (N, 4, F); returns them with
    the frames per segment."""
    source, work = Path(source), Path(work)
    _prepare(work, config, source, models, None)
    run = _Run(source, work, config, models, None, progress)
    if config.find_lens and not (work / W.LENS).is_file():
        run.lens()
    if not (work / W.INGEST).is_file():
        run.ingest()
    run.check_length()
    if not (work / W.DEPTH).is_file():
        run.depth_stage()
    if config.self_calibrate and not (work / W.SELF_CALIBRATION).is_file():
        run.self_calibration()
    count = len(run.depth())
    return run.frame_outputs(run.cues(count), 0, count)[1], run.segment_frames


GEOMETRIC_STAGES = ("posegraph", "reconstruction", "geometric")


def work_segments(out: Path, config: RunConfig, context: int | None = None,
                  window_scale: bool = False, name: str = "video") -> list[LocalSegment]:
    """Each segment's geometric coverage from a work folder, as the geometric stage computes
    it: its depth, network K, image region and smoothed poses, each segment on its own window
    (poses drift) of `context` frames either side (None: half a segment), at the whole
    video's metric scale from the reconstruction stage (the radius rule reads more wall over
    the whole video than over one window), or with window_scale at each window's own rule;
    each window's lumen oriented by its cameras' ℓ on the whole video's lumen, so that a
    window where the camera pushes in for longer than it withdraws is not read backwards."""
    ingested = Ingested.load(out / W.INGEST)
    depth = NpyRows(out / W.DEPTH)
    frames = segment_frame_count(config, ingested.fps)
    poses = np.load(out / W.POSES)
    whole_scale = json.loads((out / W.RECONSTRUCTION).read_text())["scale_cm_per_unit"]
    along, _ = Lumen(FittedLumen.load(out / W.LUMEN).points).project(
        poses[:, :3, 3] * whole_scale)
    return local_segment_coverage(depth, read_network_K(out, *np.asarray(depth[0]).shape),
                                  poses, frames, frames // 2 if context is None else context,
                                  read_region(out), config.reconstruction, config.geometric,
                                  ingested.fps, name,
                                  scale=None if window_scale else whole_scale, along=along)


def run_video(source: Path, out: Path, config: RunConfig = RunConfig(),
              models: Models | None = None, region: np.ndarray | None = None,
              progress: bool = True, echo: Callable[[str], None] = log.info) -> dict:
    """Run (or resume) every stage; returns {'timing': seconds per stage, 'warnings': [...]}.

    Raises InputError for bad input; a geometric-branch failure is recorded, not raised.
    Warnings (results written but incomplete or doubtful): segments no longer than the travel
    input spans, frames that did not decode, a geometric branch
    that could not run, frame pairs the RGB-D odometry could not align, a pose graph stopped at
    its iteration cap. Notes: the frame rate an image folder is read at unless given; trailing
    frames that do not fill a segment get no verdict; for networks that read a self-calibrated
    field of view, whether they had one.
    """
    source, out = Path(source), Path(out)
    models = models or Models.load(config)
    _prepare(out, config, source, models, region)
    run = _Run(source, out, config, models, region, progress)
    stages: list[tuple[str, Callable[[], None], list[str]]] = [
        *([("lens", run.lens, [W.LENS])] if config.find_lens else []),
        ("ingest", run.ingest, [W.FRAMES, W.INGEST, W.REGION]),
        ("depth", run.depth_stage, [W.DEPTH, W.RELATIVE, W.INTRINSICS]),
        *([("self-calibration", run.self_calibration, [W.SELF_CALIBRATION])]
          if config.self_calibrate else []),
        ("posegraph", run.posegraph, [W.POSES]),
        ("reconstruction", run.reconstruction, [W.RECONSTRUCTION]),
        ("geometric", run.geometric, [W.GEOMETRIC]),
        ("learned", run.learned, [W.LEARNED]),
        ("report", run.report, [W.REPORT]),
    ]
    timing_path = out / W.TIMING
    timing = json.loads(timing_path.read_text()) if timing_path.is_file() else {}
    geometric_error = out / W.GEOMETRIC_ERROR
    for name, stage, outputs in stages:
        if all((out / o).exists() for o in outputs):
            echo(f"{name}: done before, skipped")
        elif not (name in GEOMETRIC_STAGES and geometric_error.is_file()):
            tic = time.time()
            try:
                stage()
            except Exception as err:  # the geometric branch's failure must not stop the video
                if name not in GEOMETRIC_STAGES:
                    raise
                W.write_text(geometric_error, f"{name}: {failure_reason(err)}\n")
            finally:
                timing[name] = round(time.time() - tic, 2)
                W.write_json(timing_path, timing)
            rate = ("" if not (out / W.INGEST).is_file() else
                    f" ({run.ingested.frames / max(timing[name], 1e-9):.0f} frames/s)")
            echo(f"{name}: {timing[name]:.1f} s{rate}")
        if name == "lens":
            echo(f"note: the lens from the video: {run.lens_found().describe()}")
        if name == "ingest":
            run.check_length()
    warnings = [short] if (short := run.short_segments()) else []
    if run.ingested.decode_warning:
        warnings.append(run.ingested.decode_warning)
    if geometric_error.is_file():
        warnings.append(f"geometric branch failed at {geometric_error.read_text().strip()}")
    elif (out / W.GEOMETRIC).is_file():  # the learned value alone makes these verdicts
        for index, reason in json.loads((out / W.GEOMETRIC).read_text()).get("errors", {}).items():
            echo(f"note: the geometric branch gives segment {index} no value: {reason}")
    if models.coverage.config.field_of_view == "true":
        echo(f"note: {run.view_note()}")
    if (out / W.ODOMETRY).is_file():
        kept = json.loads((out / W.ODOMETRY).read_text())["pairs_kept_unrefined"]
        if any(kept.values()):
            warnings.append(f"RGB-D odometry could not align {sum(kept.values())} frame pairs "
                            f"(per gap: {kept}); they keep the network's relative pose")
    if (out / W.POSEGRAPH).is_file():
        record = json.loads((out / W.POSEGRAPH).read_text())
        if capped := record["capped_windows_first_frames"]:
            warnings.append(f"the pose graph stopped at its cap of {record['max_iterations']} "
                            f"iterations in {len(capped)} window(s) (first frames {capped[:10]}) "
                            f"before converging; those poses are less smoothed than the graph "
                            f"allows (to raise the cap: PoseGraphConfig.max_iterations, in "
                            f"RunConfig.posegraph through the Python API, into a new work "
                            f"folder)")
    if note := frame_rate_note(source, config, run.ingested.fps):
        echo(note)
    dropped = run.ingested.frames % run.segment_frames
    if dropped:
        echo(f"note: the last {dropped} frames ({dropped / run.ingested.fps:.1f} s) do not fill "
             f"a {config.segment_seconds:g}-s segment and have no verdict")
    return {"timing": timing, "warnings": warnings}


def frame_rate_note(source: Path, config: RunConfig, fps: float) -> str | None:
    """A note for an image folder read at a rate it was not given (it carries none)."""
    if not source.is_dir() or config.fps is not None or is_procedure(source):
        return None
    return (f"note: {source} is a folder of images, which carries no frame rate: read at "
            f"{fps:g} frames/s, so its times and segments are right only at that rate (give "
            f"the true one with --fps)")


def _source_identity(source: Path) -> dict:
    """What a work folder ran on: the path, and a video file's size, or a folder's content (a
    simulated procedure's meta.json, else the names and sizes of its images), so that a video
    simulated or copied again to the same place is not taken for the one already run."""
    identity = {"path": str(source.resolve()),
                "size": source.stat().st_size if source.is_file() else None}
    if source.is_dir():
        meta = source / "meta.json"
        if meta.is_file():
            identity["content"] = file_tag(meta)
        else:
            listing = "\n".join(f"{p.name} {p.stat().st_size}" for p in image_files(source))
            identity["content"] = hashlib.sha256(listing.encode()).hexdigest()[:12]
    return identity


def _differing(before: dict, now: dict, prefix: str = "") -> str:
    """The settings in which a work folder's configuration differs from the run's (those of
    a group both record, such as self_calibration, by name)."""
    names = []
    for key in sorted(before.keys() | now.keys()):
        if key in now and before.get(key) == now[key]:
            continue
        if isinstance(before.get(key), dict) and isinstance(now.get(key), dict):
            names.append(_differing(before[key], now[key], f"{prefix}{key}."))
        else:
            names.append(f"{prefix}{key}" if key in before else f"{prefix}{key}, which it does "
                         f"not record (a setting added to c2d2 since it was made, or one it did "
                         f"not use)")
    return "; ".join(names)


SETTINGS_ADDED = {"self_calibrate": False, "fisheye_fov_deg": None, "find_lens": False}
"""Settings added to RunConfig since work folders were first made, each with the value that
computes what runs made before it did: a folder that does not record one was made with it."""


def made_with(recorded: dict) -> dict:
    """A folder's recorded config with the settings added since filled in as it was made
    (those of self_calibration and lens_search by `fusion.self_calibration.FIELDS_ADDED`)."""
    config = {**SETTINGS_ADDED, **recorded}
    for group in ("self_calibration", "lens_search"):
        if group in config:
            config[group] = {**FIELDS_ADDED, **config[group]}
    return config


def recorded_config(config: RunConfig) -> dict:
    """The configuration as config.json records it (the self-calibration's and the lens
    search's stretches only when they are on)."""
    recorded = json.loads(json.dumps(asdict(config)))
    if not config.self_calibrate:
        del recorded["self_calibration"]
    if not config.find_lens:
        del recorded["lens_search"]
    return recorded


def _region_tag(region: np.ndarray | None) -> str | None:
    """A given image region's identity (its shape and pixels), None when it is detected."""
    if region is None:
        return None
    region = np.asarray(region, bool)
    return hashlib.sha256(f"{region.shape}".encode() + np.packbits(region).tobytes()
                          ).hexdigest()[:12]


def _prepare(out: Path, config: RunConfig, source: Path, models: Models,
             region: np.ndarray | None) -> None:
    """Create the work directory; refuse one that holds a run of another video, image region
    (--mask), config or model files, and a simulated procedure with a frame rate or mask."""
    W.check_not_input(out, source)
    if not (out / W.CONFIG).is_file():  # a new run: refused before anything is written (a
        # folder holding a run says first how the options differ from its own)
        is_procedure(source, config.fps, region)
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as err:
        raise InputError(f"cannot write to the output folder {out}: {err.strerror}; choose "
                         f"another --out") from err
    saved = out / W.CONFIG
    identity = _source_identity(source)
    resolved = {"config": recorded_config(config), "source": identity,
                "region": _region_tag(region), "checkpoints": models.tags,
                "network_input": NETWORK_INPUT, "c2d2_version": __version__}
    if saved.is_file():
        previous = json.loads(saved.read_text())
        before = previous.get("source", {}).get("path")
        if before != identity["path"]:
            raise InputError(f"{out} holds a run of {before}, not of {source}; use another "
                             f"--out")
        if previous["source"] != identity:
            why = ("it, or the order in which c2d2 reads an image folder, has changed since"
                   if "content" in previous["source"] or "content" not in identity else
                   "the run is by an earlier c2d2")
            raise InputError(f"{out} holds a run of {source} as it was before ({why}); use "
                             f"another --out or delete it to start again")
        if previous.get("region") != resolved["region"]:  # runs before it was kept: detected
            def told(tag: str | None) -> str:
                return ("detected from the frames" if tag is None else
                        f"given by a mask (SHA-256 prefix {tag})")

            before = (told(previous["region"]) if "region" in previous else
                      "not recorded (a run by an earlier c2d2, taken as detected)")
            raise InputError(f"{out} holds a run whose image region was {before}, not "
                             f"{told(resolved['region'])}; use another --out or delete it to "
                             f"start again")
        before_config = made_with(previous.get("config") or {})
        if before_config != resolved["config"]:
            raise InputError(f"{out} holds a run made with another configuration (it differs "
                             f"in {_differing(before_config, resolved['config'])}); use another "
                             f"--out or delete it to start again")
        if "checkpoints" not in previous:
            raise InputError(f"{out} holds a run by an earlier c2d2 that did not record its "
                             f"model files, so it cannot be resumed safely; use another --out "
                             f"or delete it to start again")
        if previous["checkpoints"] != models.tags:
            raise InputError(f"{out} holds a run made with other model checkpoints (SHA-256 "
                             f"prefixes {previous['checkpoints']}, now {models.tags}); use "
                             f"another --out or delete it to start again")
        if previous.get("network_input") != NETWORK_INPUT:
            if ((out / W.DEPTH).is_file() and (out / W.REGION).is_file()
                    and not read_region(out).all()):
                before = previous.get("network_input", "black")
                raise InputError(f"{out} holds a run by an earlier c2d2 whose networks read "
                                 f"the border around its image region otherwise (\"{before}\"; "
                                 f"now \"{NETWORK_INPUT}\"); use another --out or delete it "
                                 f"to start again")
            W.write_json(saved, previous | {"network_input": NETWORK_INPUT})  # nothing differs
    elif source.exists():
        W.write_json(saved, resolved)
