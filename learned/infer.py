"""Depth, ego-motion and intrinsics for a video, an image folder or a simulated procedure.

Writes into the output folder:
    depth/000000.npy       float32 (H, W) depth at the network's size, over the cropped region
    region.png             the detected image region (white) at the network's size
    relative_poses.npy     (N-1, 4, 4) transform mapping camera t's points into camera t+1
    poses.npy              (N, 4, 4) camera-to-world poses chained from them (first = identity)
    intrinsics.json        one K for the whole input, in the input's own pixels, with its spread
Depth and translation share one unknown scale.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm

from hybrid.types import Camera, InputError, chain_poses
from learned.device import device_of
from learned.frames import Crop, FrameSequence
from learned.model import DepthModel, to_tensor


class DepthFiles:
    """depth/NNNNNN.npy files, written as slices of frames are assigned (infer_sequence's
    depth_out), so that a long video's depth never sits in memory."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)

    def __setitem__(self, frames: slice, depth: np.ndarray) -> None:
        for i, d in zip(range(frames.start, frames.stop), depth, strict=True):
            np.save(self.folder / f"{i:06d}.npy", d.astype(np.float32))


@dataclass
class DepthOutput:
    """Everything inferred for one input, at the network's size."""

    depth: np.ndarray | DepthFiles
    """(N, H, W) float32, or the files it was written to."""
    relative: np.ndarray
    """(N-1, 4, 4) float64, camera t -> camera t+1."""
    K_pairs: np.ndarray
    """(N-1, 3, 3) per-pair intrinsics at the network's size."""

    @property
    def poses(self) -> np.ndarray:
        """(N, 4, 4) camera-to-world poses chained from the relative ones."""
        return chain_poses(self.relative)


@torch.no_grad()
def infer_sequence(model: DepthModel, seq: FrameSequence, batch: int = 16,
                   progress: bool = False, frames: range | None = None,
                   depth_out: DepthFiles | None = None) -> DepthOutput:
    """Run the networks over consecutive frames of seq (all, or the given range). Depth is
    kept in the result, or written into depth_out (index 0: the range's first frame)."""
    model.eval()
    frames = range(seq.num_frames) if frames is None else frames
    if len(frames) < 2:
        raise InputError(f"{seq.name}: depth and motion need at least 2 frames")
    depth, relative, K_pairs = [], [], []
    previous = None
    for start in tqdm(range(frames.start, frames.stop, batch), desc=f"depth {seq.name}",
                      disable=not progress, unit="batch"):
        ids = range(start, min(start + batch, frames.stop))
        images = to_tensor(np.stack([seq.frame(i) for i in ids]), device_of(model))
        predicted = model.depth(images)[:, 0].cpu().numpy()
        if depth_out is None:
            depth.append(predicted)
        else:
            depth_out[ids.start - frames.start:ids.stop - frames.start] = predicted
        chain = images if previous is None else torch.cat([previous, images])
        if len(chain) > 1:
            T, K = model.pair_transform(chain[:-1], chain[1:])
            relative.append(T.cpu().numpy())
            K_pairs.append(K.cpu().numpy())
        previous = images[-1:]
    return DepthOutput(np.concatenate(depth) if depth_out is None else depth_out,
                       np.concatenate(relative), np.concatenate(K_pairs).astype(np.float64))


@torch.no_grad()
def relative_poses(model: DepthModel, seq: FrameSequence, gaps: tuple[int, ...], batch: int = 16,
                   frames: range | None = None, progress: bool = False) -> dict[int, np.ndarray]:
    """Relative poses of frame pairs (t, t+g) for every gap g, over all frames or the range.

    Returns {g: (M-g, 4, 4) float64}, M the number of frames: entry t maps points of frame t's
    camera into frame t+g's (fusion.posegraph's input). Each is the mean of the forward and
    the inverted backward estimate. Frames are decoded once per batch of first frames.
    """
    model.eval()
    frames = range(seq.num_frames) if frames is None else frames
    if len(frames) < 2:
        raise InputError(f"{seq.name}: relative poses need at least 2 frames")
    if not gaps or any(g < 1 for g in gaps):
        raise InputError(f"relative-pose gaps must be positive frame counts, got {gaps}")
    relative = {g: [np.empty((0, 4, 4))] for g in gaps}
    for start in tqdm(range(frames.start, frames.stop, batch), desc=f"motion {seq.name}",
                      disable=not progress, unit="batch"):
        stop = min(start + batch + max(gaps), frames.stop)
        images = to_tensor(np.stack([seq.frame(i) for i in range(start, stop)]),
                           device_of(model))
        for g in gaps:
            firsts = min(batch, len(images) - g)
            if firsts <= 0:
                continue
            T = model.pair_transform(images[:firsts], images[g:g + firsts])[0]
            relative[g].append(T.cpu().numpy())
    return {g: np.concatenate(stacks) for g, stacks in relative.items()}


@torch.no_grad()
def predicted_depth(model: DepthModel, seq: FrameSequence, batch: int = 32,
                    progress: bool = False, out: np.ndarray | None = None) -> np.ndarray:
    """(N, H, W) depth of every frame of seq at the depth network's size, written in order
    into `out` (e.g. a file writer, to stream a long video) when given."""
    model.eval()
    if out is None:
        out = np.empty((seq.num_frames, *seq.size), dtype=np.float32)
    for start in tqdm(range(0, seq.num_frames, batch), desc=f"depth {Path(seq.name).name}",
                      unit="batch", disable=not progress):
        ids = range(start, min(start + batch, seq.num_frames))
        images = to_tensor(np.stack([seq.frame(i) for i in ids]), device_of(model))
        out[ids.start:ids.stop] = model.depth(images)[:, 0].cpu().numpy()
    return out


def aggregate_intrinsics(K_pairs: np.ndarray, size: tuple[int, int], crop: Crop, fps: float
                         ) -> dict:
    """Median K over pairs in the input's pixels, with the spread (std, IQR) of each entry, and
    the median K at the network's size (H, W) under 'network'."""
    height, width = size
    cams = [crop.camera_to_input(Camera(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], fps))
            for K in K_pairs]
    table = {k: np.array([getattr(c, k) for c in cams]) for k in ("fx", "fy", "cx", "cy")}
    out = {"width": crop.input_width, "height": crop.input_height, "fps": fps}
    out.update({k: float(np.median(v)) for k, v in table.items()})
    out["spread"] = {k: {"std": float(v.std()),
                         "iqr": float(np.subtract(*np.percentile(v, [75, 25])))}
                     for k, v in table.items()}
    out["pairs"] = len(cams)
    out["crop"] = vars(crop)
    out["network_size"] = {"height": height, "width": width}
    K = np.median(K_pairs, axis=0)
    out["network"] = {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]),
                      "cy": float(K[1, 2])}
    return out


def infer_to_folder(model: DepthModel, seq: FrameSequence, out: Path, progress: bool = False
                    ) -> None:
    """Infer and write the files listed in the module docstring, the depth maps batch by
    batch."""
    out = Path(out)
    result = infer_sequence(model, seq, progress=progress, depth_out=DepthFiles(out / "depth"))
    cv2.imwrite(str(out / "region.png"), seq.region.astype(np.uint8) * 255)
    np.save(out / "relative_poses.npy", result.relative)
    np.save(out / "poses.npy", result.poses)
    intrinsics = aggregate_intrinsics(result.K_pairs, seq.size, seq.crop, seq.fps)
    (out / "intrinsics.json").write_text(json.dumps(intrinsics, indent=1) + "\n")
