"""The network's relative poses refined by RGB-D odometry on its own depth (Open3D).

The motion network finds about half of the true pitch and yaw between frames
(docs/depth.md). Open3D's multi-scale RGB-D odometry aligns each frame pair directly, by its
colour and by the network's depth and K, starting from the network's estimate; on simulated
procedures it finds nearly all of the rotation (docs/posegraph.md). Every pair (t, t+g) of
every gap is refined, so the pose graph gets refined measurements at all its gaps. A pair the
odometry cannot align (too few valid correspondences) keeps the network's estimate, and how
many did is returned. The fit itself is not judged: a poor alignment is kept. Open3D runs each
pair on one thread: its parallel reductions differ in the last digits from run to run, and the
lumen fit downstream turned that into a different coverage (a jump of 0.08 on one 110-frame
clip). The cores are used instead by aligning several pairs at once, in threads (Open3D
releases the GIL), so the refined poses repeat exactly whatever the number of cores.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.ndimage import distance_transform_edt
from tqdm import tqdm

from hybrid.types import InputError, check_depth, sampling_stride, thread_count

_odometry = o3d.t.pipelines.odometry
_BLOCK = 64
"""Frames whose pairs are handed to the threads at once."""


@dataclass(frozen=True)
class OdometryConfig:
    """Whether and how the relative poses are refined; distances are fractions of the median
    depth, since the network's depth has no unit."""

    enabled: bool = True
    iterations: tuple[int, ...] = (5, 3, 2)
    """Gauss-Newton iterations per pyramid level, coarsest first (one level per entry; Open3D's
    default is (10, 5, 3)): on two tuning procedures the same rotation error within 0.015°, in
    68% of the time (benchmarks/odometry_rotation.py, docs/posegraph.md)."""
    depth_outlier: float = 0.21
    """Correspondences whose depths differ by more than this are outliers (Open3D's default
    0.07 m, for a median depth of about 0.33 m; not tuned)."""
    depth_huber: float = 0.05
    """Huber threshold of the geometric (point-to-plane) residual (Open3D's default 0.05 m read
    as a fraction; not tuned)."""
    intensity_huber: float = 0.1
    """Huber threshold of the intensity residual (intensity in [0, 1]; Open3D's default)."""

    def __post_init__(self) -> None:
        if min(self.depth_outlier, self.depth_huber, self.intensity_huber) <= 0:
            raise InputError("odometry depth_outlier, depth_huber and intensity_huber must be "
                             "positive")
        if not self.iterations or min(self.iterations) < 1:
            raise InputError(f"odometry iterations must be one positive count per pyramid "
                             f"level, got {self.iterations}")


@dataclass
class RefinedPoses:
    """The refined relative poses ({g: (N-g, 4, 4)}, entry t mapping camera t's points into
    camera t+g), per gap how many pairs kept the network's estimate, and each pair's fitness:
    the fraction of the source's valid pixels that found a correspondence (Open3D's
    `fitness`; NaN for a kept pair). Adjacent video frames give nearly 1; frames that share
    little give less (docs/posegraph.md)."""

    relative: dict[int, np.ndarray]
    kept: dict[int, int]
    fitness: dict[int, np.ndarray]


def refine_relative_poses(relative: dict[int, np.ndarray], depth: Sequence[np.ndarray],
                          rgb: Sequence[np.ndarray], K: np.ndarray,
                          region: np.ndarray | None = None,
                          config: OdometryConfig = OdometryConfig(), name: str = "video",
                          progress: bool = False, threads: int | None = None,
                          depth_max: float = float("inf"), light_power: float = 0.0,
                          method: str = "hybrid", median: float | None = None
                          ) -> RefinedPoses:
    """Refine every relative pose of `relative` by RGB-D odometry (colour + depth: hybrid).

    depth: (H, W) maps, 0 where unknown; rgb: (H, W, 3) uint8 frames of the same size; K at
    that size. Frames are read in order, a block at a time (before that, every 10th or at most
    SAMPLED_FRAMES of them for the median depth); the pairs of a block are aligned in
    `threads` threads (None: one per core) while the next block is read. The result does not
    depend on the threads. Diagnostics of benchmarks/geometric_eval.py and
    benchmarks/odometry_rotation.py, left at their defaults by `c2d2 run` (docs/geometric.md,
    "Where the poses' cost lies"):
    - depth_max, in median depths: both frames' deeper pixels are left out;
    - light_power: the colour times (depth / median depth) ** light_power, undoing a light at
      the camera whose brightness falls with distance (displayed intensity goes as distance
      ** (-2 / gamma) under an inverse-square light: about 1 for gamma 2);
    - method: Open3D's "hybrid" (colour and depth), "point-to-plane" (depth) or "intensity"
      (colour);
    - median: the depth (and the poses' translations) rescaled to this median while aligned,
      since the hybrid method weighs its depth residual, in the depth's unit, against the
      intensity's, in [0, 1] (None: the depth's own unit).
    """
    if not relative:
        raise InputError(f"{name}: no relative poses to refine")
    n = len(depth)
    if len(rgb) != n:
        raise InputError(f"{name}: {n} depth maps but {len(rgb)} frames")
    for g, rel in relative.items():
        if not isinstance(g, int) or g < 1:
            raise InputError(f"{name}: frame gaps must be positive integers, got {g!r}")
        if rel.shape != (max(n - g, 0), 4, 4) or not np.isfinite(rel).all():
            raise InputError(f"{name}: gap-{g} relative poses must be a finite "
                             f"({max(n - g, 0)}, 4, 4) array, got shape {rel.shape}")
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3) or not np.isfinite(K).all():
        raise InputError(f"{name}: K must be a finite 3x3 matrix, got shape {K.shape}")
    size = np.shape(depth[0]) if n else ()
    if region is not None and (np.shape(region) != size or np.asarray(region).dtype != bool):
        raise InputError(f"{name}: the region must be a boolean {size} mask like the depth, got "
                         f"{np.asarray(region).dtype} {np.shape(region)}")
    if not depth_max > 0:
        raise InputError(f"{name}: the odometry's depth_max must be positive, got {depth_max}")
    if median is not None and not median > 0:
        raise InputError(f"{name}: the odometry's median must be positive, got {median}")
    if not 0 <= light_power < float("inf"):
        raise InputError(f"{name}: the odometry's light_power must be finite and not negative, "
                         f"got {light_power}")
    if region is not None and region.all():  # nothing outside: no masking, no copying
        region = None
    methods = {"hybrid": _odometry.Method.Hybrid, "intensity": _odometry.Method.Intensity,
               "point-to-plane": _odometry.Method.PointToPlane}
    if method not in methods:
        raise InputError(f"{name}: the odometry's method must be one of {sorted(methods)}, "
                         f"got {method!r}")
    scale = median_depth(depth, region, name)
    unit = 1.0 if median is None else median / scale  # depth and translations times this
    scale *= unit
    params = _odometry.OdometryLossParams(config.depth_outlier * scale, config.depth_huber * scale,
                                          config.intensity_huber)
    intrinsics = o3d.core.Tensor(K)
    criteria = [_odometry.OdometryConvergenceCriteria(i) for i in config.iterations]
    refined = {g: rel.copy() for g, rel in relative.items()}
    kept = dict.fromkeys(relative, 0)
    fitness = {g: np.full(len(rel), np.nan) for g, rel in relative.items()}
    nearest = None if region is None else _nearest_in(region)
    window: dict[int, tuple[o3d.t.geometry.RGBDImage, o3d.t.geometry.RGBDImage]] = {}
    back = max(relative)

    def align(source: o3d.t.geometry.RGBDImage, target: o3d.t.geometry.RGBDImage,
              start: np.ndarray) -> _odometry.OdometryResult | None:
        start = start.copy()
        start[:3, 3] *= unit
        try:
            result = _odometry.rgbd_odometry_multi_scale(
                source, target, intrinsics, o3d.core.Tensor(start), depth_scale=1.0,
                depth_max=depth_max * scale, criteria_list=criteria,
                method=methods[method], params=params)
        except RuntimeError as err:  # Open3D's two ways of saying "cannot solve"
            if not any(m in str(err) for m in ("inlier_count", "tracking failed")):
                raise
            return None
        return result if np.isfinite(result.transformation.numpy()).all() else None

    def pair(job: tuple[int, int]) -> _odometry.OdometryResult | None:
        g, t = job  # frame t - g onto frame t
        return align(window[t - g][0], window[t][1], relative[g][t - g])

    def collect(jobs: list[tuple[int, int]],
                results: Iterator[_odometry.OdometryResult | None]) -> None:
        for (g, t), result in zip(jobs, results, strict=True):
            if result is None:
                kept[g] += 1
            else:
                refined[g][t - g] = result.transformation.numpy()
                refined[g][t - g, :3, 3] /= unit
                fitness[g][t - g] = result.fitness

    threads = thread_count(threads, "odometry threads")
    pending: tuple[list[tuple[int, int]], Iterator[_odometry.OdometryResult | None]] | None = None
    with (_one_thread(), ThreadPoolExecutor(threads) as pool,
          tqdm(total=n, desc=f"odometry {name}", unit="frame", disable=not progress) as bar):
        for begin in range(0, n, _BLOCK):
            stop = min(n, begin + _BLOCK)
            for t in range(begin, stop):  # read while the threads align the block before
                d = check_depth(depth[t], size, f"{name} frame {t}")
                if median is not None:
                    d = d * np.float32(unit)
                window[t] = _images(rgb[t], d, region, nearest, f"{name} frame {t}",
                                    (scale, light_power))
            bar.update(stop - begin)
            if pending is not None:
                collect(*pending)
            for t in [t for t in window if t < begin - back]:  # no pair left reads them
                del window[t]
            jobs = [(g, t) for t in range(begin, stop) for g in relative if g <= t]
            pending = (jobs, pool.map(pair, jobs))
        if pending is not None:
            collect(*pending)
    return RefinedPoses(refined, kept, fitness)


@contextmanager
def _one_thread() -> Iterator[None]:
    previous = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(1)
    try:
        yield
    finally:
        o3d.utility.set_max_threads(previous)


def _nearest_in(region: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every pixel, the (row, column) of the nearest pixel of the region."""
    return tuple(distance_transform_edt(~region, return_distances=False, return_indices=True))


def _images(rgb: np.ndarray, depth: np.ndarray, region: np.ndarray | None,
            nearest: tuple[np.ndarray, np.ndarray] | None, name: str,
            light: tuple[float, float] = (1.0, 0.0)
            ) -> tuple[o3d.t.geometry.RGBDImage, o3d.t.geometry.RGBDImage]:
    """The frame as the source of a pair and as its target. Outside the region, colour (and the
    target's depth) are copied from the nearest pixel inside, so that nothing outside is read,
    even through the pyramid's blur, and the region's edge makes no gradient that would hold
    the alignment in place; the source's depth there is 0, so it has no points there."""
    d = np.asarray(depth, np.float32)
    if np.shape(rgb) != (*d.shape, 3) or np.asarray(rgb).dtype != np.uint8:
        raise InputError(f"{name}: expected a uint8 {d.shape + (3,)} RGB frame like its depth "
                         f"map, got {np.asarray(rgb).dtype} {np.shape(rgb)}")
    colour = np.asarray(rgb, np.float32) / 255.0
    reference, power = light  # the light's compensation: (depth / reference) ** power
    if power:
        colour *= (np.maximum(d, 0) / np.float32(reference))[..., None] ** np.float32(power)
    if region is None:
        both = _rgbd(colour, d)
        return both, both
    colour = colour[nearest]
    return _rgbd(colour, np.where(region, d, np.float32(0))), _rgbd(colour, d[nearest])


def _rgbd(colour: np.ndarray, depth: np.ndarray) -> o3d.t.geometry.RGBDImage:
    return o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(np.ascontiguousarray(colour)),
                                    o3d.t.geometry.Image(np.ascontiguousarray(depth[..., None])))


def median_depth(depth: Sequence[np.ndarray], region: np.ndarray | None, name: str) -> float:
    """Median of the valid depth inside the region of every 10th frame, of at most
    SAMPLED_FRAMES evenly spaced ones in a longer video (of every frame if those hold none):
    the unit of the odometry's thresholds."""
    for stride in (sampling_stride(len(depth), 10), 1):
        values = []
        for f in range(0, len(depth), stride):
            d = np.asarray(depth[f], np.float32)
            if region is not None:
                d = d[region]
            values.append(d[np.isfinite(d) & (d > 0)])
        values = np.concatenate(values) if values else np.empty(0)
        if values.size:
            return float(np.median(values))
    raise InputError(f"{name}: the depth maps hold no valid (positive) depth")
