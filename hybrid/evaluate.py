"""The whole pipeline on simulated procedures, against their ground truth.

Runs (or resumes) `run_video` on each procedure's RGB frames in out/<procedure>/, then compares
per segment: learned and geometric coverage against the truth (MAE, bias, 3-class accuracy)
and the 3-class agreement between the two branches. Writes out/eval.json and
out/eval_scatter.png.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hybrid import workdir as W
from hybrid.crosscheck import coverage_class
from hybrid.dataset import Procedure
from hybrid.pipeline import Models, RunConfig, run_video
from hybrid.types import InputError

log = logging.getLogger(__name__)


def _stats(pred: np.ndarray, truth: np.ndarray) -> dict:
    ok = np.isfinite(pred) & np.isfinite(truth)
    if not ok.any():
        return {"mae": None, "bias": None, "3class": None, "segments": 0}
    err = pred[ok] - truth[ok]
    same = [coverage_class(p) == coverage_class(t) for p, t in zip(pred[ok], truth[ok],
                                                                    strict=True)]
    return {"mae": float(np.abs(err).mean()), "bias": float(err.mean()),
            "3class": float(np.mean(same)), "segments": int(ok.sum())}


def evaluate_pipeline(procedures: list[Procedure], out: Path, config: RunConfig,
                      models: Models, echo: Callable[[str], None] | None = None) -> dict:
    out = Path(out)
    echo = echo or log.info
    rows = []
    for proc in procedures:
        work = out / f"{proc.path.parent.name}-{proc.path.name}"
        run_video(proc.path, work, config, models, progress=False, echo=lambda _: None)
        table = json.loads((work / W.COVERAGE_JSON).read_text())["segments"]
        truth = proc.coverage.segment_labels()
        spans = [(s.start, s.stop) for s in proc.coverage.segments]
        if [(r["start_frame"], r["stop_frame"]) for r in table] != spans:
            raise InputError(f"{proc.path}: the pipeline's segments differ from the ground "
                             f"truth's {spans[:3]}...; evaluate at the simulator's frame rate "
                             f"and segment length")
        for row, true in zip(table, truth, strict=True):
            rows.append({"procedure": str(proc.path), "segment": row["index"],
                         "truth": float(true), "learned": row["learned"],
                         "geometric": row["geometric"]})
        echo(f"{proc.path}: truth {np.round(truth, 2).tolist()} learned "
             f"{[round(r['learned'], 2) for r in table]} geometric "
             f"{[None if r['geometric'] is None else round(r['geometric'], 2) for r in table]}")
    values = {k: np.array([np.nan if r[k] is None else r[k] for r in rows], dtype=float)
              for k in ("truth", "learned", "geometric")}
    both = np.isfinite(values["learned"]) & np.isfinite(values["geometric"])
    agree = [coverage_class(a) == coverage_class(b)
             for a, b in zip(values["learned"][both], values["geometric"][both], strict=True)]
    summary = {"learned": _stats(values["learned"], values["truth"]),
               "geometric": _stats(values["geometric"], values["truth"]),
               "branch_agreement": float(np.mean(agree)) if agree else None,
               "procedures": len(procedures)}
    W.write_json(out / "eval.json", {"summary": summary, "segments": rows})
    _scatter(values, out / "eval_scatter.png")
    return {"summary": summary, "segments": rows}


def _scatter(values: dict[str, np.ndarray], path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4.3))
    pairs = [("truth", "learned"), ("truth", "geometric"), ("geometric", "learned")]
    for ax, (x, y) in zip(axes, pairs, strict=True):
        ok = np.isfinite(values[x]) & np.isfinite(values[y])
        ax.scatter(values[x][ok], values[y][ok], s=16, alpha=0.7)
        ax.plot([0, 1], [0, 1], "k--", lw=1)
        mae = np.abs(values[x][ok] - values[y][ok]).mean() if ok.any() else float("nan")
        ax.set(xlim=(0, 1), ylim=(0, 1), xlabel=x, ylabel=y,
               title=f"{y} vs {x}: mean |diff| {mae:.3f}")
        ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
