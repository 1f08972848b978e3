"""The pipeline on the real footage in ../shared/data (not shipped; no ground truth).

1. real-clip/colonoscopy_192px_6fps.mp4 (100 s, 6 fps, circular mask), run as a withdrawal
   (the default) and as an insertion.
2. CVC-ClinicDB: the 612 frames split into their 29 sequences (start frames from the data's
   README); each sequence is one image folder, played as one 10-s segment (its frame rate set to
   frames / 10 s: the frames are not adjacent, so this is a stress test).
Prints per run the segments' learned and geometric coverage, the branches' 3-class agreement
the share of frames the motion network has moving along their view (travel z > 0 before
`--insertion` negates it: a withdrawal looking back, or an advance looking ahead) and the 5th
percentile and median of the odometry's fitness between consecutive frames, and writes a JSON
summary. --coverage-checkpoint runs them with another coverage model than the shipped one.

    python benchmarks/real_runs.py --data ../shared/data --out /tmp/c2d2-real
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from hybrid import workdir as W
from learned.checkpoints import SHIPPED_COVERAGE
from learned.coverage_nets import load_coverage_model
from learned.travel import travel_features

CVC_STARTS = (1, 26, 51, 68, 79, 104, 127, 152, 178, 200, 206, 228, 253, 278, 298, 318, 343, 364,
              384, 409, 429, 448, 467, 479, 504, 529, 547, 572, 592)


def run(source: Path, out: Path, coverage: Path, *extra: str) -> dict:
    c2d2 = str(Path(sys.executable).with_name("c2d2"))
    done = subprocess.run([c2d2, "run", str(source), "--out", str(out),
                           "--coverage-checkpoint", str(coverage), *extra],
                          capture_output=True, text=True)
    if done.returncode not in (0, 3):
        return {"source": str(source), "error": done.stderr.strip().splitlines()[-1]}
    table = json.loads((out / "coverage.json").read_text())
    return {"source": str(source), "exit": done.returncode, "agreement": table["agreement"],
            "geometric_error": table["geometric_error"],
            "segments": [{k: s[k] for k in ("start_s", "end_s", "learned", "geometric",
                                            "geometric_support", "coverage",
                                            "agree", "deficient", "assessable")}
                         for s in table["segments"]],
            "intrinsics": {k: json.loads((out / "intrinsics.json").read_text())[k]
                           for k in ("fx", "fy", "cx", "cy", "width", "height")},
            "moving_along_view": moving_along_view(out, coverage),
            "odometry_fitness_gap1": json.loads((out / W.ODOMETRY).read_text())[
                "fitness_p5_median"]["1"]}


def moving_along_view(out: Path, coverage: Path) -> float:
    """Share of a run's frames whose travel (at the coverage model's gap) has z > 0."""
    ingested = json.loads((out / W.INGEST).read_text())
    gap = load_coverage_model(coverage).config.travel_frames(ingested["fps"])
    with np.load(out / W.RELATIVE) as data:
        relative = data[f"gap{gap}"]
    return float(np.mean(travel_features(relative, ingested["frames"])[:, 2] > 0))


def cvc_sequences(frames: Path, work: Path) -> list[Path]:
    """One folder of symbolic links per sequence."""
    files = sorted(frames.glob("*.png"), key=lambda p: int(p.stem))
    bounds = [*CVC_STARTS, len(files) + 1]
    folders = []
    for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        folder = work / f"cvc_seq{k:02d}"
        folder.mkdir(parents=True, exist_ok=True)
        for f in files[a - 1:b - 1]:
            link = folder / f.name
            if not link.exists():
                link.symlink_to(f.resolve())
        folders.append(folder)
    return folders


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--out", type=Path, default=Path("/tmp/c2d2-real"))
    parser.add_argument("--coverage-checkpoint", type=Path, default=SHIPPED_COVERAGE)
    args = parser.parse_args()
    clip = args.data / "real-clip" / "colonoscopy_192px_6fps.mp4"
    model = args.coverage_checkpoint
    results = {"clip-withdrawal": run(clip, args.out / "clip", model),
               "clip-insertion": run(clip, args.out / "clip-insertion", model, "--insertion")}
    for folder in cvc_sequences(args.data / "cvc-clinicdb" / "frames", args.out / "cvc-input"):
        count = len(list(folder.iterdir()))
        results[folder.name] = run(folder, args.out / folder.name, model, "--fps",
                                   f"{count / 10:g}")
    (args.out / "real_runs.json").write_text(json.dumps(results, indent=1) + "\n")
    for name, r in results.items():
        if "error" in r:
            print(f"{name:16s} error: {r['error']}")
            continue
        learned = [s["learned"] for s in r["segments"]]
        geometric = [s["geometric"] for s in r["segments"]]
        fmt = [None if v is None else round(v, 2) for v in geometric]
        print(f"{name:16s} agreement {r['agreement']}  learned {[round(v, 2) for v in learned]}"
              f"  geometric {fmt}  K fx {r['intrinsics']['fx']:.0f} "
              f"({r['intrinsics']['width']}x{r['intrinsics']['height']})  moving along the "
              f"view {r['moving_along_view']:.0%}  odometry fitness p5/median "
              f"{r['odometry_fitness_gap1']}")


if __name__ == "__main__":
    main()
