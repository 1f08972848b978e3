"""The `c2d2` command line (hybrid.cli): coverage of external meshes, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from conftest import make_cylinder, mesh_tolerance, pose, unboxed, wall_fraction
from typer.testing import CliRunner

from hybrid.cli import app
from hybrid.coverage import DELTA_PAIRS_CM, Lumen, SurfaceMesh, compute_coverage, pair_key
from hybrid.types import Camera

runner = CliRunner()

CAMERA = Camera(64, 48, 30.0, 33.0, 37.3, 21.6)
ELL = 2.02  # on the cylinder fixture's 0.02 + 0.04 k grid: band edges fall between rings
IDENTITY = ((1, 0, 0), (0, 1, 0), (0, 0, 1))
VIEWS = [pose(IDENTITY, (0.0, 0.0, ELL)), pose(IDENTITY, (0.6, -0.4, ELL)),
         pose(((-1, 0, 0), (0, 1, 0), (0, 0, -1)), (0.0, 0.0, ELL))]
"""Forward on the axis, forward off the axis, backward (towards the rectum)."""


def run_coverage(mesh: Path, lumen: Path, poses: Path, camera: Path, *extra: str):
    return runner.invoke(app, ["coverage", "--mesh", str(mesh), "--lumen", str(lumen),
                               "--poses", str(poses), "--camera", str(camera), *extra])


def write_inputs(folder: Path, vertices, triangles, lumen, poses, camera: Camera,
                 mesh_name: str = "wall.ply") -> dict[str, Path]:
    """Write the four inputs under distinctive names; return their paths by option name."""
    paths = {"mesh": folder / mesh_name, "lumen": folder / "centre_line.npy",
             "poses": folder / "trajectory.npy", "camera": folder / "intrinsics.json"}
    trimesh.Trimesh(vertices, triangles, process=False).export(paths["mesh"])
    np.save(paths["lumen"], np.asarray(lumen))
    np.save(paths["poses"], np.asarray(poses))
    camera.save(paths["camera"])
    return paths


def test_cli_coverage_of_an_external_mesh(tmp_path, cylinder):
    """The cylinder written as a PLY with its vertices shuffled: the CLI's JSON equals the
    in-process result and the analytic field-of-view integral."""
    perm = np.random.default_rng(1).permutation(len(cylinder.vertices))
    inverse = np.argsort(perm)
    paths = write_inputs(tmp_path, cylinder.vertices[perm], inverse[cylinder.triangles],
                         cylinder.lumen, np.stack(VIEWS), CAMERA)
    result = run_coverage(*paths.values(), "--segment-frames", "3")
    assert result.exit_code == 0, result.output
    got = json.loads(result.stdout)

    in_process = compute_coverage(SurfaceMesh.from_arrays(cylinder.vertices, cylinder.triangles),
                                  Lumen(cylinder.lumen), np.stack(VIEWS), CAMERA,
                                  segment_frames=3).to_json()
    assert got["segment_frames"] == 3 and len(got["segments"]) == 1
    for pair in DELTA_PAIRS_CM:
        key = pair_key(pair)
        # PLY stores float32: the fixture's coordinates are float32 already, so only the
        # summation order (vertices shuffled) differs.
        assert got["per_frame"][key] == pytest.approx(in_process["per_frame"][key], abs=1e-12)
        assert got["segments"][0]["coverage"][key] == pytest.approx(
            in_process["segments"][0]["coverage"][key], abs=1e-12)

        d0, d1 = pair
        for frame, view in enumerate(VIEWS[:2]):
            # Forward views: at most 4 visible arcs per ring (see test_coverage.VIEWS).
            expected = wall_fraction(CAMERA, [view], cylinder.radius, ELL + d0, ELL + d1, 4)
            tol = mesh_tolerance(cylinder, d1 - d0, expected.total_variation, 4) \
                + expected.grid_error
            assert got["per_frame"][key][frame] == pytest.approx(expected.value, abs=tol)
        assert got["per_frame"][key][2] == 0.0
        union = wall_fraction(CAMERA, VIEWS, cylinder.radius, ELL + d0, ELL + d1, 8)
        tol = mesh_tolerance(cylinder, d1 - d0, union.total_variation, 8) + union.grid_error
        assert got["segments"][0]["coverage"][key] == pytest.approx(union.value, abs=tol)


def test_cli_reproduces_simulated_ground_truth(tmp_path, simulated):
    stored = json.loads((simulated / "coverage.json").read_text())
    out = tmp_path / "again.json"
    result = run_coverage(simulated / "colon.ply", simulated / "lumen.npy",
                          simulated / "poses.npy", simulated / "camera.json",
                          "--segment-frames", str(stored["segment_frames"]), "--out", str(out))
    assert result.exit_code == 0, result.output
    assert json.loads(out.read_text()) == stored
    # And the same on stdout.
    result = run_coverage(simulated / "colon.ply", simulated / "lumen.npy",
                          simulated / "poses.npy", simulated / "camera.json",
                          "--segment-frames", str(stored["segment_frames"]))
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout) == stored


def test_cli_coverage_within_an_image_region(tmp_path, cylinder):
    """--region: the left half of the image as a PNG gives the in-process coverage with that
    region (less than without); a missing or wrongly sized region image is named."""
    import cv2

    paths = write_inputs(tmp_path, cylinder.vertices, cylinder.triangles, cylinder.lumen,
                         np.stack(VIEWS), CAMERA)
    left = np.zeros((CAMERA.height, CAMERA.width), dtype=bool)
    left[:, :CAMERA.width // 2] = True
    cv2.imwrite(str(tmp_path / "left.png"), left.astype(np.uint8) * 255)
    result = run_coverage(*paths.values(), "--segment-frames", "3", "--region",
                          str(tmp_path / "left.png"))
    assert result.exit_code == 0, result.output
    mesh = SurfaceMesh.from_arrays(cylinder.vertices, cylinder.triangles)
    within = compute_coverage(mesh, Lumen(cylinder.lumen), np.stack(VIEWS), CAMERA,
                              segment_frames=3, region=left).to_json()
    whole = compute_coverage(mesh, Lumen(cylinder.lumen), np.stack(VIEWS), CAMERA,
                             segment_frames=3).to_json()
    for pair in DELTA_PAIRS_CM:
        key = pair_key(pair)
        got = json.loads(result.stdout)["per_frame"][key]
        assert got == pytest.approx(within["per_frame"][key], abs=1e-12)
        assert got[0] < whole["per_frame"][key][0]
    missing = run_coverage(*paths.values(), "--region", str(tmp_path / "absent.png"))
    assert_fails_naming(missing, tmp_path, "absent.png")
    cv2.imwrite(str(tmp_path / "small.png"), left[1:].astype(np.uint8) * 255)
    message = assert_fails_naming(run_coverage(*paths.values(), "--region",
                                               str(tmp_path / "small.png")), tmp_path, "region")
    assert "bool mask of the camera's size (48, 64)" in unboxed(message)


# --- bad input -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_tube():
    """A coarse tube: bad-input checks need no accuracy."""
    return make_cylinder(radius=2.0, length=10.0, spacing=0.1, segments=64)


@pytest.fixture
def inputs(tmp_path, small_tube) -> dict[str, Path]:
    return write_inputs(tmp_path, small_tube.vertices, small_tube.triangles, small_tube.lumen,
                        np.stack(VIEWS), CAMERA)


def test_valid_inputs_pass(inputs):
    """The baseline of the bad-input tests works, so their failures come from the change."""
    result = run_coverage(*inputs.values(), "--segment-frames", "3")
    assert result.exit_code == 0, result.output


def assert_fails_naming(result, folder: Path, *names: str) -> str:
    """Non-zero exit, no traceback, and the message names one of `names`. Returns the message
    with `folder` (whose name holds the test's name) cut out, for checks of its wording."""
    assert result.exit_code != 0
    message = result.stderr
    assert message.startswith("error: "), result.output
    assert "Traceback" not in result.output
    message = message.replace(str(folder), "<folder>")
    assert any(name in message for name in names), message
    return message


@pytest.mark.parametrize("option", ["mesh", "lumen", "poses", "camera"])
def test_missing_file(tmp_path, inputs, option):
    missing = inputs[option].with_name("absent_" + inputs[option].name)
    args = {**inputs, option: missing}
    message = assert_fails_naming(run_coverage(*args.values()), tmp_path, missing.name)
    assert "not found" in message


def test_poses_of_wrong_shape(tmp_path, inputs):
    np.save(inputs["poses"], np.stack(VIEWS)[:, :3, :])
    message = assert_fails_naming(run_coverage(*inputs.values()), tmp_path,
                                  inputs["poses"].name, "poses")
    assert "(N, 4, 4)" in message and "(3, 3, 4)" in message


def test_lumen_of_wrong_shape(tmp_path, inputs, small_tube):
    np.save(inputs["lumen"], small_tube.lumen[:, :2])
    message = assert_fails_naming(run_coverage(*inputs.values()), tmp_path, inputs["lumen"].name)
    assert "(M, 3)" in message


def test_lumen_of_one_point(tmp_path, inputs, small_tube):
    np.save(inputs["lumen"], small_tube.lumen[:1])
    message = assert_fails_naming(run_coverage(*inputs.values()), tmp_path, inputs["lumen"].name)
    assert "at least 2" in message


def _nan_translation(poses):
    poses[1, 0, 3] = np.nan


def _scaled_rotation(poses):
    poses[0, :3, :3] *= 2.0  # a scale is not a camera pose


def _off_axis(poses):
    poses[1, 0, 3] += 10.0  # 10 cm off the axis of a 2 cm tube


def _beyond_open_end(poses):
    poses[2, 2, 3] = -3.0  # on the axis, 3 cm past the open end: no wall surrounds it


@pytest.mark.parametrize("spoil, words", [
    (_nan_translation, ("NaN", "[1]")),
    (_scaled_rotation, ("rigid", "[0]")),
    (_off_axis, ("outside the mesh", "[1]")),
    (_beyond_open_end, ("outside the mesh", "[2]")),
], ids=["nan", "non_rigid", "outside", "beyond_open_end"])
def test_bad_poses(tmp_path, inputs, spoil, words):
    poses = np.stack(VIEWS)
    spoil(poses)
    np.save(inputs["poses"], poses)
    message = assert_fails_naming(run_coverage(*inputs.values()), tmp_path,
                                  inputs["poses"].name, "poses")
    assert all(word in message for word in words), message


@pytest.mark.parametrize("kind", ["point_cloud", "no_faces"])
def test_mesh_without_triangles(tmp_path, inputs, small_tube, kind):
    """A PLY of vertices only: the message must say that triangles are missing (the file does
    have vertices)."""
    if kind == "point_cloud":
        trimesh.PointCloud(small_tube.vertices).export(inputs["mesh"])
    else:
        trimesh.Trimesh(small_tube.vertices, np.zeros((0, 3), dtype=np.int64),
                        process=False).export(inputs["mesh"])
    message = assert_fails_naming(run_coverage(*inputs.values()), tmp_path, inputs["mesh"].name)
    assert "triangle" in message


def test_unreadable_mesh(tmp_path, inputs):
    inputs["mesh"].write_text("not a mesh")
    assert_fails_naming(run_coverage(*inputs.values()), tmp_path, inputs["mesh"].name)


def test_unreadable_npy(tmp_path, inputs):
    inputs["poses"].write_text("not an array")
    assert_fails_naming(run_coverage(*inputs.values()), tmp_path, inputs["poses"].name)


def test_camera_json_missing_a_key(tmp_path, inputs):
    data = json.loads(inputs["camera"].read_text())
    del data["fx"]
    inputs["camera"].write_text(json.dumps(data))
    message = assert_fails_naming(run_coverage(*inputs.values()), tmp_path,
                                  inputs["camera"].name)
    assert "fx" in message


def test_installed_command_exits_non_zero(tmp_path, inputs):
    """The console script itself (not only the Typer app) reports bad input with exit code 2."""
    import subprocess
    import sys

    c2d2 = Path(sys.executable).parent / "c2d2"
    missing = tmp_path / "no_such_mesh.ply"
    done = subprocess.run([str(c2d2), "coverage", "--mesh", str(missing),
                           "--lumen", str(inputs["lumen"]), "--poses", str(inputs["poses"]),
                           "--camera", str(inputs["camera"])], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 2
    assert "no_such_mesh.ply" in done.stderr and "Traceback" not in done.stderr


def test_out_folder_that_does_not_exist(tmp_path, inputs):
    """Checked before the computation, so no work is lost."""
    result = run_coverage(*inputs.values(), "--out", str(tmp_path / "absent" / "c.json"))
    assert "does not exist" in assert_fails_naming(result, tmp_path, "absent")


@pytest.mark.parametrize("length", ["5", "-1", "nan", "inf"])
def test_simulate_a_colon_too_short_to_withdraw(tmp_path, length):
    result = runner.invoke(app, ["simulate", "--out", str(tmp_path), "--length-cm", length])
    assert result.exit_code == 2 and "colon length must be finite and exceed" in result.stderr
    assert not any(tmp_path.iterdir())  # nothing half-written


def test_simulate_refuses_a_negative_first_index(tmp_path):
    result = runner.invoke(app, ["simulate", "--out", str(tmp_path), "--first-index", "-1"])
    assert result.exit_code == 2
    assert "Invalid value for '--first-index'" in unboxed(result.stderr)
    assert not any(tmp_path.iterdir())


def test_simulate_labels_the_coverage_networks_windows(tmp_path):
    """By default the training windows (every 30 of 300 frames) are labelled with the truth,
    not for sparse procedures; a stride that does not divide the segments is refused."""
    common = ["simulate", "--length-cm", "14", "--max-frames", "24"]
    result = runner.invoke(app, [*common, "--out", str(tmp_path / "full")])
    assert result.exit_code == 0, result.output
    (cached,) = (tmp_path / "full" / "proc_0000" / "cache").iterdir()
    assert cached.name == "windows-300-30.npy" and np.load(cached).shape == (0, 2)
    result = runner.invoke(app, [*common, "--out", str(tmp_path / "sparse"), "--frame-step", "4"])
    assert result.exit_code == 0, result.output
    assert not (tmp_path / "sparse" / "proc_0000" / "cache").exists()
    result = runner.invoke(app, [*common, "--out", str(tmp_path / "bad"), "--window-stride", "7"])
    assert result.exit_code == 2 and "window stride must be a positive divisor" in result.stderr
    assert not (tmp_path / "bad").exists()


def test_simulate_fisheye_films_the_same_procedure_through_an_equidistant_lens(tmp_path):
    from hybrid.dataset import Procedure

    common = ["simulate", "--length-cm", "14", "--max-frames", "4", "--window-stride", "0"]
    for name, flags in (("pinhole", []), ("fisheye", ["--fisheye"])):
        result = runner.invoke(app, [*common, *flags, "--out", str(tmp_path / name)])
        assert result.exit_code == 0, result.output
    pinhole, fisheye = (Procedure.open(tmp_path / name / "proc_0000")
                        for name in ("pinhole", "fisheye"))
    assert (pinhole.camera.model, fisheye.camera.model) == ("pinhole", "equidistant")
    assert fisheye.camera.hfov_deg == pytest.approx(pinhole.camera.hfov_deg)
    np.testing.assert_array_equal(fisheye.poses, pinhole.poses)
    assert not np.array_equal(fisheye.rgb(0), pinhole.rgb(0))


def test_demo_prints_the_truth_and_both_branches(tmp_path):
    """`c2d2 demo`, the README's main command, on its shortest video: each printed row holds
    the simulated procedure's true coverage and the run's learned and geometric values, the
    report is written, and a second call resumes the same work without changing a figure."""
    from hybrid.dataset import Procedure

    args = ["demo", "--out", str(tmp_path), "--max-frames", "300", "--length-cm", "20"]
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    truth = Procedure.open(tmp_path / "proc_0000").coverage
    key = pair_key(truth.default_pair)
    table = json.loads((tmp_path / "run" / "coverage.json").read_text())["segments"]
    lines = first.stdout.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("segment"))
    rows = [line.split() for line in lines[header + 1:header + 1 + len(table)]]
    assert len(rows) == len(truth.segments) == 1
    for cells, true, row in zip(rows, truth.segments, table, strict=True):
        values = (true.coverage[key], row["learned"], row["geometric"])
        assert cells[2:] == ["n/a" if v is None else f"{v:.3f}" for v in values]
    assert table[0]["geometric"] is not None  # this video's geometric branch answers
    assert (tmp_path / "run" / "report.html").stat().st_size > 0

    again = runner.invoke(app, args)
    assert again.exit_code == 0, again.output
    assert "depth: done before, skipped" in again.stdout
    assert again.stdout.splitlines()[-len(lines) + header:] == lines[header:]
