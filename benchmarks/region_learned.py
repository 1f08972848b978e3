"""Why the learned coverage reads otherwise through an image region (or a resampled lens):
its stage redone with one input at a time taken from the run of the same procedure filmed
whole through a pinhole.

--runs holds the `c2d2 eval` work folders of procedures simulated with `--octagon` (or
fisheye ones resampled to their pinhole twins by benchmarks/fisheye_to_pinhole.py), --twins
those of the same procedures without it (the same seeds: inside the region the frames are
the same, or nearly: the resampled ones are interpolated). For each variant the learned
stage (and the report) of `c2d2 run` is redone in a scratch folder that links the run's
files but takes the named ones from the twin's folder, or, for "no region", an all-white
region.png. "no region" differs from "as run" only in taking each frame's median over the
whole image; before 2026-11-30's fifty-seventh session "as run" read the depth filled from
inside the region, and before the fifty-fifth a constant there (docs/coverage.md, "The image
region").
Printed per variant: the segment MAE and bias of the learned coverage against the run's
procedures' truth, and against the twin run's learned values.

    python benchmarks/region_learned.py --runs data/eval-octagon-h2 \
        --twins data/eval-s54-final-h2 --data data/heldout2-octagon \
        --variants "no region" "full depth" "full travel"
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from hybrid import workdir as W
from hybrid.coverage import pair_key
from hybrid.dataset import Procedure
from hybrid.pipeline import Models, RunConfig, made_with, run_video
from learned.frames import NETWORK_INPUT

VARIANTS = {"as run": (), "no region": ("region",), "full depth": (W.DEPTH,),
            "full travel": (W.RELATIVE,), "full depth and travel": (W.DEPTH, W.RELATIVE)}
REDONE = {W.LEARNED, W.COVERAGE_JSON, W.COVERAGE_CSV, W.REPORT, W.CONFIG}


def learned_values(run: Path, twin: Path, source: Path, taken: tuple[str, ...],
                   models: Models) -> list[float]:
    """The learned segment coverage of `source` with the files `taken` from the twin run."""
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch) / run.name
        work.mkdir()
        for item in run.iterdir():
            if item.name in REDONE:
                continue
            given = twin / item.name if item.name in taken else item
            (work / item.name).symlink_to(given.resolve())
        # today's learned stage on these inputs, whatever the run's networks read
        config = json.loads((run / W.CONFIG).read_text())
        W.write_json(work / W.CONFIG, config | {"network_input": NETWORK_INPUT})
        if "region" in taken:
            (work / W.REGION).unlink()
            shape = np.load(work / W.DEPTH, mmap_mode="r").shape[1:]
            W.write_png(work / W.REGION, np.full(shape, 255, np.uint8))
        # the run's configuration: eval's default, with its fisheye angle (eval --known-lens)
        lens = made_with(config["config"])["fisheye_fov_deg"]
        run_video(source, work, RunConfig(fisheye_fov_deg=lens), models=models,
                  progress=False, echo=lambda _: None)
        record = json.loads((work / W.LEARNED).read_text())
    return [s["coverage"] for s in record["segments"]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, required=True)
    parser.add_argument("--twins", type=Path, required=True)
    parser.add_argument("--data", type=Path, required=True, help="the runs' procedures")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    args = parser.parse_args()
    models = Models.load(RunConfig())
    rows: dict[str, list[tuple[float, float, float]]] = {v: [] for v in args.variants}
    for run in sorted(p for p in args.runs.iterdir() if (p / W.LEARNED).is_file()):
        twin = _twin(run, args.twins)
        procedure = Procedure.open(args.data / run.name.split("-")[-1])
        key = pair_key(procedure.coverage.default_pair)
        truth = [s.coverage[key] for s in procedure.coverage.segments]
        before = [s["coverage"] for s in json.loads((twin / W.LEARNED).read_text())["segments"]]
        for variant in args.variants:
            values = learned_values(run, twin, procedure.path, VARIANTS[variant], models)
            rows[variant] += list(zip(values, truth, before, strict=True))
        print(run.name, " ".join(f"{v}: {np.round(rows[v][-len(truth):], 3)[:, 0]}"
                                 for v in args.variants), flush=True)
    for variant, values in rows.items():
        value, truth, before = np.array(values).T
        print(f"{variant:24s} MAE {np.abs(value - truth).mean():.4f} bias "
              f"{(value - truth).mean():+.4f}; against the twin run's learned: mean "
              f"{(value - before).mean():+.4f} ({len(value)} segments)")


def _twin(run: Path, twins: Path) -> Path:
    """The twin run's work folder of the same procedure (named ...-proc_NNNN)."""
    found = [p for p in twins.iterdir() if p.name.endswith(run.name.split("-")[-1])]
    if len(found) != 1:
        raise SystemExit(f"{twins}: expected one work folder of {run.name}, found {found}")
    return found[0]


if __name__ == "__main__":
    main()
