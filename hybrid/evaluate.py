"""The whole pipeline on simulated procedures, against their ground truth.

Runs (or resumes) `run_video` on each procedure's RGB frames in out/<procedure>/, then compares
per segment: learned and geometric coverage, and the report's combined coverage
(hybrid.crosscheck.combined_coverage), against the truth (MAE, bias, 3-class accuracy), and
the 3-class agreement between the two branches; the MAEs and the agreement with 95% intervals
bootstrapped over procedures. Writes out/eval.json (with the model files, the geometric
weight the combined coverage was made with, for networks that read a self-calibrated field
of view how many procedures had one, and, when the lens is told from the video, each
procedure's found lens beside its true one) and out/eval_scatter.png. With the lens told from
the video, a procedure whose stretches agree on none is listed and left out.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from hybrid import workdir as W
from hybrid.dataset import Procedure
from hybrid.pipeline import LensNotFound, Models, RunConfig, run_video
from hybrid.types import InputError
from learned.coverage_eval import procedure_interval, three_class

log = logging.getLogger(__name__)
KEYS = ("truth", "learned", "geometric", "combined")
"""The coverages of a segment that eval compares."""


def _columns(rows: list[dict]) -> dict[str, np.ndarray]:
    """Each of KEYS over rows as a float array, NaN where a row has None."""
    return {k: np.array([np.nan if r[k] is None else r[k] for r in rows], dtype=float)
            for k in KEYS}


def _stats(pred: np.ndarray, truth: np.ndarray) -> dict:
    ok = np.isfinite(pred) & np.isfinite(truth)
    if not ok.any():
        return {"mae": None, "bias": None, "3class": None, "segments": 0}
    err = pred[ok] - truth[ok]
    return {"mae": float(np.abs(err).mean()), "bias": float(err.mean()),
            "3class": _agreement(pred[ok], truth[ok]), "segments": int(ok.sum())}


def _mae(a: np.ndarray, b: np.ndarray) -> float:
    """Mean |a - b| over the pairs where both are finite."""
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.abs(a[ok] - b[ok]).mean())


def _agreement(a: np.ndarray, b: np.ndarray) -> float:
    """Share of the pairs, both finite, where a and b fall in the same 3-class bin (NaN if
    none)."""
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.mean(three_class(a[ok]) == three_class(b[ok]))) if ok.any() else np.nan


def summarise(rows: list[dict], resamples: int = 2000, seed: int = 0) -> dict:
    """MAE, bias and 3-class accuracy against the truth of each branch and of the report's
    combined coverage, and the 3-class agreement between the branches, over rows (one per
    segment: procedure, truth, learned, geometric, combined; None where there is no value).
    Each MAE and the agreement also get a 95% interval from a percentile bootstrap over the
    procedures that have a value for it (segments of one procedure are not independent);
    None with fewer than two such procedures."""
    names = list(dict.fromkeys(r["procedure"] for r in rows))
    per_procedure = [_columns([r for r in rows if r["procedure"] == name]) for name in names]

    def interval(a: str, b: str, statistic) -> list[float] | None:
        have = [p for p in per_procedure if (np.isfinite(p[a]) & np.isfinite(p[b])).any()]
        return procedure_interval(len(have), lambda picks: statistic(
            *(np.concatenate([have[i][k] for i in picks]) for k in (a, b))), resamples, seed)

    values = _columns(rows)
    summary = {}
    for branch in KEYS[1:]:
        stats = _stats(values[branch], values["truth"])
        stats["mae_ci95"] = interval(branch, "truth", _mae)
        summary[branch] = stats
    agree = _agreement(values["learned"], values["geometric"])
    summary["branch_agreement"] = None if np.isnan(agree) else agree
    summary["branch_agreement_ci95"] = interval("learned", "geometric", _agreement)
    summary["procedures"] = len(names)
    return summary


def work_folder(out: Path, proc: Procedure) -> Path:
    """A procedure's work folder under an evaluation's `out`."""
    return Path(out) / f"{proc.path.parent.name}-{proc.path.name}"


def procedure_config(config: RunConfig, proc: Procedure, known_lens: bool) -> RunConfig:
    """The run configuration of one simulated procedure: with known_lens, a fisheye one's
    field of view across the width from its camera, as a user gives the endoscope's
    specification (--fisheye-fov)."""
    if known_lens and proc.camera.model == "equidistant":
        return replace(config, fisheye_fov_deg=proc.camera.hfov_deg)
    return config


def evaluate_pipeline(procedures: list[Procedure], out: Path, config: RunConfig,
                      models: Models, echo: Callable[[str], None] | None = None,
                      known_lens: bool = False) -> dict:
    out = Path(out)
    echo = echo or log.info
    rows = []
    views: dict[str, int] = {}
    lenses: dict[str, dict] = {}
    left_out: dict[str, str] = {}
    for proc in procedures:
        work = work_folder(out, proc)
        try:
            run_video(proc.path, work, procedure_config(config, proc, known_lens), models,
                      progress=False, echo=lambda _: None)
        except LensNotFound as err:
            echo(f"left out: {err}")
            left_out[str(proc.path)] = str(err)
            continue
        finally:
            if config.find_lens and (work / W.LENS).is_file():
                lenses[str(proc.path)] = {
                    "found": json.loads((work / W.LENS).read_text())["lens"],
                    "true": {"model": proc.camera.model, "width_deg": proc.camera.hfov_deg}}
        if "field_of_view" in (learned := json.loads((work / W.LEARNED).read_text())):
            source = learned["field_of_view"]["source"]
            views[source] = views.get(source, 0) + 1
        table = json.loads((work / W.COVERAGE_JSON).read_text())["segments"]
        truth = proc.coverage.segment_labels()
        spans = [(s.start, s.stop) for s in proc.coverage.segments]
        if [(r["start_frame"], r["stop_frame"]) for r in table] != spans:
            raise InputError(f"{proc.path}: the pipeline's segments differ from the ground "
                             f"truth's {spans[:3]}...; evaluate at the simulator's frame rate "
                             f"and segment length")
        for row, true in zip(table, truth, strict=True):
            rows.append({"procedure": str(proc.path), "segment": row["index"],
                         "truth": float(true) if np.isfinite(true) else None,
                         "learned": row["learned"],
                         "geometric": row["geometric"], "combined": row["coverage"],
                         "geometric_support": row.get("geometric_support")})
        echo(f"{proc.path}: truth {np.round(truth, 2).tolist()} learned "
             f"{[round(r['learned'], 2) for r in table]} geometric "
             f"{[None if r['geometric'] is None else round(r['geometric'], 2) for r in table]}")
    if procedures and len(left_out) == len(procedures):
        raise InputError(f"every procedure was left out, its lens not told from its video (the "
                         f"first: {next(iter(left_out.values()))})")
    summary = summarise(rows)
    result = {"summary": summary, "checkpoints": models.tags,
              "geometric_weight": config.geometric_weight,
              "self_calibrate": config.self_calibrate, "field_of_view": views or None,
              "known_lens": known_lens, "find_lens": config.find_lens,
              "lenses": lenses or None, "left_out": left_out or None,
              "segments": rows}
    W.write_json(out / "eval.json", result)
    _scatter(rows, out / "eval_scatter.png")
    return result


def _scatter(rows: list[dict], path: Path) -> None:
    import matplotlib.pyplot as plt

    values = _columns(rows)
    fig, axes = plt.subplots(1, 4, figsize=(17, 4.3))
    pairs = [("truth", "learned"), ("truth", "geometric"), ("truth", "combined"),
             ("geometric", "learned")]
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
