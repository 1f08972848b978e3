"""Can a stretch's map tell, without the truth, that its focal length is wrong? A bound on one
figure of the map (fusion.self_calibration.Stretch) is chosen on some procedures and scored
on the others, from the stretches `c2d2 eval-depth --self-calibrate --out JSON` recorded (no
mapping is rerun; the JSONs must come from a version that kept the figures).

First, on the --select procedures, all of them and then per style: per figure, its median
over the mapped stretches within the config's `agreement` of the true fx ("right") and over
the others ("wrong"), and the chance that a random right stretch lies on the good side of a
random wrong one (0.5: the figure cannot tell them apart); and the head's fx error there.
Then, per figure, the candidate bounds are the deciles of the
figure over the --select procedures' mapped stretches; a stretch beyond the bound counts as not
mapped. The bound with the lowest fx error used on the --select procedures (the self-calibrated
K where the stretches agree, else the head's) is applied to the other procedures, per style and
over all, next to no bound. Below each, the bound among the same candidates that the other
procedures themselves would pick (not a rule: it looks at their truth), which bounds what any
choice of that figure could gain. The fallback to the head's K is scored by the head's error,
which is in-sample on training procedures (the head was trained on them), so the choice there
leans towards dropping stretches.

    .venv/bin/python benchmarks/self_calibration_quality.py --eval A.json B.json \\
        --select train-pink train-dusk
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from fusion.self_calibration import SelfCalibration, Stretch
from hybrid.dataset import Procedure

FIGURES = {"reprojection_error": -1, "track_length": 1, "points": 1, "turn": 1}
"""Each figure of a stretch's map, and its good direction (1: larger is better)."""


def fx_errors(found: dict[str, SelfCalibration], truth: dict[str, dict],
              keep: Callable[[Stretch], bool]) -> dict[str, tuple[float, bool]]:
    """Per procedure: (fx error used, whether the stretches agreed), with the stretches that
    `keep` refuses counted as not mapped."""
    errors = {}
    for name, calibration in found.items():
        kept = replace(calibration, stretches=[s if s.fx is None or keep(s) else replace(s, fx=None)
                                                for s in calibration.stretches])
        K = kept.K
        m = truth[name]
        errors[name] = ((m["fx_head_rel"], False) if K is None else
                        (abs(K[0, 0] / m["fx_true"] - 1), True))
    return errors


def within(figure: str, bound: float) -> Callable[[Stretch], bool]:
    sign = FIGURES[figure]
    return lambda s: getattr(s, figure) is not None and sign * getattr(s, figure) >= sign * bound


def separation(right: list[float], wrong: list[float], sign: int) -> float:
    """Chance that a right stretch lies on the good side of a wrong one (ties count half)."""
    r, w = sign * np.asarray(right)[:, None], sign * np.asarray(wrong)[None, :]
    return float(np.mean((r > w) + 0.5 * (r == w)))


def print_separation(label: str, names: list[str], found: dict[str, SelfCalibration],
                     truth: dict[str, dict]) -> None:
    """Per figure: its median over the `names`' mapped stretches within the config's
    `agreement` of the true fx and over the others, and their separation; then the head's mean
    fx error on `names`."""
    mapped = [(s, truth[n]["fx_true"]) for n in names for s in found[n].mapped]
    agreement = found[names[0]].config.agreement
    right = [s for s, true in mapped if abs(s.fx / true - 1) <= agreement]
    wrong = [s for s, true in mapped if abs(s.fx / true - 1) > agreement]
    print(f"\n{label}: {len(names)} procedures, {len(mapped)} mapped stretches, {len(right)} "
          f"within {agreement:.0%} of the true fx, {len(wrong)} not; the head's fx error "
          f"{np.mean([truth[n]['fx_head_rel'] for n in names]):.1%}")
    if right and wrong:
        print(f"{'figure':18s} {'right':>8s} {'wrong':>8s} {'separation':>10s}")
        for figure, sign in FIGURES.items():
            r, w = ([getattr(s, figure) for s in group] for group in (right, wrong))
            print(f"{figure:18s} {np.median(r):8.3f} {np.median(w):8.3f} "
                  f"{separation(r, w, sign):10.2f}")


def mean_used(errors: dict[str, tuple[float, bool]], names: list[str]) -> float:
    return float(np.mean([errors[n][0] for n in names]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval", type=Path, nargs="+", required=True)
    parser.add_argument("--select", nargs="+", required=True,
                        help="datasets (first part of the JSON's names) the bound is chosen on")
    parser.add_argument("--data-root", type=Path, default=Path("data"),
                        help="folder holding the datasets the JSONs' names refer to")
    args = parser.parse_args()
    found, truth = {}, {}
    for path in args.eval:
        scored = json.loads(path.read_text())
        found |= {n: SelfCalibration.from_record(r) for n, r in scored["self_calibration"].items()}
        truth |= {n: scored["procedures"][n] for n in scored["self_calibration"]}
    styles = {name: Procedure.open(args.data_root / name).style for name in found}
    select = [n for n in found if n.split("/")[0] in args.select]
    scored_names = [n for n in found if n not in select]
    if not select or not scored_names:
        parser.error("--select must name some, not all, of the JSONs' datasets")
    mapped = [(s, truth[n]["fx_true"]) for n in select for s in found[n].mapped]
    if any(getattr(s, f) is None for s, _ in mapped for f in FIGURES):
        parser.error("some mapped stretches have no map figures: the JSONs come from a version "
                     "that did not keep them; rerun c2d2 eval-depth --self-calibrate")
    print_separation("--select", select, found, truth)
    for style in sorted({styles[n] for n in select}):
        print_separation(f"--select, {style}", [n for n in select if styles[n] == style], found,
                         truth)

    groups = {style: [n for n in scored_names if styles[n] == style]
              for style in sorted({styles[n] for n in scored_names})} | {"all": scored_names}
    print(f"\n{'bound':46s} {'--select used fx':>16s}  " +
          "  ".join(f"{g + ': consensus, used fx':>26s}" for g in groups))

    def row(label: str, keep: Callable[[Stretch], bool]) -> None:
        errors = fx_errors(found, truth, keep)
        cells = [f"{sum(errors[n][1] for n in names):3d}/{len(names):<3d} "
                 f"{mean_used(errors, names):6.1%}" for names in groups.values()]
        print(f"{label:46s} {mean_used(errors, select):16.1%}  " +
              "  ".join(f"{c:>26s}" for c in cells))

    row("none", lambda s: True)
    for figure, sign in FIGURES.items():
        values = [getattr(s, figure) for s, _ in mapped]  # none missing: refused above
        bounds = np.quantile(values, np.linspace(0.1, 0.9, 9))
        for names, label in ((select, ""), (scored_names, " (best on the others)")):
            best = min(bounds, key=lambda b: mean_used(
                fx_errors(found, truth, within(figure, b)), names))
            row(f"{figure} {'>=' if sign > 0 else '<='} {best:.3g}{label}", within(figure, best))


if __name__ == "__main__":
    main()
