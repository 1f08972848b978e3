"""Depth, ego-motion and intrinsics for a video, an image folder or a simulated procedure.

`infer_sequence` runs both networks in one pass over the frames, decoding each frame once.
`infer_to_folder` writes into the output folder:
    depth/000000.npy       float32 (H, W) depth at the network's size, over the cropped region
    region.png             the detected image region (white) at the network's size
    relative_poses.npy     (N-1, 4, 4) transform mapping camera t's points into camera t+1
    poses.npy              (N, 4, 4) camera-to-world poses chained from them (first = identity)
    intrinsics.json        one K for the whole input, in the input's own pixels, with its spread:
                           the intrinsics head's, or fusion.self_calibration's (`source`)
Depth and translation share one unknown scale. Each file is written whole or not at all, the
depth maps into depth.partial/, which replaces depth/ when every map is written.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np
import torch
from tqdm import tqdm

from hybrid import workdir as W
from hybrid.types import Camera, InputError, chain_poses
from learned.device import device_of
from learned.frames import Crop, FrameSequence
from learned.model import DepthModel, to_tensor

if TYPE_CHECKING:
    from fusion.self_calibration import SelfCalibration


class RowSink(Protocol):
    """Where depth is streamed: rows assigned in order by slices (an array, DepthFiles,
    hybrid.npyio.NpyWriter)."""

    def __setitem__(self, rows: slice, values: np.ndarray) -> None: ...


class DepthFiles:
    """depth/NNNNNN.npy files, written as slices of frames are assigned, so that a long
    video's depth never sits in memory."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)

    def __setitem__(self, frames: slice, depth: np.ndarray) -> None:
        for i, d in zip(range(frames.start, frames.stop), depth, strict=True):
            np.save(self.folder / f"{i:06d}.npy", d.astype(np.float32))


@dataclass
class DepthOutput:
    """Everything inferred for one input (or a range of its frames), at the network's size."""

    depth: np.ndarray | RowSink | None
    """(N, H, W) float32, or the sink it was written to; None when depth was not asked for."""
    relative: dict[int, np.ndarray]
    """{g: (max(N-g, 0), 4, 4) float64}: entry t maps points of camera t into camera t+g."""
    K_pairs: np.ndarray | None
    """(max(N-g, 0), 3, 3) intrinsics of the pairs of the smallest gap g (None without gaps)."""

    @property
    def poses(self) -> np.ndarray:
        """(N, 4, 4) camera-to-world poses chained from the consecutive relative ones."""
        if 1 not in self.relative:
            raise ValueError("poses are chained from gap 1, which was not inferred")
        return chain_poses(self.relative[1])


@torch.no_grad()
def infer_sequence(model: DepthModel, seq: FrameSequence, gaps: tuple[int, ...] = (1,), *,
                   depth: bool = True, depth_out: RowSink | None = None,
                   frames: range | None = None, batch: int = 16, progress: bool = False
                   ) -> DepthOutput:
    """Depth of the frames of seq (all, or the given range) and the relative poses of the
    frame pairs (t, t+g) for every gap g, each the mean of the forward and the inverted
    backward estimate (DepthModel.pair_transform); K_pairs are those of the smallest gap's
    pairs. A gap longer than the range gives no pairs.

    Depth is kept in the result, or written into depth_out (row 0: the range's first frame),
    or skipped (depth=False). The last max(gaps) decoded frames are kept for the pairs that
    reach into the next batch, so each frame is decoded once.
    """
    model.eval()
    frames = range(seq.num_frames) if frames is None else frames
    gaps = tuple(sorted(set(gaps)))
    if any(g < 1 for g in gaps):
        raise InputError(f"relative-pose gaps must be positive frame counts, got {gaps}")
    if frames.step != 1 or not 0 <= frames.start < frames.stop <= seq.num_frames:
        raise InputError(f"{seq.name}: frames {frames} is not a consecutive range of its "
                         f"{seq.num_frames} frames")
    if gaps and len(frames) < 2:
        raise InputError(f"{seq.name}: depth and motion need at least 2 frames")
    if not (depth or gaps) or (depth_out is not None and not depth):
        raise ValueError("infer_sequence: ask for depth, or gaps, and depth_out only with "
                         "depth")
    reach, smallest = max(gaps, default=0), min(gaps, default=0)
    kept: list[np.ndarray] = []
    relative: dict[int, list[np.ndarray]] = {g: [np.empty((0, 4, 4))] for g in gaps}
    K_pairs: list[np.ndarray] = [np.empty((0, 3, 3))]
    tail = None  # the last `reach` frames of the batches before, as tensors
    for start in tqdm(range(frames.start, frames.stop, batch), desc=f"infer {seq.name}",
                      disable=not progress, unit="batch"):
        ids = range(start, min(start + batch, frames.stop))
        images = to_tensor(np.stack([seq.network_frame(i) for i in ids]), device_of(model))
        if depth:
            predicted = model.predict_depth(images)[:, 0].cpu().numpy()
            if depth_out is None:
                kept.append(predicted)
            else:
                depth_out[ids.start - frames.start:ids.stop - frames.start] = predicted
        window = images if tail is None else torch.cat([tail, images])
        first = ids.stop - len(window)  # the frame window[0] shows
        for g in gaps:  # pairs whose second frame is in this batch
            second = max(ids.start, frames.start + g) - first
            if second < len(window):
                T, K = model.pair_transform(window[second - g:len(window) - g], window[second:])
                relative[g].append(T.cpu().numpy())
                if g == smallest:
                    K_pairs.append(K.cpu().numpy())
        tail = window[max(len(window) - reach, 0):] if reach else None
    depth_result = (np.concatenate(kept) if depth_out is None else depth_out) if depth else None
    return DepthOutput(depth_result, {g: np.concatenate(r) for g, r in relative.items()},
                       np.concatenate(K_pairs).astype(np.float64) if gaps else None)


def aggregate_intrinsics(K_pairs: np.ndarray, size: tuple[int, int], crop: Crop, fps: float
                         ) -> dict:
    """Median K over pairs in the input's pixels, with the spread (std, IQR) of each entry, and
    the median K at the network's size (H, W) under 'network'."""
    height, width = size
    cams = [_in_input(K, size, crop, fps) for K in K_pairs]
    table = {k: np.array([getattr(c, k) for c in cams]) for k in ("fx", "fy", "cx", "cy")}
    out = {"width": crop.input_width, "height": crop.input_height, "fps": fps,
           "source": "intrinsics head"}
    out.update({k: float(np.median(v)) for k, v in table.items()})
    out["spread"] = {k: {"std": float(v.std()),
                         "iqr": float(np.subtract(*np.percentile(v, [75, 25])))}
                     for k, v in table.items()}
    out["pairs"] = len(cams)
    out["crop"] = vars(crop)
    out["network_size"] = {"height": height, "width": width}
    out["network"] = _entries(np.median(K_pairs, axis=0))
    return out


def self_calibrated_intrinsics(head: dict, calibration: SelfCalibration, crop: Crop) -> dict:
    """`head` (aggregate_intrinsics) with the self-calibrated K in its place: the head's
    estimate moves under 'head', the stretches' record goes under 'self_calibration'. Without
    a consensus (K None) the head's estimate stays in place, beside the record."""
    K, record = calibration.K, calibration.record()
    if K is None:
        return {**head, "self_calibration": record}
    size = head["network_size"]
    camera = _in_input(K, (size["height"], size["width"]), crop, head["fps"])
    out = {k: head[k] for k in ("width", "height", "fps")}
    out["source"] = "self-calibration"
    out.update({k: float(getattr(camera, k)) for k in ("fx", "fy", "cx", "cy")})
    out.update(crop=head["crop"], network_size=size, network=_entries(K),
               self_calibration=record)
    out["head"] = {k: v for k, v in head.items()
                   if k not in ("width", "height", "fps", "source", "crop", "network_size")}
    return out


def _in_input(K: np.ndarray, size: tuple[int, int], crop: Crop, fps: float) -> Camera:
    """K (3, 3) at the network's size (H, W) as a camera in the input's pixels."""
    height, width = size
    return crop.camera_to_input(Camera(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], fps))


def _entries(K: np.ndarray) -> dict[str, float]:
    return {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]),
            "cy": float(K[1, 2])}


def infer_to_folder(model: DepthModel, seq: FrameSequence, out: Path, progress: bool = False,
                    calibration: SelfCalibration | None = None) -> None:
    """Infer and write the files listed in the module docstring, the depth maps batch by
    batch; intrinsics.json gives `calibration`'s K where one is given and has one."""
    out = Path(out)
    (out / "intrinsics.json").unlink(missing_ok=True)  # an earlier run's mark of completion
    partial = out / "depth.partial"  # replaces depth/ when whole: no maps of an earlier run
    shutil.rmtree(partial, ignore_errors=True)
    result = infer_sequence(model, seq, progress=progress, depth_out=DepthFiles(partial))
    intrinsics = aggregate_intrinsics(result.K_pairs, seq.size, seq.crop, seq.fps)
    if calibration is not None:
        intrinsics = self_calibrated_intrinsics(intrinsics, calibration, seq.crop)
    shutil.rmtree(out / "depth", ignore_errors=True)
    partial.rename(out / "depth")
    W.write_png(out / "region.png", seq.region.astype(np.uint8) * 255)
    W.write_npy(out / "relative_poses.npy", result.relative[1])
    W.write_npy(out / "poses.npy", result.poses)
    W.write_json(out / "intrinsics.json", intrinsics)  # last: it marks the folder complete
