"""How good the structure-from-motion training signal is, against the simulator's truth.

For the triplets that `depth_bounds.py --signal sfm` and `train-depth --maps` train on
(`learned.map_triplets.MapTriplets`: frames placed in one agreeing stretch of `c2d2
sfm-maps`'s maps), every `--every`-th one is
scored: the sparse depth's scale-free error (median over the target's points of
|log(map / true) - their median|), and the motion target -> next against the true one, the
rotation's error and the angle between the translations, for the map and for the depth
model's motion network on the same pair. Also each procedure's agreeing stretches and their
focal error, with its sign (the stretch's fx over the camera's, less 1). Prints one row per
style and writes the rows per procedure as JSON.

    .venv/bin/python benchmarks/sfm_map_quality.py --data data/train-pink data/train-dusk \\
        --maps data/sfm-maps --out docs/sfm_depth/map-quality.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix

from learned.config import DepthConfig
from learned.frames import open_sequence
from learned.map_triplets import MapTriplets, relative_motion
from learned.model import load_depth_model, to_tensor
from learned.train import TripletSampler, expand_inputs


def angle(a: torch.Tensor, b: torch.Tensor) -> float:
    """Degrees between two 3-vectors."""
    cos = torch.dot(a, b) / (a.norm() * b.norm())
    return float(torch.rad2deg(torch.arccos(cos.clamp(-1, 1))))


def rotation_error(a: torch.Tensor, b: torch.Tensor) -> float:
    """Degrees of the rotation between two axis-angle rotations' matrices."""
    Ra, Rb = axis_angle_to_rotation_matrix(torch.stack([a, b]))
    cos = (torch.trace(Ra.T @ Rb) - 1) / 2
    return float(torch.rad2deg(torch.arccos(cos.clamp(-1, 1))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--maps", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--every", type=int, default=10)
    parser.add_argument("--min-points", type=int, default=20)
    parser.add_argument("--model", type=Path,
                        default=Path("learned/checkpoints/depth-fast.safetensors"))
    args = parser.parse_args()
    config = DepthConfig()
    model = load_depth_model(args.model, "fast").eval()
    sampler = TripletSampler([open_sequence(p, (config.height, config.width))
                              for p in expand_inputs(args.data)], config.pair_gap_s)
    rows = []
    for k, seq in enumerate(sampler.sequences):
        triplets = MapTriplets([seq], [sampler.gaps[k]], args.maps, args.min_points)
        poses, fx, _, stretch, points = triplets.maps[0]
        used = np.unique(stretch[stretch >= 0])
        gap = sampler.gaps[k]
        signed = [fx[s] / seq.camera.K[0, 0] - 1 for s in used]
        row = {"procedure": seq.name, "stretches": len(fx),
               "mapped": int(np.isfinite(fx).sum()), "agreeing": len(used),
               "fx_rel": [abs(e) for e in signed], "fx_signed": signed,
               "triplets": len(triplets.triplets), "depth": [], "rotation": [],
               "translation": [], "net_rotation": [], "net_translation": []}
        for _, t in triplets.triplets[::args.every]:
            x, y, z = points[t].T
            true = seq.depth(t)[np.clip(y.round().astype(int), 0, seq.size[0] - 1),
                                np.clip(x.round().astype(int), 0, seq.size[1] - 1)]
            deviation = np.log(z[true > 0] / true[true > 0])  # 0: no surface at that pixel
            row["depth"].append(float(np.median(np.abs(deviation - np.median(deviation)))))
            mapped = relative_motion(poses, t, t + gap)
            truth = relative_motion(seq.poses, t, t + gap)
            with torch.no_grad():
                r, tr, *_ = model.pair_motion(to_tensor(seq.network_frame(t))[None],
                                              to_tensor(seq.network_frame(t + gap))[None])
            row["rotation"].append(rotation_error(mapped[0][0], truth[0][0]))
            row["translation"].append(angle(mapped[1][0], truth[1][0]))
            row["net_rotation"].append(rotation_error(r[0], truth[0][0]))
            row["net_translation"].append(angle(tr[0], truth[1][0]))
        rows.append(row)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1))
    print("| style | procedures | stretches agreeing / mapped / all | fx error (agreeing) | "
          "fx / true - 1 (agreeing) | triplets | sparse depth error | "
          "rotation error, map / network (deg) | translation angle, map / network (deg) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for style in sorted({Path(r["procedure"]).parent.name for r in rows}):
        mine = [r for r in rows if Path(r["procedure"]).parent.name == style]

        def median(key: str, of: list[dict] = mine) -> str:
            values = [v for r in of for v in r[key]]
            return f"{np.median(values):.3g}" if values else "-"

        print(f"| {style} | {len(mine)} | {sum(r['agreeing'] for r in mine)} / "
              f"{sum(r['mapped'] for r in mine)} / {sum(r['stretches'] for r in mine)} | "
              f"{median('fx_rel')} | {median('fx_signed')} | "
              f"{sum(r['triplets'] for r in mine)} | {median('depth')} | "
              f"{median('rotation')} / {median('net_rotation')} | "
              f"{median('translation')} / {median('net_translation')} |")


if __name__ == "__main__":
    main()
