"""`c2d2 eval --self-calibrate` on procedures whose stretches `c2d2 eval-depth --self-calibrate`
has mapped already.

The run's self-calibration stage maps up to 5 stretches of 120 frames per procedure (minutes
each). Where eval-depth's JSONs hold that mapping for the same procedures, this writes each
work folder's `self_calibration.json` from them, so the stage is read rather than run again,
then evaluates as `c2d2 eval` does (`hybrid.evaluate.evaluate_pipeline`; out/eval.json). The
run's own rule (`RunConfig.self_calibration`: 3 agreeing) is applied to the stretches as
mapped. A record must have been mapped with the run's stretches and contrast, and on as many
frames, at the depth network's size. With `--check N` the first N procedures are mapped by
the run itself instead, and their stretches compared with the records' (the two map the same
frames when the run's ingest keeps the simulator's frames whole).

    python benchmarks/pipeline_self_calibration.py --data data/heldout \\
        --out data/eval-heldout-view --coverage-checkpoint MODEL \\
        --self-calibration docs/self_calibration/heldout-contrast.json [--check 1]
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from hybrid import workdir as W
from hybrid.dataset import Procedure
from hybrid.evaluate import evaluate_pipeline
from hybrid.pipeline import Models, RunConfig
from learned.train import expand_inputs


def records(paths: list[Path]) -> dict[str, dict]:
    """Self-calibration records by 'folder/procedure', from eval-depth JSONs."""
    return {k: v for path in paths
            for k, v in json.loads(path.read_text())["self_calibration"].items()}


def check_record(name: str, record: dict, config: RunConfig, frames: int,
                 size: tuple[int, int]) -> None:
    """Refuse a record mapped otherwise than the run would map `frames` frames of `size`."""
    ours = {k: v for k, v in asdict(config.self_calibration).items() if k != "min_agreeing"}
    theirs = {k: record["config"].get(k) for k in ours}
    if theirs != ours or record["frames"] != frames or tuple(record["size"]) != size:
        raise SystemExit(f"{name}: its record was mapped with {theirs} on {record['frames']} "
                         f"frames of {record['size']}; the run maps {ours} on {frames} frames "
                         f"of {list(size)}")


def stretch_differences(work: Path, record: dict) -> str:
    """The run's stretches against the record's: start, fraction placed and fx of each."""
    mapped = json.loads((work / W.SELF_CALIBRATION).read_text())["stretches"]
    rows = [f"start {a['start']}: placed {a['registered']:.2f} / {b['registered']:.2f}, "
            f"fx {a['fx']} / {b['fx']}" for a, b in zip(mapped, record["stretches"], strict=True)]
    return "; ".join(rows)


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
                        help="Map the first N procedures in the run and compare.")
    args = parser.parse_args()

    config = RunConfig(depth_checkpoint=args.depth_checkpoint and str(args.depth_checkpoint),
                       coverage_checkpoint=str(args.coverage_checkpoint), self_calibrate=True)
    models = Models.load(config)
    size = (models.depth.config.height, models.depth.config.width)
    mapped = records(args.self_calibration)
    procedures = [Procedure.open(p) for p in expand_inputs(args.data)]
    checked = {}
    for k, proc in enumerate(procedures):
        name = f"{proc.path.parent.name}/{proc.path.name}"
        if name not in mapped:
            raise SystemExit(f"{name}: not in {', '.join(map(str, args.self_calibration))}")
        check_record(name, mapped[name], config, proc.num_frames, size)
        work = args.out / f"{proc.path.parent.name}-{proc.path.name}"
        if k < args.check:
            checked[name] = work
        elif not (work / W.SELF_CALIBRATION).is_file():
            work.mkdir(parents=True, exist_ok=True)
            W.write_json(work / W.SELF_CALIBRATION, mapped[name])
    result = evaluate_pipeline(procedures, args.out, config, models, echo=print)
    for name, work in checked.items():
        print(f"{name}, the run's stretches / the record's: "
              f"{stretch_differences(work, mapped[name])}")
    print(json.dumps(result["summary"], indent=1))


if __name__ == "__main__":
    main()
