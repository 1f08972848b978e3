"""Depth maps and intrinsics on the real footage in ../shared/data (no ground truth).

For each source (CVC-ClinicDB frame sequences, the 6 fps real clip) it runs the depth model,
prints the intrinsics it estimates in the source's own pixels (median over pairs, with the
spread), and draws a figure of a few frames with their depth. With --self-calibrate it also
prints the focal length from structure from motion (fusion.self_calibration), as
`c2d2 depth --self-calibrate` would write it.

    .venv/bin/python benchmarks/real_depth_figure.py --out docs/depth_real.png
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from fusion.self_calibration import calibrate_sequence  # noqa: E402
from learned.checkpoints import SHIPPED_DEPTH  # noqa: E402
from learned.frames import open_sequence  # noqa: E402
from learned.infer import (  # noqa: E402
    aggregate_intrinsics,
    infer_sequence,
    self_calibrated_intrinsics,
)
from learned.model import load_depth_model  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
# CVC-ClinicDB sequences (first frame numbers from ../shared/data/README.md), a few of them.
CVC_SEQUENCES = [(1, 25), (104, 126), (298, 317), (467, 478)]


def cvc_sequence(first: int, last: int, folder: Path) -> Path:
    """A folder of symlinks to one CVC-ClinicDB sequence's frames."""
    folder.mkdir(parents=True, exist_ok=True)
    for n in range(first, last + 1):
        (folder / f"{n:03d}.png").symlink_to(SHARED / "cvc-clinicdb" / "frames" / f"{n:03d}.png")
    return folder


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, default=SHIPPED_DEPTH)
    parser.add_argument("--out", type=Path, default=Path("docs/depth_real.png"))
    parser.add_argument("--self-calibrate", action="store_true")
    args = parser.parse_args()
    model = load_depth_model(args.checkpoint)
    size = (model.config.height, model.config.width)
    with tempfile.TemporaryDirectory() as tmp:
        sources = {f"CVC-ClinicDB {a}-{b}": cvc_sequence(a, b, Path(tmp) / f"cvc{a}")
                   for a, b in CVC_SEQUENCES}
        sources["real clip (6 fps)"] = SHARED / "real-clip" / "colonoscopy_192px_6fps.mp4"
        rows = []
        for name, path in sources.items():
            seq = open_sequence(path, size)
            result = infer_sequence(model, seq)
            K = aggregate_intrinsics(result.K_pairs, seq.size, seq.crop, seq.fps)
            print(f"{name}: input {K['width']}x{K['height']}, fx {K['fx']:.1f} "
                  f"(std {K['spread']['fx']['std']:.1f}), fy {K['fy']:.1f}, cx {K['cx']:.1f}, "
                  f"cy {K['cy']:.1f}; pairs {K['pairs']}")
            if args.self_calibrate:
                found = calibrate_sequence(seq)
                if found.K is not None:
                    S = self_calibrated_intrinsics(K, found, seq.crop)
                    print(f"  self-calibration, input pixels: fx {S['fx']:.1f}, fy "
                          f"{S['fy']:.1f}")
                print(f"  self-calibration: {found.describe()}")
            pick = seq.num_frames // 2
            rows.append((name, seq.frame(pick), np.where(seq.region, result.depth[pick], np.nan)))
    fig, axes = plt.subplots(2, len(rows), figsize=(2.6 * len(rows), 4.4), layout="constrained")
    for col, (name, rgb, depth) in enumerate(rows):
        axes[0, col].imshow(rgb)
        axes[0, col].set_title(name, fontsize=8)
        axes[1, col].imshow(depth, cmap="viridis")
        for ax in axes[:, col]:
            ax.axis("off")
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
