"""Fit a lumen (centerline + radius profile) to a reconstructed colon surface.

Reads camera-to-world poses (the smoothed trajectory) and surface points (TSDF mesh vertices or
back-projected depth) in one unit, and returns a `FittedLumen` parametrised by arc length.

1. Stations: the camera centres, smoothed over time, resampled every `spacing` along their
   path; a station closer than spacing/2 to an earlier one, or closer than half a radius to
   one that the path left more than twice as far back (and a spacing more), is a return
   visit and is dropped.
   A camera that pushes in and then withdraws over the same stretch leaves them out of order
   in time: the runs of stations that follow one another are joined end to end by the
   shortest links between their ends (`_ordered`). ℓ grows towards the cecum, where the
   look-ahead Δ1 of the coverage definition points: the direction in which the cameras'
   nearest station grows with their given places along the colon (`along`: in `c2d2 run`,
   a segment's window takes its cameras' ℓ on the whole video's lumen), or else, the video
   taken to be a withdrawal (unless configured as an insertion), falls over time, from where
   the camera ends towards where it started.
   The path is continued straight on beyond its deep end, to cover the look-ahead band, and a
   little beyond its other end; so is the fitted centreline where the surface ends, and at
   least past the cameras beyond it, so that each camera has its own ℓ.
2. The surface is thinned to one point per small cube (`thinning`), so that each part of the
   wall counts once however often and closely the video saw it.
3. Cross-sections: at each station, the surface points in a slab one spacing thick normal to
   the path are projected into its plane and fitted with a circle (the algebraic fit refined
   by least squares on the points' distances to the circle, outliers beyond 3 MADs trimmed);
   a section whose inliers occupy fewer than 5 of the twelve 30° sectors around its centre
   (an arc under 90-120°), or whose circle does not enclose the station (inside the lumen),
   is skipped and filled in from its neighbours (only a gap of one station counts as
   fitted).
4. The centres and radii go through a running median along the stations (one bad section,
   often at the ragged end of the surface, is outvoted), then are smoothed; the path is
   replaced by the fitted centreline and steps 3-4 run again.
Cube, spacing, slab and reach scale with a first radius estimate (median distance from the
surface to the camera path), so the fit works in any unit, e.g. before the metric scale is
known.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import open3d as o3d
from scipy.ndimage import gaussian_filter1d, median_filter
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import minimum_spanning_tree, shortest_path
from scipy.spatial import cKDTree

from hybrid.types import InputError, check_poses
from hybrid.workdir import write_json

_REVISIT = 0.5
"""A camera back within this distance (× r0, about the lumen's radius) of a station it left
more than twice as far back along its path is on a return visit, in the same stretch of
lumen, though to the side of its earlier pass (`_stations`)."""


@dataclass(frozen=True)
class LumenFitConfig:
    """Sizes of the fit, as fractions of the first radius estimate r0 unless said otherwise."""

    spacing: float = 0.25
    """Distance between stations (and slab thickness), × r0."""
    reach: float = 3.0
    """Surface points farther than this from a station are ignored, × r0."""
    path_smoothing_s: float = 1.0
    """Gaussian smoothing of the camera centres over time, in seconds."""
    median_stations: int = 5
    """Running median of the fitted centres and radii over this many stations (when at least
    this many were fitted), before the smoothing: one bad cross-section (a piece of a fold,
    the ragged end of the surface) is outvoted by its neighbours instead of pulling the fit
    and, at an end, the continuation (two in a row are outvoted too, but not at an end)."""
    smoothing_stations: float = 2.0
    """Gaussian smoothing of the fitted centres and radii, in stations."""
    min_points: int = 30
    """Fewest surface points for a cross-section fit."""
    min_arc_bins: int = 5
    """Fewest 30° sectors (of 12) around the fitted centre that its inliers must occupy for
    a cross-section fit: 5, an arc of at least 90-120°, on which the fitted radius comes out
    5-10% short at 2 mm of noise (docs/geometric.md, "Unbiased cross-sections")."""
    iterations: int = 2
    """Fit passes; each pass after the first uses the previous centreline as the path."""
    withdrawal: bool = True
    """The video withdraws the endoscope (ℓ grows back in time, towards where the camera
    started); False for an insertion (ℓ grows forward in time)."""
    extend: float = 3.5
    """The path, and the fitted centreline where the surface ends, are continued straight on
    this far (× r0) beyond their deep end, where the look-ahead band of the coverage
    definition lies (for the centreline: beyond the farther of its end and the cameras past
    it)."""
    extend_back: float = 1.0
    """... and this far (× r0) beyond their other end, which smoothing would otherwise
    shorten."""
    thinning: float = 0.1
    """Before the fit, the surface keeps one point (the mean) per cube of this side, × r0
    (0: every point). The wall then counts by its area, not by how many frames saw it or from
    how close, and the fit reads far fewer points. (The cubes are axis-aligned, so the fit
    depends a little on how the world frame is turned.)"""

    def __post_init__(self) -> None:
        if not self.thinning >= 0:
            raise InputError(f"LumenFitConfig.thinning must be >= 0, got {self.thinning}")
        if self.iterations < 1 or self.median_stations < 1 or self.spacing <= 0 \
                or self.reach <= 0:
            raise InputError(f"LumenFitConfig needs iterations >= 1, median_stations >= 1 and "
                             f"positive spacing and reach: {self}")


@dataclass
class FittedLumen:
    """Centreline points (M, 3) from ℓ = 0 and the wall radius (M,) at each, in one unit."""

    points: np.ndarray
    radius: np.ndarray
    fitted: np.ndarray | None = None
    """(M,) bool: the radius was fitted to the surface there, or on a single station between
    two where it was (False where the centreline is continued straight beyond the surface, or
    interpolated across a longer stretch without usable cross-sections); None: everywhere."""

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=np.float64)
        self.radius = np.asarray(self.radius, dtype=np.float64)
        if self.fitted is not None:
            self.fitted = np.asarray(self.fitted, dtype=bool)
        m = len(self.points)
        flags = None if self.fitted is None else self.fitted.shape
        if self.points.ndim != 2 or self.points.shape[1:] != (3,) or m == 0 \
                or self.radius.shape != (m,) or flags not in (None, (m,)):
            raise InputError(f"a lumen needs (M, 3) centreline points with M radii (and M "
                             f"fitted flags), got {self.points.shape}, {self.radius.shape}"
                             f"{'' if flags is None else f', {flags}'}")
        if not (np.isfinite(self.points).all() and np.isfinite(self.radius).all()
                and (self.radius > 0).all()):
            raise InputError("a lumen's centreline points must be finite and its radii finite "
                             "and positive")

    @property
    def arclength(self) -> np.ndarray:
        steps = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        return np.concatenate([[0.0], np.cumsum(steps)])

    def save(self, path: Path) -> None:
        """lumen.json: points, radius, arclength, fitted (written atomically)."""
        fitted = None if self.fitted is None else self.fitted.tolist()
        write_json(path, {"points": self.points.tolist(), "radius": self.radius.tolist(),
                          "arclength": self.arclength.tolist(), "fitted": fitted})

    @classmethod
    def load(cls, path: Path) -> FittedLumen:
        data = json.loads(Path(path).read_text())
        fitted = data.get("fitted")
        try:
            return cls(np.asarray(data["points"], float), np.asarray(data["radius"], float),
                       None if fitted is None else np.asarray(fitted, bool))
        except InputError as err:
            raise InputError(f"{path}: {err}; delete it to fit the lumen again") from err


def fit_lumen(poses: np.ndarray, surface: np.ndarray, fps: float = 30.0,
              config: LumenFitConfig = LumenFitConfig(), name: str = "reconstruction",
              along: np.ndarray | None = None, ahead_at_least: float = 0.0) -> FittedLumen:
    """Centreline and radius profile of the surface around the camera path (see module doc).

    along: (N,) each camera's place along the colon, growing towards its deep end (e.g. its ℓ
    on a lumen fitted to the whole video), which orients the fit; None: the cameras' order in
    time, read backwards on a withdrawal (config.withdrawal).
    ahead_at_least: the least length, in the surface's unit, of the straight continuation
    beyond the deep end (config.extend × r0 where that is longer), of the first pass's path
    as of the fitted centreline; with a metric surface, the look-ahead band's reach, so that
    the tube covers every camera's band."""
    poses = check_poses(poses, name=f"{name} poses")
    if along is None:
        along = np.arange(len(poses), dtype=np.float64) * (-1.0 if config.withdrawal else 1.0)
    along = np.asarray(along, dtype=np.float64)
    if along.shape != (len(poses),) or not np.isfinite(along).all():
        raise InputError(f"{name}: `along` must give each of the {len(poses)} cameras a finite "
                         f"place along the colon, got shape {along.shape}")
    surface = np.asarray(surface, dtype=np.float64)
    if surface.ndim != 2 or surface.shape[1] != 3 or len(surface) < config.min_points:
        raise InputError(f"{name}: no surface to fit a lumen to ({surface.shape} points); the "
                         f"reconstruction is empty, check the depth and poses")
    if not np.isfinite(surface).all():
        raise InputError(f"{name}: surface points contain NaN or infinite values")
    surface = _sorted(surface)
    centres = gaussian_filter1d(poses[:, :3, 3], config.path_smoothing_s * fps, axis=0,
                                mode="nearest")
    r0 = float(np.median(cKDTree(centres).query(surface[:: max(1, len(surface) // 20000)])[0]))
    if not r0 > 0:
        raise InputError(f"{name}: the surface lies on the camera path; no lumen to fit")
    if config.thinning > 0:
        surface = _thinned(surface, config.thinning * r0)
    spacing = config.spacing * r0
    stations, follows = _stations(centres, spacing, _REVISIT * r0)
    path = stations if len(stations) < 4 else _ordered(stations, follows, spacing, centres,
                                                          along, name)
    if len(path) < 4:
        raise InputError(f"{name}: the camera's path passes fewer than 4 cross-sections "
                         f"{spacing:.3g} apart (it moves {_length(centres):.3g} units in all, "
                         f"some of them back over its path); too short for a lumen fit")
    ahead = max(round(config.extend / config.spacing), int(np.ceil(ahead_at_least / spacing)))
    behind = round(config.extend_back / config.spacing)
    path = _extended(path, ahead, behind, spacing)
    tree = cKDTree(surface)
    sigma = config.smoothing_stations
    for _ in range(config.iterations):
        centre, radius, on_wall = _cross_sections(path, surface, tree, spacing,
                                                  config.reach * r0, config, name)
        fitted = _resample(FittedLumen(gaussian_filter1d(centre, sigma, axis=0, mode="nearest"),
                                       gaussian_filter1d(radius, sigma, mode="nearest"),
                                       on_wall), spacing)
        if len(fitted.points) < 2:  # no direction to go on in, nor a tube to cut into cells
            raise InputError(f"{name}: the surface gives usable cross-sections of the lumen over "
                             f"less than half a station ({0.5 * spacing:.3g}); too little wall "
                             f"around the camera path for a lumen fit")
        # Where the surface ends, the centreline goes on straight with the end radius, and
        # past the cameras beyond it (the wall beside the last ones is rarely seen).
        before, after = _past_cameras(fitted.points, poses[:, :3, 3], spacing)
        ends = (behind + before, ahead + after)
        lumen = FittedLumen(_extended(fitted.points, ahead=ends[1], behind=ends[0],
                                      spacing=spacing),
                            np.pad(fitted.radius, ends, mode="edge"),
                            np.pad(fitted.fitted, ends))
        path = lumen.points
    return lumen


def metric_scale(lumen: FittedLumen, typical_radius_cm: float) -> float:
    """The factor that makes the median radius fitted to the surface equal typical_radius_cm
    (the straight continuations beyond the surface, which repeat the end radii, left out)."""
    radius = lumen.radius if lumen.fitted is None else lumen.radius[lumen.fitted]
    return typical_radius_cm / float(np.median(radius))


def _length(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def _sorted(points: np.ndarray) -> np.ndarray:
    """The points in a fixed (lexicographic) order, so that the fit depends on the points and
    not on their order (Open3D's threaded meshing lists the same vertices in a different order
    from run to run)."""
    return points[np.lexsort(points.T[::-1])]


def _thinned(points: np.ndarray, cell: float) -> np.ndarray:
    """The mean of the points in each occupied cube of side `cell` (Open3D's voxel
    down-sampling), in a fixed order."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    try:
        thin = cloud.voxel_down_sample(cell)
    except RuntimeError as err:  # more cubes than Open3D can index: a far outlier
        raise InputError(f"the surface spans {np.ptp(points, axis=0).max():.3g}, too far for "
                         f"cubes of {cell:.3g} (Open3D: {err}); check the depth for outliers"
                         ) from err
    return _sorted(np.asarray(thin.points))


def _stations(centres: np.ndarray, spacing: float, revisit: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Points every `spacing` along the path, first visits only, and whether each follows the
    one kept before it along the path (False after a return visit was skipped). A point is a
    return visit if a kept station lies within spacing/2 of it, or within `revisit` of it and
    more than twice as far back along the path, and a spacing more (the camera went away and
    came back beside its earlier pass; along one pass, even round a bend, the path back to a
    station is about as long as the straight line)."""
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    ell = np.concatenate([[0.0], np.cumsum(steps)])
    at = np.arange(0.0, ell[-1], spacing)
    samples = np.stack([np.interp(at, ell, centres[:, k]) for k in range(3)], axis=1)
    kept: list[np.ndarray] = []
    kept_at: list[float] = []
    follows: list[bool] = []
    previous_kept = False
    for point, here in zip(samples, at, strict=True):
        distance = np.linalg.norm(np.asarray(kept) - point, axis=1) if kept else np.empty(0)
        behind = here - np.asarray(kept_at)
        new = not ((distance < 0.5 * spacing)
                   | ((distance < revisit) & (behind > 2 * distance + spacing))).any()
        if new:
            kept.append(point)
            kept_at.append(here)
            follows.append(previous_kept)
        previous_kept = new
    return np.asarray(kept), np.asarray(follows, bool)


def _ordered(stations: np.ndarray, follows: np.ndarray, spacing: float, centres: np.ndarray,
             along: np.ndarray, name: str = "reconstruction") -> np.ndarray:
    """The stations in order along the lumen, oriented so that ℓ grows as the cameras' places
    `along` the colon do (towards its deep end).

    The runs of stations that follow one another along the camera path are joined end to end
    by the shortest links between their ends (a minimum spanning tree over the links within
    each run and those between run ends), and the longest path through that tree is the order;
    stations off it are dropped. A path without return visits is one run, kept as it is. The
    orientation: the stations nearest to the cameras run up with `along` (a least-squares
    slope over the frames; along time, it follows where the camera spent its time)."""
    n = len(stations)  # 4 or more (fit_lumen)
    run = np.flatnonzero(follows[1:]) + 1  # station k follows k - 1 within a run
    starts = np.flatnonzero(~follows)
    ends = np.unique(np.concatenate([starts, starts[1:] - 1, [n - 1]]))
    a, b = np.meshgrid(ends, ends, indexing="ij")
    between = (a < b) & ~((b == a + 1) & follows[b])  # the links within runs are below
    first, second = np.concatenate([run - 1, a[between]]), np.concatenate([run, b[between]])
    length = np.linalg.norm(stations[first] - stations[second], axis=1)
    # stations are spacing/2 or more apart: links within a run (0.01) are taken first
    weight = np.where(np.arange(len(first)) < len(run), 0.01, length / spacing)
    tree = minimum_spanning_tree(coo_matrix((weight, (first, second)), shape=(n, n))).tocoo()
    tree = coo_matrix((np.linalg.norm(stations[tree.row] - stations[tree.col], axis=1),
                       (tree.row, tree.col)), shape=(n, n))

    def farthest(start: int) -> tuple[int, np.ndarray]:
        lengths, previous = shortest_path(tree, directed=False, indices=start,
                                          return_predecessors=True)
        return int(np.argmax(lengths)), previous

    one_end, _ = farthest(0)
    other_end, previous = farthest(one_end)
    chain = [other_end]
    while chain[-1] != one_end:
        chain.append(int(previous[chain[-1]]))
    path = stations[chain]
    if np.ptp(along) == 0:
        raise InputError(f"{name}: the cameras' places along the colon are all the same "
                         f"(`along`): no direction to orient the lumen by")
    nearest = cKDTree(path).query(centres)[1]
    return path[::-1] if np.polyfit(along, nearest, 1)[0] < 0 else path


def _extended(path: np.ndarray, ahead: int, behind: int, spacing: float) -> np.ndarray:
    """The path continued straight on by `ahead` stations after its (deep) end and `behind`
    stations before its start."""
    head, tail = _end_directions(path)
    before = path[0] + spacing * np.arange(behind, 0, -1)[:, None] * head
    after = path[-1] + spacing * np.arange(1, ahead + 1)[:, None] * tail
    return np.vstack([before, path, after])


def _end_directions(path: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions out of the path's start and out of its end."""
    k = min(3, len(path) - 1)
    head, tail = path[0] - path[k], path[-1] - path[-1 - k]
    return tuple(d / max(np.linalg.norm(d), 1e-12) for d in (head, tail))


def _past_cameras(line: np.ndarray, cameras: np.ndarray, spacing: float) -> tuple[int, int]:
    """Stations to add before the line's start and after its end, continuing it straight, so
    that it reaches past the cameras nearest to either end, which would otherwise share the
    end's ℓ. Cameras that turn a bend beyond the fitted wall are not
    followed round it: the continuation is straight."""
    nearest = cKDTree(line).query(cameras)[1]
    head, tail = _end_directions(line)
    before = ((cameras[nearest == 0] - line[0]) @ head).max(initial=0.0)
    after = ((cameras[nearest == len(line) - 1] - line[-1]) @ tail).max(initial=0.0)
    return int(np.ceil(before / spacing)), int(np.ceil(after / spacing))


def _tangents(path: np.ndarray) -> np.ndarray:
    tangent = np.gradient(path, axis=0)
    return tangent / np.linalg.norm(tangent, axis=1, keepdims=True).clip(1e-12)


def _cross_sections(path: np.ndarray, surface: np.ndarray, tree: cKDTree, spacing: float,
                    reach: float, config: LumenFitConfig, name: str = "reconstruction"
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Circle centre and radius at the stations from the first to the last fitted one, gaps
    between them filled by interpolation, then a running median along the stations; and
    whether each station was fitted to the surface (a gap of one station between two that
    were counts too; a longer one is not wall the fit saw)."""
    tangents = _tangents(path)
    centre = np.full_like(path, np.nan)
    radius = np.full(len(path), np.nan)
    for i, (p, t) in enumerate(zip(path, tangents, strict=True)):
        near = surface[tree.query_ball_point(p, reach)]
        offset = near - p
        near = offset[np.abs(offset @ t) <= 0.5 * spacing]
        if len(near) < config.min_points:
            continue
        u = np.cross(t, [1.0, 0.0, 0.0] if abs(t[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(t, u)
        xy = np.stack([near @ u, near @ v], axis=1)
        fit = _circle(xy)
        if fit is None:
            continue
        (cx, cy), r, inliers = fit
        if np.hypot(cx, cy) >= r:  # the station (on the path, in the lumen) lies outside
            continue
        angles = np.arctan2(xy[inliers, 1] - cy, xy[inliers, 0] - cx)
        sectors = np.unique(((angles + np.pi) / (np.pi / 6)).astype(int) % 12)
        if len(sectors) >= config.min_arc_bins:
            centre[i], radius[i] = p + cx * u + cy * v, r
    ok = np.isfinite(radius)
    good = np.flatnonzero(ok)
    if len(good) < 2:
        raise InputError(f"{name}: no usable cross-section of the lumen (too few surface "
                         f"points around the camera path, or only short arcs of the wall); "
                         f"check depth and poses")
    index = np.arange(good[0], good[-1] + 1)  # from the first to the last fitted station
    bridged = ok.copy()
    bridged[1:-1] |= ok[:-2] & ok[2:]
    on_wall = bridged[index]
    centre = np.stack([np.interp(index, good, centre[good, k]) for k in range(3)], axis=1)
    radius = np.interp(index, good, radius[good])
    if len(index) < config.median_stations:  # too short to outvote anything
        return centre, radius, on_wall
    # Mirrored at the ends, so that a bad end section is outvoted too; an end centre then
    # takes its neighbour's place, shortening the centreline by up to a station.
    size = (config.median_stations, 1)
    return (median_filter(centre, size=size, mode="mirror"),
            median_filter(radius, size=size[0], mode="mirror"), on_wall)


def _circle(xy: np.ndarray, rounds: int = 3) -> tuple[np.ndarray, float, np.ndarray] | None:
    """Circle fit with outliers beyond 3 MADs trimmed: centre, radius and its inliers (a
    mask: the points within 3 MADs of the circle returned). Each round starts from the
    algebraic (Kåsa) fit, which on a noisy partial arc draws the circle too small, and
    refines it by least squares on the points' distances to the circle (scipy's
    least_squares)."""
    keep = np.ones(len(xy), dtype=bool)
    result = None
    for _ in range(rounds):
        pts = xy[keep]
        if len(pts) < 3:
            return result
        A = np.column_stack([pts, np.ones(len(pts))])
        b = -(pts ** 2).sum(axis=1)
        (d, e, f), *_ = np.linalg.lstsq(A, b, rcond=None)
        start = np.array([-d / 2, -e / 2])
        r2 = start @ start - f
        if not r2 > 0:
            return result
        fit = least_squares(_off_circle, np.append(start, np.sqrt(r2)),
                            jac=_off_circle_jacobian, method="lm", args=(pts,))
        centre, radius = fit.x[:2], float(abs(fit.x[2]))
        residual = np.abs(np.linalg.norm(xy - centre, axis=1) - radius)
        mad = np.median(residual[keep]) + 1e-12
        keep = residual <= 3 * 1.4826 * mad
        result = (centre, radius, keep)
    return result


def _off_circle(circle: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Each point's distance from the circle (cx, cy, r)."""
    return np.linalg.norm(pts - circle[:2], axis=1) - circle[2]


def _off_circle_jacobian(circle: np.ndarray, pts: np.ndarray) -> np.ndarray:
    towards = pts - circle[:2]
    distance = np.linalg.norm(towards, axis=1, keepdims=True).clip(1e-12)
    return np.column_stack([-towards / distance, -np.ones(len(pts))])


def _resample(lumen: FittedLumen, spacing: float) -> FittedLumen:
    """The lumen resampled every `spacing` of its own arc length (fitted: where the nearer
    of the two stations around a point was)."""
    ell = lumen.arclength
    at = np.append(np.arange(0.0, ell[-1] - 0.5 * spacing, spacing), ell[-1])
    fitted = None if lumen.fitted is None else np.interp(at, ell, lumen.fitted) >= 0.5
    return FittedLumen(np.stack([np.interp(at, ell, lumen.points[:, k]) for k in range(3)], 1),
                       np.interp(at, ell, lumen.radius), fitted)
