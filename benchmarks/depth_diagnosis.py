"""Where a trained depth model sits against the truth, and how sharply the loss separates them.

Whole-image procedures only (others are refused): it feeds their frames to the networks as
they are, where c2d2 fills the black corners of ones simulated with `--octagon`
(FrameSequence.network_frame).

On simulated procedures, for triplets every `--every` frames:
  1. The training loss (learned.losses.view_synthesis_loss, the model's own config) at the
     truth (true depth, motion and K) and at the model's prediction. A model whose loss is
     higher than the truth's has not found the optimum of its own loss.
  2. The model's systematic errors: the slope of log(predicted depth) against log(true depth)
     per frame (1: no compression); the relative depth error (median scaling per frame) of the
     nearest quarter, the middle half and the farthest tenth of the pixels by true depth; the
     ratio of predicted to true rotation angle over pairs turning more than 2 degrees, the
     least-squares slope of predicted on true rotation about each camera axis (x right, y
     down, z forward), and the ratio of predicted to true fx.
  3. For each number of coarse levels, the loss at the truth and its ratio when the truth is
     spoiled in the model's ways: depth compressed to gt^0.63 or gt^0.8, focal length x0.8,
     rotation angles x0.65 (depth compressed about the target's median depth, so its scale
     against the true translation is kept). Larger ratios: a loss that tells the truth apart
     more sharply; and the depth-consistency term (before its weight) for each. The
     procedures must be rendered at the model's input size (the fast
     preset's simulator output is).

    .venv/bin/python benchmarks/depth_diagnosis.py \
        --model learned/checkpoints/depth-fast.safetensors --data data/val
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from hybrid.dataset import Procedure, list_procedures
from learned.config import DepthConfig
from learned.flow import flows_to_sources
from learned.losses import view_synthesis_loss
from learned.map_triplets import relative_motion
from learned.model import load_depth_model, to_tensor

SPOILED = {"depth^0.63": {"power": 0.63}, "depth^0.8": {"power": 0.8},
           "focal x0.8": {"focal": 0.8}, "rotation x0.65": {"rotation": 0.65}}


def triplets(procs: list[Procedure], gap_s: float, every: int):
    """(procedure, frames (1, 3, 3, H, W), true depths [3 x (1, 1, H, W)], true motions, K)."""
    for proc in procs:
        gap = max(1, round(proc.camera.fps * gap_s))
        K = torch.tensor(proc.camera.K, dtype=torch.float32)[None]
        for t in range(gap, proc.num_frames - gap, every):
            ids = (t - gap, t, t + gap)
            frames = torch.stack([to_tensor(proc.rgb(i)) for i in ids])[None]
            depths = [torch.from_numpy(proc.depth(i))[None, None].clamp(min=0.01) for i in ids]
            yield proc, frames, depths, [relative_motion(proc.poses, t, s) for s in ids[::2]], K


def loss_of(frames, depths, motions, K, config: DepthConfig, power: float = 1.0,
            focal: float = 1.0, rotation: float = 1.0) -> dict[str, float]:
    """The loss terms (LossTerms.as_floats) at the truth spoiled as asked."""
    K = K.clone()
    K[:, 0, 0] *= focal
    K[:, 1, 1] *= focal
    motions = [(r * rotation, t, r_back * rotation, t_back) for r, t, r_back, t_back in motions]
    # Compress about the target's median depth, so that the scale against the true
    # translation stays right and only the shape changes.
    median = depths[1][depths[1] > 0.01].median()
    depths = [d**power * median ** (1 - power) for d in depths]
    region = torch.ones(1, 1, *frames.shape[-2:])
    torch.manual_seed(0)  # the same auto-mask tie-breaking everywhere
    sources = [frames[:, 0], frames[:, 2]]
    return view_synthesis_loss(frames[:, 1], sources, depths[1], [depths[0], depths[2]],
                               motions, K, region, config,
                               flows_to_sources(frames[:, 1], sources, config)).as_floats()


def axis_slopes(predicted: np.ndarray, true: np.ndarray) -> list[float]:
    """Least-squares slope of predicted on true rotation (N, 3) about each camera axis."""
    return [float(predicted[:, k] @ true[:, k] / (true[:, k] @ true[:, k])) for k in range(3)]


def systematic_errors(model, procs: list[Procedure], gap_s: float) -> dict[str, float]:
    slopes, rotations, focals, truths, errors = [], [], [], [], []
    axes_pred, axes_true = [], []
    with torch.no_grad():
        for proc in procs:
            gap = max(1, round(proc.camera.fps * gap_s))
            ts = np.arange(gap, proc.num_frames, 7)
            a = torch.stack([to_tensor(proc.rgb(t - gap)) for t in ts])
            b = torch.stack([to_tensor(proc.rgb(t)) for t in ts])
            rotation, _, _, _, K = model.pair_motion(a, b)
            focals.append(float(K[:, 0, 0].median()) / proc.camera.fx)
            vectors = np.concatenate([relative_motion(proc.poses, t - gap, t)[0].numpy()
                                      for t in ts])
            axes_pred.append(rotation.numpy())
            axes_true.append(vectors)
            true = np.linalg.norm(vectors, axis=1)
            turning = true > np.radians(2.0)
            rotations += list(rotation.norm(dim=1).numpy()[turning] / true[turning])
            depth = model.predict_depth(b[::10])[:, 0].numpy()
            for pred, t in zip(depth, ts[::10], strict=True):
                gt = proc.depth(int(t))
                ok = gt > 0
                slopes.append(np.polyfit(np.log(gt[ok]), np.log(pred[ok]), 1)[0])
                scaled = pred[ok] * np.median(gt[ok] / pred[ok])
                truths.append(gt[ok])
                errors.append(np.abs(scaled - gt[ok]) / gt[ok])
    truth, error = np.concatenate(truths), np.concatenate(errors)
    q25, q75, q90 = np.percentile(truth, [25, 75, 90])
    slopes_xyz = axis_slopes(np.concatenate(axes_pred), np.concatenate(axes_true))
    return {"log-log slope": float(np.median(slopes)),
            "error nearest 25%": float(error[truth < q25].mean()),
            "error middle 50%": float(error[(truth >= q25) & (truth < q75)].mean()),
            "error farthest 10%": float(error[truth >= q90].mean()),
            "rotation ratio": float(np.median(rotations)),
            **{f"rotation slope {axis}": v for axis, v in zip("xyz", slopes_xyz, strict=True)},
            "fx ratio": float(np.mean(focals))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--every", type=int, default=50, help="frames between target frames")
    parser.add_argument("--levels", type=int, nargs="+", default=[0, 1, 2, 3])
    args = parser.parse_args()
    torch.set_num_threads(1)
    model = load_depth_model(args.model)
    # The view-synthesis loss only (a chain-trained model's loss would need chain targets),
    # as the ordinary batches see it (photo_blur_on may keep photo_blur to the map batches).
    model.config = replace(model.config, w_chain=0.0).ordinary_view()
    procs = [p for d in args.data for p in list_procedures(d, whole_images=True)]
    truth, predicted = [], []
    for _, frames, depths, motions, K in triplets(procs, model.config.pair_gap_s, args.every):
        truth.append(loss_of(frames, depths, motions, K, model.config)["total"])
        with torch.no_grad():
            torch.manual_seed(0)
            region = torch.ones(1, 1, *frames.shape[-2:])
            predicted.append(float(model.loss(frames, region).total))
    print(f"training loss ({len(truth)} triplets, coarse_levels "
          f"{model.config.coarse_levels}): truth {np.mean(truth):.4f}, "
          f"model {np.mean(predicted):.4f}")
    print("systematic errors: " + ", ".join(
        f"{k} {v:.2f}" for k, v in systematic_errors(model, procs,
                                                     model.config.pair_gap_s).items()))
    for levels in args.levels:
        config = replace(model.config, coarse_levels=levels)
        rows: dict[str, list[dict]] = {"truth": [], **{k: [] for k in SPOILED}}
        for _, frames, depths, motions, K in triplets(procs, config.pair_gap_s, args.every):
            rows["truth"].append(loss_of(frames, depths, motions, K, config))
            for name, spoil in SPOILED.items():
                rows[name].append(loss_of(frames, depths, motions, K, config, **spoil))
        mean = {k: {term: np.mean([r[term] for r in v]) for term in v[0]}
                for k, v in rows.items()}
        base = mean["truth"]["total"]
        print(f"coarse_levels {levels}: truth {base:.4f}  " + "  ".join(
            f"{k} x{m['total'] / base:.3f}" for k, m in mean.items() if k != "truth"))
        print("  its depth-consistency term: " + "  ".join(
            f"{k} {m['depth_consistency']:.4f}" for k, m in mean.items()))


if __name__ == "__main__":
    main()
