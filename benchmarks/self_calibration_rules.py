"""The self-calibration's focal error by style, and under other consensus rules, from the
stretches that `c2d2 eval-depth --self-calibrate --out JSON` recorded (no mapping is rerun).

Per style and over all procedures: how many reached a consensus, the fx error of the
self-calibrated K on those and of the intrinsics head on the same procedures, and the fx error
of what a user gets (the self-calibrated K where there is one, else the head's). Each
--agreement / --min-agreeing pair is applied to the same recorded stretches.

    .venv/bin/python benchmarks/self_calibration_rules.py --eval EVAL.json \\
        --agreement 0.1 0.15 0.2 --min-agreeing 1 2 3
"""

from __future__ import annotations

import argparse
import itertools
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from fusion.self_calibration import SelfCalibration, SelfCalibrationConfig, Stretch


def rebuilt(record: dict, config: SelfCalibrationConfig) -> SelfCalibration:
    return SelfCalibration(record["frames"], [Stretch(**s) for s in record["stretches"]], config,
                           tuple(record["size"]), record["fy_over_fx"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval", type=Path, required=True)
    parser.add_argument("--data-root", type=Path, default=Path("data"),
                        help="folder holding the datasets the JSON's names refer to")
    parser.add_argument("--agreement", type=float, nargs="+", default=None)
    parser.add_argument("--min-agreeing", type=int, nargs="+", default=None)
    args = parser.parse_args()
    scored = json.loads(args.eval.read_text())
    records = scored["self_calibration"]
    recorded = SelfCalibrationConfig(**next(iter(records.values()))["config"])
    styles = {name: json.loads((args.data_root / name / "meta.json").read_text())
              ["config"]["style"] for name in records}
    print(f"{'agreement':>9s} {'min':>3s} {'style':6s} {'consensus':>9s} {'self-cal fx':>11s} "
          f"{'head, same':>10s} {'used fx':>8s} {'head fx':>8s}")
    for agreement, least in itertools.product(args.agreement or [recorded.agreement],
                                              args.min_agreeing or [recorded.min_agreeing]):
        config = replace(recorded, agreement=agreement, min_agreeing=least)
        rows = []
        for name, record in records.items():
            m = scored["procedures"][name]
            K = rebuilt(record, config).K
            self_cal = None if K is None else abs(K[0, 0] / m["fx_true"] - 1)
            rows.append((styles[name], self_cal, m["fx_head_rel"]))
        for style in [*sorted(set(styles.values())), "all"]:
            picked = [r for r in rows if style in ("all", r[0])]
            agreed = [r for r in picked if r[1] is not None]
            used = [r[2] if r[1] is None else r[1] for r in picked]

            def mean(values):
                return f"{np.mean(values):.1%}" if values else "-"

            print(f"{agreement:9.2f} {least:3d} {style:6s} {len(agreed):4d}/{len(picked):<4d} "
                  f"{mean([r[1] for r in agreed]):>11s} {mean([r[2] for r in agreed]):>10s} "
                  f"{mean(used):>8s} {mean([r[2] for r in picked]):>8s}")


if __name__ == "__main__":
    main()
