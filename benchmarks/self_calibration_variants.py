"""The self-calibration of simulated procedures under a variant of its config, without the depth
network: each procedure's stretches are mapped as `c2d2 eval-depth --self-calibrate` maps them
(`fusion.self_calibration.calibrate_sequence`, the frames at the fast preset's size), with
`--set FIELD=VALUE` overriding fields of `SelfCalibrationConfig`.

Writes, after each procedure, a JSON laid out as eval-depth's (`procedures`: the true fx, and
the head's error copied from `--head`, eval-depth JSONs of the same procedures, when given;
`self_calibration`: the records), so that `benchmarks/self_calibration_rules.py` can score it
when `--head` was given; a rerun skips the procedures it holds (mapped with the same config:
another is refused). Prints per style the procedures with a consensus, its fx error, and the
mapped stretches within the config's `agreement` of the true fx.

    .venv/bin/python benchmarks/self_calibration_variants.py --data data/cov-dusk/proc_000{0..7} \\
        --set highlights=true --out data/selfcal-variants/dusk-highlights.json
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from fusion.self_calibration import (
    SelfCalibration,
    SelfCalibrationConfig,
    calibrate_sequence,
    config_of_record,
)
from hybrid.dataset import Procedure
from learned.config import DepthConfig, parse_overrides
from learned.frames import open_sequence
from learned.train import input_name


def summary(scored: dict) -> None:
    """Per style: consensus count and error, mapped stretches near the true fx."""
    rows: dict[str, list] = {}
    for name, record in scored["self_calibration"].items():
        found = SelfCalibration.from_record(record)
        true = scored["procedures"][name]["fx_true"]
        K = found.K
        near = [abs(s.fx / true - 1) <= found.config.agreement for s in found.mapped]
        rows.setdefault(scored["procedures"][name]["style"], []).append(
            (None if K is None else abs(K[0, 0] / true - 1), len(found.mapped), sum(near)))
    print("| style | procedures | consensus | its fx error | stretches mapped | of those near |")
    print("| --- | --- | --- | --- | --- | --- |")
    for style, found in sorted(rows.items()):
        errors = [e for e, _, _ in found if e is not None]
        mean = f"{np.mean(errors):.1%}" if errors else "-"
        print(f"| {style} | {len(found)} | {len(errors)} | {mean} | "
              f"{sum(m for _, m, _ in found)} | {sum(n for _, _, n in found)} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE")
    parser.add_argument("--head", type=Path, nargs="*", default=[],
                        help="eval-depth JSONs giving the head's fx error")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--workers", type=int, default=1, help="stretches mapped at once")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    defaults = SelfCalibrationConfig()
    config = replace(defaults, **parse_overrides(args.set, defaults))
    head = {name: scored for path in args.head
            for name, scored in json.loads(path.read_text())["procedures"].items()}
    scored = (json.loads(args.out.read_text()) if args.out.exists()
              else {"procedures": {}, "self_calibration": {}})
    size = (DepthConfig().height, DepthConfig().width)
    for path in args.data:
        name = input_name(path)
        if name in scored["self_calibration"]:  # mapped by an earlier run of this command
            if config_of_record(scored["self_calibration"][name]) != config:
                raise SystemExit(f"{args.out} holds {name} mapped with another config: "
                                 f"use another --out")
            continue
        seq = open_sequence(path, size)
        start = time.perf_counter()
        found = calibrate_sequence(seq, config, progress=True, workers=args.workers)
        print(f"{name}: {time.perf_counter() - start:.1f} s, {args.workers} worker(s)")
        scored["procedures"][name] = {"fx_true": float(seq.camera.fx),
                                      "style": Procedure.open(path).style,
                                      **({"fx_head_rel": head[name]["fx_head_rel"]}
                                         if name in head else {})}
        scored["self_calibration"][name] = found.record()
        args.out.parent.mkdir(parents=True, exist_ok=True)
        partial = args.out.with_suffix(".partial")
        partial.write_text(json.dumps(scored, indent=1))
        partial.replace(args.out)
    summary(scored)


if __name__ == "__main__":
    main()
