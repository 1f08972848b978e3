"""The cross-check: learned and geometric coverage on identical segments, side by side.

Reads learned.json, geometric.json (or geometric_error.txt) and ingest.json from a work
directory; writes coverage.json and coverage.csv with one row per segment: its time range,
both coverages (default Δ pair), the geometric one's support (the share of its expected wall
on reconstructed surface), their difference, both 3-class labels, whether they agree, the
two combined, a deficient flag and an assessable flag.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from hybrid import workdir as W
from hybrid.coverage import DEFAULT_PAIR_CM, pair_key
from hybrid.ingest import Ingested
from hybrid.types import InputError
from learned.coverage_eval import CLASS_EDGES, three_class

CLASS_NAMES = ("mostly not covered", "partial", "mostly covered")
"""Names of the 3-class bins (learned.coverage_eval.CLASS_EDGES)."""


def combined_coverage(learned: float | None, geometric: float | None,
                      support: float | None, geometric_weight: float) -> float | None:
    """The report's coverage of a segment: the learned and geometric values averaged with
    weights 1 and `geometric_weight` times the geometric one's support, so that a geometric
    value resting on extrapolated wall counts less (support 1 where it is not known, as in
    work folders written before it was recorded); the one value where only one branch gave
    one."""
    if geometric is None or learned is None:
        return geometric if learned is None else learned
    weight = geometric_weight * (1.0 if support is None else support)
    return float((learned + weight * geometric) / (1.0 + weight))


def coverage_class(value: float | None) -> int | None:
    return None if value is None else int(three_class(value))


@dataclass
class SegmentRow:
    """One segment of the cross-check."""

    index: int
    start_frame: int
    stop_frame: int
    start_s: float
    end_s: float
    learned: float | None
    geometric: float | None
    geometric_support: float | None
    """The share of the segment's expected wall that the geometric branch's lumen was fitted to
    (the rest is its straight continuation beyond the reconstructed surface)."""
    difference: float | None
    """learned - geometric."""
    learned_class: int | None
    geometric_class: int | None
    agree: bool | None
    """Both branches give the same 3-class label."""
    coverage: float | None
    """The branches combined (see `combined_coverage`)."""
    deficient: bool
    """Assessable and coverage below the run's threshold."""
    assessable: bool
    """Enough usable frames (not dark, overexposed or blurred)."""
    usable_fraction: float
    geometric_error: str | None = None
    """Why the geometric branch gave this segment no value (None: it gave one, or the whole
    branch failed: CrossCheck.geometric_error)."""


@dataclass
class CrossCheck:
    rows: list[SegmentRow]
    deficient_below: float
    min_usable_fraction: float
    geometric_weight: float
    geometric_error: str | None = None

    @property
    def agreement(self) -> float | None:
        """Fraction of segments with both values whose 3-class labels agree."""
        both = [r.agree for r in self.rows if r.agree is not None]
        return float(np.mean(both)) if both else None

    def to_json(self) -> dict:
        return {"default_pair_cm": list(DEFAULT_PAIR_CM),
                "class_edges": list(CLASS_EDGES), "class_names": list(CLASS_NAMES),
                "deficient_below": self.deficient_below,
                "min_usable_fraction": self.min_usable_fraction,
                "geometric_weight": self.geometric_weight,
                "agreement": self.agreement, "geometric_error": self.geometric_error,
                "segments": [asdict(r) for r in self.rows]}

    def save(self, json_path: Path, csv_path: Path) -> None:
        W.write_json(json_path, self.to_json())
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=list(asdict(self.rows[0])) if self.rows else [])
        writer.writeheader()
        for row in self.rows:
            writer.writerow({k: "" if v is None else v for k, v in asdict(row).items()})
        W.write_text(csv_path, text.getvalue())


def cross_check(out: Path, ingested: Ingested, config) -> CrossCheck:
    """Join the branches' segment coverages (config: a RunConfig's thresholds and geometric
    weight)."""
    out = Path(out)
    learned = json.loads((out / W.LEARNED).read_text())["segments"]
    geometric, support, reasons, error = {}, {}, {}, None
    if (out / W.GEOMETRIC).is_file():
        key = pair_key(DEFAULT_PAIR_CM)
        saved = json.loads((out / W.GEOMETRIC).read_text())
        for s in saved["segments"]:
            geometric[s["index"]], support[s["index"]] = s["coverage"][key], s.get("support")
        reasons = {int(k): v for k, v in saved.get("errors", {}).items()}
    elif (out / W.GEOMETRIC_ERROR).is_file():
        error = (out / W.GEOMETRIC_ERROR).read_text().strip()
    for index, value in geometric.items():  # the geometric branch never stops a video
        if value is not None and not math.isfinite(value):
            geometric[index] = None
            reasons[index] = f"the geometric coverage is not a number ({value})"
    if bad := [s["index"] for s in learned if not math.isfinite(s["coverage"])]:
        raise InputError(f"{out / W.LEARNED}: segments {bad} have a learned coverage that is "
                         f"not a number: the networks read an input out of range (a defect "
                         f"of c2d2's checks: please report it with the video)")
    usable = ingested.usable
    rows = []
    for segment in learned:
        index, start, stop = segment["index"], segment["start"], segment["stop"]
        value_l, value_g = segment["coverage"], geometric.get(index)
        combined = combined_coverage(value_l, value_g, support.get(index),
                                     config.geometric_weight)
        fraction = float(usable[start:stop].mean())
        assessable = fraction >= config.min_usable_fraction
        classes = coverage_class(value_l), coverage_class(value_g)
        rows.append(SegmentRow(
            index, start, stop, round(start / ingested.fps, 3), round(stop / ingested.fps, 3),
            value_l, value_g, support.get(index),
            None if value_g is None else value_l - value_g,
            classes[0], classes[1], None if value_g is None else classes[0] == classes[1],
            combined,
            bool(assessable and combined is not None and combined < config.deficient_below),
            bool(assessable), fraction, reasons.get(index)))
    return CrossCheck(rows, config.deficient_below, config.min_usable_fraction,
                      config.geometric_weight, error)
