"""How much one procedure weighs in an evaluation: each branch's (or mode's) MAE over all
segments and the largest change when one procedure's segments are left out; then its MAE
and bias by the segment's place in its video (first, middle, last: a video's first segment
has context frames after it only, its last before it only); for `c2d2 eval`, the geometric
branch's MAE and bias also by its support (the share of the segment's expected wall on the
lumen fitted to the reconstruction: all of it, at least half, less than half), and the
branches' 3-class agreement by the same bins. With --versus OTHER.json MODE OTHER_MODE, over
the segments both files give a value for (procedures matched by folder name, which must then
be unique in each file): in how many procedures MODE errs less or more than OTHER_MODE of the
other file, the difference of their MAEs with a 95% interval bootstrapped over those
procedures as `c2d2 eval` does (paired: the same procedures are drawn for both), and both
MAEs; for two `c2d2 eval` files, also both files' agreement of the branches over the
segments they share, and the segments whose branches agree in one and not in the other.

Reads the eval.json of `c2d2 eval` (branches learned, geometric and the report's combined
coverage), the geometric_eval.json of benchmarks/geometric_eval.py (each of its modes) or the
metrics.json of `c2d2 eval-coverage` (mode learned).

    python benchmarks/eval_spread.py data/eval-sim-w03/eval.json
    python benchmarks/eval_spread.py docs/geometric/thinned/geometric_eval.json
    python benchmarks/eval_spread.py data/eval-heldout-6fps/eval.json \
        --versus data/eval-heldout-support-vscale/eval.json geometric geometric
    python benchmarks/eval_spread.py data/eval-heldout-cov72/eval.json \
        --versus data/eval-heldout-s44/eval.json combined combined
    python benchmarks/eval_spread.py data/runs/coral-nbi72/coral/metrics.json \
        --versus data/runs/coral-nbi72/no-coral/metrics.json learned learned
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import NamedTuple

import numpy as np

from learned.coverage_eval import procedure_interval, three_class


class Row(NamedTuple):
    procedure: str
    segment: int
    segments: int
    """How many segments the procedure has."""
    error: float
    """Predicted minus true coverage."""
    support: float | None = None
    """The geometric branch's support (c2d2 eval written since it had one), else None."""


def pipeline_eval(data: dict) -> bool:
    """Whether data is c2d2 eval's (a list of segments with both branches)."""
    return isinstance(data.get("segments"), list)


def errors(data: dict) -> dict[str, list[Row]]:
    """Per branch or mode: a row for every segment with a value."""
    if pipeline_eval(data):
        counts: dict[str, int] = {}
        for s in data["segments"]:
            counts[s["procedure"]] = max(counts.get(s["procedure"], 0), s["segment"] + 1)
        return {branch: [Row(s["procedure"], s["segment"], counts[s["procedure"]],
                             s[branch] - s["truth"],
                             s.get("geometric_support") if branch == "geometric" else None)
                         for s in data["segments"] if s.get(branch) is not None]
                for branch in ("learned", "geometric", "combined")}
    if "procedures" not in data:
        raise SystemExit("no segments to read: a metrics.json of eval-coverage written before "
                         "2026-11-30 holds none; evaluate again")
    rows: dict[str, list[Row]] = {}
    for name, procedure in data["procedures"].items():
        truth = procedure["truth"]
        for mode, result in procedure.items():
            if isinstance(result, dict) and "pred" in result:
                rows.setdefault(mode, []).extend(
                    Row(name, k, len(truth), p - t)
                    for k, (p, t) in enumerate(zip(result["pred"], truth, strict=True))
                    if p is not None and t is not None and np.isfinite(p) and np.isfinite(t))
    return rows


SUPPORT_BINS = ("all", "half or more", "under half")


def support_bin(support: float | None) -> str | None:
    """A geometric support as 'all', 'half or more' or 'under half' (None: not known)."""
    if support is None:
        return None
    return "all" if support >= 1 else "half or more" if support >= 0.5 else "under half"


def place(row: Row) -> str:
    """first, middle or last segment of its video (a one-segment video's is first)."""
    return "first" if row.segment == 0 else "last" if row.segment == row.segments - 1 \
        else "middle"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("json", type=Path, help="eval.json of c2d2 eval, geometric_eval.json, "
                        "or metrics.json of c2d2 eval-coverage")
    parser.add_argument("--versus", nargs=3, metavar=("OTHER_JSON", "MODE", "OTHER_MODE"),
                        help="compare MODE with the other file's OTHER_MODE on the segments "
                             "both have: procedures where it errs less or more, and the "
                             "paired MAE difference with its interval")
    args = parser.parse_args()
    data = json.loads(args.json.read_text())
    branches = errors(data)
    for branch, rows in branches.items():
        procedures = sorted({r.procedure for r in rows})
        mae = np.mean([abs(r.error) for r in rows])
        left_out = np.array([np.mean([abs(r.error) for r in rows if r.procedure != p])
                             for p in procedures])
        print(f"{branch:13s} MAE {mae:.3f}; leaving one of {len(procedures)} procedures out "
              f"gives {left_out.min():.3f}-{left_out.max():.3f}, up to "
              f"{np.max(np.abs(left_out - mae)):.3f} away")
        by_place = {name: [r.error for r in rows if place(r) == name]
                    for name in ("first", "middle", "last")}
        print(f"{'':13s} by the segment's place in its video: " + ", ".join(
            f"{name} MAE {np.abs(e).mean():.3f} bias {np.mean(e):+.3f} ({len(e)})"
            for name, e in by_place.items() if e))
        by_support = {name: [r.error for r in rows if support_bin(r.support) == name]
                      for name in SUPPORT_BINS}
        if any(by_support.values()):
            print(f"{'':13s} by the support of its V: " + ", ".join(
                f"{name} MAE {np.abs(e).mean():.3f} bias {np.mean(e):+.3f} ({len(e)})"
                for name, e in by_support.items() if e))
    if pipeline_eval(data):  # both branches
        print_agreement_by_support(data["segments"])
    if args.versus:
        other, mode, other_mode = args.versus
        other_data = json.loads(Path(other).read_text())
        print_versus(branches[mode], errors(other_data)[other_mode],
                     f"{mode} against {other}'s {other_mode}")
        if pipeline_eval(data) and pipeline_eval(other_data):
            print_agreement_changes(data["segments"], other_data["segments"])


def segment_errors(rows: list[Row]) -> dict[str, dict[int, float]]:
    """Each segment's absolute error by procedure folder name, then segment index; an error
    if two procedures of the rows share a folder name (they could not be matched)."""
    by_name: dict[str, dict[int, float]] = {}
    paths: dict[str, str] = {}
    for r in rows:
        name = Path(r.procedure).name
        if paths.setdefault(name, r.procedure) != r.procedure:
            raise SystemExit(f"--versus matches procedures by folder name, but {paths[name]} "
                             f"and {r.procedure} share one: compare evaluations of one data folder")
        by_name.setdefault(name, {})[r.segment] = abs(r.error)
    return by_name


def print_versus(rows: list[Row], other: list[Row], label: str) -> None:
    """Over the segments both have: in how many procedures the rows err less, more or the
    same, the paired difference of the MAEs with its bootstrap interval, and both MAEs."""
    mine, theirs = segment_errors(rows), segment_errors(other)
    pairs = [np.array([(mine[name][k], theirs[name][k])
                       for k in sorted(mine[name].keys() & theirs[name].keys())]).reshape(-1, 2)
             for name in sorted(mine.keys() & theirs.keys())]
    pairs = [p for p in pairs if p.size]
    diffs = [p[:, 0] - p[:, 1] for p in pairs]
    if not diffs:
        print(f"{label}: no segment has a value in both")
        return
    less = sum(d.mean() < 0 for d in diffs)
    more = sum(d.mean() > 0 for d in diffs)
    print(f"{label}: MAE lower in {less}, higher in {more}, the same in "
          f"{len(diffs) - less - more} of {len(diffs)} procedures")
    bounds = procedure_interval(len(diffs), lambda picks: float(
        np.mean(np.concatenate([diffs[i] for i in picks]))))
    interval = "" if bounds is None else f" [{bounds[0]:+.4f}, {bounds[1]:+.4f}]"
    print(f"{'':13s} MAE difference over the {sum(d.size for d in diffs)} segments both "
          f"give: {np.mean(np.concatenate(diffs)):+.4f}{interval} (95%, bootstrapped over "
          f"{len(diffs)} procedures)")
    both = np.concatenate(pairs)
    print(f"{'':13s} their MAE: {both[:, 0].mean():.4f}, the other's {both[:, 1].mean():.4f}")


def print_agreement_changes(segments: list[dict], other: list[dict]) -> None:
    """Both c2d2 eval files' agreement of the branches over the segments they share (matched
    as in --versus), and the segments whose branches agree in one and not in the other, with
    both files' values."""
    def agree(s: dict) -> bool | None:
        if s["learned"] is None or s["geometric"] is None:
            return None
        return bool(three_class(s["learned"]) == three_class(s["geometric"]))

    theirs = {(Path(s["procedure"]).name, s["segment"]): s for s in other}
    matched = [(s, theirs[key]) for s in segments
               if (key := (Path(s["procedure"]).name, s["segment"])) in theirs
               and None not in (agree(s), agree(theirs[key]))]
    if matched:
        print(f"agreement over the {len(matched)} segments where both give both branches: "
              f"{np.mean([agree(s) for s, _ in matched]):.3f}, the other's "
              f"{np.mean([agree(t) for _, t in matched]):.3f}")
    changed = [(s, t) for s, t in matched if agree(s) != agree(t)]
    print(f"agreement changed in {len(changed)} segments: "
          f"{sum(agree(s) for s, _ in changed)} now agree, "
          f"{sum(not agree(s) for s, _ in changed)} no longer")
    for s, t in changed:
        print(f"  {Path(s['procedure']).name} segment {s['segment']}: truth {s['truth']:.3f}, "
              f"learned {t['learned']:.3f} -> {s['learned']:.3f}, geometric "
              f"{t['geometric']:.3f} -> {s['geometric']:.3f}, "
              f"{'agree' if agree(s) else 'disagree'}")


def print_agreement_by_support(segments: list[dict]) -> None:
    """The branches' 3-class agreement by the geometric support's bin."""
    both = [s for s in segments if s["learned"] is not None and s["geometric"] is not None
            and s.get("geometric_support") is not None]
    bins: dict[str, list[bool]] = {}
    for s in both:
        bins.setdefault(support_bin(s["geometric_support"]), []).append(
            bool(three_class(s["learned"]) == three_class(s["geometric"])))
    if bins:
        print("agreement by the geometric support: " + ", ".join(
            f"{name} {np.mean(bins[name]):.3f} ({len(bins[name])})"
            for name in SUPPORT_BINS if name in bins))


if __name__ == "__main__":
    main()
