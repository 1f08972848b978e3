"""The `c2d2` command line."""

from __future__ import annotations

import functools
import json
import logging
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from hybrid import LOG_FORMAT
from hybrid import workdir as W
from hybrid.types import InputError

if TYPE_CHECKING:
    from collections.abc import Iterator

    import numpy as np

    from fusion.self_calibration import SelfCalibration
    from hybrid.pipeline import RunConfig
    from learned.frames import FrameSequence

Device = Annotated[str, typer.Option(envvar="C2D2_DEVICE",
                                    help="Device for the networks: auto (the GPU when torch "
                                    "sees one, else the CPU), cpu, cuda or cuda:N.")]
AdaptSteps = Annotated[int, typer.Option(min=0, help="First adapt the depth model to each "
                                         "input by this many steps of its own training loss "
                                         "on that input's frames (0: off; 1-2 s a step on 2 "
                                         "CPU cores), then read the geometric mean of the "
                                         "adapted and the starting model's depth. Only "
                                         "where the model's photometric error on the input "
                                         "lies between learned.adapt.CLEAR and NOISY: above, "
                                         "on dim, noisy videos, adapting made the depth much "
                                         "worse; below, on videos the model explains well, "
                                         "mostly worse; between, mostly better "
                                         "(docs/depth.md, 'Adapting to the video' and after). "
                                         "Elsewhere the input keeps the model's own depth, "
                                         "with a warning (--adapt-always).")]
AdaptAlways = Annotated[bool, typer.Option(
    help="With --adapt-steps: adapt to every input, whatever the depth model's photometric "
    "error on it.")]
SelfCalibrate = Annotated[bool, typer.Option(
    "--self-calibrate", help="Take K from structure from motion on up to 5 stretches of 120 "
    "frames (fusion/self_calibration.py; 1-4 minutes a video on 2 CPU cores) instead of the "
    "network's intrinsics head. Without 2 stretches that map and agree (dark, textureless or "
    "short video; a stretch mapped at a field of view under 60 degrees does not count) the "
    "head's K is kept, with a warning; intrinsics.json's 'source' says which.")]
Contrast = Annotated[float | None, typer.Option(
    min=0, help="With --self-calibrate: the clip limit of the CLAHE on each frame's lightness "
    "before SIFT (0: the frames as they are; default: fusion.self_calibration's, 3).")]

ViewSelfCalibrate = Annotated[bool, typer.Option(
    "--self-calibrate", help="Give coverage networks trained with field_of_view=true and "
    "view_hidden the video's field of view, by structure from motion on up to 5 stretches of "
    "120 frames where at least 3 agree, each at 60 degrees or more (1-4 minutes a video on 2 "
    "CPU cores; self_calibration.json); otherwise they run with it hidden. The geometric "
    "branch keeps the intrinsics head's K.")]
FisheyeFov = Annotated[float | None, typer.Option(
    "--fisheye-fov", help="The video comes through an equidistant fisheye lens that sees this "
    "many degrees across its image region's width (from the endoscope's specification; the "
    "principal point taken at the region's centre): its frames are resampled to a pinhole "
    "camera of the same angle (at most 130 degrees, the widest the networks were trained on) "
    "before every stage, and intrinsics.json gives that pinhole's K.")]
FindLens = Annotated[bool, typer.Option(
    "--find-lens", help="Tell the lens from the video, with no calibration: structure from "
    "motion with a one-coefficient fisheye camera on up to 5 stretches of 120 frames of the "
    "video as recorded, each at a field of view of 60 degrees or more (lens.json; about 2 "
    "minutes of mapping on 2 CPU cores, and two more readings of the video). Where at least 3 "
    "read as an equidistant fisheye and agree on its angle, the frames are resampled as "
    "--fisheye-fov does, at that angle; where at least 3 read as a pinhole, as they are; "
    "otherwise the video is refused.")]
PipelineDepth = Annotated[Path | None, typer.Option(help="Depth model (default: shipped).")]
Insertion = Annotated[bool, typer.Option(
    help="The video is an insertion, not a withdrawal (the look-ahead band lies where the "
    "camera is going; both branches).")]
SegmentSeconds = Annotated[float, typer.Option(help="Segment length in seconds.")]
PipelineCoverage = Annotated[Path | None, typer.Option(
    help="Coverage model, e.g. one adapted with `c2d2 adapt` (default: shipped); it must read "
    "the depth model's output (networks trained since 2026-11-30 record which depth model "
    "they learned on, and refuse another's).")]

app = typer.Typer(help="C2D2: detect deficient coverage in colonoscopy video.",
                  no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False)


def _direction(config: RunConfig, insertion: bool) -> RunConfig:
    """The configuration for an insertion video (the lumen's ℓ and the travel cues read the
    other way) or for a withdrawal."""
    rec = config.reconstruction
    return replace(config, reconstruction=replace(rec, lumen=replace(
        rec.lumen, withdrawal=not insertion)))


def _reports_input_errors(command):
    """Turn an InputError into a one-line message and exit status 2."""
    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        try:
            return command(*args, **kwargs)
        except InputError as err:
            typer.echo(f"error: {err}", err=True)
            raise typer.Exit(2) from err
    return wrapper


@app.callback()
def main(verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Log progress.")] = False):
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format=LOG_FORMAT)


@app.command()
@_reports_input_errors
def simulate(
    out: Annotated[Path, typer.Option(help="Folder to write procedures into.")],
    procedures: Annotated[int, typer.Option(min=1, help="Number of procedures.")] = 1,
    seed: Annotated[int, typer.Option(min=0, help="Random seed; same seed, same output.")] = 0,
    preset: Annotated[str, typer.Option(help="Image size: fast (128x160) or paper (320x384).")
                      ] = "fast",
    style: Annotated[str, typer.Option(help="Appearance style: pink, dusk or nbi.")] = "pink",
    length_cm: Annotated[float | None, typer.Option(help="Colon length in cm (default 120).")
                         ] = None,
    max_frames: Annotated[int | None, typer.Option(min=1, help="Stop each withdrawal after N "
                                                   "frames.")] = None,
    first_index: Annotated[int, typer.Option(min=0, help="Index of the first procedure.")] = 0,
    workers: Annotated[int, typer.Option(min=1, help="Procedures simulated in parallel.")] = 1,
    camera_seed: Annotated[int | None, typer.Option(
        min=0, help="Give procedure i the camera that procedure i of this seed has with the same "
             "--preset and --length-cm (colon, withdrawal and texture stay --seed's), so that "
             "two styles can share their cameras.")] = None,
    frame_step: Annotated[int | None, typer.Option(
        min=1, help="Keep every N-th frame of each withdrawal only (a video at 30 / N fps; N "
                    "divides the 300-frame segments): cheap procedures for the per-frame "
                    "coverage network (train-coverage --frame-data, where N must also divide "
                    "the travel gap of 8 frames: 2 or 4).")] = None,
    window_stride: Annotated[int | None, typer.Option(
        min=0, help="Also label the windows of a segment's length that start every N frames, "
                    "in the same pass as the ground truth: train-coverage's training windows, "
                    "which it would otherwise label itself. Default: 30, the coverage "
                    "networks' stride; none with --frame-step. 0: none.")] = None,
    octagon: Annotated[bool, typer.Option(
        help="Show the wall through an octagonal image region, as real endoscopes do: each "
             "frame's corners cut off along 45° lines with legs of 0.15-0.25 of its shorter "
             "side (drawn per procedure; region.png), black in the frames and unseen for the "
             "ground truth. Everything else is the procedure without it.")] = False,
    fisheye: Annotated[bool, typer.Option(
        help="Film through a fisheye lens (equidistant, r = f θ) of the field of view across "
             "the width the pinhole one would have (camera.json's model). Everything else is "
             "the procedure without it.")] = False,
):
    """Simulate procedures with rendered RGB, depth, poses and exact ground-truth coverage."""
    from hybrid.sim.simulate import OCTAGON_CUT, SimConfig, simulate_dataset, with_overrides
    from learned.config import CoverageConfig

    if window_stride is None:
        window_stride = 0 if frame_step and frame_step > 1 else CoverageConfig().segment_stride
    try:
        config = with_overrides(SimConfig(preset=preset, style=style, camera_seed=camera_seed,
                                          corner_cut=OCTAGON_CUT if octagon else None,
                                          lens="equidistant" if fisheye else None),
                                length_cm, max_frames, frame_step)
    except ValueError as err:
        raise InputError(str(err)) from err
    for path in simulate_dataset(out, procedures, seed, config, workers, first_index,
                                 window_stride or None):
        typer.echo(str(path))


@app.command()
@_reports_input_errors
def coverage(
    mesh: Annotated[Path, typer.Option(help="Colon surface mesh (PLY, OBJ, STL, OFF), cm.")],
    lumen: Annotated[Path, typer.Option(help="(M, 3) .npy centerline from the rectum end, cm.")],
    poses: Annotated[Path, typer.Option(help="(N, 4, 4) .npy camera-to-world poses, cm.")],
    camera: Annotated[Path, typer.Option(help="camera.json: width, height, fx, fy, cx, cy.")],
    segment_frames: Annotated[int, typer.Option(min=1, help="Frames per segment.")] = 300,
    region: Annotated[Path | None, typer.Option(
        help="The camera's image region: an image of its size, white where the wall is shown "
             "(a simulated procedure's region.png). Default: all of the image.")] = None,
    out: Annotated[Path | None, typer.Option(help="Write the JSON here instead of stdout.")
                   ] = None,
):
    """Ground-truth coverage of any mesh, centerline and trajectory (JSON as coverage.json)."""
    from hybrid.coverage import Lumen, SurfaceMesh, compute_coverage
    from hybrid.types import Camera

    if out is not None and not out.parent.is_dir():
        raise InputError(f"folder for --out does not exist: {out.parent}")
    result = compute_coverage(SurfaceMesh.load(mesh), Lumen(_load_npy(lumen), name=str(lumen)),
                              _load_npy(poses), Camera.load(camera), segment_frames,
                              progress=out is not None, poses_name=str(poses),
                              region=_read_mask(region, "region"))
    if out is None:
        typer.echo(json.dumps(result.to_json(), indent=1))
    else:
        result.save(out)
        typer.echo(str(out))


@app.command()
@_reports_input_errors
def demo(
    out: Annotated[Path, typer.Option(help="Folder for the demo's outputs.")] = Path("c2d2-demo"),
    seed: Annotated[int, typer.Option(min=0, help="Random seed.")] = 0,
    length_cm: Annotated[float, typer.Option(help="Colon length in cm.")] = 50.0,
    max_frames: Annotated[int, typer.Option(min=300, help="Frames of the withdrawal (30 fps).")
                          ] = 1200,
    device: Device = "auto",
):
    """Simulate a procedure with ground truth, run the whole pipeline on its video, and print
    per segment the true, learned and geometric coverage."""
    from hybrid.coverage import pair_key
    from hybrid.dataset import Procedure
    from hybrid.pipeline import Models, RunConfig, run_video
    from hybrid.sim.simulate import SimConfig, simulate_procedure, with_overrides
    from learned.device import pick_device

    try:
        config = with_overrides(SimConfig(), length_cm=length_cm, max_frames=max_frames)
    except ValueError as err:
        raise InputError(str(err)) from err
    W.make_folder(out)
    models = Models.load(RunConfig(), pick_device(device))
    procedure = Procedure.open(simulate_procedure(out, seed, 0, config, progress=True))
    result = run_video(procedure.path, out / "run", models=models, echo=typer.echo)
    table = json.loads((out / "run" / "coverage.json").read_text())
    truth = procedure.coverage
    key = pair_key(truth.default_pair)
    typer.echo(f"segment  time (s)      truth  learned  geometric   (Δ = {key} cm)")
    for row, true in zip(table["segments"], truth.segments, strict=True):
        cells = [true.coverage[key], row["learned"], row["geometric"]]
        typer.echo(f"{row['index']:7d}  {row['start_s']:5.1f}-{row['end_s']:<6.1f} "
                   + "  ".join("      n/a" if c is None else f"{c:7.3f}" for c in cells))
    typer.echo(f"report: {out / 'run' / 'report.html'}")
    _print_warnings(result["warnings"])


@app.command()
@_reports_input_errors
def run(
    video: Annotated[Path, typer.Argument(help="Video file (or image folder, or simulated "
                                          "procedure).")],
    out: Annotated[Path, typer.Option(help="Work folder: every stage's output and "
                                      "report.html; rerun to resume.")],
    fps: Annotated[float | None, typer.Option(help="Frame rate, if the video's is wrong or "
                                              "missing (an image folder is read at 30 unless "
                                              "given).")] = None,
    mask: Annotated[Path | None, typer.Option(help="Image-region mask (white = image) in the "
                                              "video's size; detected if omitted.")] = None,
    depth_checkpoint: PipelineDepth = None,
    coverage_checkpoint: PipelineCoverage = None,
    insertion: Insertion = False,
    segment_seconds: SegmentSeconds = 10.0,
    fisheye_fov: FisheyeFov = None,
    find_lens: FindLens = False,
    self_calibrate: ViewSelfCalibrate = False,
    device: Device = "auto",
):
    """The whole pipeline on one video: coverage.json/.csv, mesh.ply, maps/, report.html."""
    from hybrid.pipeline import Models, RunConfig, run_video
    from learned.device import pick_device

    config = _direction(RunConfig(depth_checkpoint=_opt(depth_checkpoint),
                                  coverage_checkpoint=_opt(coverage_checkpoint), fps=fps,
                                  segment_seconds=segment_seconds, fisheye_fov_deg=fisheye_fov,
                                  find_lens=find_lens, self_calibrate=self_calibrate), insertion)
    result = run_video(video, out, config, Models.load(config, pick_device(device)),
                       region=_read_mask(mask), echo=typer.echo)
    table = json.loads((out / "coverage.json").read_text())
    typer.echo("segment  time (s)      learned  geometric  agree  deficient  assessable")
    for r in table["segments"]:
        cells = ["    n/a" if r[k] is None else f"{r[k]:7.3f}" for k in ("learned", "geometric")]
        typer.echo(f"{r['index']:7d}  {r['start_s']:5.1f}-{r['end_s']:<6.1f} {cells[0]}  "
                   f"{cells[1]}    {_yes(r['agree']):5s}  {_yes(r['deficient']):9s}  "
                   f"{_yes(r['assessable'])}")
    typer.echo(f"report: {out / 'report.html'}")
    _print_warnings(result["warnings"])


@app.command()
@_reports_input_errors
def batch(
    folder: Annotated[Path, typer.Argument(help="Folder of videos.")],
    out: Annotated[Path, typer.Option(help="Output folder: one work folder per video and "
                                      "summary.csv; rerun to resume.")],
    workers: Annotated[int, typer.Option(min=1, help="Videos processed in parallel.")] = 1,
    depth_checkpoint: PipelineDepth = None,
    coverage_checkpoint: PipelineCoverage = None,
    insertion: Annotated[bool, typer.Option(
        help="The videos are insertions, not withdrawals (all of them).")] = False,
    segment_seconds: SegmentSeconds = 10.0,
    fisheye_fov: FisheyeFov = None,
    find_lens: FindLens = False,
    self_calibrate: ViewSelfCalibrate = False,
    device: Device = "auto",
):
    """Every video file in a folder (not its subfolders); failures are recorded per video
    while the rest go on. Exit status 1 if a video failed, else 3 if a video's results are
    incomplete (its warnings, as `c2d2 run` gives them)."""
    from hybrid.batch import run_batch
    from hybrid.pipeline import RunConfig
    from learned.device import pick_device

    config = _direction(RunConfig(depth_checkpoint=_opt(depth_checkpoint),
                                  coverage_checkpoint=_opt(coverage_checkpoint),
                                  segment_seconds=segment_seconds, fisheye_fov_deg=fisheye_fov,
                                  find_lens=find_lens, self_calibrate=self_calibrate), insertion)
    result = run_batch(folder, out, config, workers=workers, device=pick_device(device))
    failed = [r for r in result.rows if r["status"] == "failed"]
    for r in failed:
        typer.echo(f"failed: {r['video']}: {r['error']}", err=True)
    incomplete = [r for r in result.rows if r.get("warnings")]
    for r in incomplete:
        typer.echo(f"warning: {r['video']}: {r['warnings']}", err=True)
    typer.echo(f"{len(result.rows) - len(failed)} of {len(result.rows)} videos done"
               f"{f', {len(incomplete)} with incomplete results' if incomplete else ''}; "
               f"summary: {result.summary}")
    if failed or incomplete:
        raise typer.Exit(1 if failed else 3)


@app.command("eval")
@_reports_input_errors
def eval_pipeline(
    data: Annotated[list[Path], typer.Option(help="Simulated procedures, or folders of them.")],
    out: Annotated[Path, typer.Option(help="Work folders per procedure and eval.json.")],
    depth_checkpoint: PipelineDepth = None,
    coverage_checkpoint: PipelineCoverage = None,
    known_lens: Annotated[bool, typer.Option(
        help="Run each fisheye procedure (simulate --fisheye) with its field of view across "
             "the width from its camera.json, as `c2d2 run --fisheye-fov` is given an "
             "endoscope's specification. Pinhole procedures run as they are.")] = False,
    find_lens: Annotated[bool, typer.Option(
        "--find-lens", help="Tell each procedure's lens from its video, as `c2d2 run "
        "--find-lens` does; eval.json gives each found lens beside the true one, and a "
        "procedure whose lens is not told is listed and left out.")] = False,
    self_calibrate: ViewSelfCalibrate = False,
    device: Device = "auto",
):
    """MAE of learned, geometric and combined coverage against the truth, and the branches'
    agreement, with 95% intervals bootstrapped over procedures."""
    from hybrid.dataset import Procedure
    from hybrid.evaluate import evaluate_pipeline
    from hybrid.pipeline import Models, RunConfig
    from learned.device import pick_device
    from learned.train import expand_inputs

    if known_lens and find_lens:
        raise InputError("give either --known-lens or --find-lens, not both")
    config = RunConfig(depth_checkpoint=_opt(depth_checkpoint),
                       coverage_checkpoint=_opt(coverage_checkpoint),
                       find_lens=find_lens, self_calibrate=self_calibrate)
    models = Models.load(config, pick_device(device))
    paths = expand_inputs(data)
    _each_once(paths)
    procedures = [Procedure.open(p) for p in paths]
    summary = evaluate_pipeline(procedures, out, config, models, echo=typer.echo,
                                known_lens=known_lens)
    typer.echo(json.dumps(summary["summary"], indent=1))


def _each_once(paths: list[Path]) -> None:
    """InputError if --data names a procedure twice (its segments would count twice)."""
    from learned.train import input_name

    names = [input_name(p) for p in paths]
    if repeated := sorted({n for n in names if names.count(n) > 1}):
        raise InputError(f"--data gives {', '.join(repeated)} more than once (a procedure "
                         f"twice, or two whose folder and parent folder share names); give "
                         f"each once")


def _opt(path: Path | None) -> str | None:
    return None if path is None else str(path)


def _with_options(overrides: dict, **options) -> dict:
    """--set overrides and the command's own options together; a field given both ways is an
    error (the option's value is used only if given)."""
    given = {k: v for k, v in options.items() if v is not None}
    if clash := sorted(given.keys() & overrides.keys()):
        raise ValueError(f"--set {clash[0]}=... repeats --{clash[0].replace('_', '-')}; give "
                         f"it once")
    return {**overrides, **given}


def _yes(value) -> str:
    return "n/a" if value is None else ("yes" if value else "no")


def _read_mask(mask: Path | None, what: str = "mask"):
    from hybrid.types import read_mask

    return None if mask is None else read_mask(mask, what)


def _print_warnings(warnings: list[str]) -> None:
    """Warnings mean the results are written but incomplete: exit status 3."""
    for warning in warnings:
        typer.echo(f"warning: {warning}", err=True)
    if warnings:
        raise typer.Exit(3)


def _load_npy(path: Path):
    import numpy as np

    if not path.is_file():
        raise InputError(f"file not found: {path}")
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError) as err:
        raise InputError(f"cannot read {path} as a .npy array: {err}") from err


@app.command("train-depth")
@_reports_input_errors
def train_depth(
    data: Annotated[list[Path], typer.Option(help="Procedures, image folders or videos, or "
                                             "folders of procedures or videos; RGB only is "
                                             "used.")],
    out: Annotated[Path, typer.Option(help="Run folder: checkpoint, config, metrics log.")],
    preset: Annotated[str, typer.Option(help="fast (CPU, 128x160) or paper (ResNet-18, "
                                        "320x384).")] = "fast",
    val: Annotated[list[Path] | None, typer.Option(help="Simulated procedures for validation "
                                                   "metrics (their truth is used for nothing "
                                                   "else).")] = None,
    steps: Annotated[int | None, typer.Option(min=1, help="Training steps (preset default).")
                     ] = None,
    batch_size: Annotated[int | None, typer.Option(min=1, help="Triplets per step.")] = None,
    seed: Annotated[int | None, typer.Option(min=0, help="Random seed.")] = None,
    init: Annotated[Path | None, typer.Option(
        help="Start a new run from this depth model's weights (fine-tuning, e.g. on your own "
             "endoscope's videos); the optimiser starts afresh.")] = None,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", help="Override a config field, e.g. --set pair_gap_s=0.6 (see learned/config.py)."
    )] = None,
    fps: Annotated[float | None, typer.Option(help="Frame rate of the training videos or image "
                                              "folders, if theirs is missing or wrong (not for "
                                              "simulated procedures; kept by the run)."
                                              )] = None,
    maps: Annotated[Path | None, typer.Option(
        help="Structure-from-motion maps of the --data inputs (c2d2 sfm-maps): each step also "
             "trains on triplets of their agreeing stretches, weighted by --set w_map=W "
             "(depth) and --set w_map_motion=W (motion and intrinsics).")] = None,
    device: Device = "auto",
):
    """Train depth, ego-motion and intrinsics by view synthesis; resumes from --out."""
    from learned.config import depth_config, parse_overrides
    from learned.device import pick_device
    from learned.frames import check_fps
    from learned.train import train_depth as run

    check_fps(fps)  # 0 would read as "the inputs' own" in the config
    try:
        config = depth_config(preset, **_with_options(
            parse_overrides(set_ or []), steps=steps, batch_size=batch_size, seed=seed,
            init=None if init is None else str(init), input_fps=fps,
            maps=None if maps is None else str(maps)))
    except ValueError as err:
        raise InputError(str(err)) from err
    typer.echo(str(run(data, out, config, val or [], device=pick_device(device))))


@app.command("sfm-maps")
@_reports_input_errors
def sfm_maps(
    data: Annotated[list[Path], typer.Option(help="Training inputs, as train-depth takes them.")],
    out: Annotated[Path, typer.Option(help="Folder of maps, one .npz per input; inputs "
                                      "already mapped there are skipped.")],
    preset: Annotated[str, typer.Option(help="Preset whose frame size the maps are made at "
                                        "(train-depth's).")] = "fast",
    length: Annotated[int, typer.Option(help="Frames per stretch, each mapped on its own.")
                      ] = 120,
    workers: Annotated[int, typer.Option(help="Inputs mapped at once (one core each).")] = 1,
):
    """Map every stretch of the training inputs by structure from motion (pycolmap), for
    train-depth --maps: per frame its pose and sparse depth, per stretch its focal length."""
    from tqdm import tqdm

    from fusion.sfm_maps import map_inputs
    from learned.config import depth_config
    from learned.train import expand_inputs

    try:
        config = depth_config(preset)
    except ValueError as err:
        raise InputError(str(err)) from err
    inputs = expand_inputs(data)
    for line in tqdm(map_inputs(inputs, out, (config.height, config.width), length, workers),
                     total=len(inputs), desc="sfm-maps", unit="input"):
        tqdm.write(line)


@app.command()
@_reports_input_errors
def depth(
    input: Annotated[Path, typer.Argument(help="Video, folder of images, or simulated "
                                          "procedure.")],
    out: Annotated[Path, typer.Option(help="Folder for depth/, poses and intrinsics.json.")],
    checkpoint: Annotated[Path | None, typer.Option(help="Depth checkpoint (default: the "
                                                    "shipped fast one).")] = None,
    mask: Annotated[Path | None, typer.Option(help="Image-region mask (white = image) in the "
                                              "input's size; detected if omitted.")] = None,
    fps: Annotated[float | None, typer.Option(help="Frame rate, if the video's is missing or "
                                              "wrong (image folders: 30).")] = None,
    adapt_steps: AdaptSteps = 0,
    adapt_always: AdaptAlways = False,
    self_calibrate: SelfCalibrate = False,
    contrast: Contrast = None,
    device: Device = "auto",
):
    """Per-frame depth, relative poses and one intrinsics estimate for an input."""
    from learned.adapt import adapt_depth_model
    from learned.device import pick_device
    from learned.frames import open_sequence
    from learned.infer import infer_to_folder
    from learned.model import load_depth_model

    _check_contrast(contrast, self_calibrate)
    _check_always(adapt_always, adapt_steps)
    checkpoint, device = checkpoint or _shipped_checkpoint(), pick_device(device)
    model = load_depth_model(checkpoint, device=device)
    seq = open_sequence(input, (model.config.height, model.config.width), _read_mask(mask), fps)
    W.check_not_input(out, input)
    W.make_folder(out)
    calibration = _self_calibration(seq, contrast) if self_calibrate else None
    if adapt_steps:
        model = adapt_depth_model(checkpoint, model.config, seq, out / "adapted", adapt_steps,
                                  True, device, adapt_always).model
    infer_to_folder(model, seq, out, progress=True, calibration=calibration)
    typer.echo(str(out))


def _self_calibration(seq: FrameSequence, contrast: float | None) -> SelfCalibration:
    """fusion.self_calibration on the frames as the network sees them (its default config, or
    another `contrast`); a warning without a consensus (the intrinsics head's K is then
    kept); as many stretches mapped at once as torch has threads."""
    import torch

    from fusion.self_calibration import SelfCalibrationConfig, calibrate_sequence

    config = SelfCalibrationConfig(**({} if contrast is None else {"contrast": contrast}))
    found = calibrate_sequence(seq, config, progress=True, workers=torch.get_num_threads())
    if found.K is None:
        typer.echo(f"warning: {seq.name}: self-calibration gave no K, so the intrinsics head's "
                   f"is kept: {found.describe()}", err=True)
    return found


def _only_with(given: bool, needed: bool, message: str) -> None:
    """An option that means something only beside another: `message` where it is given alone."""
    if given and not needed:
        raise InputError(message)


def _check_always(adapt_always: bool, adapt_steps: int) -> None:
    _only_with(adapt_always, bool(adapt_steps),
               "--adapt-always forces an adaptation: give --adapt-steps too")


def _check_contrast(contrast: float | None, self_calibrate: bool) -> None:
    _only_with(contrast is not None, self_calibrate,
               "--contrast sets the self-calibration's frames: give --self-calibrate too")


@app.command("eval-depth")
@_reports_input_errors
def eval_depth(
    data: Annotated[list[Path], typer.Option(help="Simulated procedures (or folders of them).")],
    checkpoint: Annotated[Path | None, typer.Option(help="Depth checkpoint (default: the "
                                                    "shipped fast one).")] = None,
    out: Annotated[Path | None, typer.Option(help="Write the metrics JSON here.")] = None,
    frames: Annotated[int, typer.Option(min=1, help="Frames per procedure for depth metrics.")
                      ] = 24,
    adapt_steps: AdaptSteps = 0,
    adapt_dir: Annotated[Path | None, typer.Option(help="Keep the adapted models here, one "
                                                   "folder per procedure (resumable); default: "
                                                   "a temporary folder.")] = None,
    adapt_always: AdaptAlways = False,
    self_calibrate: SelfCalibrate = False,
    contrast: Contrast = None,
    device: Device = "auto",
):
    """MRE, DR-MRE, DOM, abs_rel & co., intrinsics error, ATE and RPE on simulated data.
    The intrinsics scored are the head's median over all consecutive pairs, as `c2d2 depth`
    writes them (so every frame is read); ATE and RPE are over the first 150 frames. With
    --self-calibrate the intrinsics error is that of the self-calibrated K where the
    stretches agree, else of the head's (column self_calibrated: 1 or 0); fx_head_rel is the
    head's own. Depth and trajectory metrics do not change."""
    from learned.adapt import adapt_depth_model
    from learned.device import pick_device
    from learned.evaluate import DEPTH_KEYS, evaluate_sequence, summarise
    from learned.frames import open_sequence
    from learned.model import load_depth_model
    from learned.train import expand_inputs, input_name

    _only_with(adapt_dir is not None, bool(adapt_steps),
               "--adapt-dir keeps adapted models: give --adapt-steps too")
    _check_always(adapt_always, adapt_steps)
    if out is not None and not out.parent.is_dir():
        raise InputError(f"folder for --out does not exist: {out.parent}")
    _check_contrast(contrast, self_calibrate)
    checkpoint, device = checkpoint or _shipped_checkpoint(), pick_device(device)
    model = load_depth_model(checkpoint, device=device)
    size = (model.config.height, model.config.width)
    paths = expand_inputs(data)
    _each_once(paths)
    names = [input_name(p) for p in paths]
    results, stretches = {}, {}
    with tempfile.TemporaryDirectory() as scratch:
        for name, path in zip(names, paths, strict=True):
            seq = open_sequence(path, size)
            adaptation = None if not adapt_steps else adapt_depth_model(
                checkpoint, model.config, seq, Path(adapt_dir or scratch) /
                name.replace("/", "-"), adapt_steps, True, device, adapt_always)
            read = model if adaptation is None else adaptation.model
            calibration = _self_calibration(seq, contrast) if self_calibrate else None
            results[name] = evaluate_sequence(read, seq, frames,
                                              K=None if calibration is None else calibration.K)
            if adaptation is not None:
                results[name].update(photometric_error=adaptation.photometric_error,
                                     adapted=float(adaptation.adapted))
            if calibration is not None:
                results[name]["self_calibrated"] = float(calibration.K is not None)
                stretches[name] = calibration.record()
    summary = summarise(results)
    keys = DEPTH_KEYS + ("fx_rel", "fy_rel", "cx_rel", "cy_rel", "ate", "rpe_translation",
                         "rpe_rotation_deg") + (("fx_head_rel", "self_calibrated")
                                                if self_calibrate else ()) + (
        ("photometric_error", "adapted") if adapt_steps else ())
    width = max(14, *map(len, names))
    columns = [max(9, len(k)) for k in keys]
    typer.echo(f"{'procedure':{width}s} " + " ".join(f"{k:>{c}s}" for k, c in zip(
        keys, columns, strict=True)))
    for name, m in [*results.items(), ("MEAN", summary)]:
        typer.echo(f"{name:{width}s} " + " ".join(f"{m[k]:{c}.4f}" for k, c in zip(
            keys, columns, strict=True)))
    if out is not None:
        W.write_json(out, {"mean": summary, "procedures": results, "adapt_steps": adapt_steps,
                           "intrinsics": ("self-calibration where its stretches agree, else "
                                          "the intrinsics head" if self_calibrate
                                          else "intrinsics head"),
                           "self_calibration": stretches})


@app.command("train-coverage")
@_reports_input_errors
def train_coverage(
    data: Annotated[list[Path], typer.Option(help="Simulated procedures, or folders of them.")],
    out: Annotated[Path, typer.Option(help="Run folder: fold models, CV metrics, final model.")],
    preset: Annotated[str, typer.Option(help="fast (small ResNet on 64x80 depth) or paper "
                                        "(ResNet-50 at 320x384).")] = "fast",
    depth_checkpoint: Annotated[Path | None, typer.Option(help="Depth model whose output the "
                                                          "per-frame net reads (default: the "
                                                          "shipped one).")] = None,
    folds: Annotated[int | None, typer.Option(help="Cross-validation folds by procedure "
                                              "(0: none; calibrate=true then calibrates "
                                              "nothing).")] = None,
    seed: Annotated[int | None, typer.Option(min=0, help="Random seed.")] = None,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", help="Override a config field, e.g. --set input_depth=true (see "
        "learned/config.py CoverageConfig).")] = None,
    frame_data: Annotated[list[Path] | None, typer.Option(
        help="More simulated procedures for the per-frame network alone, in the training "
             "set of every fold (e.g. made with simulate --frame-step 4).")] = None,
    device: Device = "auto",
):
    """Train the per-frame then the per-segment coverage network, with k-fold CV; resumes.
    With --set calibrate=true the final segment coverage is calibrated on the CV's held-out
    windows."""
    from learned.config import COVERAGE_PRESETS, coverage_config, parse_overrides
    from learned.coverage_train import train_coverage as run
    from learned.device import pick_device

    try:
        config = coverage_config(preset, **_with_options(
            parse_overrides(set_ or [], COVERAGE_PRESETS["fast"]), folds=folds, seed=seed))
    except ValueError as err:
        raise InputError(str(err)) from err
    typer.echo(str(run(data, out, config, depth_checkpoint or _shipped_checkpoint(),
                       device=pick_device(device), frame_data=frame_data or [])))


@app.command("eval-coverage")
@_reports_input_errors
def eval_coverage(
    data: Annotated[list[Path], typer.Option(help="Simulated procedures, or folders of them.")],
    out: Annotated[Path, typer.Option(help="Folder for metrics.json and scatter.png.")],
    model: Annotated[Path | None, typer.Option(help="Coverage model (default: the shipped "
                                               "one).")] = None,
    depth_checkpoint: Annotated[Path | None, typer.Option(help="Depth model (default: the "
                                                          "shipped one).")] = None,
    view_hidden: Annotated[bool, typer.Option(
        "--view-hidden", help="Score networks trained with field_of_view=true and view_hidden "
        "with the field of view hidden, as `c2d2 run` gives it them without a self-calibrated "
        "one (otherwise they read the simulator's).")] = False,
    device: Device = "auto",
):
    """Per-frame MAE per Δ pair, per-segment MAE (with a 95% interval bootstrapped over the
    procedures), bias and 3-class accuracy, deficient segments found (recall, precision), with
    scatter plots; metrics.json also holds each procedure's segments, which
    benchmarks/eval_spread.py compares between two evaluations."""
    from learned.coverage_eval import (
        coverage_metrics,
        format_table,
        procedure_segments,
        scatter_plots,
        segment_mae_interval,
    )
    from learned.coverage_nets import load_coverage_model
    from learned.coverage_train import evaluate, load_samples
    from learned.device import pick_device
    from learned.train import expand_inputs
    from learned.view import hidden_view

    model_path, device = model or _shipped_coverage(), pick_device(device)
    net = load_coverage_model(model_path, device=device)
    if view_hidden and not (net.config.field_of_view == "true" and net.config.view_hidden):
        raise InputError(f"--view-hidden: {model_path} was not trained with field_of_view "
                         f"'true' and view_hidden, so it does not run with its field of view "
                         f"hidden")
    depth_checkpoint = depth_checkpoint or _shipped_checkpoint()
    net.check_depth(depth_checkpoint, str(model_path))
    _each_once(expand_inputs(data))
    samples = load_samples(data, net.config, depth_checkpoint, progress=True, device=device)
    if view_hidden:
        samples = [replace(s, view=hidden_view(len(s.view))) for s in samples]
    predictions = evaluate(net, samples)
    metrics = coverage_metrics(predictions)
    W.make_folder(out)
    W.write_json(out / "metrics.json", {
        "model": str(model_path), "data": [str(p) for p in data], "view_hidden": view_hidden,
        **metrics, "segment_mae_interval": segment_mae_interval(predictions),
        "procedures": procedure_segments(predictions, [s.name for s in samples])})
    scatter_plots(predictions, out / "scatter.png", f"{model_path.name} on "
                  f"{', '.join(p.name for p in data)}")
    typer.echo(format_table({model_path.stem: metrics}))


@app.command()
@_reports_input_errors
def adapt(
    target: Annotated[list[Path], typer.Option(help="Unlabelled videos, image folders or "
                                               "procedures (RGB only), or folders of them.")],
    out: Annotated[Path, typer.Option(help="Where to write the adapted model.")],
    model: Annotated[Path | None, typer.Option(help="Coverage model (default: the shipped "
                                               "one).")] = None,
    depth_checkpoint: Annotated[Path | None, typer.Option(help="Depth model (default: the "
                                                          "shipped one).")] = None,
    segment_seconds: Annotated[float, typer.Option(help="Segment length, as `c2d2 run` will "
                                                   "use it.")] = 10.0,
    insertion: Annotated[bool, typer.Option(
        help="The target videos are insertions, as `c2d2 run --insertion` will read them (the "
        "travel cues, whose statistics CORAL aligns, read the other way).")] = False,
    source: Annotated[list[Path] | None, typer.Option(
        help="Synthetic videos or procedures the model was NOT trained on: their windows "
             "replace the training windows as CORAL's source statistics.")] = None,
    fisheye_fov: FisheyeFov = None,
    find_lens: FindLens = False,
    self_calibrate: ViewSelfCalibrate = False,
    device: Device = "auto",
):
    """Fit CORAL on unlabelled target videos and save the adapted coverage model (for networks
    that read a self-calibrated field of view, adapt with --self-calibrate as set for the runs
    that will use it: the features CORAL aligns depend on it).

    Each video is ingested and its depth computed as `c2d2 run` does (streamed), its 10-s
    segments resampled to the per-segment network's window, and windows taken every
    `segment_stride` frames of that resampled time. With --source, the same is done for
    held-out synthetic videos, whose windows then give the source statistics. Without it (and
    unless the model was adapted with it before) the target is mapped onto the training
    windows' statistics, where the segment network is not shrunk towards the mean, so a
    calibrated model's table (fitted on held-out windows) is kept but not applied.
    """
    import tempfile

    from hybrid.pipeline import Models, RunConfig, video_features
    from learned.coral import adapt as fit
    from learned.coral import set_source
    from learned.coverage_nets import resample_features
    from learned.device import pick_device
    from learned.train import expand_inputs

    if not out.parent.is_dir():
        raise InputError(f"folder for --out does not exist: {out.parent}")
    config = _direction(RunConfig(depth_checkpoint=_opt(depth_checkpoint),
                                  coverage_checkpoint=str(model or _shipped_coverage()),
                                  segment_seconds=segment_seconds, fisheye_fov_deg=fisheye_fov,
                                  find_lens=find_lens, self_calibrate=self_calibrate), insertion)
    models = Models.load(config, pick_device(device))
    T, stride = models.coverage.config.segment_frames, models.coverage.config.segment_stride

    def features(paths: list[Path], work: Path, config: RunConfig) -> Iterator[np.ndarray]:
        """Each video's resampled per-frame features, computed when CORAL asks for them (and
        dropped once it has embedded their windows: one video's are held at a time)."""
        for k, path in enumerate(expand_inputs(paths)):
            yield resample_features(*video_features(path, work / str(k), config, models), T)

    with tempfile.TemporaryDirectory() as work:
        if source:  # simulated pinhole withdrawals, whatever the target videos are
            simulated = replace(_direction(config, False), fisheye_fov_deg=None, find_lens=False)
            windows = set_source(models.coverage, features(
                source, Path(work) / "source", simulated), stride)
            typer.echo(f"CORAL source statistics from {windows} held-out windows")
        windows = fit(models.coverage, features(target, Path(work) / "target", config), stride)
    if models.coverage.segment.holds_table() and not models.coverage.segment.calibrates():
        typer.echo("the segment calibration is not applied (CORAL maps the target onto the "
                   "training windows' statistics; give --source to apply it)")
    models.coverage.save(out)
    typer.echo(f"CORAL fitted on {windows} target windows: {out}")


def _shipped_coverage() -> Path:
    from learned.checkpoints import SHIPPED_COVERAGE

    if not SHIPPED_COVERAGE.is_file():
        raise InputError(f"no shipped coverage model at {SHIPPED_COVERAGE}; train one with "
                         f"`c2d2 train-coverage` and pass --model")
    return SHIPPED_COVERAGE


def _shipped_checkpoint() -> Path:
    from learned.checkpoints import SHIPPED_DEPTH

    if not SHIPPED_DEPTH.is_file():
        raise InputError(f"no shipped checkpoint at {SHIPPED_DEPTH}; train one with "
                         f"`c2d2 train-depth` and pass --checkpoint")
    return SHIPPED_DEPTH
