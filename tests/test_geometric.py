"""Lumen fit and geometric coverage against known tubes and analytic views."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from conftest import pose, wall_fraction
from test_coverage import (
    BACKWARD,
    ELL,
    FORWARD,
    FORWARD_CAMERA,
    IDENTITY,
    SIDE,
    SIDE_CAMERA,
    VIEWS,
)

from hybrid.coverage import DELTA_PAIRS_CM, Lumen, pair_key
from hybrid.geometric_coverage import GeometricConfig, geometric_coverage, tube_cells
from hybrid.lumen_fit import FittedLumen, LumenFitConfig, fit_lumen, metric_scale
from hybrid.types import Camera, InputError

BEND_RADIUS = 15.0
"""The curved test tube's centreline is an arc of this radius in the x-z plane."""


def arc_centreline(angle: np.ndarray) -> np.ndarray:
    return np.stack([BEND_RADIUS * (1 - np.cos(angle)), np.zeros_like(angle),
                     BEND_RADIUS * np.sin(angle)], 1)


def tube_radius(angle: np.ndarray) -> np.ndarray:
    return 2.0 + 0.3 * np.sin(3 * angle)


def curved_tube(angles: int = 700, around: int = 180) -> np.ndarray:
    """Wall points of a bent tube: arc length 15·1.6 = 24 cm, radius 1.7-2.3 cm."""
    a = np.linspace(0, 1.6, angles)
    theta = np.linspace(0, 2 * np.pi, around, endpoint=False)
    centre = arc_centreline(a)
    normal = np.stack([np.cos(a), np.zeros_like(a), -np.sin(a)], 1)  # in-plane, ⟂ tangent
    binormal = np.array([0.0, 1.0, 0.0])
    ring = np.cos(theta)[None, :, None] * normal[:, None] + np.sin(theta)[None, :, None] \
        * binormal
    return (centre[:, None] + tube_radius(a)[:, None, None] * ring).reshape(-1, 3)


def withdrawal_on_arc(frames: int = 400) -> np.ndarray:
    """Cameras from angle 1.3 back to 0.2 (a withdrawal), 0.4 cm off the axis, looking deeper."""
    a = np.linspace(1.3, 0.2, frames)
    poses = np.repeat(np.eye(4)[None], frames, 0)
    tangent = np.stack([np.sin(a), np.zeros_like(a), np.cos(a)], 1)
    y = np.array([0.0, 1.0, 0.0])
    poses[:, :3, 2] = tangent
    poses[:, :3, 1] = y
    poses[:, :3, 0] = np.cross(y, tangent)
    poses[:, :3, 3] = arc_centreline(a) + 0.4 * y * np.sin(np.linspace(0, 6, frames))[:, None]
    return poses


@pytest.mark.parametrize("thinning", [LumenFitConfig().thinning, 0.0])
def test_lumen_fit_recovers_a_curved_tube(thinning):
    poses = withdrawal_on_arc()
    lumen = fit_lumen(poses, curved_tube(), config=LumenFitConfig(thinning=thinning))
    # True arc position of each fitted point: the angle of its projection on the bend plane.
    angle = np.arctan2(lumen.points[:, 2], BEND_RADIUS - lumen.points[:, 0])
    distance = np.linalg.norm(lumen.points - arc_centreline(angle), axis=1)
    # Along the camera path and the wall ahead of it (the tube's ends, where the centreline
    # goes on straight, excluded): circle fits to exact wall points are exact; what is left is
    # the slab's curvature and smoothing along a bend of radius 15 cm (hundredths of a cm).
    covered = (angle > 0.15) & (angle < 1.5)
    assert distance[covered].mean() < 0.05 and distance[covered].max() < 0.15
    error = lumen.radius[covered] - tube_radius(angle[covered])
    assert np.abs(error).mean() < 0.05
    # A withdrawal: ℓ = 0 near the last camera, growing towards the first (the deep end), and
    # continued beyond it into the look-ahead band.
    assert np.all(np.diff(angle) > 0)
    assert angle[0] < 0.2 and angle[-1] > 1.3 + 4.0 / BEND_RADIUS
    # The radius is fitted where there is wall; the straight continuations repeat the end
    # radii, and the scale rule leaves them out.
    assert not lumen.fitted[(angle < 0) | (angle > 1.6)].any()  # beyond the tube's ends
    assert lumen.fitted[(angle > 0.2) & (angle < 1.3)].all()
    assert metric_scale(lumen, 2.5) == pytest.approx(2.5 / np.median(lumen.radius[lumen.fitted]))


def test_lumen_saves_and_loads(tmp_path):
    lumen = fit_lumen(withdrawal_on_arc(), curved_tube())
    lumen.save(tmp_path / "lumen.json")
    again = FittedLumen.load(tmp_path / "lumen.json")
    for field in ("points", "radius", "fitted"):
        np.testing.assert_array_equal(getattr(again, field), getattr(lumen, field))


def test_lumen_fit_outvotes_bad_cross_sections():
    """Wall points with 1 mm of noise (a TSDF surface) and a ragged deep end, cut by a slanted
    plane: near the end the slabs hold short, noisy arcs, whose circle fits can come out far
    too small or large. One such section must not pull the radius along the fit, nor the
    radius continued into the look-ahead band beyond the end: both stay within 5% and 10% of
    the tube's 2 cm (the fit before the running median and the enclosing rule fails this)."""
    surface, poses = curved_tube(), withdrawal_on_arc()
    angle = np.arctan2(surface[:, 2], BEND_RADIUS - surface[:, 0])
    for seed in range(5):
        noisy = surface + 0.1 * np.random.default_rng(seed).standard_normal(surface.shape)
        lumen = fit_lumen(poses, noisy[angle < 1.45 + 0.08 * noisy[:, 1]])
        at = np.arctan2(lumen.points[:, 2], BEND_RADIUS - lumen.points[:, 0])
        along, ahead = (at > 0.15) & (at < 1.5), at > 1.5
        assert np.abs(lumen.radius[along] - tube_radius(at[along])).max() < 0.05 * 2.0
        assert np.abs(lumen.radius[ahead] - tube_radius(1.45)).max() < 0.1 * 2.0


def noisy_arc_tube(degrees: float, noise: float = 0.2, seed: int = 1) -> np.ndarray:
    """20,000 points of the straight 2-cm tube from z = -1 to 21 cm, on an arc of the wall
    from 0 to `degrees`, with Gaussian radial noise (cm)."""
    rng = np.random.default_rng(seed)
    angle = rng.uniform(0, np.radians(degrees), 20_000)
    r = RADIUS + rng.normal(0, noise, len(angle))
    return np.column_stack([r * np.cos(angle), r * np.sin(angle), rng.uniform(-1, 21, len(angle))])


@pytest.mark.parametrize("degrees", [130, 180, 360])
def test_the_radius_of_a_noisy_partial_arc_is_not_drawn_too_small(degrees):
    """A wall seen on a 130° or 180° arc (and all round), 2 mm of noise: the circles are
    fitted by their points' distances, so the radius stays within 3% of 2 cm (the algebraic
    fit alone gave 1.63 on the 130° arc)."""
    lumen = fit_lumen(cameras_at(np.linspace(18, 2, 300), 0.0), noisy_arc_tube(degrees))
    assert np.median(lumen.radius[lumen.fitted]) == pytest.approx(RADIUS, rel=0.03)


def test_the_lumen_is_fitted_only_where_there_is_wall():
    """No wall at all from z = 5 to 12 cm: the centreline is interpolated across, but not
    marked fitted there (the support of a segment's coverage reads it)."""
    tube = straight_tube()
    tube = tube[(tube[:, 2] > -2) & (tube[:, 2] < 18) & ((tube[:, 2] < 5) | (tube[:, 2] > 12))]
    lumen = fit_lumen(cameras_at(np.linspace(14, 0, 160), 0.2), tube)
    z = lumen.points[:, 2]
    assert not lumen.fitted[(z > 5.5) & (z < 12)].any()  # the slab at 5.1 reaches the wall
    assert lumen.fitted[(z > 1) & (z < 4)].all() and lumen.fitted[(z > 13) & (z < 14)].all()


@pytest.mark.parametrize("radius", [1.0, 1.2, 1.5])
def test_the_tube_reaches_every_cameras_look_ahead_band(radius):
    """A narrow tube whose wall ends 0.5 cm past the deepest camera: continued 3.5 radii
    from the cameras' smoothed path, it ended 5.85 cm beyond that camera at 1 cm (at 42b6e32),
    short of the farthest band (6 cm); with ahead_at_least it reaches that band, or a farther
    one (9 cm, which 3.5 radii past the raw cameras do not reach either)."""
    tube = straight_tube(radius)
    tube = tube[tube[:, 2] < 8.5]
    poses = cameras_at(np.linspace(8, 2, 120), 0.2)
    lumen = fit_lumen(poses, tube, ahead_at_least=6.0)
    ell, _ = Lumen(lumen.points).project(poses[:, :3, 3])
    assert lumen.arclength[-1] >= ell.max() + 6.0
    lumen = fit_lumen(poses, tube, ahead_at_least=9.0)
    ell, _ = Lumen(lumen.points).project(poses[:, :3, 3])
    assert lumen.arclength[-1] >= ell.max() + 9.0


def test_lumen_fit_rejects_circles_that_miss_the_station():
    """Along 3 cm of the tube the wall is missing and a narrow tube (0.4 cm, a fold or a
    polyp in section) lies against it, off the camera path: its slabs fit small circles that
    do not enclose the stations. They are rejected, and the radius there comes from the wall
    either side (without the rule it drops to the narrow tube's scale; every point is kept
    here, so that the narrow tube's slabs hold enough points to be fitted)."""
    surface, poses = curved_tube(), withdrawal_on_arc()
    angle = np.arctan2(surface[:, 2], BEND_RADIUS - surface[:, 0])
    band = np.abs(angle - 0.7) < 0.1
    a = angle[band]
    around = np.random.default_rng(0).uniform(0, 2 * np.pi, len(a))
    in_plane = np.stack([np.cos(a), np.zeros_like(a), -np.sin(a)], 1)  # ⟂ tangent, in the bend
    narrow = (arc_centreline(a) + [0.0, 1.3, 0.0] + 0.4 * (np.cos(around)[:, None] * in_plane
                                                            + np.sin(around)[:, None] * [0, 1, 0]))
    lumen = fit_lumen(poses, np.vstack([surface[~band], narrow]),
                      config=LumenFitConfig(thinning=0.0))
    at = np.arctan2(lumen.points[:, 2], BEND_RADIUS - lumen.points[:, 0])
    assert lumen.radius[np.abs(at - 0.7) < 0.1].min() > 0.75 * 2.0


def test_lumen_reaches_past_the_cameras():
    """The wall beside the last cameras of a withdrawal is rarely seen (they look deeper).
    With wall only from angle 0.6 on and cameras back to 0.2 (6 cm short of it), the
    centreline still goes on past the last camera, so each camera gets its own ℓ rather than
    all sharing the centreline's end."""
    surface, poses = curved_tube(), withdrawal_on_arc()
    deep = surface[np.arctan2(surface[:, 2], BEND_RADIUS - surface[:, 0]) > 0.6]
    lumen = fit_lumen(poses, deep)
    ell, _ = Lumen(lumen.points).project(poses[:, :3, 3])
    assert ell.min() > 0
    # The continuation is not fitted (nor read by the scale rule).
    at = np.arctan2(lumen.points[:, 2], BEND_RADIUS - lumen.points[:, 0])
    assert not lumen.fitted[at < 0.55].any()
    # ℓ follows the cameras' path (a withdrawal: ℓ falls with time), to within a station.
    path = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).cumsum()
    assert ell[0] - ell[-1] == pytest.approx(path[-1], abs=0.25 * 2.0)


def straight_tube(radius: float = 2.0) -> np.ndarray:
    """Points on the cylinder x² + y² = radius² for z in [-6, 40) cm."""
    z = np.arange(-6.0, 40.0, 0.05)
    angle = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    return np.stack(np.broadcast_arrays(radius * np.cos(angle)[None], radius * np.sin(
        angle)[None], z[:, None]), axis=-1).reshape(-1, 3)


def cameras_at(z: np.ndarray, x: float | np.ndarray = 0.3) -> np.ndarray:
    """Cameras looking down +z from (x, 0, z) in the straight tube."""
    poses = np.repeat(np.eye(4)[None], len(z), axis=0)
    poses[:, 0, 3], poses[:, 2, 3] = x, z
    return poses


def coverage_on_fit_and_axis(fitted: FittedLumen, withdrawal: np.ndarray) -> tuple[float, float]:
    """The (1, 4) coverage of one segment of these cameras in the 2-cm tube, on the fitted
    lumen and on the tube's axis (ℓ growing with z)."""
    axis = FittedLumen(np.array([[0.0, 0.0, -10.0], [0.0, 0.0, 40.0]]), np.array([RADIUS] * 2))
    depth = [cylinder_depth(FORWARD_CAMERA, p) for p in withdrawal]
    config = GeometricConfig(segment_frames=len(withdrawal))
    return tuple(geometric_coverage(lumen, withdrawal, depth, FORWARD_CAMERA.K, config=config)
                 .segments[0].coverage[pair_key((1.0, 4.0))] for lumen in (fitted, axis))


@pytest.mark.parametrize("depths", [(10, 16, 2), (10, 13, 2), (14, 2, 8), (14, 2)])
def test_lumen_fit_follows_the_tube_when_the_camera_goes_back_over_its_path(depths):
    """A window that pushes in before withdrawing visits stations out of order in time: the
    centreline still runs one way along the tube (taken in time order, it folded back on
    itself for a 6-cm push, and the fit failed for a 3-cm one), with ℓ growing towards the
    deep end on a withdrawal and against it on an insertion, and the cameras get the ℓ of
    their depth; as they do, as before, when the camera pushes in again at the end or goes
    one way only."""
    frames = [150 if abs(b - a) < 7 else 450 for a, b in zip(depths, depths[1:], strict=False)]
    z = np.concatenate([np.linspace(a, b, n) for a, b, n in zip(depths, depths[1:], frames,
                                                                      strict=False)])
    poses = cameras_at(z)
    for withdrawal in (True, False):
        lumen = fit_lumen(poses, straight_tube(), config=LumenFitConfig(withdrawal=withdrawal))
        step = np.diff(lumen.points[:, 2])
        assert (step > 0).all() if withdrawal else (step < 0).all()
    ell, _ = Lumen(lumen.points).project(poses[:, :3, 3])  # the insertion's, ℓ = start - z
    assert ell + z == pytest.approx(np.full_like(z, (ell + z).mean()), abs=0.1)


@pytest.mark.parametrize("side", [0.6, 1.0])
def test_lumen_fit_follows_the_tube_when_the_camera_comes_back_beside_its_path(side):
    """The 6-cm push-in, then the withdrawal `side` cm to one side of it in the 2-cm tube,
    whose wall is seen from 1 to 22 cm: the stations of the way back are return visits though
    half a radius away, and the centreline does not fold back (it did for both sides when
    only stations within half a spacing were taken for return visits)."""
    z = np.concatenate([np.linspace(10, 16, 150), np.linspace(16, 2, 450)])
    poses = cameras_at(z, np.concatenate([np.full(150, 0.3), np.linspace(0.3, 0.3 - side, 30),
                                          np.full(420, 0.3 - side)]))
    tube = straight_tube()
    lumen = fit_lumen(poses, tube[(tube[:, 2] > 1) & (tube[:, 2] < 22)])
    assert (np.diff(lumen.points[:, 2]) > 0).all()
    ell, _ = Lumen(lumen.points).project(poses[:, :3, 3])  # a withdrawal: ℓ = z + constant
    assert ell - z == pytest.approx(np.full_like(z, (ell - z).mean()), abs=0.25 * 2.0)


def test_a_withdrawal_after_a_push_in_reads_its_coverage_on_the_fitted_lumen():
    """The 6-cm push-in above, then the withdrawal from 16 to 2 cm: its segment's coverage on
    the lumen fitted to the whole window is that on the true axis (a folded lumen gave some
    of its cameras one ℓ and cut V short)."""
    z = np.concatenate([np.linspace(10, 16, 150), np.linspace(16, 2, 450)])
    poses = cameras_at(z)
    on_fit, on_axis = coverage_on_fit_and_axis(fit_lumen(poses, straight_tube()), poses[300:])
    assert on_fit == pytest.approx(on_axis, abs=0.02)


def test_a_window_that_pushes_in_for_longer_than_it_withdraws_is_oriented_by_along():
    """A withdrawal's window in which the camera pushes in 6 cm over 15 s, then withdraws 4 cm
    over 5: by time spent it reads as an insertion, and its lumen runs backwards (the
    withdrawal's stretch read 0.118 against 0.837 on the true axis). Given the cameras'
    places along the colon (in `c2d2 run`, their ℓ on the whole video's lumen; here their
    depth), ℓ grows towards the deep end and that stretch reads what the axis gives."""
    z = np.concatenate([np.linspace(10, 16, 450), np.linspace(16, 12, 150)])
    poses = cameras_at(z)
    tube = straight_tube()
    tube = tube[(tube[:, 2] > 1) & (tube[:, 2] < 24)]
    by_time, by_place = fit_lumen(poses, tube), fit_lumen(poses, tube, along=z)
    assert (np.diff(by_time.points[:, 2]) < 0).all()
    assert (np.diff(by_place.points[:, 2]) > 0).all()
    on_fit, on_axis = coverage_on_fit_and_axis(by_place, poses[450:])
    assert on_fit == pytest.approx(on_axis, abs=0.02)
    for bad in (z[:-1], np.where(z > 15, np.nan, z)):
        with pytest.raises(InputError, match="must give each of the 600 cameras a finite place"):
            fit_lumen(poses, tube, along=bad)
    with pytest.raises(InputError, match="^window 3: the cameras' places along the colon are "
                                         "all the same"):
        fit_lumen(poses, tube, along=np.full_like(z, 3.0), name="window 3")
    with pytest.raises(InputError, match="passes fewer than 4 cross-sections"):  # not `along`
        fit_lumen(cameras_at(np.full(600, 10.0)), tube, along=np.full(600, 3.0))


def test_stations_of_a_path_that_crosses_itself_stay_in_order():
    """An 'alpha' path: 20 cm along x, a half turn, then back across its own start. Where it
    crosses the first arm its stations are return visits, and the run after them must join
    the others at their ends, not midway (which dropped a whole arm from the longest path)."""
    from hybrid.lumen_fit import _ordered, _stations

    turn = np.linspace(0, np.pi, 300)
    path = np.concatenate([np.linspace([0, 0, 0], [20, 0, 0], 400),
                           np.c_[20 + 5 * np.sin(turn), 5 - 5 * np.cos(turn), 0 * turn],
                           np.linspace([20, 10, 0], [0.3, -9.7, 0], 600)])
    stations, follows = _stations(path, 1.0, 2.0)  # spacing and revisit as fit_lumen's
    assert not follows.all()  # the crossing skipped some
    ordered = _ordered(stations, follows, 1.0, path, np.arange(len(path)))  # an insertion
    assert len(ordered) == len(stations)
    assert np.abs(ordered[0]).max() < 1e-9  # an insertion: ℓ grows from where it started
    # no jump but over the stations dropped at the crossing: those of the second arm within
    # 2 of the first, which it crosses at 45°, 4√2 = 5.7 of its length
    assert np.linalg.norm(np.diff(ordered, axis=0), axis=1).max() < 4 * np.sqrt(2) + 1


def test_lumen_fit_is_unit_free():
    """The same fit in another unit. The factor is a power of two, so that scaling is exact in
    floating point: with 0.1, rounding moved the number of stations by one and the centreline
    by 0.3% of the radius."""
    poses = withdrawal_on_arc()
    surface = curved_tube()
    lumen = fit_lumen(poses, surface)
    scaled = poses.copy()
    scaled[:, :3, 3] *= 0.125
    small = fit_lumen(scaled, surface * 0.125)
    assert np.allclose(small.points, lumen.points * 0.125, rtol=1e-12, atol=1e-9)
    assert np.allclose(small.radius, lumen.radius * 0.125, rtol=1e-12, atol=1e-9)


def test_lumen_fit_does_not_depend_on_the_order_of_the_points():
    poses, surface = withdrawal_on_arc(), curved_tube()
    shuffled = surface[np.random.default_rng(0).permutation(len(surface))]
    for config in (LumenFitConfig(), LumenFitConfig(thinning=0.0)):
        lumen, again = fit_lumen(poses, surface, config=config), fit_lumen(poses, shuffled,
                                                                            config=config)
        np.testing.assert_array_equal(again.points, lumen.points)
        np.testing.assert_array_equal(again.radius, lumen.radius)


def test_lumen_fit_bad_input():
    poses = withdrawal_on_arc()
    with pytest.raises(InputError, match="no surface"):
        fit_lumen(poses, np.zeros((0, 3)))
    with pytest.raises(InputError, match="NaN"):
        fit_lumen(poses, np.full((100, 3), np.nan))
    with pytest.raises(InputError, match="too short"):
        fit_lumen(poses[:3], curved_tube())
    for thinning in (-0.1, float("nan")):
        with pytest.raises(InputError, match="thinning"):
            LumenFitConfig(thinning=thinning)
    # Wall in a band 6 mm long only (of the tube's 24 cm): its cross-sections span less than
    # half a station, and the fitted centreline would collapse to a point (a real clip did this).
    surface = curved_tube()
    band = surface[np.abs(np.arctan2(surface[:, 2], BEND_RADIUS - surface[:, 0]) - 0.8) < 0.02]
    with pytest.raises(InputError, match="less than half a station"):
        fit_lumen(poses, band)
    with pytest.raises(InputError, match="too short for two cells"):
        tube_cells(FittedLumen(np.zeros((3, 3)), np.ones(3)), 0.2, 72)
    with pytest.raises(InputError, match="^window 3: no usable cross-section"):  # 60° of wall
        fit_lumen(cameras_at(np.linspace(18, 2, 300), 0.0), noisy_arc_tube(60), name="window 3")


# --- geometric coverage on the straight cylinder of test_coverage ------------------------

RADIUS = 2.0
AXIS = FittedLumen(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 10.0]]), np.array([RADIUS, RADIUS]))
"""The exact lumen of the cylinder: the z axis, radius 2 cm, ℓ = z."""
FINE = GeometricConfig(cell_length_cm=0.02, cells_around=720, segment_frames=1)


def cylinder_depth(camera: Camera, view: np.ndarray, radius: float = RADIUS) -> np.ndarray:
    """z-depth of the inside of the infinite cylinder x² + y² = R² seen from `view`."""
    v, u = np.mgrid[:camera.height, :camera.width].astype(float)
    rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy,
                     np.ones_like(u)], -1) @ view[:3, :3].T  # world direction per unit z
    o = view[:3, 3]
    a = rays[..., 0] ** 2 + rays[..., 1] ** 2
    b = 2 * (o[0] * rays[..., 0] + o[1] * rays[..., 1])
    c = o[0] ** 2 + o[1] ** 2 - radius ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a)  # the exit root: we are inside
    return np.where(np.isfinite(t) & (t > 0), t, 0.0).astype(np.float32)


def cell_grid_bound(config: GeometricConfig, expected, band: float, n_arcs: int) -> float:
    """How far a cell count can fall from the integral over a band `band` long: a row of
    cells per cell length where the seen share varies (its total variation), a cell per arc
    of the field of view's edge around the ring, and the integral's own quadrature error."""
    return (config.cell_length_cm * expected.total_variation / band
            + n_arcs / config.cells_around + expected.grid_error)


@pytest.mark.parametrize("name,camera,view,n_arcs", VIEWS, ids=[v[0] for v in VIEWS])
def test_one_frame_matches_the_field_of_view_integral(name, camera, view, n_arcs):
    result = geometric_coverage(AXIS, view[None], [cylinder_depth(camera, view)], camera.K,
                                config=FINE)
    for d0, d1 in DELTA_PAIRS_CM:
        expected = wall_fraction(camera, [view], RADIUS, ELL + d0, ELL + d1, n_arcs)
        # Cells instead of mesh vertices: the quadrature bound of conftest.mesh_tolerance with
        # the cell grid (length h, K around).
        tol = cell_grid_bound(FINE, expected, d1 - d0, n_arcs)
        got = result.segments[0].coverage[pair_key((d0, d1))]
        assert got == pytest.approx(expected.value, abs=tol), (name, d0, d1)


def test_a_segment_is_the_union_of_its_frames():
    views = [FORWARD, SIDE]  # one lens for the whole video: the side camera's
    depth = [cylinder_depth(SIDE_CAMERA, v) for v in views]
    config = GeometricConfig(cell_length_cm=0.02, cells_around=720, segment_frames=2)
    both = geometric_coverage(AXIS, np.stack(views), depth, SIDE_CAMERA.K, config=config)
    alone = [geometric_coverage(AXIS, v[None], [d], SIDE_CAMERA.K, config=FINE)
             for v, d in zip(views, depth, strict=True)]
    key = pair_key((1.0, 4.0))
    union = both.segments[0].coverage[key]
    assert union >= max(a.segments[0].coverage[key] for a in alone) - 1e-12
    expected = wall_fraction(SIDE_CAMERA, views, RADIUS, ELL + 1.0, ELL + 4.0, 6)
    assert union == pytest.approx(expected.value, abs=cell_grid_bound(config, expected, 3.0, 6))


def test_v_includes_the_row_at_its_far_edge():
    """V(Δ0, Δ1) includes ℓ = ℓmax + Δ1 (as the truth does): with the camera where that is a
    cell row's centre exactly, the row is part of the expected wall (it was left out of the
    rows scanned when Δ1 is the widest pair's, while in V by the inequality)."""
    config = GeometricConfig(segment_frames=1)
    long = FittedLumen(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 40.0]]), np.array([RADIUS] * 2))
    rows = tube_cells(long, config.cell_length_cm, config.cells_around).ell
    for z in np.arange(2.0, 10.0, 0.02):
        view = pose(IDENTITY, (0.0, 0.0, z))
        ell = Lumen(long.points).project(view[None, :3, 3])[0][0]
        if (edge := np.flatnonzero(rows == ell + 4.0)).size:
            break
    else:
        pytest.fail("no camera ℓ puts ℓ + 4 on a row centre")
    result = geometric_coverage(long, view[None], [np.full((48, 64), 50.0)], FORWARD_CAMERA.K,
                                config=config, delta_pairs=((1.0, 4.0),))  # the widest Δ1
    assert result.expected[edge[0]].all()
    assert not result.expected[edge[0] + 1].any()


def test_support_is_the_share_of_v_on_the_fitted_lumen():
    """The same axis, fitted to the surface only up to ℓ = 4.5 cm and continued straight from
    5 cm: the forward camera's V(1, 4) = [3.02, 6.02] lies on fitted wall up to the midpoint
    4.75, so its support is (4.75 - 3.02) / 3; the coverage does not depend on it. Support
    weighs by area: with a radius r(ℓ) = 1 + ℓ / 2 the share is the integral of r over the
    fitted part of V over that over V."""
    z = np.arange(0.0, 10.01, 0.5)
    part = FittedLumen(np.stack([0 * z, 0 * z, z], 1), np.full(len(z), RADIUS), z <= 4.5)
    depth = [cylinder_depth(FORWARD_CAMERA, FORWARD)]
    cut = geometric_coverage(part, FORWARD[None], depth, FORWARD_CAMERA.K, config=FINE)
    whole = geometric_coverage(AXIS, FORWARD[None], depth, FORWARD_CAMERA.K, config=FINE)
    cell = FINE.cell_length_cm / 3.0
    assert cut.support[0] == pytest.approx((4.75 - (ELL + 1.0)) / 3.0, abs=cell)
    assert whole.support == [1.0]  # no mask: every point fitted
    key = pair_key((1.0, 4.0))
    assert cut.segments[0].coverage[key] == pytest.approx(whole.segments[0].coverage[key])

    def integral(a: float, b: float) -> float:  # of 1 + ℓ / 2
        return (b - a) + (b * b - a * a) / 4.0

    lo, hi = ELL + 1.0, ELL + 4.0
    wide = FittedLumen(part.points, 1.0 + z / 2.0, part.fitted)
    tapered = geometric_coverage(wide, FORWARD[None], depth, FORWARD_CAMERA.K, config=FINE)
    assert tapered.support[0] == pytest.approx(integral(lo, 4.75) / integral(lo, hi), abs=cell)
    assert abs(integral(lo, 4.75) / integral(lo, hi) - (4.75 - lo) / 3.0) > 5 * cell
    # no support where V is not measured: the default pair not asked for
    other = geometric_coverage(part, FORWARD[None], depth, FORWARD_CAMERA.K, config=FINE,
                               delta_pairs=((1.0, 3.0),))
    assert other.support == [None]


def test_looking_backwards_sees_nothing_and_an_occluder_hides_everything():
    back = geometric_coverage(AXIS, BACKWARD[None], [cylinder_depth(FORWARD_CAMERA, BACKWARD)],
                              FORWARD_CAMERA.K, config=FINE)
    assert back.segments[0].coverage[pair_key((1.0, 4.0))] == 0.0
    # Something 0.5 cm in front of the camera fills the view: the band from 1 cm is hidden.
    wall = np.full((FORWARD_CAMERA.height, FORWARD_CAMERA.width), 0.5, np.float32)
    hidden = geometric_coverage(AXIS, FORWARD[None], [wall], FORWARD_CAMERA.K, config=FINE)
    assert hidden.segments[0].coverage[pair_key((1.0, 4.0))] == 0.0
    assert (hidden.first_seen == -1).all() and hidden.expected.any()


def test_geometric_coverage_bad_input():
    depth = cylinder_depth(FORWARD_CAMERA, FORWARD)
    two = np.stack([FORWARD, FORWARD])
    config = GeometricConfig(segment_frames=2)
    with pytest.raises(InputError, match="1 depth maps for 2 poses"):
        geometric_coverage(AXIS, two, [depth], FORWARD_CAMERA.K, config=config)
    with pytest.raises(InputError, match="shorter than one segment"):
        geometric_coverage(AXIS, FORWARD[None], [depth], FORWARD_CAMERA.K, config=config)
    for bad in (depth * np.nan, -depth):
        with pytest.raises(InputError, match="^video frame 1: depth has NaN, infinite or "
                                             "negative values"):
            geometric_coverage(AXIS, two, [depth, bad], FORWARD_CAMERA.K, config=config)
    with pytest.raises(InputError, match="NaN"):
        geometric_coverage(AXIS, two * np.nan, [depth, depth], FORWARD_CAMERA.K, config=config)
    for region in (np.ones((3, 3), bool), np.ones(depth.shape, np.uint8)):
        with pytest.raises(InputError, match="image region must be a bool mask"):
            geometric_coverage(AXIS, two, [depth, depth], FORWARD_CAMERA.K, region=region,
                               config=config)


def test_a_lumens_fitted_flags_are_a_mask():
    """Flags given as 0/1 select stations as a mask (by index they would pick the wrong radii),
    and their number must match the stations'."""
    points = np.array([[0.0, 0, 0], [0, 0, 1], [0, 0, 2]])
    lumen = FittedLumen(points, np.array([1.0, 2.0, 3.0]), np.array([0, 1, 1]))
    assert lumen.fitted.dtype == bool
    assert metric_scale(lumen, 5.0) == pytest.approx(2.0)  # the median of 2 and 3 is 2.5
    with pytest.raises(InputError, match=r"got \(3, 3\), \(3,\), \(2,\)"):
        FittedLumen(points, np.ones(3), np.ones(2, bool))


@pytest.mark.parametrize("points, radius", [
    (np.array([[0.0, 0, 0], [0, 0, np.nan]]), np.array([2.0, 2.0])),
    (np.array([[0.0, 0, 0], [0, 0, 10]]), np.array([2.0, 0.0])),
    (np.array([[0.0, 0, 0], [0, 0, 10]]), np.array([2.0])),
    (np.zeros((0, 3)), np.zeros(0)),
])
def test_a_lumen_that_is_not_finite_or_has_no_positive_radius_is_refused(points, radius, tmp_path):
    with pytest.raises(InputError, match="^a lumen"):
        FittedLumen(points, radius)
    path = tmp_path / "lumen.json"
    path.write_text(json.dumps({"points": points.tolist(), "radius": radius.tolist()}))
    with pytest.raises(InputError, match=f"^{path}: a lumen.*delete it"):
        FittedLumen.load(path)


def test_reconstruction_fixes_the_scale_by_the_typical_radius():
    """Cameras withdrawing along the axis of a 2 cm cylinder, depth in mm (× 10): the scale rule
    (median radius 2.5 cm) gives 0.125 cm per input unit, a mesh on the 2.5 cm wall, and a
    lumen on the axis."""
    from hybrid.reconstruction import ReconstructionConfig, reconstruct

    camera = Camera(64, 48, 30.0, 30.0, 31.5, 23.5)
    poses = np.repeat(np.eye(4)[None], 90, 0)
    poses[:, 2, 3] = np.linspace(8.0, 2.0, 90)  # withdrawal, looking deeper (+z)
    depth = [cylinder_depth(camera, p) * 10 for p in poses]
    mm = poses.copy()
    mm[:, :3, 3] *= 10
    config = ReconstructionConfig(typical_radius_cm=2.5, voxel_cm=0.05)
    rec = reconstruct(depth, camera.K, mm, config=config)
    # The scale from a lumen fitted to the back-projected cloud: within a few % of the exact
    # 0.125 (the circle fits see the wall in partial arcs at the image edges).
    assert rec.scale == pytest.approx(0.125, rel=0.03)
    radial = np.linalg.norm(rec.mesh.vertices[:, :2], axis=1)
    assert np.median(radial) == pytest.approx(2.0 * 10 * rec.scale, abs=config.voxel_cm)
    # The fused wall is good to a voxel or two (partial, grazing views at the image edges), and
    # so is the centreline fitted to it.
    z = rec.lumen.points[:, 2]  # where there is wall (beyond it the centreline goes straight)
    walled = (z > rec.mesh.vertices[:, 2].min() + 0.5) & (z < rec.mesh.vertices[:, 2].max() - 0.5)
    off_axis = np.linalg.norm(rec.lumen.points[walled, :2], axis=1)
    assert off_axis.mean() < 2 * config.voxel_cm and off_axis.max() < 3 * config.voxel_cm
    assert np.median(rec.lumen.radius) == pytest.approx(2.5, rel=0.03)
    assert np.allclose(rec.poses[:, :3, 3], poses[:, :3, 3] * 10 * rec.scale)


def test_local_segment_coverage_matches_the_exact_lumen(tmp_path):
    """Two segments of a withdrawal along a 2 cm cylinder, depth in mm: each reconstructed on
    its own window (scale rule with the true radius), against geometric coverage on the exact
    axis in cm. The windows' TSDF and lumen fit are good to a voxel or two, a few hundredths of
    coverage."""
    from hybrid.reconstruction import ReconstructionConfig
    from hybrid.segment_geometry import local_segment_coverage, save_maps

    camera = Camera(64, 48, 30.0, 30.0, 31.5, 23.5)
    poses = np.repeat(np.eye(4)[None], 90, 0)
    poses[:, 2, 3] = np.linspace(8.0, 2.0, 90)
    depth = [cylinder_depth(camera, p) for p in poses]
    long_axis = FittedLumen(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 20.0]]), np.full(2, RADIUS))
    exact = geometric_coverage(long_axis, poses, depth, camera.K,
                               config=GeometricConfig(segment_frames=45))
    mm = poses.copy()
    mm[:, :3, 3] *= 10
    config = ReconstructionConfig(typical_radius_cm=RADIUS, voxel_cm=0.05)
    local = local_segment_coverage([d * 10 for d in depth], camera.K, mm, 45, 20, None, config,
                                   GeometricConfig(), threads=2)
    key = pair_key((1.0, 4.0))
    assert [s.segment.start for s in local] == [0, 45] and all(s.error is None for s in local)
    alone = local_segment_coverage([d * 10 for d in depth], camera.K, mm, 45, 20, None, config,
                                   GeometricConfig(), threads=1)  # segments one at a time
    assert [s.segment for s in alone] == [s.segment for s in local]
    # The visibility test reads visibility_depth: the same depth changes nothing; a wall read
    # at half its distance hides the vertices behind it.
    same = local_segment_coverage([d * 10 for d in depth], camera.K, mm, 45, 20, None, config,
                                  GeometricConfig(), visibility_depth=[d * 10 for d in depth])
    assert [s.segment for s in same] == [s.segment for s in local]
    near = local_segment_coverage([d * 10 for d in depth], camera.K, mm, 45, 20, None, config,
                                  GeometricConfig(), visibility_depth=[d * 5 for d in depth])
    for hidden, full in zip(near, local, strict=True):
        assert hidden.segment.coverage[key] < 0.5 * full.segment.coverage[key]
    for got, want in zip(local, exact.segments, strict=True):
        assert got.segment.coverage[key] == pytest.approx(want.coverage[key], abs=0.05)
    save_maps(local, tmp_path, "two segments")
    maps = np.load(tmp_path / "coverage_map.npz")
    seen, expected = maps["segment1_seen"], maps["segment1_expected"]
    area = local[1].result.cells.area
    assert area[seen & expected].sum() / area[expected].sum() == pytest.approx(
        local[1].segment.coverage[key])
    assert (tmp_path / "coverage_map.png").stat().st_size > 0
    # Too little motion for a lumen: the segment gets no value and the reason, not a crash.
    still = np.repeat(mm[:1], 90, 0)
    stuck = local_segment_coverage([d * 10 for d in depth], camera.K, still, 45, 20, None,
                                   config, GeometricConfig())
    assert all(s.segment.coverage[key] is None and "too short" in s.error for s in stuck)


def test_the_reconstructed_tube_reaches_the_farthest_look_ahead_band():
    """A 1-cm colon whose wall ends 0.5 cm past the deepest camera, in cm: the metric lumen
    goes on at least LOOK_AHEAD_CM (6 cm) beyond that camera (3.5 first radii, 3.6 cm, before
    reconstruct asked for it)."""
    from hybrid.reconstruction import LOOK_AHEAD_CM, ReconstructionConfig, reconstruct

    camera = Camera(64, 48, 30.0, 30.0, 31.5, 23.5)
    poses = np.repeat(np.eye(4)[None], 90, 0)
    poses[:, 2, 3] = np.linspace(8.0, 2.0, 90)  # looking along +z, so a pixel's z is z + depth
    depth = [np.where(p[2, 3] + d > 8.5, 0.0, d).astype(np.float32)
             for p in poses for d in [cylinder_depth(camera, p, radius=1.0)]]
    rec = reconstruct(depth, camera.K, poses, config=ReconstructionConfig(voxel_cm=0.05),
                      scale=1.0)
    ell, _ = Lumen(rec.lumen.points).project(rec.poses[:, :3, 3])
    assert LOOK_AHEAD_CM == 6.0
    assert rec.lumen.arclength[-1] >= ell.max() + LOOK_AHEAD_CM


def test_one_segment_failing_in_a_library_leaves_the_others_theirs(monkeypatch):
    """A window whose fit raises an error of a library (not an InputError) gets no value and
    that error as its reason; the other segments are computed (the whole branch failed)."""
    from hybrid import segment_geometry
    from hybrid.reconstruction import ReconstructionConfig

    camera = Camera(64, 48, 30.0, 30.0, 31.5, 23.5)
    poses = np.repeat(np.eye(4)[None], 90, 0)
    poses[:, 2, 3] = np.linspace(8.0, 2.0, 90)
    depth = [cylinder_depth(camera, p) for p in poses]
    reconstruct = segment_geometry.reconstruct

    def failing_second(*args, name: str, **kwargs):
        if name.endswith("segment 1"):
            raise np.linalg.LinAlgError("SVD did not converge")
        return reconstruct(*args, name=name, **kwargs)

    monkeypatch.setattr(segment_geometry, "reconstruct", failing_second)
    config = ReconstructionConfig(typical_radius_cm=RADIUS, voxel_cm=0.05)
    local = segment_geometry.local_segment_coverage(depth, camera.K, poses, 45, 20, None,
                                                    config, GeometricConfig())
    assert local[0].error is None and local[0].segment.coverage[pair_key((1.0, 4.0))] > 0.3
    assert local[1].result is None and local[1].segment.coverage[pair_key((1.0, 4.0))] is None
    assert local[1].error == "LinAlgError: SVD did not converge"


def test_a_bad_depth_frame_is_named_by_its_number_in_the_video():
    """Windows of frames 0-64 and 25-89 fuse every 2nd frame from their first: frame 62 is
    the 32nd fused by the first, frame 61 the 19th by the second, and each reason names the
    frame by its number in the video."""
    from hybrid.reconstruction import ReconstructionConfig
    from hybrid.segment_geometry import local_segment_coverage

    camera = Camera(64, 48, 30.0, 30.0, 31.5, 23.5)
    poses = np.repeat(np.eye(4)[None], 90, 0)
    poses[:, 2, 3] = np.linspace(8.0, 2.0, 90)
    depth = [cylinder_depth(camera, p) for p in poses]
    depth[61] = depth[62] = np.full_like(depth[61], np.nan)
    config = ReconstructionConfig(typical_radius_cm=RADIUS, voxel_cm=0.05)
    local = local_segment_coverage(depth, camera.K, poses, 45, 20, None, config,
                                   GeometricConfig(), name="clip")
    assert [s.error.split(":")[0] for s in local] == ["clip segment 0 frame 62",
                                                      "clip segment 1 frame 61"]
    assert all("depth has NaN" in s.error for s in local)
    # Frame 50: fused by the first window only; the second segment's coverage (frames 45-89)
    # reads it as its 6th frame.
    depth = [cylinder_depth(camera, p) for p in poses]
    depth[50] = np.full_like(depth[50], np.nan)
    local = local_segment_coverage(depth, camera.K, poses, 45, 20, None, config,
                                   GeometricConfig(), name="clip")
    assert [s.error.split(":")[0] for s in local] == ["clip segment 0 frame 50",
                                                      "clip segment 1 frame 50"]


def test_maps_of_a_segment_with_an_empty_v(tmp_path, monkeypatch):
    """A segment with a result but no coverage (its V empty) is drawn with 'n/a', and its
    cells are saved as they are."""
    from matplotlib.figure import Figure

    from hybrid.segment_geometry import LocalSegment, save_maps

    result = geometric_coverage(AXIS, FORWARD[None], [cylinder_depth(FORWARD_CAMERA, FORWARD)],
                                FORWARD_CAMERA.K, config=FINE)
    empty = {k: None for k in result.segments[0].coverage}
    drawn = []
    savefig = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: (drawn.append(fig),
                                                                 savefig(fig, *a, **k)))
    save_maps([LocalSegment(replace(result.segments[0], coverage=empty), result)], tmp_path,
              "empty V")
    (figure,) = drawn
    assert [ax.get_title() for ax in figure.axes if ax.axison] == ["0: n/a"]
    assert (tmp_path / "coverage_map.png").stat().st_size > 0
    with np.load(tmp_path / "coverage_map.npz") as saved:
        np.testing.assert_array_equal(saved["segment0_seen"], result.first_seen >= 0)
        np.testing.assert_array_equal(saved["segment0_expected"], result.expected)


def test_the_scale_fit_of_a_long_video_back_projects_a_bounded_number_of_frames(monkeypatch):
    """Every cloud_stride-th frame of a short video; at most SAMPLED_FRAMES of a long one (its
    memory would grow with the video's length)."""
    from hybrid import reconstruction
    from hybrid.types import SAMPLED_FRAMES

    strides = []

    def recorded(depth, K, poses, frame_stride, pixel_stride):
        strides.append(frame_stride)
        raise InputError("stop here")

    monkeypatch.setattr(reconstruction, "back_project", recorded)
    for frames in (1000, 60_000):
        poses = np.repeat(np.eye(4)[None], frames, axis=0)
        with pytest.raises(InputError, match="stop here"):
            reconstruction.reconstruct([np.ones((4, 5), np.float32)] * frames, np.eye(3), poses)
    assert strides == [10, 60_000 // SAMPLED_FRAMES]
