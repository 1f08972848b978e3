"""Ground-truth coverage (hybrid.coverage) against analytic answers on a hand-made cylinder,
and its monotonicity and fold behaviour on simulated colons."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import Cylinder, in_image, mesh_tolerance, pose, wall_fraction

from hybrid.coverage import (
    DELTA_PAIRS_CM,
    Lumen,
    SurfaceMesh,
    compute_coverage,
    pair_key,
)
from hybrid.sim.colon import ColonConfig, make_colon
from hybrid.sim.trajectory import TrajectoryConfig, make_withdrawal
from hybrid.types import Camera, InputError

# Non-square image, off-centre principal point, fx != fy: the answers are not symmetric.
FORWARD_CAMERA = Camera(64, 48, 30.0, 33.0, 37.3, 21.6)
# A wider lens for the side view, so that a fair part of the band is in the image.
SIDE_CAMERA = Camera(64, 48, 14.0, 15.0, 30.1, 21.6)
# On the 0.02 + 0.04 k grid (see the cylinder fixture): band edges fall between rings.
ELL = 2.02

IDENTITY = ((1, 0, 0), (0, 1, 0), (0, 0, 1))
FORWARD = pose(IDENTITY, (0.0, 0.0, ELL))
FORWARD_OFF_AXIS = pose(IDENTITY, (0.6, -0.4, ELL))
# Camera z along world +x (towards the wall), y (down) along +z (deeper), x = y × z.
SIDE = pose(((0, 1, 0), (0, 0, 1), (1, 0, 0)), (0.0, 0.0, ELL))
# Looking towards the rectum: z along -z.
BACKWARD = pose(((-1, 0, 0), (0, 1, 0), (0, 0, -1)), (0.0, 0.0, ELL))

# (name, camera, pose, n_arcs): n_arcs bounds the number of separate visible arcs of one ring.
# Forward: the ring's image is a closed convex curve; it meets each of the 4 image sides at
# most twice, so at most 4 arcs lie inside. Side: the u and v limits each cut one θ interval
# (within cos θ > 0), their intersection is one arc.
VIEWS = [
    ("forward", FORWARD_CAMERA, FORWARD, 4),
    ("forward_off_axis", FORWARD_CAMERA, FORWARD_OFF_AXIS, 4),
    ("side", SIDE_CAMERA, SIDE, 1),
]


@pytest.fixture(scope="module")
def mesh(cylinder: Cylinder) -> SurfaceMesh:
    return SurfaceMesh.from_arrays(cylinder.vertices, cylinder.triangles)


@pytest.fixture(scope="module")
def lumen(cylinder: Cylinder) -> Lumen:
    return Lumen(cylinder.lumen)


@pytest.mark.parametrize("name,camera,view,n_arcs", VIEWS, ids=[v[0] for v in VIEWS])
def test_single_frame_matches_field_of_view_integral(cylinder, mesh, lumen, name, camera, view,
                                                     n_arcs):
    result = compute_coverage(mesh, lumen, view[None], camera, segment_frames=1)
    for d0, d1 in DELTA_PAIRS_CM:
        expected = wall_fraction(camera, [view], cylinder.radius, ELL + d0, ELL + d1, n_arcs)
        got = result.per_frame[pair_key((d0, d1))][0]
        tol = mesh_tolerance(cylinder, d1 - d0, expected.total_variation, n_arcs) \
            + expected.grid_error
        assert 0.0 < expected.value < 1.0, "the test geometry should give a partial view"
        assert got == pytest.approx(expected.value, abs=tol), (name, d0, d1)
        # With one frame, the segment is that frame.
        assert result.segments[0].coverage[pair_key((d0, d1))] == got


@pytest.mark.parametrize("name,camera,view,n_arcs", VIEWS, ids=[v[0] for v in VIEWS])
def test_single_frame_equals_vertex_count(cylinder, mesh, lumen, name, camera, view, n_arcs):
    """Exact discrete answer: the convex tube never occludes itself seen from inside, and all
    vertices of a band have the same area (none lies on the open ends), so coverage is the
    fraction of band vertices that project inside the image extent. (Areas are equal up to the
    float32 rounding of the coordinates, < 1e-6 relative: hence the 1e-6 tolerance.)"""
    result = compute_coverage(mesh, lumen, view[None], camera, segment_frames=1)
    z = cylinder.ring_z
    inside = in_image(camera, view, cylinder.vertices)
    for d0, d1 in DELTA_PAIRS_CM:
        band = (z >= ELL + d0) & (z <= ELL + d1)
        assert band.sum() == round((d1 - d0) / cylinder.spacing) * cylinder.segments
        expected = inside[band].mean()
        assert result.per_frame[pair_key((d0, d1))][0] == pytest.approx(expected, abs=1e-6)


def test_only_the_image_region_sees(cylinder, mesh, lumen):
    """With the left half of the image as its region the camera sees exactly the band vertices
    that project into a pixel column left of the middle (u < W/2 - 0.5); the whole image as the
    region is no region; a region of another size is refused."""
    camera, view = FORWARD_CAMERA, FORWARD_OFF_AXIS
    left = np.zeros((camera.height, camera.width), dtype=bool)
    left[:, :camera.width // 2] = True
    result = compute_coverage(mesh, lumen, view[None], camera, segment_frames=1, region=left)
    whole = compute_coverage(mesh, lumen, view[None], camera, segment_frames=1,
                             region=np.ones_like(left))
    plain = compute_coverage(mesh, lumen, view[None], camera, segment_frames=1)
    xc = (cylinder.vertices - view[:3, 3]) @ view[:3, :3]
    u = camera.fx * xc[:, 0] / np.where(xc[:, 2] > 0, xc[:, 2], 1.0) + camera.cx
    seen = in_image(camera, view, cylinder.vertices) & (u < camera.width / 2 - 0.5)
    z = cylinder.ring_z
    for d0, d1 in DELTA_PAIRS_CM:
        key = pair_key((d0, d1))
        expected = seen[(z >= ELL + d0) & (z <= ELL + d1)].mean()
        assert 0 < expected < plain.per_frame[key][0]
        assert result.per_frame[key][0] == pytest.approx(expected, abs=1e-6)
        assert whole.per_frame[key] == plain.per_frame[key]
    with pytest.raises(InputError, match="bool mask of the camera's size"):
        compute_coverage(mesh, lumen, view[None], camera, region=left[:, 1:])


def test_looking_backwards_sees_nothing_of_the_band(mesh, lumen):
    result = compute_coverage(mesh, lumen, BACKWARD[None], FORWARD_CAMERA, segment_frames=1)
    for pair in DELTA_PAIRS_CM:
        assert result.per_frame[pair_key(pair)] == [0.0]
        assert result.segments[0].coverage[pair_key(pair)] == 0.0


def test_segment_is_union_over_its_frames(cylinder, mesh, lumen):
    """Two frames: forward at ℓ = 2.02 and a side view at ℓ = 2.42 (also on the grid).
    V spans [ℓmin + Δ0, ℓmax + Δ1] and A is the union of what either frame sees."""
    side = SIDE.copy()
    side[2, 3] = ELL + 0.4
    views = [FORWARD, side]
    camera = FORWARD_CAMERA
    result = compute_coverage(mesh, lumen, np.stack(views), camera, segment_frames=2)
    (segment,) = result.segments
    assert segment.ell_min == pytest.approx(ELL, abs=1e-9)
    assert segment.ell_max == pytest.approx(ELL + 0.4, abs=1e-9)
    for d0, d1 in DELTA_PAIRS_CM:
        # Up to 4 arcs from the forward frame plus 1 from the side frame.
        expected = wall_fraction(camera, views, cylinder.radius, ELL + d0, ELL + 0.4 + d1, 5)
        tol = mesh_tolerance(cylinder, d1 - d0 + 0.4, expected.total_variation, 5) \
            + expected.grid_error
        assert segment.coverage[pair_key((d0, d1))] == pytest.approx(expected.value, abs=tol)
        # And the per-frame values use each frame's own band.
        alone = wall_fraction(camera, [side], cylinder.radius, ELL + 0.4 + d0, ELL + 0.4 + d1, 1)
        tol = mesh_tolerance(cylinder, d1 - d0, alone.total_variation, 1) + alone.grid_error
        assert result.per_frame[pair_key((d0, d1))][1] == pytest.approx(alone.value, abs=tol)


def test_band_beyond_the_lumen_is_undefined(cylinder, mesh, lumen):
    """A camera 0.5 cm from the end: every band starts beyond ℓ = L, so V is empty -> None."""
    near_end = pose(IDENTITY, (0.0, 0.0, cylinder.length - 0.5))
    result = compute_coverage(mesh, lumen, near_end[None], FORWARD_CAMERA, segment_frames=1)
    for pair in DELTA_PAIRS_CM:
        assert result.per_frame[pair_key(pair)] == [None]
        assert np.isnan(result.segment_labels(pair)).all()


def test_frames_after_last_full_segment_get_per_frame_values_only(mesh, lumen):
    poses = np.stack([FORWARD, FORWARD_OFF_AXIS, BACKWARD])
    result = compute_coverage(mesh, lumen, poses, FORWARD_CAMERA, segment_frames=2)
    assert [(s.start, s.stop) for s in result.segments] == [(0, 2)]
    for pair in DELTA_PAIRS_CM:
        assert len(result.per_frame[pair_key(pair)]) == 3
        assert result.per_frame[pair_key(pair)][2] == 0.0


def test_vertex_order_does_not_matter(cylinder, lumen):
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(cylinder.vertices))
    inverse = np.argsort(perm)
    shuffled = SurfaceMesh.from_arrays(cylinder.vertices[perm], inverse[cylinder.triangles])
    plain = SurfaceMesh.from_arrays(cylinder.vertices, cylinder.triangles)
    poses = np.stack([FORWARD, FORWARD_OFF_AXIS])
    a = compute_coverage(plain, lumen, poses, FORWARD_CAMERA, segment_frames=2)
    b = compute_coverage(shuffled, lumen, poses, FORWARD_CAMERA, segment_frames=2)
    for pair in DELTA_PAIRS_CM:
        key = pair_key(pair)
        assert b.per_frame[key] == pytest.approx(a.per_frame[key], abs=1e-12)
        assert b.segments[0].coverage[key] == pytest.approx(a.segments[0].coverage[key],
                                                            abs=1e-12)


def test_mesh_vertex_areas_sum_to_surface_area(cylinder, mesh):
    """Each vertex carries a third of its triangles' area: the total is the polygonal tube's
    lateral area, 2·S·R·sin(π/S)·L (to the float32 rounding of the coordinates, 1e-6)."""
    S, R, L = cylinder.segments, cylinder.radius, cylinder.length
    assert mesh.vertex_area.sum() == pytest.approx(2 * S * R * np.sin(np.pi / S) * L, rel=1e-6)


def test_camera_outside_the_mesh_is_rejected(mesh, lumen):
    outside = pose(IDENTITY, (10.0, 0.0, ELL))
    with pytest.raises(InputError, match="outside the mesh"):
        compute_coverage(mesh, lumen, np.stack([FORWARD, outside]), FORWARD_CAMERA)


# --- simulated colons: monotonicity and folds --------------------------------------------

CAMERA_90 = Camera(80, 64, 40.0, 40.0, 39.5, 31.5)
"""A 90° horizontal field of view, centred."""


@pytest.fixture(scope="module")
def folded_colon_and_poses():
    """A 20 cm folded colon and a 60-frame simulated withdrawal (which keeps its clearance
    from the fold tips)."""
    colon = make_colon(ColonConfig(length_cm=20.0, folds=True), np.random.default_rng(3))
    poses = make_withdrawal(colon, TrajectoryConfig(max_frames=60), np.random.default_rng(4))
    return colon, poses


def centerline_poses(colon, ell_from: float, ell_to: float, n: int) -> np.ndarray:
    """n cameras on the centerline from ell_from to ell_to, looking along the lumen towards
    the cecum (camera z = tangent, y = the lumen's normal)."""
    ring = np.round(np.interp(np.linspace(ell_from, ell_to, n), colon.arclength,
                              np.arange(len(colon.arclength)))).astype(int)
    frames = colon.frames[ring]
    z, y = frames[:, :, 0], frames[:, :, 1]
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = np.stack([np.cross(y, z), y, z], axis=2)
    poses[:, :3, 3] = colon.centerline[ring]
    return poses


def _surface(colon):
    return SurfaceMesh.from_arrays(colon.vertices, colon.triangles)


def _turned(poses: np.ndarray, angle_deg: float) -> np.ndarray:
    """Same positions, camera turned by angle_deg about its own y axis."""
    a = np.radians(angle_deg)
    turn = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    out = poses.copy()
    out[:, :3, :3] = poses[:, :3, :3] @ turn
    return out


def test_adding_frames_never_lowers_segment_coverage(folded_colon_and_poses):
    colon, poses = folded_colon_and_poses
    mesh, lumen = _surface(colon), Lumen(colon.centerline)
    camera = CAMERA_90
    n = len(poses)
    # The extra frames repeat the positions, so ℓmin/ℓmax (and V) stay the same. They come
    # last: a segment that kept only its last frames' view would lose coverage.
    extra = _turned(poses, 70.0)
    base = compute_coverage(mesh, lumen, poses, camera, segment_frames=n).segments[0]
    alone = compute_coverage(mesh, lumen, extra, camera, segment_frames=n).segments[0]
    both = compute_coverage(mesh, lumen, np.concatenate([poses, extra]), camera,
                            segment_frames=2 * n).segments[0]
    # Every second frame plus the last keeps the same ℓ range, with fewer frames.
    sub_idx = np.unique(np.r_[np.arange(0, n, 2), n - 1])
    sub = compute_coverage(mesh, lumen, poses[sub_idx], camera,
                           segment_frames=len(sub_idx)).segments[0]
    for s in (alone, both, sub):
        assert (s.ell_min, s.ell_max) == (base.ell_min, base.ell_max)
    for pair in DELTA_PAIRS_CM:
        key = pair_key(pair)
        values = [base.coverage[key], alone.coverage[key], both.coverage[key], sub.coverage[key]]
        assert all(0.0 <= v <= 1.0 for v in values)
        # The inequalities below are exact set inclusions; 1e-12 only absorbs the rounding of
        # area sums of ~1e4 vertices taken over different masks.
        assert sub.coverage[key] <= base.coverage[key] + 1e-12
        # Same V, A(both) = A(base) ∪ A(alone): max <= union <= sum.
        assert both.coverage[key] >= max(base.coverage[key], alone.coverage[key]) - 1e-12
        assert both.coverage[key] <= base.coverage[key] + alone.coverage[key] + 1e-12
        # The turned views do add wall the forward views missed.
        assert both.coverage[key] > base.coverage[key]


@pytest.mark.parametrize("stride, starts", [(7, [0, 7, 14, 21, 28, 35]), (25, [0, 25])])
def test_overlapping_windows_equal_each_window_alone(folded_colon_and_poses, stride, starts):
    """A window of a run of windows every `stride` frames covers what its own frames saw, no
    more (none of the earlier frames) and no less: the same as the window given alone."""
    colon, poses = folded_colon_and_poses
    mesh, lumen = _surface(colon), Lumen(colon.centerline)
    # turned views in the second half, so that the windows differ
    poses = np.concatenate([poses[:30], _turned(poses[30:], 60.0)])
    run = compute_coverage(mesh, lumen, poses, CAMERA_90, segment_frames=20,
                           segment_stride=stride)
    assert [s.start for s in run.segments] == starts
    key = pair_key(DELTA_PAIRS_CM[0])
    for segment in run.segments:
        (alone,) = compute_coverage(mesh, lumen, poses[segment.start:segment.stop], CAMERA_90,
                                    segment_frames=20).segments
        assert segment.coverage == alone.coverage
    assert len({s.coverage[key] for s in run.segments}) == len(starts)


def test_windows_hold_the_back_to_back_segments_exactly(folded_colon_and_poses):
    """One pass with overlapping windows gives, bit for bit, the per-frame values and the
    back-to-back segments of a pass without them (the simulator labels both in one pass),
    and its window table lists every window's start and default-pair coverage."""
    colon, poses = folded_colon_and_poses
    mesh, lumen = _surface(colon), Lumen(colon.centerline)
    plain = compute_coverage(mesh, lumen, poses, CAMERA_90, segment_frames=20)
    windows = compute_coverage(mesh, lumen, poses, CAMERA_90, segment_frames=20,
                               segment_stride=5)
    assert len(windows.segments) == 9 and len(plain.segments) == 3
    assert windows.back_to_back().to_json() == plain.to_json()
    table = windows.window_table()
    assert table.shape == (9, 2)
    np.testing.assert_array_equal(table[:, 0], np.arange(0, 41, 5))
    np.testing.assert_array_equal(table[:, 1], windows.segment_labels())
    assert len(set(table[:, 1])) > 3  # the windows between the segments are their own


def test_all_per_frame_values_in_unit_interval(folded_colon_and_poses):
    colon, poses = folded_colon_and_poses
    result = compute_coverage(_surface(colon), Lumen(colon.centerline), poses,
                              CAMERA_90, segment_frames=20)
    assert len(result.segments) == 3
    for values in result.per_frame.values():
        assert len(values) == len(poses)
        assert all(v is not None and 0.0 <= v <= 1.0 for v in values)


@pytest.mark.parametrize("seed", [5, 11])
def test_folds_lower_coverage(seed):
    """Folds hide the wall behind them. Not a theorem for every colon (folds also move the
    wall), so checked on fixed seeds for the camera moving on the centerline."""
    folded = make_colon(ColonConfig(length_cm=20.0, folds=True), np.random.default_rng(seed))
    plain = make_colon(ColonConfig(length_cm=20.0, folds=False), np.random.default_rng(seed))
    # Folds are drawn after the centerline and radius: the two colons share them.
    np.testing.assert_array_equal(folded.centerline, plain.centerline)
    np.testing.assert_array_equal(folded.radius, plain.radius)
    assert folded.fold_depth.max() > 0 and not plain.fold_depth.any()
    # On the centerline the cameras are inside both colons (fold tips leave >= 0.5 cm free:
    # radius >= 1.5 cm, fold height <= 1 cm); compute_coverage checks it.
    poses = centerline_poses(folded, 12.0, 10.0, 30)
    results = [compute_coverage(_surface(c), Lumen(c.centerline), poses, CAMERA_90,
                                segment_frames=len(poses)).segments[0] for c in (folded, plain)]
    for pair in DELTA_PAIRS_CM:
        key = pair_key(pair)
        assert results[0].coverage[key] < results[1].coverage[key], key
