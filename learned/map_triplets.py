"""Training triplets from structure-from-motion maps of the training videos (`fusion.sfm_maps`):
the maps' motion and K drive the depth network's view synthesis and are targets for the motion
network and its intrinsics head (`c2d2 train-depth --maps`). No labels and no calibration."""

from __future__ import annotations

import logging
from contextlib import nullcontext
from dataclasses import dataclass, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from kornia.geometry.conversions import rotation_matrix_to_axis_angle

from fusion.self_calibration import SelfCalibration, SelfCalibrationConfig, SquarePixels, Stretch
from fusion.sfm_maps import fingerprint, map_path
from hybrid.types import InputError
from learned.config import DepthConfig
from learned.flow import flows_to_sources
from learned.frames import FrameSequence
from learned.losses import LossTerms, view_synthesis_loss
from learned.model import DepthModel, to_tensor
from learned.zoom import zoom_pairs, zoomed_intrinsics

log = logging.getLogger(__name__)
Motion = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]
"""Axis-angle and translation target -> source, then source -> target, each (B, 3)."""


@dataclass
class MapBatch:
    """Triplets (previous, target, next) with their stretch's motion, K and sparse depth."""

    frames: torch.Tensor
    """(B, 3, 3, H, W) in [0, 1]."""
    regions: torch.Tensor
    """(B, 1, H, W) image regions."""
    K: torch.Tensor
    """(B, 3, 3) the stretch's intrinsics."""
    motions: list[Motion]
    """Target -> previous and target -> next, in the map's unit."""
    points: list[torch.Tensor]
    """Per target, (M, 3): pixel x, y and depth (map's unit) of the map points it sees."""
    triplets: list[tuple[int, int]]
    """Per triplet, its input's index and its target frame (MapTriplets.triplets)."""


class InputMap(NamedTuple):
    """One input's map as MapTriplets uses it."""

    poses: np.ndarray
    """(N, 4, 4) camera-to-world in its stretch's model."""
    fx: np.ndarray
    """Per stretch, at the frames' size."""
    fy_over_fx: float
    stretch: np.ndarray
    """(N,) each frame's stretch where that stretch agrees, else -1."""
    points: list[np.ndarray]
    """Per frame, (M, 3): x, y, depth of the map points it sees."""


def relative_motion(poses: np.ndarray, target: int, source: int) -> Motion:
    """Motion target -> source, then source -> target, between two frames of camera-to-world
    `poses` (N, 4, 4), as a batch of one (the target -> source transform maps points of the
    target camera into the source camera)."""
    T = torch.tensor(np.linalg.inv(poses[source]) @ poses[target], dtype=torch.float32)[None]
    back = torch.linalg.inv(T)
    return (rotation_matrix_to_axis_angle(T[:, :3, :3]), T[:, :3, 3],
            rotation_matrix_to_axis_angle(back[:, :3, :3]), back[:, :3, 3])


def stack_motions(per_triplet: list[list[Motion]]) -> list[Motion]:
    """Per side (target -> previous, target -> next), the batch of the triplets' motions, from
    each triplet's list of two motions (relative_motion's batches of one)."""
    return [tuple(torch.cat(parts) for parts in zip(*side, strict=True))
            for side in zip(*per_triplet, strict=True)]


class MapTriplets:
    """Triplets at the sampler's gaps whose three frames were placed in one stretch of their
    input's map, that stretch's focal length agreeing with the input's other stretches (the
    self-calibration's consensus, `fusion.self_calibration`), with at least `min_points` map
    points seen in the target."""

    def __init__(self, sequences: list[FrameSequence], gaps: list[int], maps: Path,
                 min_points: int):
        self.sequences, self.gaps, self.maps = sequences, gaps, []
        self.triplets: list[tuple[int, int]] = []
        for k, (seq, gap) in enumerate(zip(sequences, gaps, strict=True)):
            found = _load(Path(maps), seq)
            stretch = _agreeing(found, seq)
            observations = found["observations"]  # sorted by frame
            points = np.split(observations[:, 1:], np.searchsorted(
                observations[:, 0].astype(int), np.arange(1, seq.num_frames)))
            self.maps.append(InputMap(found["poses"], found["fx"], float(found["fy_over_fx"]),
                                      stretch, points))
            mine = [(k, t) for t in range(gap, seq.num_frames - gap)
                    if stretch[t] >= 0 and stretch[t - gap] == stretch[t] == stretch[t + gap]
                    and len(points[t]) >= min_points]
            if not mine:
                log.warning("%s: no triplet in an agreeing stretch of its map; it trains "
                            "without the maps", seq.name)
            self.triplets += mine
        log.info("%d map triplets from %d of %d inputs", len(self.triplets),
                 len({k for k, _ in self.triplets}), len(sequences))

    def batch(self, size: int, rng: np.random.Generator, device: torch.device | str = "cpu"
              ) -> MapBatch:
        """`size` triplets drawn uniformly, on `device`."""
        frames, regions, Ks, sides, points = [], [], [], [], []
        drawn = [self.triplets[pick] for pick in rng.choice(len(self.triplets), size)]
        for k, t in drawn:
            seq, gap = self.sequences[k], self.gaps[k]
            found = self.maps[k]
            height, width = seq.size
            f = found.fx[found.stretch[t]]
            frames.append(np.stack([seq.network_frame(i) for i in (t - gap, t, t + gap)]))
            regions.append(seq.region)
            Ks.append([[f, 0, (width - 1) / 2], [0, f * found.fy_over_fx, (height - 1) / 2],
                       [0, 0, 1]])
            sides.append([relative_motion(found.poses, t, s) for s in (t - gap, t + gap)])
            points.append(torch.from_numpy(found.points[t]).to(device))
        motions = [tuple(part.to(device) for part in side) for side in stack_motions(sides)]
        return MapBatch(to_tensor(np.stack(frames), device),
                        torch.from_numpy(np.stack(regions))[:, None].to(device),
                        torch.tensor(Ks, dtype=torch.float32, device=device), motions, points,
                        drawn)


def map_view_loss(depths: torch.Tensor, batch: MapBatch, config: DepthConfig
                  ) -> tuple[LossTerms, torch.Tensor]:
    """View synthesis of the batch's targets with depths (B, 3, 1, H, W) and the maps' motion
    and K, the translations brought into the depth's unit by each target's median ratio of its
    depth to the map's at the map points (not differentiated); and the mean over targets of
    the mean |log ratio - median| (a scale-free loss of the depth on the sparse depth)."""
    height, width = depths.shape[-2:]
    ratios = [torch.log(d[0, p[:, 1].round().long().clamp(0, height - 1),
                          p[:, 0].round().long().clamp(0, width - 1)] / p[:, 2])
              for d, p in zip(depths[:, 1], batch.points, strict=True)]
    medians = torch.stack([r.median() for r in ratios]).detach()
    unit = medians.exp()[:, None]
    sparse = torch.stack([(r - m).abs().mean() for r, m in zip(ratios, medians, strict=True)])
    motions = [(r, t * unit, r_back, t_back * unit) for r, t, r_back, t_back in batch.motions]
    target, sources = batch.frames[:, 1], [batch.frames[:, 0], batch.frames[:, 2]]
    terms = view_synthesis_loss(target, sources, depths[:, 1], [depths[:, 0], depths[:, 2]],
                                motions, batch.K, batch.regions, config,
                                flows_to_sources(target, sources, config))
    return terms, sparse.mean()


def with_map_terms(terms: LossTerms, model: DepthModel, batch: MapBatch) -> LossTerms:
    """`terms` plus the map batch's: `w_map` times the view synthesis with the maps' motion
    and K (depth network), `w_map_motion` times the motion network's and its K's distance from
    the maps' (`map_motion_errors`; with `map_zoom`, on `zoomed_map_targets`), each of the
    model's config; a term whose weight is 0 is not computed (and logged as 0)."""
    config = model.config
    frames = batch.frames
    zero = torch.zeros((), device=frames.device)
    view, rotation, direction, focal = zero, zero, zero, zero
    if config.w_map:
        depths = model.depth(frames.flatten(0, 1)).unflatten(0, frames.shape[:2])
        view = map_view_loss(depths, batch, config)[0].total
    if config.w_map_motion:
        seen, motions, K_map = frames, batch.motions, batch.K
        if config.map_zoom:
            seen, motions, K_map = zoomed_map_targets(batch, config.zoom_max)
        with model.crop_batch() if config.map_zoom else nullcontext():
            estimates = model.triplet_motion(seen)
        rotation, direction, focal = map_motion_errors(*estimates, motions, K_map)
    total = (terms.total + config.w_map * view
             + config.w_map_motion * (rotation + direction + focal))
    return replace(terms, total=total, map_view=view, map_rotation=rotation,
                   map_direction=direction, map_focal=focal)


def zoomed_map_targets(batch: MapBatch, zoom_max: float
                       ) -> tuple[torch.Tensor, list[Motion], torch.Tensor]:
    """The map term's triplets and targets for `map_zoom`: each triplet cut to a random box
    (learned.zoom.zoom_pairs) and enlarged, with the map's K carried through the zoom (a crop
    is a frame of a camera with a longer focal length and the same motion), then the whole
    triplets at the crops' detail with the map's own K, so that blur does not tell the head the
    zoom. One batch (2B, 3, 3, H, W), its motions (each the map's, twice) and K (2B, 3, 3)."""
    views = zoom_pairs(batch.frames, zoom_max)
    K_map = torch.cat([zoomed_intrinsics(batch.K, views.boxes, batch.frames.shape[-2:]),
                       batch.K])
    motions = [tuple(torch.cat([part, part]) for part in side) for side in batch.motions]
    return torch.cat([views.zoomed, views.whole]), motions, K_map


def map_motion_errors(estimates: list[Motion], K: torch.Tensor, motions: list[Motion],
                      K_map: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """How far the motion network's estimates target -> previous and target -> next and its K
    (B, 3, 3) lie from the maps' `motions` and `K_map`: the rotation's L1 distance
    (axis-angle, radians, as the chain term's), 1 - cos of the angle between the translations
    (the map's unit is free), and |log| of the ratio of the focal lengths (fx and fy against
    the map's), each a mean over the batch."""
    rotation = torch.stack([(est[0] - ref[0]).abs().sum(1).mean()
                            for est, ref in zip(estimates, motions, strict=True)]).mean()
    direction = torch.stack([1 - F.cosine_similarity(est[1], ref[1], dim=1).mean()
                             for est, ref in zip(estimates, motions, strict=True)]).mean()
    focal = torch.log(torch.diagonal(K[:, :2, :2], dim1=1, dim2=2)
                      / torch.diagonal(K_map[:, :2, :2], dim1=1, dim2=2)).abs().mean()
    return rotation, direction, focal


def _load(maps: Path, seq: FrameSequence) -> np.lib.npyio.NpzFile:
    path = map_path(maps, seq.name)
    if not path.is_file():
        raise InputError(f"{seq.name}: no map {path}; make the maps of the training inputs "
                         f"with `c2d2 sfm-maps` into {maps}")
    found = np.load(path)
    again = (f"delete {path} or map the inputs into a new folder with `c2d2 sfm-maps` at the "
             f"training preset")
    if not {"source", "fingerprint", "size", "fy_over_fx"} <= set(found.files):
        raise InputError(f"{path}: a map made by an earlier version of C2D2; {again}")
    (height, width), frames = found["size"], len(found["stretch"])
    if (height, width) != tuple(seq.size) or frames != seq.num_frames or not np.isclose(
            found["fy_over_fx"], SquarePixels(seq.size, seq.pixel_aspect).fy_over_fx):
        raise InputError(f"{path}: a map of {frames} frames of {height}x{width} (fy / fx "
                         f"{float(found['fy_over_fx']):.3f}), but {seq.name} has "
                         f"{seq.num_frames} of {seq.size[0]}x{seq.size[1]} here; {again}")
    if not np.allclose(found["fingerprint"], fingerprint(seq), atol=0.5):
        raise InputError(f"{path}: a map of other frames ({found['source']}), not of "
                         f"{seq.name}; {again}")
    return found


def _agreeing(found: np.lib.npyio.NpzFile, seq: FrameSequence) -> np.ndarray:
    """Each frame's stretch where that stretch agrees with the input's consensus, else -1."""
    length = int(found["length"])
    stretches = [Stretch(int(start), length, float(placed), None if np.isnan(f) else f)
                 for start, placed, f in zip(found["starts"], found["registered"], found["fx"],
                                             strict=True)]
    calibration = SelfCalibration(seq.num_frames, stretches, SelfCalibrationConfig(
        windows=max(len(stretches), 2), length=length, min_field_of_view=0.0), seq.size,
        float(found["fy_over_fx"]))  # no bound on the field of view, as the maps were made
    agreeing = [s.start // length for s in calibration.agreeing] if calibration.K is not None \
        else []
    return np.where(np.isin(found["stretch"], agreeing), found["stretch"], -1)
