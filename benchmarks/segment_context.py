"""How much context a segment's window needs: the geometric coverage and its support with other
window sizes, on a finished `c2d2 eval`.

For each procedure of the eval (its work folders and eval.json), every segment is reconstructed
again as `c2d2 run` does (hybrid.segment_geometry), with --contexts frames either side (the
pipeline's: half a segment), and its geometric coverage (Δ = 1-4 cm) and support are compared
with the truth. Prints the MAE and bias of each context, and of the rule that takes the first
context, in the order given, whose support reaches --min-support (the last where none does):
whether a wider window helps the segments whose own window left most of their wall to the
lumen's straight continuation. The windows are built as the geometric stage builds them
(hybrid.pipeline.work_segments: the work folders' depth, poses and the whole video's metric
scale), with the current code's settings.
Writes one JSON line per segment with --out.

    python benchmarks/segment_context.py --eval data/eval-heldout --contexts 150 300 600
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from hybrid.coverage import DEFAULT_PAIR_CM, pair_key
from hybrid.pipeline import RunConfig, work_segments


def segment_values(work: Path, contexts: list[int], config: RunConfig) -> list[dict]:
    """Per segment of one work folder: {context: (coverage, support)}."""
    key = pair_key(DEFAULT_PAIR_CM)
    by_context = {c: work_segments(work, config, context=c, name=work.name) for c in contexts}
    return [{c: (by_context[c][i].segment.coverage[key], by_context[c][i].support)
             for c in contexts} for i in range(len(by_context[contexts[0]]))]


def chosen(values: dict, contexts: list[int], min_support: float) -> float | None:
    """The coverage of the first context whose support reaches min_support, else the last's."""
    for c in contexts:
        if values[c][1] is not None and values[c][1] >= min_support:
            return values[c][0]
    return values[contexts[-1]][0]


def line(label: str, pred: list[float | None], truth: list[float]) -> str:
    ok = [(p, t) for p, t in zip(pred, truth, strict=True) if p is not None]
    if not ok:
        return f"{label}: no segment has a value"
    err = np.array([p - t for p, t in ok])
    return (f"{label}: MAE {np.abs(err).mean():.4f}, bias {err.mean():+.4f} "
            f"({len(ok)} of {len(truth)} segments)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--eval", type=Path, required=True, help="output folder of c2d2 eval")
    parser.add_argument("--contexts", type=int, nargs="+", default=[150, 300, 600],
                        help="frames either side of a segment (the pipeline: half a segment)")
    parser.add_argument("--min-support", type=float, default=0.5)
    parser.add_argument("--out", type=Path, help="JSON lines, one per segment")
    args = parser.parse_args()
    if min(args.contexts) < 0:
        raise SystemExit(f"--contexts must be frame counts >= 0, got {args.contexts}")
    rows = json.loads((args.eval / "eval.json").read_text())["segments"]
    config = RunConfig()
    records = []
    for procedure in dict.fromkeys(r["procedure"] for r in rows):
        work = args.eval / f"{Path(procedure).parent.name}-{Path(procedure).name}"
        truth = [r["truth"] for r in rows if r["procedure"] == procedure]
        values = segment_values(work, args.contexts, config)
        if len(values) != len(truth):
            raise SystemExit(f"{work}: {len(values)} segments against {len(truth)} in eval.json")
        records += [{"procedure": procedure, "segment": i, "truth": t,
                     **{f"coverage_{c}": v[c][0] for c in args.contexts},
                     **{f"support_{c}": v[c][1] for c in args.contexts},
                     "chosen": chosen(v, args.contexts, args.min_support)}
                    for i, (t, v) in enumerate(zip(truth, values, strict=True))]
    truth = [r["truth"] for r in records]
    for c in args.contexts:
        low = sum(r[f"support_{c}"] is not None and r[f"support_{c}"] < args.min_support
                  for r in records)
        print(line(f"context {c}", [r[f"coverage_{c}"] for r in records], truth)
              + f"; support under {args.min_support:g}: {low}")
    print(line(f"first context with support >= {args.min_support:g}",
               [r["chosen"] for r in records], truth))
    if args.out:
        args.out.write_text("".join(json.dumps(r) + "\n" for r in records))


if __name__ == "__main__":
    main()
