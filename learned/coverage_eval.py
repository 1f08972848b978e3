"""Metrics and plots of predicted against true coverage (paper section 5.2), with intervals
bootstrapped over procedures."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hybrid.coverage import DELTA_PAIRS_CM, pair_key

CLASS_EDGES = (0.4, 0.8)
"""3-class bins: [0, 0.4) mostly not covered, [0.4, 0.8) partial, [0.8, 1] mostly covered."""


def three_class(coverage: np.ndarray) -> np.ndarray:
    """0, 1 or 2 per coverage value."""
    return np.digitize(np.asarray(coverage), CLASS_EDGES)


def bias_per_class(pred: np.ndarray, true: np.ndarray) -> list[float]:
    """Mean pred - true over the values of each 3-class bin of the truth (NaN for an empty
    bin)."""
    pred, true = np.asarray(pred, float), np.asarray(true, float)
    classes = three_class(true)
    return [float((pred - true)[classes == c].mean()) if (classes == c).any() else np.nan
            for c in range(3)]


@dataclass
class Predictions:
    """Pooled predictions and truth over procedures (per-frame (N, 3) per Δ pair; segments)."""

    frame_pred: list[np.ndarray] = field(default_factory=list)
    frame_true: list[np.ndarray] = field(default_factory=list)
    segment_pred: list[np.ndarray] = field(default_factory=list)
    segment_true: list[np.ndarray] = field(default_factory=list)

    def add(self, frame_pred, frame_true, segment_pred, segment_true) -> None:
        self.frame_pred.append(frame_pred)
        self.frame_true.append(frame_true)
        self.segment_pred.append(segment_pred)
        self.segment_true.append(segment_true)

    def extend(self, other: Predictions) -> None:
        for column in ("frame_pred", "frame_true", "segment_pred", "segment_true"):
            getattr(self, column).extend(getattr(other, column))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return (np.concatenate(self.frame_pred), np.concatenate(self.frame_true),
                np.concatenate(self.segment_pred), np.concatenate(self.segment_true))


def coverage_metrics(predictions: Predictions) -> dict:
    """Per-frame MAE per Δ pair, per-segment MAE, bias and 3-class accuracy, with counts, and
    how well deficient segments (coverage below the lowest class edge) are found: the share of
    them flagged (recall) and the share of flagged segments that are (precision). A figure
    with nothing to average over (no segment, nothing flagged) is None."""
    frame_pred, frame_true, seg_pred, seg_true = predictions.arrays()
    out: dict = {}
    for k, pair in enumerate(DELTA_PAIRS_CM):
        ok = np.isfinite(frame_true[:, k])
        out[f"frame_mae_{pair_key(pair)}"] = _mean(np.abs(frame_pred[ok, k] - frame_true[ok, k]))
    out["frames"] = int(np.isfinite(frame_true).any(axis=1).sum())
    ok = np.isfinite(seg_true)
    error = seg_pred[ok] - seg_true[ok]
    out["segment_mae"] = _mean(np.abs(error))
    out["segment_bias"] = _mean(error)
    out["segment_3class_accuracy"] = _mean(three_class(seg_pred[ok]) == three_class(seg_true[ok]))
    out["segments"] = int(ok.sum())
    flagged, deficient = seg_pred[ok] < CLASS_EDGES[0], seg_true[ok] < CLASS_EDGES[0]
    out["deficient_recall"] = _mean(flagged[deficient])
    out["deficient_precision"] = _mean(deficient[flagged])
    return out


def _mean(values: np.ndarray) -> float | None:
    return float(np.mean(values)) if len(values) else None


def procedure_interval(procedures: int, statistic: Callable[[np.ndarray], float],
                       resamples: int = 2000, seed: int = 0) -> list[float] | None:
    """95% percentile-bootstrap interval of statistic(picks), picks being procedure indices
    drawn with replacement (segments of one procedure are not independent, so procedures are
    resampled whole); None with fewer than two procedures."""
    import scipy.stats  # here: the pipeline imports this module, and scipy.stats is slow to load

    if procedures < 2:
        return None
    bounds = scipy.stats.bootstrap(
        (np.arange(procedures),), statistic, vectorized=False, n_resamples=resamples,
        method="percentile", random_state=seed).confidence_interval
    return [float(bounds.low), float(bounds.high)]


def segment_mae_interval(predictions: Predictions) -> list[float] | None:
    """95% interval of the segment MAE, bootstrapped over the procedures (one per `add`) that
    have a segment with a defined truth."""
    errors = [np.abs(p - t)[np.isfinite(t)]
              for p, t in zip(predictions.segment_pred, predictions.segment_true, strict=True)]
    errors = [e for e in errors if e.size]
    return procedure_interval(len(errors), lambda picks: float(
        np.mean(np.concatenate([errors[i] for i in picks]))))


def procedure_segments(predictions: Predictions, names: list[str]) -> dict:
    """Each procedure's segment truth (None where undefined) and learned prediction, by name,
    in the form benchmarks/eval_spread.py reads (its mode `learned`)."""
    if len(names) != len(predictions.segment_pred) or len(set(names)) != len(names):
        raise ValueError(f"{len(predictions.segment_pred)} procedures need as many distinct "
                         f"names, got {names}")
    return {name: {"truth": [float(t) if np.isfinite(t) else None for t in truth],
                   "learned": {"pred": [float(p) for p in pred]}}
            for name, pred, truth in zip(names, predictions.segment_pred,
                                         predictions.segment_true, strict=True)}


def format_table(rows: dict[str, dict]) -> str:
    """One line per named metrics dict, the names in full."""
    keys = [f"frame_mae_{pair_key(p)}" for p in DELTA_PAIRS_CM] + [
        "segment_mae", "segment_bias", "segment_3class_accuracy", "deficient_recall",
        "deficient_precision", "segments"]
    width = max([18, *map(len, rows)])
    head = " " * width + "".join(f"{k.replace('segment_', 'seg_'):>16.15s}" for k in keys)
    lines = [head]
    for name, m in rows.items():
        lines.append(f"{name:{width}s}" + "".join(
            f"{'n/a':>16s}" if m[k] is None else f"{m[k]:16d}" if isinstance(m[k], int)
            else f"{m[k]:16.4f}" for k in keys))
    return "\n".join(lines)


def scatter_plots(predictions: Predictions, out: Path, title: str) -> Path:
    """Predicted against true coverage: one panel per Δ pair (frames) and one for segments."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frame_pred, frame_true, seg_pred, seg_true = predictions.arrays()
    fig, axes = plt.subplots(1, 4, figsize=(16, 4.2))
    panels = [(frame_true[:, k], frame_pred[:, k], f"per frame, Δ = {pair_key(p)} cm", 2)
              for k, p in enumerate(DELTA_PAIRS_CM)]
    panels.append((seg_true, seg_pred, "per segment (default Δ)", 12))
    for ax, (truth, pred, name, size) in zip(axes, panels, strict=True):
        ok = np.isfinite(truth)
        ax.scatter(truth[ok], pred[ok], s=size, alpha=0.3 if size < 5 else 0.7, lw=0)
        ax.plot([0, 1], [0, 1], "k--", lw=1)
        for edge in CLASS_EDGES:
            ax.axvline(edge, color="0.8", lw=0.8)
            ax.axhline(edge, color="0.8", lw=0.8)
        mae = np.abs(pred[ok] - truth[ok]).mean() if ok.any() else float("nan")
        ax.set(xlim=(0, 1), ylim=(0, 1), xlabel="true coverage", ylabel="predicted coverage",
               title=f"{name}\nMAE {mae:.3f}, n = {ok.sum()}")
        ax.set_aspect("equal")
    fig.suptitle(title)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
