"""The lens `c2d2 run --find-lens` tells, input by input, without running the rest.

Runs the run's lens stage (`hybrid.pipeline.tell_lens` under `RunConfig().lens_search`:
structure from motion with the one-coefficient fisheye camera on up to 5 stretches of 120
frames of the input as recorded, 3 of which must agree) on each simulated procedure of the
folders given (their true lens and angle across the width from camera.json) and on each
video or image folder (lens unknown). It prints what it finds, then per true lens how many
were told right, wrong or not at all, and the angle's error for the fisheyes told.

    python benchmarks/find_lens.py --data data/heldout --procedures 12
    python benchmarks/find_lens.py --inputs ../shared/data/real-clip/colonoscopy_192px_6fps.mp4
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lens_from_sfm import inputs_parser, true_lenses

from hybrid.pipeline import RunConfig, tell_lens
from learned.config import DEPTH_PRESETS

_SIZE = (DEPTH_PRESETS["fast"].height, DEPTH_PRESETS["fast"].width)
"""The frames' size: the shipped depth network's, as the run's lens stage reads them."""


def main() -> None:
    args = inputs_parser(__doc__.splitlines()[0], None).parse_args()
    truth = true_lenses(args)
    told: dict[str, list[tuple[str, float]]] = {}
    for path in [*truth, *map(str, args.inputs)]:
        found = tell_lens(Path(path), _SIZE, RunConfig(), workers=args.workers)
        lens, angle = truth.get(path, ("unknown", float("nan")))
        print(f"{path} (true: {lens}, {angle:.1f} deg): {found.describe()}", flush=True)
        got = found.lens
        told.setdefault(lens, []).append(("none", np.nan) if got is None else
                                         (got.model, got.width_deg - angle))
    for lens, results in told.items():
        models = [m for m, _ in results]
        counts = ", ".join(f"{models.count(m)} {m}" for m in ("equidistant", "pinhole", "none"))
        errors = np.array([e for m, e in results if m == "equidistant" == lens])
        angle = (f"; angle error median {np.median(errors):+.1f}, median absolute "
                 f"{np.median(np.abs(errors)):.1f}, largest {np.abs(errors).max():.1f} deg"
                 if errors.size else "")
        print(f"true {lens}: {len(results)} inputs told {counts}{angle}")


if __name__ == "__main__":
    main()
