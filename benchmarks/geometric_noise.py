"""How much the geometric branch moves under changes far below the data's precision.

For each procedure of a finished `c2d2 eval` (its work folders and eval.json), a copy of the
work folder gets one of two nudges, and the stages after it run again:
  - `posegraph`: one float16 step up on a random 1% of the depth pixels (the depth is stored
    as float16); pose graph, reconstruction and geometric coverage rerun;
  - `reconstruction`: the smoothed poses' translations moved by --pose-nudge (normal noise
    per axis, in the network's unit: reconstruction.json's scale_cm_per_unit gives it in cm,
    10-15 for data/heldout); reconstruction and geometric coverage rerun.
The stages that rerun take their settings from the current code, with --geometric FIELD=VALUE
overriding a field of hybrid.geometric_coverage.GeometricConfig (to try another setting on a
finished eval), and the model files from the eval's. They first rerun without a nudge (so a
change to those settings is measured too), and the nudged runs are compared with that (no
--seeds: only that rerun). Each procedure's nudge is drawn from (seed, procedure name), so
--procedures reruns a subset as the whole run nudged it. Prints the eval's and the unnudged
rerun's geometric MAE, bias and 3-class accuracy against the truth and the agreement with the
learned branch, then the same per seed with the largest change of one segment's geometric
coverage (and which), and the largest move of a smoothed camera position in cm.

    python benchmarks/geometric_noise.py --eval data/eval-heldout-shipped --stage posegraph \
        --seeds 0 1 --out /tmp/noise
"""
from __future__ import annotations

import argparse
import json
import shutil
import zlib
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from hybrid import workdir as W
from hybrid.evaluate import summarise
from hybrid.geometric_coverage import GeometricConfig
from hybrid.pipeline import Models, RunConfig, run_video
from learned.config import parse_overrides

RERUN = {"posegraph": [W.POSES, W.POSES_RAW, W.ODOMETRY], "reconstruction": []}
SETTINGS = {"posegraph": ["odometry", "posegraph", "reconstruction", "geometric",
                          "geometric_weight"],
            "reconstruction": ["reconstruction", "geometric", "geometric_weight"]}
"""The run's settings of the stages that rerun (the report's combination among them): taken
from the current code, so that a change to them is measured on the eval's earlier stages (the
rest must match, or run_video refuses)."""
DOWNSTREAM = [W.RECONSTRUCTION, W.MESH, W.LUMEN, W.GEOMETRIC, W.REPORT, W.COVERAGE_JSON,
              W.COVERAGE_CSV, W.GEOMETRIC_ERROR, W.MAPS]


def nudge(work: Path, stage: str, rng: np.random.Generator, pose_nudge: float) -> None:
    """Apply the stage's nudge to the inputs of the stages that rerun, in `work`."""
    if stage == "posegraph":
        depth = np.load(work / W.DEPTH)
        if depth.dtype != np.float16:
            raise SystemExit(f"{work / W.DEPTH}: expected float16 depth, found {depth.dtype}")
        up = np.nextafter(depth, np.float16(np.inf))
        np.save(work / W.DEPTH, np.where(rng.random(depth.shape) < 0.01, up, depth))
    else:
        poses = np.load(work / W.POSES)
        poses[:, :3, 3] += pose_nudge * rng.standard_normal(poses[:, :3, 3].shape)
        np.save(work / W.POSES, poses)


def reset(work: Path, stage: str, config: RunConfig) -> None:
    """Give `work` the settings of `config` for the stages that rerun, and delete their
    outputs."""
    saved = json.loads((work / W.CONFIG).read_text())
    current = json.loads(json.dumps(asdict(config)))
    saved["config"].update({key: current[key] for key in SETTINGS[stage]})
    W.write_json(work / W.CONFIG, saved)
    for name in RERUN[stage] + DOWNSTREAM:
        path = work / name
        shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)


def eval_config(folder: Path, geometric: dict) -> RunConfig:
    """The current settings, the geometric ones overridden by `geometric`, with the model files
    the eval ran with (read from a work folder)."""
    work = next(folder.glob(f"*/{W.CONFIG}"), None)
    if work is None:
        raise SystemExit(f"{folder} holds no work folder of a procedure; give the --out of a "
                         f"finished c2d2 eval")
    saved = json.loads(work.read_text())["config"]
    return replace(RunConfig(), depth_checkpoint=saved["depth_checkpoint"],
                   coverage_checkpoint=saved["coverage_checkpoint"],
                   geometric=replace(GeometricConfig(), **geometric))


def rerun(args: argparse.Namespace, rows: list[dict], config: RunConfig, models: Models,
          seed: int | None) -> tuple[list[dict], float]:
    """The eval's rows with the geometric coverage of a nudged rerun (seed None: not nudged),
    and the largest move of a smoothed camera position from the unnudged rerun's, in cm."""
    nudged, pose_moves = [], []
    for procedure in dict.fromkeys(r["procedure"] for r in rows):
        src = args.eval / f"{Path(procedure).parent.name}-{Path(procedure).name}"
        work = args.out / f"{src.name}-{args.stage}-{seed}"
        shutil.rmtree(work, ignore_errors=True)
        shutil.copytree(src, work)
        if seed is not None:
            rng = np.random.default_rng([seed, zlib.crc32(src.name.encode())])
            nudge(work, args.stage, rng, args.pose_nudge)
        reset(work, args.stage, config)
        run_video(Path(procedure), work, config, models, progress=False,
                  echo=lambda _: None)
        table = json.loads((work / W.COVERAGE_JSON).read_text())["segments"]
        mine = [r for r in rows if r["procedure"] == procedure]
        nudged += [{**r, "geometric": t["geometric"], "combined": t["coverage"],
                    "geometric_support": t.get("geometric_support")}
                   for r, t in zip(mine, table, strict=True)]
        base = args.out / f"{src.name}-{args.stage}-None"
        cm = json.loads((base / W.RECONSTRUCTION).read_text())["scale_cm_per_unit"]
        step = np.load(work / W.POSES)[:, :3, 3] - np.load(base / W.POSES)[:, :3, 3]
        pose_moves.append(cm * np.linalg.norm(step, axis=1).max())
    return nudged, max(pose_moves)


def summary_line(label: str, rows: list[dict]) -> str:
    summary = summarise(rows)
    geometric = summary["geometric"]
    return (f"{label}: geometric MAE {geometric['mae']:.4f}, bias {geometric['bias']:+.4f}, "
            f"3-class {geometric['3class']:.3f}, agreement {summary['branch_agreement']:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--eval", type=Path, required=True, help="output folder of c2d2 eval")
    parser.add_argument("--stage", choices=sorted(RERUN), default="posegraph")
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1],
                        help="nudge seeds (none: only the unnudged rerun)")
    parser.add_argument("--pose-nudge", type=float, default=1e-9,
                        help="with --stage reconstruction: the translations' noise")
    parser.add_argument("--procedures", nargs="*", help="only these (e.g. proc_0015)")
    parser.add_argument("--out", type=Path, required=True, help="scratch folder for the copies")
    parser.add_argument("--geometric", action="append", default=[], metavar="FIELD=VALUE",
                        help="override a GeometricConfig field in the stages that rerun, "
                             "e.g. occlusion_tolerance=0.1 (repeatable)")
    args = parser.parse_args()
    try:
        geometric = parse_overrides(args.geometric, GeometricConfig())
    except ValueError as err:  # its messages name --set, the option of the c2d2 commands
        raise SystemExit(str(err).replace("--set", "--geometric", 1)) from err
    evaluated = [r for r in json.loads((args.eval / "eval.json").read_text())["segments"]
                 if not args.procedures or Path(r["procedure"]).name in args.procedures]
    if not evaluated:
        raise SystemExit(f"no segments of {args.procedures} in {args.eval / 'eval.json'}; name "
                         f"procedures as its 'procedure' paths end (e.g. proc_0015)")
    config = eval_config(args.eval, geometric)
    models = Models.load(config)
    print(summary_line("as evaluated", evaluated))
    rows = rerun(args, evaluated, config, models, None)[0]
    print(summary_line("rerun, not nudged", rows))
    for seed in args.seeds:
        nudged, pose_move = rerun(args, rows, config, models, seed)
        moved = [(abs(a["geometric"] - b["geometric"]), f"{Path(a['procedure']).name} "
                  f"segment {a['segment']}: {a['geometric']:.3f} -> {b['geometric']:.3f}")
                 for a, b in zip(rows, nudged, strict=True)
                 if a["geometric"] is not None and b["geometric"] is not None]
        print(f"{summary_line(f'seed {seed}', nudged)}, segment moves median "
              f"{np.median([m for m, _ in moved]):.4f}, largest {max(moved)[0]:.3f} "
              f"({max(moved)[1]}); camera moved at most {pose_move:.3f} cm")


if __name__ == "__main__":
    main()
