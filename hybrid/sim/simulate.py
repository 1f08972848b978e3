"""Simulate procedures to disk: colon, camera, withdrawal, rendered frames, ground truth.

Reads nothing; writes one procedure folder per index in the format of `hybrid.dataset`.
The procedure with index i of seed s depends only on (s, i) and the config (camera_seed
included), so a dataset can be extended or resumed and stays identical.
"""

from __future__ import annotations

import json
import logging
import shutil
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import trimesh
from tqdm import tqdm

from hybrid import __version__
from hybrid import workdir as W
from hybrid.coverage import Lumen, SurfaceMesh, compute_coverage
from hybrid.dataset import (
    REGION_FILE,
    REQUIRED_FILES,
    frame_name,
    window_labels_path,
    write_depth,
    write_region,
    write_rgb,
)
from hybrid.sim.appearance import get_style, make_texture
from hybrid.sim.colon import Colon, ColonConfig, make_colon
from hybrid.sim.render import ColonRenderer
from hybrid.sim.trajectory import TrajectoryConfig, make_withdrawal
from hybrid.types import PRESET_IMAGE_SIZE, Camera, InputError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SimConfig:
    """Everything that defines a simulated dataset besides the seed."""

    preset: str = "fast"
    """Image size preset: 'fast' (128x160) or 'paper' (320x384), height x width."""
    style: str = "pink"
    """Appearance style (see hybrid.sim.appearance.STYLES)."""
    colon: ColonConfig = field(default_factory=ColonConfig)
    """Colon shape and mesh resolution."""
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    """Withdrawal behaviour."""
    hfov_deg: tuple[float, float] = (90.0, 130.0)
    """Range of the horizontal field of view of the simulated endoscopes."""
    aspect_jitter: float = 0.02
    """fy/fx is drawn in 1 +- this."""
    principal_jitter: float = 0.03
    """The principal point is drawn within +- this fraction of the size from the centre."""
    camera_seed: int | None = None
    """None: each procedure draws its own camera. Otherwise procedure i gets the camera that
    procedure i of this seed gets (same config), and everything else stays its own seed's:
    datasets of two styles can then share their cameras, so that style says nothing about
    the field of view (docs/depth.md, "Cameras shared by the styles")."""
    lens: str | None = None
    """None: pinhole cameras. 'equidistant': fisheye lenses, r = f θ (hybrid.types.Camera),
    with the field of view across the image width drawn as for the pinhole ones, so that
    their diagonal one is 115-166° for the default range (real endoscopes': 140-170°).
    Everything else is the procedure through a pinhole lens (`c2d2 simulate --fisheye`)."""
    corner_cut: tuple[float, float] | None = None
    """The endoscope's image region. None: the whole image. (lo, hi): an octagon, the image
    with its corners cut off along 45° lines whose legs are a fraction drawn in [lo, hi] of
    the image's shorter side, as on real endoscopes (`OCTAGON_CUT`, docs/simulator.md). The
    frames are black outside it, and the ground truth counts only the wall shown inside it."""
    segment_frames: int = 300
    """Frames per coverage segment."""
    frame_step: int | None = None
    """Keep every frame_step-th frame of the withdrawal only: a video at fps / frame_step, with
    segments of segment_frames / frame_step frames (the same 10 s) and that many times fewer
    frames to render and label. None: every frame. Cheap procedures for the per-frame coverage
    network, whose labels are per frame (docs/coverage.md, "Sparse procedures for the
    per-frame network")."""

    def __post_init__(self) -> None:
        if self.preset not in PRESET_IMAGE_SIZE:
            raise ValueError(f"unknown preset {self.preset!r}; choose {sorted(PRESET_IMAGE_SIZE)}")
        get_style(self.style)
        shortest = self.trajectory.start_depth_cm + self.trajectory.end_margin_cm
        if not shortest < self.colon.length_cm < float("inf"):
            raise ValueError(f"colon length must be finite and exceed {shortest:g} cm (the "
                             f"withdrawal starts {self.trajectory.start_depth_cm:g} cm before "
                             f"the cecum and stops {self.trajectory.end_margin_cm:g} cm before "
                             f"the rectum)")
        if self.trajectory.max_frames is not None and self.trajectory.max_frames < 1:
            raise ValueError("max_frames must be at least 1")
        if self.lens not in (None, "equidistant"):
            raise ValueError(f"lens must be None (pinhole) or 'equidistant', got {self.lens!r}")
        if self.corner_cut is not None and not 0 <= self.corner_cut[0] <= self.corner_cut[1] < 0.5:
            raise ValueError(f"corner_cut must be (lo, hi) with 0 <= lo <= hi < 0.5 of the "
                             f"shorter side, got {self.corner_cut}")
        if self.frame_step is not None and (self.frame_step < 1
                                            or self.segment_frames % self.frame_step):
            raise ValueError(f"frame_step must be a positive divisor of the {self.segment_frames}"
                             f"-frame segments, got {self.frame_step}")


OCTAGON_CUT = (0.15, 0.25)
"""`c2d2 simulate --octagon`'s corner_cut: 4-10% of the image outside, about as in the real
footage in ../shared/data, whose corner cuts are mostly 0.14-0.25 of its shorter side with
3.7-8.2% outside (benchmarks/region_corners.py, docs/simulator.md)."""


def procedure_name(index: int) -> str:
    return f"proc_{index:04d}"


def draw_camera(config: SimConfig, rng: np.random.Generator) -> Camera:
    """Per-procedure intrinsics: a different endoscope each time (the same draws with either
    lens)."""
    height, width = PRESET_IMAGE_SIZE[config.preset]
    half_angle = np.radians(rng.uniform(*config.hfov_deg)) / 2
    fx = (width / 2) / (half_angle if config.lens == "equidistant" else np.tan(half_angle))
    fy = fx * (1 + rng.uniform(-config.aspect_jitter, config.aspect_jitter))
    cx = (width - 1) / 2 + rng.uniform(-1, 1) * config.principal_jitter * width
    cy = (height - 1) / 2 + rng.uniform(-1, 1) * config.principal_jitter * height
    return Camera(width, height, float(fx), float(fy), float(cx), float(cy),
                  fps=config.trajectory.fps, model=config.lens or "pinhole")


def octagon_region(height: int, width: int, cut_px: float) -> np.ndarray:
    """(height, width) bool: the image without four right-angled corners whose legs are
    cut_px pixels long (a pixel is inside when its centre is)."""
    x = np.minimum(np.arange(width), width - 1 - np.arange(width)) + 0.5
    y = np.minimum(np.arange(height), height - 1 - np.arange(height)) + 0.5
    return y[:, None] + x[None, :] >= cut_px


def draw_region(config: SimConfig, camera: Camera, seed: int, index: int) -> np.ndarray | None:
    """Procedure `index`'s image region, None for the whole image. Drawn from a generator of
    its own, so a procedure with a region is the one without, its corners blacked out; with
    a camera_seed, that seed's (the region belongs to the endoscope, as the camera does)."""
    if config.corner_cut is None:
        return None
    endoscope = seed if config.camera_seed is None else config.camera_seed
    fraction = np.random.default_rng([endoscope, index, 1]).uniform(*config.corner_cut)
    return octagon_region(camera.height, camera.width,
                          fraction * min(camera.height, camera.width))


@dataclass
class Scene:
    """One procedure in memory: what it is rendered from, and the generator to render with."""

    colon: Colon
    camera: Camera
    region: np.ndarray | None
    poses: np.ndarray
    renderer: ColonRenderer
    rng: np.random.Generator


def draw_scene(config: SimConfig, seed: int, index: int) -> Scene:
    """Colon, camera, withdrawal and renderer of procedure `index` of `seed`."""
    rng = np.random.default_rng([seed, index])
    colon = make_colon(config.colon, rng)
    camera = draw_camera(config, rng)
    if config.camera_seed is not None:  # replay that seed's draws up to its camera
        other = np.random.default_rng([config.camera_seed, index])
        make_colon(config.colon, other)
        camera = draw_camera(config, other)
    poses = make_withdrawal(colon, config.trajectory, rng)
    style = get_style(config.style)
    circumference = 2 * np.pi * float(np.mean(config.colon.radius_range_cm))
    texture = make_texture(config.colon.length_cm, circumference, style, rng)
    return Scene(colon, camera, draw_region(config, camera, seed, index), poses,
                 ColonRenderer(colon, texture, style, camera, circumference), rng)


def simulate_procedure(out_dir: Path, seed: int, index: int, config: SimConfig,
                       progress: bool = False, window_stride: int | None = None) -> Path:
    """Write procedure `index` of `seed` under out_dir; skip it if already complete, refuse
    one that was simulated with another seed or config.

    window_stride: also label the windows of a segment's length that start every this many
    frames (of the written video), in the same pass as coverage.json (cache/, see
    hybrid.dataset.window_labels_path): the coverage networks' training windows.
    """
    segment_frames = _window_check(config, window_stride)
    final = Path(out_dir) / procedure_name(index)
    if _complete(final, seed, index, config):
        log.info("%s exists, skipped", final)
        return final
    work = final.with_name(final.name + ".partial")
    shutil.rmtree(work, ignore_errors=True)
    (work / "rgb").mkdir(parents=True)
    (work / "depth").mkdir()

    scene = draw_scene(config, seed, index)
    step = config.frame_step or 1
    colon, poses, region = scene.colon, scene.poses[::step], scene.region
    camera = replace(scene.camera, fps=scene.camera.fps / step)
    for i in tqdm(range(len(poses)), desc=f"render {final.name}", unit="frame",
                  disable=not progress, leave=False):
        rgb, depth = scene.renderer.render(poses[i], scene.rng)
        if region is not None:
            rgb[~region] = 0
        write_rgb(work / "rgb" / frame_name(i), rgb)
        write_depth(work / "depth" / frame_name(i), depth)
    del scene  # free the texture and the render scene before labelling

    trimesh.Trimesh(colon.vertices, colon.triangles, process=False).export(work / "colon.ply")
    np.save(work / "lumen.npy", colon.centerline)
    np.save(work / "poses.npy", poses)
    camera.save(work / "camera.json")
    if region is not None:
        write_region(work / REGION_FILE, region)
    # Ground truth from the files just written, so `c2d2 coverage` on them gives the same.
    coverage = compute_coverage(SurfaceMesh.load(work / "colon.ply"),
                                Lumen(np.load(work / "lumen.npy")), poses, camera,
                                segment_frames=segment_frames, progress=progress,
                                segment_stride=window_stride, region=region)
    coverage.back_to_back().save(work / "coverage.json")
    if window_stride:
        windows = window_labels_path(work, segment_frames, window_stride)
        windows.parent.mkdir()
        np.save(windows, coverage.window_table())
    meta = {"seed": seed, "index": index, "c2d2_version": __version__,
            "num_frames": len(poses), "config": asdict(config)}
    (work / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")
    shutil.rmtree(final, ignore_errors=True)
    work.rename(final)
    return final


def _complete(folder: Path, seed: int, index: int, config: SimConfig) -> bool:
    """Whether `folder` holds this procedure, complete; an error if it holds another."""
    if not all((folder / f).is_file() for f in REQUIRED_FILES):
        return False
    try:
        meta = json.loads((folder / "meta.json").read_text())
    except json.JSONDecodeError as err:
        raise InputError(f"{folder}/meta.json is damaged ({err}); delete {folder} to simulate "
                         f"it again") from err
    saved = meta.get("config", {})
    asked = {"seed": seed, "index": index, **json.loads(json.dumps(asdict(config)))}
    saved = {"seed": meta.get("seed"), "index": meta.get("index"), **saved}
    differ = sorted(k for k in asked.keys() | saved.keys() if asked.get(k) != saved.get(k))
    if differ:
        raise InputError(f"{folder} holds a procedure simulated with other settings (by c2d2 "
                         f"{meta.get('c2d2_version')}; differing: {', '.join(differ)}); use "
                         f"another --out or delete it")
    return True


def _window_check(config: SimConfig, window_stride: int | None) -> int:
    """The written video's segment length in frames, once window_stride is known to divide it."""
    segment_frames = config.segment_frames // (config.frame_step or 1)
    if window_stride is not None and not (window_stride >= 1
                                          and segment_frames % window_stride == 0):
        raise InputError(f"the window stride must be a positive divisor of the "
                         f"{segment_frames}-frame segments, got {window_stride}")
    return segment_frames


def _simulate_one(args: tuple[Path, int, int, SimConfig], window_stride: int | None) -> Path:
    return simulate_procedure(*args, window_stride=window_stride)


def simulate_dataset(out_dir: Path, procedures: int, seed: int, config: SimConfig,
                     workers: int = 1, first_index: int = 0,
                     window_stride: int | None = None) -> list[Path]:
    """Simulate procedures first_index .. first_index + procedures - 1 (resumable); with
    window_stride, label overlapping windows too (simulate_procedure)."""
    _window_check(config, window_stride)
    out_dir = W.make_folder(out_dir)
    jobs = [(out_dir, seed, first_index + k, config) for k in range(procedures)]
    for job in jobs:  # refuse a folder of other settings before rendering anything
        _complete(out_dir / procedure_name(job[2]), seed, job[2], config)
    if workers <= 1:
        return [simulate_procedure(*job, progress=True, window_stride=window_stride)
                for job in tqdm(jobs, desc="procedures")]
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
        one = partial(_simulate_one, window_stride=window_stride)
        return list(tqdm(pool.map(one, jobs), total=len(jobs), desc="procedures"))


def with_overrides(config: SimConfig, length_cm: float | None = None,
                   max_frames: int | None = None, frame_step: int | None = None) -> SimConfig:
    """The config with a different colon length, frame cap or frame step."""
    if frame_step is not None:  # 1 is every frame: the default, so that folders resume
        config = replace(config, frame_step=None if frame_step == 1 else frame_step)
    if length_cm is not None:
        config = replace(config, colon=replace(config.colon, length_cm=length_cm))
    if max_frames is not None:
        config = replace(config, trajectory=replace(config.trajectory, max_frames=max_frames))
    return config
