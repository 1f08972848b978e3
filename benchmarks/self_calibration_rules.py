"""The self-calibration's focal error by style, and under other consensus rules, from the
stretches that `c2d2 eval-depth --self-calibrate --out JSON` recorded (no mapping is rerun).

First, per style, the stretches as recorded: how many were mapped, how many of those lie
more than the recorded `agreement` from the true fx (and how many of these read too long, and
how many had every frame placed), and how many procedures mapped any stretch (and their first
one). Then, per style and over all procedures: how many reached a consensus, the fx error of
the self-calibrated K on those and of the intrinsics head on the same procedures, and the fx
error of what a user gets (the self-calibrated K where there is one, else the head's). Each
combination of --agreement, --min-agreeing and --min-field-of-view is applied to the same
recorded stretches; what is not given stays each record's own rule (column fov: "own").

    .venv/bin/python benchmarks/self_calibration_rules.py --eval EVAL.json [EVAL2.json ...] \\
        --agreement 0.1 0.15 0.2 --min-agreeing 1 2 3 [--min-field-of-view 0 60]
"""

from __future__ import annotations

import argparse
import itertools
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from fusion.self_calibration import SelfCalibration
from hybrid.dataset import Procedure


def percent(values: list[float]) -> str:
    return f"{np.mean(values):.1%}" if values else "-"


def print_stretches(found: dict[str, SelfCalibration], fx_true: dict[str, float],
                    styles: dict[str, str]) -> None:
    """Per style: mapped stretches, those far from the true fx (and how many of those read
    long), procedures that mapped any."""
    for style in sorted(set(styles.values())):
        names = [n for n in found if styles[n] == style]
        mapped = [(s, fx_true[n]) for n in names for s in found[n].mapped]
        far = [(s, true) for s, true in mapped
               if abs(s.fx / true - 1) > found[names[0]].config.agreement]
        any_mapped = [n for n in names if found[n].mapped]
        first = [n for n in any_mapped if found[n].mapped[0].start == 0]
        print(f"{style}: {len(mapped)} stretches mapped, {len(far)} of them more than "
              f"{found[names[0]].config.agreement:.0%} off the true fx "
              f"({sum(s.fx > true for s, true in far)} too long; "
              f"{sum(s.registered == 1 for s, _ in far)} with every frame placed); "
              f"{len(any_mapped)} of {len(names)} procedures mapped a stretch, "
              f"{len(first)} of them their first")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval", type=Path, nargs="+", required=True,
                        help="one or more JSONs (of different procedures), pooled")
    parser.add_argument("--data-root", type=Path, default=Path("data"),
                        help="folder holding the datasets the JSON's names refer to")
    parser.add_argument("--agreement", type=float, nargs="+", default=None)
    parser.add_argument("--min-agreeing", type=int, nargs="+", default=None)
    parser.add_argument("--min-field-of-view", type=float, nargs="+", default=None)
    args = parser.parse_args()
    scored = {"procedures": {}, "self_calibration": {}}
    for path in args.eval:
        run = json.loads(path.read_text())
        for key in scored:
            scored[key] |= run[key]
    found = {name: SelfCalibration.from_record(record)
             for name, record in scored["self_calibration"].items()}
    recorded = next(iter(found.values())).config
    styles = {name: Procedure.open(args.data_root / name).style for name in found}
    print_stretches(found, {n: scored["procedures"][n]["fx_true"] for n in found}, styles)
    print(f"{'agreement':>9s} {'min':>3s} {'fov':>4s} {'style':6s} {'consensus':>9s} "
          f"{'self-cal fx':>11s} {'head, same':>10s} {'used fx':>8s} {'head fx':>8s}")
    for agreement, least, bound in itertools.product(
            args.agreement or [recorded.agreement], args.min_agreeing or [recorded.min_agreeing],
            args.min_field_of_view or [None]):
        rows = []
        for name, calibration in found.items():  # each under its own rule but these
            m = scored["procedures"][name]
            config = replace(calibration.config, agreement=agreement, min_agreeing=least,
                             **({} if bound is None else {"min_field_of_view": bound}))
            K = replace(calibration, config=config).K
            self_cal = None if K is None else abs(K[0, 0] / m["fx_true"] - 1)
            rows.append((styles[name], self_cal, m["fx_head_rel"]))
        for style in [*sorted(set(styles.values())), "all"]:
            picked = [r for r in rows if style in ("all", r[0])]
            agreed = [r for r in picked if r[1] is not None]
            used = [r[2] if r[1] is None else r[1] for r in picked]
            print(f"{agreement:9.2f} {least:3d} {'own' if bound is None else f'{bound:g}':>4s} "
                  f"{style:6s} {len(agreed):4d}/{len(picked):<4d} "
                  f"{percent([r[1] for r in agreed]):>11s} "
                  f"{percent([r[2] for r in agreed]):>10s} "
                  f"{percent(used):>8s} {percent([r[2] for r in picked]):>8s}")


if __name__ == "__main__":
    main()
