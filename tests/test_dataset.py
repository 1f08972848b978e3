"""Dataset format (hybrid.dataset): the loader reads back exactly what the simulator made."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from hybrid.coverage import Lumen, compute_coverage
from hybrid.dataset import DEPTH_UNIT_CM, Procedure, list_procedures, read_depth, write_depth
from hybrid.sim.simulate import draw_scene, octagon_region
from hybrid.types import InputError


@pytest.fixture(scope="module")
def regenerated(sim_config):
    """The simulator's in-memory colon, camera, poses and renderer for seed 7, index 0, drawn
    in the same order as simulate_procedure."""
    scene = draw_scene(sim_config, 7, 0)
    return scene.colon, scene.camera, scene.poses, scene.renderer, scene.rng


def test_loader_round_trip(simulated, regenerated):
    colon, camera, poses, renderer, rng = regenerated
    proc = Procedure.open(simulated)
    assert proc.num_frames == len(poses) == 40
    assert proc.camera == camera
    np.testing.assert_array_equal(proc.poses, poses)
    np.testing.assert_array_equal(proc.lumen, colon.centerline)
    mesh = proc.mesh()
    # colon.ply stores float32 coordinates (trimesh's PLY writer); coverage.json is computed
    # from the file, so it is these coordinates that count.
    np.testing.assert_array_equal(mesh.vertices, colon.vertices.astype(np.float32))
    np.testing.assert_array_equal(mesh.triangles, colon.triangles)

    # Frame 0 is rendered with the generator as it stands after the texture: same image.
    rgb0, _ = renderer.render(poses[0], rng)
    loaded = proc.rgb(0)
    assert loaded.dtype == np.uint8 and loaded.shape == (camera.height, camera.width, 3)
    np.testing.assert_array_equal(loaded, rgb0)

    # Depth does not depend on the generator. Stored in steps of DEPTH_UNIT_CM, rounded:
    # off by at most half a step (plus float32 rounding of values up to ~30 cm, < 1e-5 cm).
    for i in (0, 17, 39):
        _, depth = renderer.render(poses[i], np.random.default_rng(0))
        got = proc.depth(i)
        assert got.dtype == np.float32 and got.shape == (camera.height, camera.width)
        assert (depth > 0).mean() > 0.5  # the comparison covers most of the image
        np.testing.assert_array_equal(got == 0, depth == 0)
        assert np.abs(got - depth).max() <= DEPTH_UNIT_CM / 2 + 1e-5


def test_stored_coverage_equals_recomputed(simulated, sim_config):
    proc = Procedure.open(simulated)
    recomputed = compute_coverage(proc.mesh(), Lumen(proc.lumen), proc.poses, proc.camera,
                                  segment_frames=sim_config.segment_frames)
    stored = proc.coverage
    assert stored.to_json() == recomputed.to_json()
    assert len(stored.segments) == 2
    labels = stored.segment_labels()
    assert labels.shape == (2,) and np.all((labels >= 0) & (labels <= 1))
    assert stored.default_pair == (1.0, 4.0)


def test_list_procedures(simulated, tmp_path):
    found = list_procedures(simulated.parent)
    assert [p.path for p in found] == [simulated]
    with pytest.raises(InputError, match="no simulated procedures"):
        list_procedures(tmp_path)


def test_open_names_the_missing_file(simulated, tmp_path):
    copy = tmp_path / "proc"
    shutil.copytree(simulated, copy)
    (copy / "lumen.npy").unlink()
    with pytest.raises(InputError, match="lumen.npy"):
        Procedure.open(copy)
    with pytest.raises(InputError, match="not found"):
        Procedure.open(tmp_path / "nothing")


@pytest.mark.parametrize("name, read", [
    ("poses.npy", lambda p: p.poses), ("lumen.npy", lambda p: p.lumen),
    ("coverage.json", lambda p: p.coverage), ("meta.json", lambda p: p.style)])
def test_a_damaged_file_of_a_procedure_is_named(simulated, tmp_path, name, read):
    """It was a traceback from NumPy or json."""
    copy = tmp_path / "proc"
    shutil.copytree(simulated, copy)
    (copy / name).write_bytes(b"\x00 not what it should be")
    with pytest.raises(InputError, match=f"{name} cannot be read .*simulate the procedure again"):
        read(Procedure.open(copy))


def test_a_region_that_would_crop_the_frames_or_is_damaged_is_refused(simulated, tmp_path):
    """region.png must be the camera's size and reach every image edge (the frames are then
    not cropped, so camera.json stays their camera); without it, the whole image."""
    import cv2

    copy = tmp_path / "proc"
    shutil.copytree(simulated, copy)
    camera = Procedure.open(copy).camera
    assert Procedure.open(copy).region.all()
    y, x = np.mgrid[:camera.height, :camera.width]
    disc = np.hypot(x - camera.width / 2, y - camera.height / 2) < camera.height / 3
    for mask, words in ((disc, "must reach every edge of the image"),
                        (np.ones((camera.height, camera.width - 1), bool), "camera's size")):
        cv2.imwrite(str(copy / "region.png"), mask.astype(np.uint8) * 255)
        with pytest.raises(InputError, match=words):
            _ = Procedure.open(copy).region
    (copy / "region.png").write_bytes(b"not an image")
    with pytest.raises(InputError, match="cannot read region image"):
        _ = Procedure.open(copy).region
    octagon = octagon_region(camera.height, camera.width, 20)
    cv2.imwrite(str(copy / "region.png"), octagon.astype(np.uint8) * 255)
    np.testing.assert_array_equal(Procedure.open(copy).region, octagon)
    assert list_procedures(tmp_path) == [Procedure(copy)]
    with pytest.raises(InputError, match="proc have an image region; this tool reads whole"):
        list_procedures(tmp_path, whole_images=True)


def test_a_procedure_still_being_simulated_is_no_training_input(simulated, tmp_path):
    """A killed `simulate` leaves proc_NNNN.partial, camera.json and rgb/ in it."""
    from learned.train import expand_inputs

    shutil.copytree(simulated, tmp_path / "proc_0000")
    shutil.copytree(simulated, tmp_path / "proc_0001.partial")
    assert expand_inputs([tmp_path]) == [tmp_path / "proc_0000"]


def test_depth_png_quantisation(tmp_path):
    depth = np.array([[0.0, 0.001, 0.0031, 12.345678], [65535 * DEPTH_UNIT_CM, 200.0, 1.0, 0.5]],
                     dtype=np.float32)
    write_depth(tmp_path / "d.png", depth)
    back = read_depth(tmp_path / "d.png")
    # Rounded to the nearest step (0.001 is exactly half a step: numpy rounds half to even,
    # i.e. to 0); beyond the 16-bit range the value saturates.
    expected = np.array([[0.0, 0.0, 0.004, 12.346], [131.07, 131.07, 1.0, 0.5]])
    np.testing.assert_allclose(back, expected, atol=1e-5)
