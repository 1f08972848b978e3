"""`c2d2 eval --self-calibrate` on procedures whose stretches `c2d2 eval-depth --self-calibrate`
has mapped already.

The run's self-calibration stage maps up to 5 stretches of 120 frames per procedure (minutes
each). Where eval-depth's JSONs hold that mapping for the same procedures, this writes each
work folder's `self_calibration.json` from them, so the stage is read rather than run again,
then evaluates as `c2d2 eval` does (`hybrid.evaluate.evaluate_pipeline`; out/eval.json). The
run's own rule (`RunConfig.self_calibration`: 3 agreeing, at 60 degrees or more) is applied
to the stretches as mapped. A record must have been mapped with the run's stretches and
contrast, and on as many frames, at the depth network's size. With `--check N` the first N
procedures are mapped by the run itself instead (in a fresh `--out`), and their stretches
compared with the records' (the two map the same frames when the run's ingest keeps the
simulator's frames whole).

    python benchmarks/pipeline_self_calibration.py --data data/heldout \\
        --out data/eval-heldout-view --coverage-checkpoint MODEL \\
        --self-calibration docs/self_calibration/heldout-contrast.json [--check 1]
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from fusion.self_calibration import config_of_record, eval_records
from hybrid import workdir as W
from hybrid.dataset import Procedure
from hybrid.evaluate import evaluate_pipeline, work_folder
from hybrid.pipeline import Models, RunConfig
from learned.train import expand_inputs, input_name


def check_record(name: str, record: dict, config: RunConfig, frames: int,
                 size: tuple[int, int]) -> None:
    """Refuse a record mapped otherwise than the run would map `frames` frames of `size`."""
    ours = {k: v for k, v in asdict(config.self_calibration).items()
            if k not in ("min_agreeing", "min_field_of_view")}  # the consensus's, not the map's
    theirs = {k: v for k, v in asdict(config_of_record(record)).items() if k in ours}
    if theirs != ours or record["frames"] != frames or tuple(record["size"]) != size:
        raise SystemExit(f"{name}: its record was mapped with {theirs} on {record['frames']} "
                         f"frames of {record['size']}; the run maps {ours} on {frames} frames "
                         f"of {list(size)}")


def stretch_differences(work: Path, record: dict) -> str:
    """The run's stretches against the record's: start, fraction placed and fx of each."""
    mapped = json.loads((work / W.SELF_CALIBRATION).read_text())["stretches"]
    if [a["start"] for a in mapped] != [b["start"] for b in record["stretches"]]:
        return (f"other stretches: the run's start at {[a['start'] for a in mapped]}, the "
                f"record's at {[b['start'] for b in record['stretches']]}")
    return "; ".join(f"start {a['start']}: placed {a['registered']:.2f} / "
                     f"{b['registered']:.2f}, fx {a['fx']} / {b['fx']}"
                     for a, b in zip(mapped, record["stretches"], strict=True))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--coverage-checkpoint", type=Path, required=True,
                        help="Networks trained with field_of_view=true and view_hidden.")
    parser.add_argument("--depth-checkpoint", type=Path)
    parser.add_argument("--self-calibration", type=Path, nargs="+", required=True,
                        help="JSONs of c2d2 eval-depth --self-calibrate on these procedures.")
    parser.add_argument("--check", type=int, default=0,
                        help="Map the first N procedures in the run (in work folders that have "
                             "no self-calibration yet) and compare.")
    args = parser.parse_args()

    config = RunConfig(depth_checkpoint=args.depth_checkpoint and str(args.depth_checkpoint),
                       coverage_checkpoint=str(args.coverage_checkpoint), self_calibrate=True)
    models = Models.load(config)
    size = (models.depth.config.height, models.depth.config.width)
    mapped = eval_records(args.self_calibration)
    procedures = [Procedure.open(p) for p in expand_inputs(args.data)]
    for proc in procedures:  # every record checked before any folder is written
        name = input_name(proc.path)
        if name not in mapped:
            raise SystemExit(f"{name}: not in {', '.join(map(str, args.self_calibration))}")
        check_record(name, mapped[name], config, proc.num_frames, size)
    checked = procedures[:args.check]
    for proc in checked:
        if (work_folder(args.out, proc) / W.SELF_CALIBRATION).is_file():
            raise SystemExit(f"{work_folder(args.out, proc)} has a self-calibration already: "
                             f"--check maps it in the run, so give a fresh --out")
    for proc in procedures[args.check:]:
        work = work_folder(args.out, proc)
        if not (work / W.CONFIG).is_file():  # a folder run before keeps what it ran with
            work.mkdir(parents=True, exist_ok=True)
            W.write_json(work / W.SELF_CALIBRATION, mapped[input_name(proc.path)])
    result = evaluate_pipeline(procedures, args.out, config, models, echo=print)
    for proc in checked:
        print(f"{input_name(proc.path)}, the run's stretches / the record's: "
              f"{stretch_differences(work_folder(args.out, proc), mapped[input_name(proc.path)])}")
    print(json.dumps(result["summary"], indent=1))


if __name__ == "__main__":
    main()
