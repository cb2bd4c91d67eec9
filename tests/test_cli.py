"""The lbc command line: bind, deform, stats, compare and table1 through main(argv), and bad input through a real
subprocess (exit code 2, one line on stderr)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lbc_core.cli import main
from lbc_core.io import read_cage, read_mesh, write_mesh

pytestmark = pytest.mark.slow  # binds end to end: left out of the fast tier

DATA = Path(__file__).parent / "data"
LOGO = DATA / "LBClogo-control-edgeset.obj"  # 6 control points: a quick 2D bind
GARGOYLE = DATA / "cages-3d" / "gargoyle"
AFFINE = np.array([[1.2, 0.3], [-0.1, 0.9]])


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def logo_mesh(tmp_path_factory):
    """A small triangle mesh inside the LBC logo (a grid over its middle), as an OBJ file."""
    vertices, _ = read_cage(LOGO)
    lower, upper = vertices.min(axis=0), vertices.max(axis=0)
    u, v = np.meshgrid(np.linspace(0.1, 0.9, 9), np.linspace(0.1, 0.9, 7), indexing="ij")
    points = lower + np.column_stack([u.ravel(), v.ravel()]) * (upper - lower)
    index = np.arange(points.shape[0]).reshape(u.shape)
    quads = [[index[i, j], index[i + 1, j], index[i + 1, j + 1], index[i, j + 1]] for i in range(8) for j in range(6)]
    path = tmp_path_factory.mktemp("logo") / "grid.obj"
    write_mesh(path, points, quads)
    return path


@pytest.fixture(scope="module")
def gargoyle_points(tmp_path_factory):
    path = tmp_path_factory.mktemp("gargoyle") / "points.ply"
    write_mesh(path, read_mesh(GARGOYLE / "mesh.off")[0][::25])
    return path


def test_bind_stats_deform_2d(tmp_path, capsys, logo_mesh):
    binding = tmp_path / "logo.npz"
    code, out, err = run(capsys, "bind", LOGO, logo_mesh, "-o", binding, "--cells", 400, "--json")
    assert code == 0, err
    figures = json.loads(out)
    assert figures["scheme"] == "lbc" and figures["points"] == 63 and figures["control_points"] == 6
    assert figures["converged"] and "bind (lbc)" in err and binding.is_file()

    code, out, err = run(capsys, "stats", binding, "--json", "--plot", tmp_path / "pq.png",
                         "--coordinate", 1, tmp_path / "w1.svg")
    assert code == 0, err
    stats = json.loads(out)
    assert 1 <= stats["influence_mean"] <= stats["influence_max"] <= 6 and 0 < stats["P_tau"] < 1
    assert (tmp_path / "pq.png").stat().st_size > 5000 and (tmp_path / "w1.svg").stat().st_size > 5000

    # An affine map of the cage moves every point by the same map (linear reproduction), faces kept.
    cage, _ = read_cage(LOGO)
    moved_cage = tmp_path / "moved.obj"
    write_mesh(moved_cage, cage @ AFFINE.T + [5.0, -2.0])
    deformed = tmp_path / "deformed.off"
    code, out, err = run(capsys, "deform", binding, moved_cage, "-o", deformed, "--mesh", logo_mesh,
                         "--plot", tmp_path / "before_after.png", "--quiet")
    assert code == 0 and err == ""
    assert "deformed 63 points" in out
    result, faces = read_mesh(deformed)
    original, original_faces = read_mesh(logo_mesh)
    np.testing.assert_allclose(result[:, :2], original[:, :2] @ AFFINE.T + [5.0, -2.0], atol=1e-6)
    assert [f.tolist() for f in faces] == [f.tolist() for f in original_faces]
    assert (tmp_path / "before_after.png").stat().st_size > 5000


def test_bind_mvc_3d_and_deform_at_rest(tmp_path, capsys, gargoyle_points):
    binding = tmp_path / "mvc.npz"
    code, out, err = run(capsys, "bind", GARGOYLE / "cage_L16.obj", gargoyle_points, "-o", binding,
                         "--scheme", "mvc", "--cells", 300, "--quiet")
    assert code == 0 and err == "" and "with mvc" in out
    code, out, err = run(capsys, "deform", binding, GARGOYLE / "cage_L16.obj", "-o", tmp_path / "same.ply")
    assert code == 0
    np.testing.assert_allclose(read_mesh(tmp_path / "same.ply")[0], read_mesh(gargoyle_points)[0], atol=1e-6)
    # A new user took the points-only file for a broken mesh.
    assert err == (f"lbc: warning: {tmp_path / 'same.ply'} holds the deformed points only, no faces: give the bound "
                   "mesh with --mesh MESH to keep its faces\n")


def test_compare_2d(tmp_path, capsys):
    plot = tmp_path / "pq.png"
    code, out, err = run(capsys, "compare", LOGO, "--schemes", "lbc,mvc,harmonic", "--cells", 600, "--plot", plot,
                         "--json", "--quiet")
    assert code == 0, err
    rows = {row["scheme"]: row for row in json.loads(out)["schemes"]}
    assert set(rows) == {"lbc", "mvc", "harmonic"}
    assert rows["lbc"]["influence_mean"] < min(rows["mvc"]["influence_mean"], rows["harmonic"]["influence_mean"])
    assert rows["lbc"]["P_tau"] > max(rows["mvc"]["P_tau"], rows["harmonic"]["P_tau"])
    assert plot.stat().st_size > 10_000

    code, out, _ = run(capsys, "compare", LOGO, "--schemes", "mvc,harmonic", "--cells", 600, "--quiet")
    assert code == 0
    header = out.splitlines()[1]
    assert "influence mean" in header and "P(1e-3/n)" in header
    assert out.splitlines()[3].startswith("mvc") and out.splitlines()[4].startswith("harmonic")


def test_table1_on_a_pair(capsys, gargoyle_points):
    code, out, err = run(capsys, "table1", "--pair", GARGOYLE / "cage_L16.obj", gargoyle_points, "--cells", 400,
                         "--json", "--quiet")
    assert code == 0, err
    (row,) = json.loads(out)["pairs"]
    assert row["control_points"] == 6 and row["points"] == 107
    assert row["mvc_bytes"] == 107 * 6 * 8
    assert 0 < row["memory_ratio"] and 0 < row["time_ratio"]
    code, out, err = run(capsys, "table1", GARGOYLE.parent, "--min-control", 1000, "--quiet")
    assert code == 2 and "no (cage, mesh) pair" in err


@pytest.mark.parametrize(
    "make_input, argv, message",
    [
        (lambda d: (d / "cross.obj").write_text("v 0 0 0\nv 1 1 0\nv 1 0 0\nv 0 1 0\n"),
         ["bind", "{d}/cross.obj", "{d}/cross.obj", "-o", "{d}/x.npz"], "intersects itself"),
        (lambda d: None, ["bind", "{d}/missing.obj", "{d}/missing.obj", "-o", "{d}/x.npz"], "no such file"),
        (lambda d: (d / "fake.npz").write_bytes(b"not a binding"), ["stats", "{d}/fake.npz"], "not an lbc binding"),
        (lambda d: None, ["table1", "{d}/nowhere"], "not a folder"),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path, make_input, argv, message):
    make_input(tmp_path)
    argv = [a.format(d=tmp_path) for a in argv]
    result = subprocess.run([sys.executable, "-m", "lbc_core", *argv], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lbc: error:") and message in lines[0]


def test_deform_with_another_cage_exits_2(tmp_path, capsys, gargoyle_points):
    binding = tmp_path / "mvc.npz"
    assert run(capsys, "bind", GARGOYLE / "cage_L16.obj", gargoyle_points, "-o", binding, "--scheme", "mvc",
               "--cells", 300, "--quiet")[0] == 0
    # By its vertex count (a new user's find: its faces were checked first, told as corners out of range).
    code, _, err = run(capsys, "deform", binding, GARGOYLE / "cage_L12.obj", "-o", tmp_path / "x.obj")
    assert code == 2 and "got positions of shape (27, 3)" in err
    code, _, err = run(capsys, "stats", binding, "--coordinate", 0, tmp_path / "w0.png")
    assert code == 2 and "2D bindings only" in err


def test_bad_options_exit_2(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["compare", str(LOGO), "--schemes", "lbc,nope"])
    assert exit_info.value.code == 2
    assert "unknown scheme" in capsys.readouterr().err


# What lbc prints is what it did; every bad input is one line and exit 2, before the long work where it can be.


def lbc(*argv):
    """``lbc`` in a child process (a crash or a traceback fails the test): exit code, stdout, stderr."""
    result = subprocess.run([sys.executable, "-m", "lbc_core", *map(str, argv)], capture_output=True, text=True,
                            timeout=300)
    return result.returncode, result.stdout, result.stderr


def assert_one_line_error(code, err, message):
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("lbc: error:"), err
    assert message in lines[0], lines[0]


@pytest.fixture(scope="module")
def logo_binding(tmp_path_factory, logo_mesh):
    path = tmp_path_factory.mktemp("logo-binding") / "logo.npz"
    assert main(["bind", str(LOGO), str(logo_mesh), "-o", str(path), "--cells", "400", "--quiet"]) == 0
    return path


def test_the_path_written_is_the_path_printed(tmp_path, capsys, logo_mesh):
    output = tmp_path / "binding.dat"
    code, out, err = run(capsys, "bind", LOGO, logo_mesh, "-o", output, "--cells", 400, "--quiet")
    assert code == 0, err
    assert out.strip().endswith(f"wrote {output}") and [p.name for p in tmp_path.iterdir()] == ["binding.dat"]
    assert run(capsys, "stats", output, "--quiet")[0] == 0


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--cells", 0], "cells must be at least 10"),
        (["--tolerance", 0], "tolerance must be more than 0"),
        (["--epsilon", -1, "--max-iterations", -5], "epsilon must be 0 or more, got -1"),
        (["--threshold", 0.5], "threshold 0.5 would drop every weight"),
        (["-o", "{d}/nodir/b.npz"], "the folder {d}/nodir does not exist"),
        # A new user's `-o z.obj` was written as an .npz archive named z.obj, silently.
        (["-o", "{d}/z.OBJ"], "{d}/z.OBJ: bind writes a binding (an .npz archive), not a mesh; name it {d}/z.npz, "
                              "then `lbc deform z.npz NEW_CAGE --mesh {mesh} -o deformed.OBJ` writes the deformed "
                              "mesh"),
    ],
)
def test_bad_options_and_outputs_are_refused_before_the_bind(tmp_path, logo_mesh, argv, message):
    argv = [str(a).format(d=tmp_path) for a in argv]
    output = [] if "-o" in argv else ["-o", tmp_path / "b.npz"]
    code, _, err = lbc("bind", LOGO, logo_mesh, *output, *argv)
    assert_one_line_error(code, err, message.format(d=tmp_path, mesh=logo_mesh))  # one line: no progress was printed


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_full_disk_is_reported(tmp_path, logo_mesh):
    code, _, err = lbc("bind", LOGO, logo_mesh, "-o", "/dev/full", "--cells", 400, "--quiet")
    assert_one_line_error(code, err, "could not write /dev/full: the disk is full")


def test_non_convergence_and_outside_points_are_in_the_plain_output(tmp_path, capsys):
    points = tmp_path / "points.obj"
    cage, _ = read_cage(LOGO)
    write_mesh(points, np.r_[cage.mean(axis=0, keepdims=True), cage.max(axis=0, keepdims=True) + 10.0])
    code, out, err = run(capsys, "bind", LOGO, points, "-o", tmp_path / "b.npz", "--cells", 400,
                         "--max-iterations", 5)
    assert code == 0, err
    assert "1 points outside the cage (extrapolated from the closest points inside)" in out
    assert "lbc: warning: not converged: the solve stopped after 5 iterations" in err
    code, out, err = run(capsys, "bind", LOGO, points, "-o", tmp_path / "b.npz", "--cells", 400,
                         "--max-iterations", 5, "--quiet", "--json")
    assert err == "" and any(warning.startswith("not converged") for warning in json.loads(out)["warnings"])


def test_a_cage_far_too_small_is_warned_on_stderr_and_in_the_json(tmp_path, capsys):
    """Half the points outside: the cage is too small, as the add-on says; the command line says it too."""
    points = tmp_path / "points.obj"
    cage, _ = read_cage(LOGO)
    write_mesh(points, np.r_[cage.mean(axis=0, keepdims=True), cage.max(axis=0, keepdims=True) + 10.0])
    code, out, err = run(capsys, "bind", LOGO, points, "-o", tmp_path / "b.npz", "--cells", 400)
    assert code == 0, err
    warning = ("1 of 2 vertices (50%) lie outside the cage, which is too small for the mesh: they follow the cage "
               "only by extrapolation from the closest points inside it. Scale the cage up so it encloses the mesh, "
               "then bind again")
    assert f"lbc: warning: {warning}" in err
    code, out, err = run(capsys, "bind", LOGO, points, "-o", tmp_path / "c.npz", "--cells", 400, "--json", "--quiet")
    assert code == 0 and json.loads(out)["warnings"] == [warning] and "warning" not in err


def test_warnings_and_the_forecast_come_before_the_long_work(tmp_path, logo_mesh):
    cage, _ = read_cage(LOGO)
    doubled = tmp_path / "doubled.obj"
    write_mesh(doubled, np.r_[cage[:3], cage[2:3], cage[3:]])  # vertex 2 twice in a row: welded
    code, out, err = lbc("bind", doubled, logo_mesh, "-o", tmp_path / "b.npz", "--cells", 400)
    assert code == 0, err
    lines = err.splitlines()
    assert lines[0] == "lbc: warning: welded 1 duplicate cage vertex"
    assert "solving 6 control points on about 400 cells: about" in lines[1]
    assert "ADMM iteration" in err and "left" in err


def test_figure_paths_are_checked_before_the_work(tmp_path, logo_binding):
    code, _, err = lbc("stats", logo_binding, "--plot", tmp_path / "c.txt")
    assert_one_line_error(code, err, "unknown output format '.txt'")
    code, _, err = lbc("stats", logo_binding, "--coordinate", 99, tmp_path / "w.png")
    assert_one_line_error(code, err, "the coordinate index must be in 0 … 5, got 99")


def test_deform_checks_the_posed_cage_and_the_mesh(tmp_path, capsys, gargoyle_points):
    binding = tmp_path / "mvc.npz"
    cage = GARGOYLE / "cage_L16.obj"
    assert run(capsys, "bind", cage, gargoyle_points, "-o", binding, "--scheme", "mvc", "--cells", 300,
               "--quiet")[0] == 0
    vertices, faces = read_cage(cage)
    vertex_only = tmp_path / "vertex-only.obj"
    write_mesh(vertex_only, vertices)
    code, _, err = run(capsys, "deform", binding, vertex_only, "-o", tmp_path / "x.obj")
    assert code == 2 and "this cage has no faces" in err
    renumbered = tmp_path / "renumbered.obj"
    write_mesh(renumbered, vertices, faces[1:] + faces[:1])
    code, _, err = run(capsys, "deform", binding, renumbered, "-o", tmp_path / "x.obj")
    assert code == 2 and "other faces" in err
    code, _, err = run(capsys, "deform", binding, cage, "-o", tmp_path / "x.stl")
    assert code == 2 and "unknown output format '.stl'" in err
    bad_mesh = tmp_path / "bad-mesh.obj"
    bad_mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    code, _, err = run(capsys, "deform", binding, cage, "-o", tmp_path / "x.obj", "--mesh", bad_mesh)
    assert code == 2 and "face 0 (0 1 8) is invalid" in err


def test_2d_points_in_another_plane_are_refused(tmp_path, capsys, logo_mesh):
    lifted = tmp_path / "lifted.obj"
    vertices, faces = read_mesh(logo_mesh)
    write_mesh(lifted, vertices + [0.0, 0.0, 5.0], faces)
    code, _, err = run(capsys, "bind", LOGO, lifted, "-o", tmp_path / "b.npz")
    assert code == 2 and "lies in the plane z = 5 but the 2D cage" in err


def _damage(source, target, how):
    content = source.read_bytes()
    if how == "truncated":
        target.write_bytes(content[: len(content) // 2])
    elif how == "bit-flip":
        flipped = bytearray(content)
        flipped[len(content) // 3] ^= 0x10
        target.write_bytes(bytes(flipped))
    elif how == "empty":
        target.write_bytes(b"")
    elif how == "npy":
        with open(target, "wb") as handle:
            np.save(handle, np.eye(3))
    else:
        with np.load(source) as data:
            arrays = {key: data[key] for key in data.files}
        if how == "indices":
            arrays["weights_indices"] = arrays["weights_indices"] + 10**6
        elif how == "times-five":
            arrays["weights_data"] = arrays["weights_data"] * 5
        elif how == "reversed":
            arrays["weights_data"] = arrays["weights_data"][::-1].copy()
        elif how == "missing-key":
            del arrays["points"]
        with open(target, "wb") as handle:
            np.savez(handle, **arrays)


@pytest.mark.parametrize("how", ["truncated", "bit-flip", "empty", "npy", "indices", "times-five", "reversed",
                                 "missing-key"])
def test_damaged_binding_files_exit_2_with_one_line(tmp_path, logo_binding, how):
    damaged = tmp_path / "damaged.npz"
    _damage(logo_binding, damaged, how)
    code, out, err = lbc("deform", damaged, LOGO, "-o", tmp_path / "x.obj")
    assert_one_line_error(code, err, str(damaged))
    assert out == "" and not (tmp_path / "x.obj").exists()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 10**6), bit=st.integers(0, 10**7))
def test_fuzz_lbc_with_damaged_binding_files(tmp_path, capsys, logo_binding, cut, bit):
    # The same kinds of damage as load_binding's fuzz, through the command: exit 0 on a file that still checks out,
    # else exit 2 with one line; never another exit code or a traceback.
    content = bytearray(logo_binding.read_bytes())
    content[bit % len(content)] ^= 1 << (bit % 8)
    path = tmp_path / "fuzzed.npz"
    path.write_bytes(bytes(content[: max(cut % (2 * len(content)), 1)]))
    code, out, err = run(capsys, "stats", path, "--quiet")
    assert code in (0, 2)
    if code == 2:
        assert len(err.strip().splitlines()) == 1 and err.startswith("lbc: error:") and out == ""


def test_a_flat_cage_with_faces_binds_in_2d_as_in_blender(tmp_path, capsys):
    from lbc_addon import jobs
    from lbc_addon.options import AddonOptions
    from lbc_core.binding.files import load_binding
    from lbc_core.cage.planar import flatten

    # A tilted 4 × 4 grid of quads: its outline (12 vertices) is the cage, the 4 inner vertices control nothing.
    rotation = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))[0]
    cage = np.array([[c, r, 0.0] for r in range(4) for c in range(4)]) @ rotation.T + 2.0
    quads = [[r * 4 + c, r * 4 + c + 1, (r + 1) * 4 + c + 1, (r + 1) * 4 + c] for r in range(3) for c in range(3)]
    points = np.array([[0.4, 0.5, 0.0], [1.5, 2.2, 0.0], [2.6, 1.1, 0.0]]) @ rotation.T + 2.0
    write_mesh(tmp_path / "cage.obj", cage, quads)
    write_mesh(tmp_path / "points.ply", points)
    assert run(capsys, "bind", tmp_path / "cage.obj", tmp_path / "points.ply", "-o", tmp_path / "b.npz")[0] == 0
    binding = load_binding(tmp_path / "b.npz")
    assert binding.cage.dim == 2 and binding.cage.n_control_points == 12

    # The add-on's solve of the same scene (the request geometry.snapshot makes, with every option at its default but
    # the add-on's own thinning, whose Threshold of 1e-12 keeps every weight).
    read_cage, read_points = read_mesh(tmp_path / "cage.obj")[0], read_mesh(tmp_path / "points.ply")[0]
    options = AddonOptions(thinning=1e-12)
    flat = flatten(read_cage, quads, read_points)
    result = jobs.solve(jobs.BindRequest(1, 2, "Mesh", read_points, read_cage, quads, flat, options, "", ""))
    blender = np.zeros((len(points), len(cage)))
    np.add.at(blender, (np.arange(len(points))[:, None], result.index), result.weight)
    command_line = np.zeros_like(blender)
    command_line[:, flat.loop[binding.cage.first_inputs]] = binding.weights.toarray()
    np.testing.assert_allclose(blender, command_line, atol=1e-6)


def test_deform_of_an_obj_mesh_keeps_its_uvs(tmp_path, capsys):
    clothing = DATA / "cages-3d" / "clothing"
    binding, posed = tmp_path / "cloth.npz", tmp_path / "posed.obj"
    assert run(capsys, "bind", clothing / "cage.obj", clothing / "mesh.obj", "-o", binding, "--cells", 2000)[0] == 0
    assert run(capsys, "deform", binding, clothing / "cage_deformed.obj", "--mesh", clothing / "mesh.obj",
               "-o", posed)[0] == 0
    rest_lines, posed_lines = (path.read_text().splitlines() for path in (clothing / "mesh.obj", posed))
    uvs = [line for line in rest_lines if line.startswith("vt ")]
    assert uvs and uvs == [line for line in posed_lines if line.startswith("vt ")]
    assert [line.split()[1].split("/")[:2] for line in posed_lines if line.startswith("f ")][:3] == \
        [line.split()[1].split("/")[:2] for line in rest_lines if line.startswith("f ")][:3]
    vertices, _ = read_mesh(posed)
    assert not np.allclose(vertices, read_mesh(clothing / "mesh.obj")[0])


def test_a_2d_deform_stays_in_the_plane_of_its_files_and_writes_an_obj_mesh_as_obj(tmp_path, capsys):
    """A new user's finds: a 2D binding's OBJ mesh written as OBJ crashed (2D positions where x, y, z were read), and
    2D data in a plane z = 5 came out at z = 0, even at rest."""
    square, mesh = tmp_path / "square.obj", tmp_path / "mesh.obj"
    square.write_text("v 0 0 5\nv 10 0 5\nv 10 10 5\nv 0 10 5\n")
    mesh.write_text("v 5 5 5\nv 2 3 5\nv 7 2 5\nvt 0.5 0.5\nf 1/1 2/1 3/1\n")
    binding = tmp_path / "b.npz"
    assert run(capsys, "bind", square, mesh, "-o", binding, "--quiet")[0] == 0
    for output in (tmp_path / "rest.obj", tmp_path / "rest.off"):
        assert run(capsys, "deform", binding, square, "--mesh", mesh, "-o", output, "--quiet")[0] == 0
        np.testing.assert_allclose(read_mesh(output)[0], read_mesh(mesh)[0], atol=1e-12)
    assert "f 1/1 2/1 3/1" in (tmp_path / "rest.obj").read_text()


def test_an_output_that_is_one_of_the_inputs_is_refused(tmp_path, logo_mesh, logo_binding):
    """A new user's find: -o naming the mesh turned it into the binding's zip archive."""
    mesh = tmp_path / "mesh.obj"
    mesh.write_bytes(logo_mesh.read_bytes())
    code, _, err = lbc("bind", LOGO, mesh, "-o", mesh)
    assert_one_line_error(code, err, "is also an input of this command: writing it would destroy it")
    assert mesh.read_bytes() == logo_mesh.read_bytes()
    posed = tmp_path / "posed.obj"
    posed.write_bytes(LOGO.read_bytes())
    code, _, err = lbc("deform", logo_binding, posed, "-o", tmp_path / "." / "posed.obj")
    assert_one_line_error(code, err, "is also an input of this command")
    # A missing input beside an existing output is the reader's to report (the check once raised a traceback).
    existing = tmp_path / "existing.npz"
    existing.write_bytes(b"")
    code, _, err = lbc("bind", LOGO, tmp_path / "missing.obj", "-o", existing)
    assert code == 2 and "missing.obj" in err and "Traceback" not in err


def test_the_progress_bar_fits_an_80_column_terminal_and_shows_the_forecast_whole(monkeypatch, capsys, tmp_path,
                                                                                   logo_mesh):
    """A new user's find: a bar drawn 121 characters wide wrapped in an 80-column terminal, so every redraw scrolled,
    and the forecast (memory and time) was cut."""
    import io
    import os

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    monkeypatch.setattr("shutil.get_terminal_size", lambda *args: os.terminal_size((80, 24)))
    assert main(["bind", str(LOGO), str(logo_mesh), "-o", str(tmp_path / "b.npz"), "--cells", "400"]) == 0
    drawn = terminal.getvalue().replace("\r", "\n").splitlines()
    assert max(map(len, drawn)) <= 80
    forecast = " ".join(line.strip() for line in drawn if not line.startswith("bind (lbc)"))
    assert "meshing under 1 s, then solving 6 control points on about 400 cells: about" in forecast


def test_a_mesh_given_as_the_cage_asks_whether_they_were_swapped(tmp_path):
    """A new user's find: the gargoyle's mesh given first was refused for its 2674 vertices with advice to decimate
    it; the hint about swapped files came only when every point fell outside."""
    code, _, err = lbc("bind", GARGOYLE / "mesh.off", GARGOYLE / "cage_L12.obj", "-o", tmp_path / "b.npz")
    assert_one_line_error(code, err, "has more vertices than")
    assert "(2674 against 27): were they swapped? The cage comes first (lbc bind CAGE MESH)" in err


def test_version(capsys):
    import lbc_core

    with pytest.raises(SystemExit) as exit_status:
        main(["--version"])
    assert exit_status.value.code == 0 and capsys.readouterr().out == f"lbc {lbc_core.__version__}\n"


def test_a_closed_pipe_ends_the_output_quietly(logo_binding):
    """A new user's `lbc stats b.npz --json | head -5` ended in a BrokenPipeError traceback."""
    # `true` reads nothing and is gone long before the interpreter has started.
    result = subprocess.run(f"'{sys.executable}' -m lbc_core stats '{logo_binding}' --json | true", shell=True,
                            capture_output=True, text=True, timeout=300)
    assert result.stderr == ""


def test_stats_help_says_what_its_columns_mean():
    """A new user met P(1e-3/n), Q(4) and Q(8) in `lbc stats` with no word on what they are."""
    code, out, _ = lbc("stats", "--help")
    assert code == 0 and "P(1e-3/n)  the mean share of the domain" in out and "Q(4), Q(8) the share" in out
