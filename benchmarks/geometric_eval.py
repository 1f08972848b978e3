"""Geometric coverage against the simulator's ground truth, with oracle and with learned inputs.

Modes (each: pose graph where learned, TSDF, lumen fit, geometric coverage):
  oracle        true depth, K and poses, metric scale known
  oracle-s0.7   the same with every length scaled by 0.7 (the scale rule 30% short) ...
  oracle-s1.3   ... or 30% long: how coverage moves when the assumed radius is 30% off
  oracle-rule   true depth, K and poses, scale from the typical-radius rule
  learned       the shipped depth model's depth, K and relative poses (the pose graph's
                gaps, --skips), refined by RGB-D odometry (--no-odometry: not), smoothed by
                the pose graph, scale from the typical-radius rule
  learned-local the same inputs, each segment reconstructed on its own window (the segment
                and half a segment either side: hybrid.segment_geometry) at the window's own
                scale rule, as `c2d2 run` did until 2026-11-28 (it now takes the whole
                video's scale)
  learned-local-true-K  the same with the true K in the odometry and the reconstruction
Where the learned-local error comes from: each segment on its own window as in learned-local,
with the metric scale taken from the truth (one factor per procedure, the median ratio of true
to learned depth, applied to the learned depth and translations alike), and
  local-oracle  every input true
  local-metric  every input learned
  local-depth   learned depth, true K and poses (the true translations put in the learned
                depth's unit, which the scale turns into cm)
  local-K       learned K, true depth and poses
  local-poses   learned (smoothed) poses, true depth and K
  local-poses-true-odometry  the same poses with the odometry run on the true depth and K
                (the network's relative poses, put in cm, as its start): how much of the
                poses' cost the odometry could win back if the depth it reads were right
                (--odometry-depth-blend A: on true ** (1 - A) * learned ** A, the learned
                depth put in cm, so that A = 0.5 errs about half as much in log depth)
  local-poses-true-start  the same odometry started from the true relative poses: what the
                odometry's own objective costs, where its start is right
  local-poses-true-pairs  the true relative poses of the graph's gaps, smoothed by the pose
                graph with no odometry: what the graph's smoothing alone costs
  local-depth-surface     the learned depth for the surface reconstructed (and the lumen
                fitted to it), the true depth for the visibility test; K and poses true
  local-depth-visibility  the other way round
Prints MAE, bias and 3-class accuracy per mode, the lumen fit errors, and the frames/s of the
pose graph + TSDF + coverage, then the MAE by style; writes a JSON (benchmarks/eval_spread.py
splits it by the segment's place in its video) and a scatter plot.

    python benchmarks/geometric_eval.py --data data/test data/cov-dusk --out docs/geometric
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from fusion.odometry import OdometryConfig, refine_relative_poses
from fusion.posegraph import PoseGraphConfig, smooth_trajectory
from hybrid.coverage import DEFAULT_PAIR_CM, Lumen, pair_key
from hybrid.dataset import Procedure
from hybrid.geometric_coverage import GeometricConfig, geometric_coverage
from hybrid.reconstruction import ReconstructionConfig, ScaledDepth, reconstruct
from hybrid.segment_geometry import local_segment_coverage
from learned.coverage_eval import three_class
from learned.frames import open_sequence
from learned.infer import infer_sequence
from learned.metrics import mre, umeyama_sim3
from learned.model import load_depth_model
from learned.train import expand_inputs, input_name

LOCAL_SWAPS = {"local-oracle": (), "local-metric": ("depth", "K", "poses"),
               "local-depth": ("depth",), "local-K": ("K",), "local-poses": ("poses",)}
"""Diagnostic modes: which inputs are the learned ones (the rest true), scale from the truth."""
BASIC_MODES = ("oracle", "oracle-s0.7", "oracle-s1.3", "oracle-rule", "learned", "learned-local")
TRUE_ODOMETRY = "local-poses-true-odometry"
POSE_PROBES = {TRUE_ODOMETRY: "poses_true_odometry", "local-poses-true-start": "poses_true_start",
               "local-poses-true-pairs": "poses_true_pairs"}
"""Diagnostic modes of the poses alone (depth and K true, poses in cm): their poses' key."""
DEPTH_SPLIT = ("local-depth-surface", "local-depth-visibility")
"""Diagnostic modes: the learned depth for one of its two uses, the true depth for the other."""
MODES = (*BASIC_MODES, "learned-local-true-K", *LOCAL_SWAPS, *POSE_PROBES, *DEPTH_SPLIT)
LOCAL_MODES = ("learned-local", "learned-local-true-K", *LOCAL_SWAPS, *POSE_PROBES, *DEPTH_SPLIT)


def lumen_errors(fitted_points: np.ndarray, fitted_radius: np.ndarray, proc: Procedure,
                 poses: np.ndarray) -> dict:
    """Mean distance from the fitted centreline (within the camera's ℓ range + 6 cm) to the
    true one, and the radius error against the median wall distance around it."""
    true = Lumen(proc.lumen)
    ell_cam, _ = true.project(poses[:, :3, 3])
    ell, near = true.project(fitted_points)
    keep = (ell >= ell_cam.min()) & (ell <= ell_cam.max() + 6.0)
    mesh = proc.mesh()
    v_ell, v_near = true.project(mesh.vertices)
    v_r = np.linalg.norm(mesh.vertices - v_near, axis=1)
    order = np.argsort(v_ell)
    r_true = []
    for e in ell[keep]:
        a, b = np.searchsorted(v_ell[order], [e - 0.25, e + 0.25])
        r_true.append(np.median(v_r[order[a:b]]))
    return {"centreline_cm": float(np.linalg.norm(fitted_points - near, axis=1)[keep].mean()),
            "radius_error_cm": float(np.mean(fitted_radius[keep] - np.array(r_true)))}


def depth_ratio(learned: list[np.ndarray], true: list[np.ndarray], stride: int = 10) -> float:
    """The median ratio of true to learned depth over the pixels of every stride-th frame: the
    factor that makes the learned depth (and translations, in the same unit) centimetres."""
    if learned[0].shape != true[0].shape:
        raise SystemExit(f"learned and true depth side by side need the simulator's frames "
                         f"at the network's size: {true[0].shape} against {learned[0].shape}")
    ratios = []
    for pred, gt in zip(learned[::stride], true[::stride], strict=True):
        ok = (pred > 0) & (gt > 0)
        ratios.append(gt[ok] / pred[ok])
    return float(np.median(np.concatenate(ratios)))


def scaled_translations(poses: np.ndarray, factor: float) -> np.ndarray:
    """A copy of (..., 4, 4) poses with their translations times factor (a change of unit)."""
    poses = poses.copy()
    poses[..., :3, 3] *= factor
    return poses


def true_relative(poses: np.ndarray, gaps: tuple[int, ...]) -> dict[int, np.ndarray]:
    """The true relative poses of each gap as infer_sequence gives them: [g][t] maps camera
    t's points into camera t+g."""
    return {g: np.linalg.inv(poses[g:]) @ poses[:-g] for g in gaps}


def blended(true: list[np.ndarray], learned: list[np.ndarray], to_cm: float, weight: float
            ) -> list[np.ndarray]:
    """true ** (1 - weight) * (learned * to_cm) ** weight per frame, 0 where the truth is."""
    return [np.where(t > 0, np.maximum(t, 1e-6) ** (1 - weight)
                     * (np.asarray(n, np.float64) * to_cm) ** weight, 0.0).astype(np.float32)
            for t, n in zip(true, learned, strict=True)]


def learned_inputs(proc: Procedure, model, graph: PoseGraphConfig, odometry: OdometryConfig,
                   true_K_too: bool = False, probe: dict | None = None,
                   keep_translation: bool = False) -> dict:
    """The depth model's depth and K, the smoothed poses (odometry first, unless off, with
    refine_relative_poses' diagnostic arguments `probe`; with keep_translation the odometry's
    rotations and the start's translations), and the seconds of the networks and of
    the odometry + pose graph; with true_K_too also the poses smoothed after an odometry with
    the true K ('poses_true_K'); and 'smoothed', the function that makes the poses, for
    other depth and K."""
    tic = time.time()
    seq = open_sequence(proc.path, (model.config.height, model.config.width))
    inferred = infer_sequence(model, seq, tuple(sorted({1, *graph.skips})))
    out = {"depth": list(inferred.depth), "K": np.median(inferred.K_pairs, axis=0),
           "gaps": tuple(inferred.relative), "network_s": time.time() - tic}
    tic = time.time()
    frames = [seq.frame(i) for i in range(seq.num_frames)] if odometry.enabled else []

    def smoothed(K: np.ndarray, depth: list[np.ndarray] | None = None, to_cm: float = 1.0,
                 start: dict[int, np.ndarray] | None = None) -> tuple[np.ndarray, dict | None]:
        """The network's relative poses (translations times to_cm), or those of `start`,
        refined by odometry on `depth` (the network's if None) and K, then smoothed."""
        depth = out["depth"] if depth is None else depth
        relative = start if start is not None else {
            g: scaled_translations(rel, to_cm) for g, rel in inferred.relative.items()}
        kept = None
        if odometry.enabled:
            refined = refine_relative_poses(relative, depth, frames, K, seq.region,
                                            odometry, name=str(proc.path), **(probe or {}))
            if keep_translation:
                for g, rel in refined.relative.items():
                    rel[:, :3, 3] = relative[g][:, :3, 3]
            relative, kept = refined.relative, refined.kept
        return smooth_trajectory(relative, graph, name=str(proc.path)).poses, kept

    out["smoothed"] = smoothed
    out["poses"], kept = smoothed(out["K"])
    out["graph_s"] = time.time() - tic
    if kept is not None:
        out["odometry_kept"] = kept
    if true_K_too:
        tic = time.time()
        out["poses_true_K"], _ = smoothed(proc.camera.K)
        out["graph_s_true_K"] = time.time() - tic
    return out


def local_row(mode: str, proc: Procedure, learned: dict, depth_true: list[np.ndarray],
              config: ReconstructionConfig, geometric: GeometricConfig) -> dict:
    """Each segment on its own window (hybrid.segment_geometry): learned-local, or one of the
    diagnostics with the metric scale from the truth."""
    seen = None  # the depth of the visibility test, where not the reconstructed one
    if mode == "learned-local":
        depth, K, poses, scale = learned["depth"], learned["K"], learned["poses"], None
    elif mode == "learned-local-true-K":
        depth, K, poses, scale = learned["depth"], proc.camera.K, learned["poses_true_K"], None
    elif mode in POSE_PROBES:  # poses already in cm
        depth, K, poses, scale = depth_true, proc.camera.K, learned[POSE_PROBES[mode]], 1.0
    else:  # the depth-split modes are local-depth with one use of the depth swapped back
        swap, to_cm = LOCAL_SWAPS["local-depth" if mode in DEPTH_SPLIT else mode], learned["to_cm"]
        depth = learned["depth"] if "depth" in swap else depth_true
        K = learned["K"] if "K" in swap else proc.camera.K
        poses = learned["poses"] if "poses" in swap else proc.poses
        # depth and translations must share one unit, which `scale` makes cm
        if "poses" in swap and "depth" not in swap:  # learned translations to the true cm
            poses = scaled_translations(poses, to_cm)
        if "depth" in swap and "poses" not in swap:  # true translations to the learned unit
            poses = scaled_translations(poses, 1.0 / to_cm)
        scale = to_cm if "depth" in swap else 1.0
        if mode in DEPTH_SPLIT:  # the true depth, in the learned depth's unit, for one use
            seen = [d / to_cm for d in depth_true]
            if mode == "local-depth-visibility":
                depth, seen = seen, depth
    segment_frames = proc.coverage.segment_frames
    local = local_segment_coverage(depth, K, poses, segment_frames, segment_frames // 2, None,
                                   config, geometric, proc.camera.fps, proc.path.name,
                                   scale=scale, visibility_depth=seen)
    for s in local:  # a segment without a value is left out of the MAE: say why
        if s.error:
            print(f"{mode}: {proc.path.name} segment {s.segment.index}: {s.error}",
                  file=sys.stderr)
    key = pair_key(DEFAULT_PAIR_CM)
    return {"pred": [np.nan if s.segment.coverage[key] is None else s.segment.coverage[key]
                     for s in local],
            "network_seconds": 0.0, "centreline_cm": np.nan, "radius_error_cm": np.nan}


def whole_video_row(mode: str, proc: Procedure, learned: dict, depth_true: list[np.ndarray],
                    rgb: list[np.ndarray], config: ReconstructionConfig,
                    geometric: GeometricConfig) -> dict:
    """One reconstruction and lumen for the whole video: the oracle modes, or learned."""
    if mode == "learned":
        depth, K, poses = learned["depth"], learned["K"], learned["poses"]
        network_s, scale = learned["network_s"], None
    else:
        depth, K, poses, network_s = depth_true, proc.camera.K, proc.poses, 0.0
        scale = {"oracle": 1.0, "oracle-s0.7": 0.7, "oracle-s1.3": 1.3,
                 "oracle-rule": None}[mode]
    rec = reconstruct(depth, K, poses, rgb, config=config, scale=scale, fps=proc.camera.fps,
                      name=proc.path.name)
    result = geometric_coverage(rec.lumen, rec.poses, ScaledDepth(depth, rec.scale), K,
                                config=geometric)
    row = {"pred": result.labels().tolist(), "scale": rec.scale, "network_seconds": network_s}
    if mode == "learned":  # compare the lumen in the true frame after Sim(3) alignment
        s, R, t = umeyama_sim3(rec.poses[:, :3, 3], proc.poses[:, :3, 3])
        row.update(lumen_errors(s * rec.lumen.points @ R.T + t, s * rec.lumen.radius, proc,
                                proc.poses))
    else:
        back = 1.0 / rec.scale  # to the simulator's cm
        row.update(lumen_errors(rec.lumen.points * back, rec.lumen.radius * back, proc,
                                proc.poses))
    return row


def run_procedure(proc: Procedure, model, graph: PoseGraphConfig, odometry: OdometryConfig,
                  config: ReconstructionConfig, geometric: GeometricConfig,
                  modes: tuple[str, ...] = MODES, probe: dict | None = None,
                  keep_translation: bool = False, blend: float = 0.0) -> dict:
    truth = proc.coverage.segment_labels()
    depth_true = [proc.depth(i) for i in range(proc.num_frames)]
    out = {"truth": truth.tolist()}
    whole_video = [m for m in modes if m not in LOCAL_MODES]
    rgb = [proc.rgb(i) for i in range(proc.num_frames)] if whole_video else []
    learned = {}
    if any(m.startswith("learned") or m in (*LOCAL_SWAPS, *POSE_PROBES, *DEPTH_SPLIT)
           for m in modes):
        learned = learned_inputs(proc, model, graph, odometry,
                                 true_K_too="learned-local-true-K" in modes, probe=probe,
                                 keep_translation=keep_translation)
        if "odometry_kept" in learned:  # pairs the odometry could not align, per gap
            out["odometry_kept"] = learned["odometry_kept"]
        if any(m in (*LOCAL_SWAPS, TRUE_ODOMETRY, *DEPTH_SPLIT) for m in modes):
            learned["to_cm"] = depth_ratio(learned["depth"], depth_true)
        gaps = learned["gaps"]
        if TRUE_ODOMETRY in modes:  # the depth its odometry reads, and that depth's MRE
            read = blended(depth_true, learned["depth"], learned["to_cm"], blend) if blend \
                else depth_true
            out["odometry_depth_mre"] = float(np.mean([
                mre(r, t) for r, t in zip(read[::20], depth_true[::20], strict=True)]))
            print(f"{proc.path}: the true-odometry's depth, MRE "
                  f"{out['odometry_depth_mre']:.3f}", flush=True)
        probes = {TRUE_ODOMETRY: lambda: learned["smoothed"](proc.camera.K, read,
                                                            learned["to_cm"])[0],
                  "local-poses-true-start": lambda: learned["smoothed"](
                      proc.camera.K, depth_true, start=true_relative(proc.poses, gaps))[0],
                  "local-poses-true-pairs": lambda: smooth_trajectory(
                      true_relative(proc.poses, gaps), graph, name=str(proc.path)).poses}
        for mode in (m for m in modes if m in POSE_PROBES):
            tic = time.time()
            learned[POSE_PROBES[mode]] = probes[mode]()
            learned["graph_s_" + POSE_PROBES[mode]] = time.time() - tic
    for mode in modes:
        tic = time.time()
        if mode in whole_video:
            row = whole_video_row(mode, proc, learned, depth_true, rgb, config, geometric)
        else:
            row = local_row(mode, proc, learned, depth_true, config, geometric)
        # seconds: the geometry, with the odometry + pose graph where that mode's poses ran them
        graph_s = {"learned": learned.get("graph_s"), "learned-local": learned.get("graph_s"),
                   "local-metric": learned.get("graph_s"),
                   "learned-local-true-K": learned.get("graph_s_true_K"),
                   **{m: learned.get("graph_s_" + key) for m, key in POSE_PROBES.items()}
                   }.get(mode) or 0.0
        row.update(seconds=time.time() - tic + graph_s, frames=proc.num_frames)
        out[mode] = row
        scale = f"scale {row['scale']:6.3f}  " if "scale" in row else ""
        print(f"{proc.path}: {mode:12s} {scale}truth {np.round(truth, 2).tolist()}  pred "
              f"{np.round(row['pred'], 2).tolist()}  {row['seconds']:5.1f} s", flush=True)
    return out


def summary(results: dict, modes: tuple[str, ...]) -> dict:
    table = {}
    for mode in modes:
        truth = np.concatenate([r["truth"] for r in results.values()])
        pred = np.concatenate([r[mode]["pred"] for r in results.values()])
        ok = np.isfinite(truth) & np.isfinite(pred)
        err = pred[ok] - truth[ok]
        frames = sum(r[mode]["frames"] for r in results.values())
        table[mode] = {
            "mae": float(np.abs(err).mean()), "bias": float(err.mean()),
            "3class": float((three_class(pred[ok]) == three_class(truth[ok])).mean()),
            "segments": int(ok.sum()),
            "centreline_cm": float(np.mean([r[mode]["centreline_cm"] for r in results.values()])),
            "radius_error_cm": float(np.mean([r[mode]["radius_error_cm"]
                                              for r in results.values()])),
            "geometry_fps": frames / sum(r[mode]["seconds"] for r in results.values()),
        }
    return table


def scatter(results: dict, modes: tuple[str, ...], path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(modes), figsize=(4.5 * len(modes), 4.4), squeeze=False)
    for ax, mode in zip(axes[0], modes, strict=True):
        truth = np.concatenate([r["truth"] for r in results.values()])
        pred = np.concatenate([r[mode]["pred"] for r in results.values()])
        ax.scatter(truth, pred, s=14, alpha=0.7)
        ax.plot([0, 1], [0, 1], "k--", lw=1)
        ok = np.isfinite(truth) & np.isfinite(pred)
        ax.set(xlim=(0, 1), ylim=(0, 1), xlabel="true segment coverage",
               ylabel="geometric coverage",
               title=f"{mode} inputs: MAE {np.abs(pred[ok] - truth[ok]).mean():.3f}")
        ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", nargs="+", type=Path, default=[Path("data/test")])
    parser.add_argument("--out", type=Path, default=Path("docs/geometric"))
    parser.add_argument("--checkpoint", type=Path, default=None)
    parser.add_argument("--modes", nargs="+", default=list(BASIC_MODES), choices=MODES,
                        help="default: all but the local-* diagnostics")
    parser.add_argument("--occlusion-tolerance", type=float,
                        default=GeometricConfig().occlusion_tolerance,
                        help="GeometricConfig.occlusion_tolerance (× local radius)")
    parser.add_argument("--skips", type=int, nargs="+", default=list(PoseGraphConfig().skips),
                        help="PoseGraphConfig.skips: the frame gaps whose relative poses "
                             "become pose-graph factors")
    for field in ("rotation_sigma", "translation_sigma", "gap_exponent", "velocity_weight"):
        parser.add_argument("--" + field.replace("_", "-"), type=float,
                            default=getattr(PoseGraphConfig(), field),
                            help="see PoseGraphConfig")
    parser.add_argument("--voxel-cm", type=float, default=ReconstructionConfig().voxel_cm,
                        help="ReconstructionConfig.voxel_cm: TSDF voxel size once the scale "
                             "is fixed")
    parser.add_argument("--no-odometry", action="store_true",
                        help="give the pose graph the network's relative poses unrefined")
    parser.add_argument("--odometry-iterations", type=int, nargs="+",
                        default=list(OdometryConfig().iterations),
                        help="OdometryConfig.iterations: per pyramid level, coarsest first")
    parser.add_argument("--odometry-depth-max", type=float, default=float("inf"),
                        help="refine_relative_poses' depth_max: deeper pixels (in median "
                             "depths) are left out of the alignment")
    parser.add_argument("--odometry-light-power", type=float, default=0.0,
                        help="refine_relative_poses' light_power: the colour times (depth / "
                             "median depth) ** this, undoing a light at the camera")
    parser.add_argument("--odometry-method", default="hybrid",
                        choices=("hybrid", "point-to-plane", "intensity"),
                        help="refine_relative_poses' method")
    parser.add_argument("--odometry-median", type=float, default=None,
                        help="refine_relative_poses' median: the depth's median while aligned "
                             "(default: the depth's own unit)")
    parser.add_argument("--odometry-depth-blend", type=float, default=0.0,
                        help=f"{TRUE_ODOMETRY}'s odometry reads true ** (1 - A) * learned ** A")
    parser.add_argument("--odometry-keep-translation", action="store_true",
                        help="keep the odometry's rotations only, each pair's translation "
                             "staying the network's (or the start's)")
    args = parser.parse_args()
    modes = tuple(args.modes)
    geometric = GeometricConfig(occlusion_tolerance=args.occlusion_tolerance)
    torch.set_num_threads(1)
    from learned.checkpoints import SHIPPED_DEPTH

    model = load_depth_model(args.checkpoint or SHIPPED_DEPTH)
    graph = PoseGraphConfig(skips=tuple(args.skips), rotation_sigma=args.rotation_sigma,
                            translation_sigma=args.translation_sigma,
                            gap_exponent=args.gap_exponent, velocity_weight=args.velocity_weight)
    config = ReconstructionConfig(voxel_cm=args.voxel_cm)
    odometry = OdometryConfig(enabled=not args.no_odometry,
                              iterations=tuple(args.odometry_iterations))
    for mode in (TRUE_ODOMETRY, "local-poses-true-start"):
        if mode in modes and not odometry.enabled:
            parser.error(f"{mode} runs the odometry: drop --no-odometry")
    if not 0 <= args.odometry_depth_blend <= 1:
        parser.error("--odometry-depth-blend must lie in [0, 1]")
    if args.odometry_depth_blend and TRUE_ODOMETRY not in modes:
        parser.error(f"--odometry-depth-blend is read by {TRUE_ODOMETRY} alone: add it to "
                     f"--modes")
    if args.odometry_keep_translation and not odometry.enabled:
        parser.error("--odometry-keep-translation keeps the odometry's rotations: drop "
                     "--no-odometry")
    probe = {"depth_max": args.odometry_depth_max, "light_power": args.odometry_light_power,
             "method": args.odometry_method, "median": args.odometry_median}
    paths = {input_name(p): p for p in expand_inputs(args.data)}
    results = {name: run_procedure(Procedure.open(p), model, graph, odometry, config, geometric,
                                   modes, probe, args.odometry_keep_translation,
                                   args.odometry_depth_blend)
               for name, p in paths.items()}
    table = summary(results, modes)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "geometric_eval.json").write_text(json.dumps(
        {"options": vars(args), "summary": table, "procedures": results}, indent=1,
        default=str) + "\n")
    scatter(results, modes, args.out / "geometric_scatter.png")
    print(f"{'mode':12s} {'MAE':>6s} {'bias':>7s} {'3-class':>8s} {'n':>4s} "
          f"{'centre cm':>9s} {'r err cm':>8s} {'fps':>6s}")
    for mode, m in table.items():
        print(f"{mode:12s} {m['mae']:6.3f} {m['bias']:7.3f} {m['3class']:8.3f} "
              f"{m['segments']:4d} {m['centreline_cm']:9.3f} {m['radius_error_cm']:8.3f} "
              f"{m['geometry_fps']:6.0f}")
    print_by_style(results, paths, modes)


def print_by_style(results: dict, paths: dict[str, Path], modes: tuple[str, ...]) -> None:
    """The MAE of each mode over the procedures of each appearance style."""
    styles = {name: Procedure.open(path).style for name, path in paths.items()}
    for style in sorted(set(styles.values())):
        part = {name: r for name, r in results.items() if styles[name] == style}
        print(f"{style} ({len(part)} procedures): " + ", ".join(
            f"{mode} MAE {m['mae']:.3f} ({m['segments']} segments)"
            for mode, m in summary(part, modes).items()))


if __name__ == "__main__":
    main()
