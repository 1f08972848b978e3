"""How much of the true scale the depth network's own scale carries, within a video and across
videos, and where real footage falls in it.

The per-frame coverage of a band 1-3 cm ahead depends on how far the wall is in centimetres,
which the median-normalised input of the per-frame network hides (the simulated colons' radius
varies 1.5-3.5 cm along the lumen). With `median_normalise=false` the network reads the depth
network's log depth as is: its own units, which no view synthesis fixes.

On every `--every`-th frame of the simulated procedures under `--sim`, this compares the log of
the depth network's median depth inside the image region with the log of the simulator's (cm).
Per procedure: their correlation and slope, the spread of the true log median (how much the
scale varies within the procedure), the spread left after the best affine fit, and the mean log
ratio (network over truth). Pooled over all procedures: correlation and slope, the spread of the
mean log ratio across procedures (the scale the network cannot tell between videos) and its
correlation with the camera's horizontal field of view. Then the percentiles of the network's
log median depth on each `--sim` folder and on each `--real` input (a video or a folder of
frames), read every `--real-every`-th frame: real footage outside the simulated range would be
read by the coverage networks out of their training distribution.

    .venv/bin/python benchmarks/depth_scale.py --sim data/cov-pink data/cov-dusk \\
        data/heldout --count 12 --real ../shared/data/cvc-clinicdb/frames \\
        ../shared/data/real-clip/colonoscopy_192px_6fps.mp4
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from hybrid.dataset import Procedure
from learned.checkpoints import SHIPPED_DEPTH
from learned.coverage_data import true_depth
from learned.coverage_nets import region_medians
from learned.frames import open_sequence
from learned.model import DepthModel, load_depth_model, to_tensor
from learned.train import expand_inputs


def log_medians(model: DepthModel, path: Path, every: int) -> np.ndarray:
    """Log of the network's median depth inside the image region, every `every`-th frame."""
    seq = open_sequence(path, (model.config.height, model.config.width))
    ids = list(range(0, seq.num_frames, every))
    with torch.no_grad():
        depth = np.concatenate([model.predict_depth(to_tensor(np.stack(
            [seq.network_frame(i) for i in ids[start:start + 32]])))[:, 0].numpy()
            for start in range(0, len(ids), 32)])
    return np.log(region_medians(depth, seq.region, str(path)))


def percentiles(name: str, values: np.ndarray) -> None:
    low, mid, high = np.percentile(values, [5, 50, 95])
    print(f"{name:60s} {len(values):6d} frames  {low:+.2f} {mid:+.2f} {high:+.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sim", type=Path, nargs="+", required=True,
                        help="folders of simulated procedures")
    parser.add_argument("--count", type=int, default=None,
                        help="the first COUNT procedures of each --sim folder")
    parser.add_argument("--every", type=int, default=60, help="frame step on simulated video")
    parser.add_argument("--real", type=Path, nargs="*", default=[],
                        help="videos or folders of frames without ground truth")
    parser.add_argument("--real-every", type=int, default=1, help="frame step on --real")
    parser.add_argument("--depth-checkpoint", type=Path, default=SHIPPED_DEPTH)
    args = parser.parse_args()
    model = load_depth_model(args.depth_checkpoint)
    model.eval()
    folders, network, truth, fov = [], [], [], []
    print("procedure            corr   slope  sd(log true)  sd(residual)  mean log(network/truth)")
    for folder in args.sim:
        for path in expand_inputs([folder])[:args.count]:
            proc = Procedure.open(path)
            ids = np.arange(0, proc.num_frames, args.every)
            net = log_medians(model, path, args.every)
            true = np.log(region_medians(*true_depth(proc, ids), str(path)))
            slope, intercept = np.polyfit(true, net, 1)
            residual = np.std(net - (slope * true + intercept))
            print(f"{path.parent.name}/{path.name:10s}  {np.corrcoef(net, true)[0, 1]:.3f}  "
                  f"{slope:.2f}   {true.std():.3f}         {residual:.3f}         "
                  f"{np.mean(net - true):+.3f}")
            folders.append(folder)
            network.append(net)
            truth.append(true)
            fov.append(proc.camera.hfov_deg)
    pooled_net, pooled_true = np.concatenate(network), np.concatenate(truth)
    slope = np.polyfit(pooled_true, pooled_net, 1)[0]
    ratio = np.array([np.mean(n - t) for n, t in zip(network, truth, strict=True)])
    print(f"{len(network)} procedures, {len(pooled_net)} frames: log median depth, network "
          f"against truth pooled: correlation {np.corrcoef(pooled_net, pooled_true)[0, 1]:.3f}, "
          f"slope {slope:.2f}; true log median: sd {pooled_true.std():.3f} pooled, "
          f"{np.mean([t.std() for t in truth]):.3f} within a procedure (mean)")
    print(f"per procedure, mean log(network / truth): sd {ratio.std():.3f} across procedures, "
          f"correlation with the field of view {np.corrcoef(ratio, fov)[0, 1]:.2f}")
    print(f"{'network log median depth: 5th / 50th / 95th percentile; mean log ratio':60s}")
    for folder in args.sim:
        mine = [i for i, f in enumerate(folders) if f == folder]
        percentiles(str(folder), np.concatenate([network[i] for i in mine]))
        print(f"{'':60s} mean log(network / truth) {ratio[mine].mean():+.3f}")
    for path in args.real:
        percentiles(str(path), log_medians(model, path, args.real_every))


if __name__ == "__main__":
    main()
