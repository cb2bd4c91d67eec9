"""Mesh and cage files: the repository's data read as expected, faces keep their order and polygons through every
format, 2D cages read as polygons, and bad files fail with a CageError naming the file."""

import os
from pathlib import Path

import numpy as np
import pytest

from lbc_core.cage.make import make_cage
from lbc_core.errors import CageError
from lbc_core.io import FORMATS, check_output, read_cage, read_mesh, write_mesh, write_posed_obj

DATA = Path(__file__).parent / "data"
GARGOYLE = DATA / "cages-3d" / "gargoyle"
CLOTHING = DATA / "cages-3d" / "clothing"

CUBE = np.array([[x, y, z] for z in (0.0, 1.0) for y in (0.0, 1.0) for x in (0.0, 1.0)])
# Quads and triangles mixed, in an order a reader must keep (the cube with its top split into two triangles).
MIXED_FACES = [[0, 2, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]


def test_2d_reference_cages_read_as_polygons():
    vertices, faces = read_cage(DATA / "woody-control-edgeset.obj")
    assert faces is None
    assert vertices.shape == (26, 2)
    assert vertices[0].tolist() == [171.552, 416.365]
    assert make_cage(vertices).n_control_points == 26


def test_3d_data_read():
    vertices, faces = read_cage(GARGOYLE / "cage_L12.obj")
    assert vertices.shape == (27, 3) and len(faces) == 50 and all(len(f) == 3 for f in faces)
    vertices, faces = read_mesh(GARGOYLE / "mesh.off")
    assert vertices.shape == (2674, 3) and len(faces) == 5344


def test_uv_mapped_obj_with_polygons():
    # 4296 vt lines for 5021 vertices, and triangles, quads and pentagons: meshio 5.3 fails on this file.
    vertices, faces = read_mesh(CLOTHING / "mesh.obj")
    assert vertices.shape == (5021, 3)
    assert len(faces) == 4875
    assert sorted({len(f) for f in faces}) == [3, 4, 5]
    assert min(f.min() for f in faces) == 0 and max(f.max() for f in faces) == 5020


@pytest.mark.parametrize("suffix", [".obj", ".off", ".ply"])
def test_round_trip_keeps_polygons_in_order(tmp_path, suffix):
    path = tmp_path / f"cage{suffix}"
    write_mesh(path, CUBE, MIXED_FACES)
    vertices, faces = read_cage(path)
    np.testing.assert_array_equal(vertices, CUBE)
    assert [f.tolist() for f in faces] == MIXED_FACES
    assert make_cage(vertices, faces).facet_face.max() == len(MIXED_FACES) - 1


@pytest.mark.parametrize("suffix", [".obj", ".off", ".ply"])
def test_point_sets_and_2d_vertices(tmp_path, suffix):
    path = tmp_path / f"points{suffix}"
    points = np.array([[0.5, 0.25], [1.0, 2.0], [3.0, -1.0]])
    write_mesh(path, points)
    vertices, faces = read_mesh(path)
    assert faces is None
    np.testing.assert_array_equal(vertices, np.column_stack([points, np.zeros(3)]))
    np.testing.assert_array_equal(read_cage(path)[0], points)


def test_obj_relative_indices_and_slashes(tmp_path):
    path = tmp_path / "relative.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf -3/1 -2/1 -1/1\nf 1//1 2//1 3//1\n")
    _, faces = read_mesh(path)
    assert [f.tolist() for f in faces] == [[0, 1, 2], [0, 1, 2]]


def test_off_with_counts_on_the_first_line_and_comments(tmp_path):
    path = tmp_path / "tetra.off"
    path.write_text("OFF 4 4 6\n# a comment\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3 255 0 0\n")
    vertices, faces = read_cage(path)
    assert vertices.shape == (4, 3) and [f.tolist() for f in faces][-1] == [1, 2, 3]


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("missing.obj", None, "no such file"),
        ("cage.stl", "solid", "unknown mesh format"),
        ("empty.obj", "# nothing\n", "no vertices"),
        ("bad.obj", "v 0 0\n", "needs x, y and z"),
        ("short.off", "OFF\n4 1 0\n0 0 0\n", "shorter"),
        ("notoff.off", "PLY\n", "not an OFF file"),
        ("bad.ply", "ply\nnonsense\n", "cannot read it as PLY"),
        ("tilted.obj", "v 0 0 0\nv 1 0 0\nv 0 1 1\n", "z varies"),
        ("zero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "has the index 0; OBJ counts vertices from 1"),
        ("far.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", r"face 0 \(0 1 8\) is invalid: a face needs 3 or more"),
        ("far.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", r"face 0 \(0 1 7\) is invalid"),
        ("edge.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n", r"face 0 \(0 1\) is invalid"),
    ],
)
def test_bad_files(tmp_path, name, content, message):
    path = tmp_path / name
    if content is not None:
        path.write_text(content)
    with pytest.raises(CageError, match=message) as error:
        read_cage(path)
    assert name in str(error.value)


def test_writing_faces_that_are_not_among_the_vertices_is_refused(tmp_path):
    with pytest.raises(CageError, match=r"face 1 \(0 1 5\) is invalid"):
        write_mesh(tmp_path / "out.obj", CUBE[:3], [[0, 1, 2], [0, 1, 5]])
    assert not (tmp_path / "out.obj").exists()


def test_output_paths_are_checked_before_any_work(tmp_path):
    check_output(tmp_path / "fine.npz")
    check_output(tmp_path / "fine.obj", FORMATS)
    with pytest.raises(CageError, match="the folder .*nodir does not exist"):
        check_output(tmp_path / "nodir" / "b.npz")
    with pytest.raises(CageError, match="unknown output format '.txt'"):
        check_output(tmp_path / "c.txt", FORMATS)
    with pytest.raises(CageError, match="is a folder"):
        check_output(tmp_path)
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if not os.access(locked, os.W_OK):  # root may write anywhere
            with pytest.raises(CageError, match="no permission to write in"):
                check_output(locked / "b.npz")
    finally:
        locked.chmod(0o700)


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
@pytest.mark.parametrize("suffix", [".obj", ".off", ".ply"])
def test_a_full_disk_is_reported_as_such(tmp_path, suffix):
    full = tmp_path / f"full{suffix}"
    full.symlink_to("/dev/full")
    with pytest.raises(CageError, match="the disk is full"):
        write_mesh(full, CUBE, MIXED_FACES)


def test_a_posed_obj_keeps_the_template_s_uvs_groups_and_materials_without_its_rest_normals(tmp_path):
    template = tmp_path / "rest.obj"
    template.write_text("# made by hand\nmtllib body.mtl\no Body\nv 0 0 0\nv 1 0 0 0.5 0.5 0.5\nv 0 1 0\n"
                        "vt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\nusemtl skin\ns 1\nf 1/1/1 2/2/1 3/3/1\nf 1//1 2//1 3//1\n")
    posed = np.array([[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [0.0, 2.0, 1.0]])
    write_posed_obj(template, tmp_path / "posed.obj", posed)
    text = (tmp_path / "posed.obj").read_text()
    assert text.splitlines() == ["# made by hand", "mtllib body.mtl", "o Body", "v 0.0 0.0 1.0",
                                 "v 2.0 0.0 1.0 0.5 0.5 0.5", "v 0.0 2.0 1.0", "vt 0 0", "vt 1 0", "vt 0 1",
                                 "usemtl skin", "s 1", "f 1/1 2/2 3/3", "f 1 2 3"]
    vertices, faces = read_mesh(tmp_path / "posed.obj")
    np.testing.assert_array_equal(vertices, posed)
    with pytest.raises(CageError, match="has 3 vertices, not the 2 positions given"):
        write_posed_obj(template, tmp_path / "other.obj", posed[:2])
