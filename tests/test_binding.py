"""bind end to end: rest pose, locality of an edit, save and load, outside points, progress, refusals.

Quality at the points and affine exactness on every shipped cage are in test_acceptance.py.
"""

from pathlib import Path

import numpy as np
import pytest

import lbc_core
from lbc_core.io import read_cage, read_mesh

DATA = Path(__file__).parent / "data"


def polygon_points(vertices, count, seed=0):
    from matplotlib.path import Path as PolygonPath

    rng = np.random.default_rng(seed)
    points = rng.uniform(vertices.min(axis=0), vertices.max(axis=0), (count, 2))
    return points[PolygonPath(vertices).contains_points(points)]


@pytest.fixture(scope="module")
def woody():
    vertices, _ = read_cage(DATA / "woody-control-edgeset.obj")
    vertices = vertices[:, :2]
    points = polygon_points(vertices, 4000)
    return vertices, points, lbc_core.bind(vertices, None, points)


@pytest.fixture(scope="module")
def gargoyle():
    vertices, faces = read_cage(DATA / "cages-3d" / "gargoyle" / "cage_L12.obj")
    points, _ = read_mesh(DATA / "cages-3d" / "gargoyle" / "mesh.off")
    return vertices, faces, points, lbc_core.bind(vertices, faces, points, cells=3000)


def test_rest_pose_is_exact_and_moving_one_vertex_is_local(gargoyle):
    vertices, faces, points, binding = gargoyle
    np.testing.assert_array_equal(binding.deform(vertices), points)
    moved = vertices.copy()
    moved[0] += 0.1 * binding.cage.bbox_diagonal
    displaced = np.linalg.norm(binding.deform(moved) - points, axis=1) > 0
    assert displaced.mean() < 0.5


def test_save_and_load_give_identical_deformations(gargoyle, tmp_path):
    vertices, faces, points, binding = gargoyle
    path = tmp_path / "binding.npz"
    binding.save(path)
    loaded = lbc_core.load_binding(path, vertices, faces)
    posed = vertices + np.random.default_rng(2).normal(0, 0.01, vertices.shape)
    np.testing.assert_array_equal(loaded.deform(posed), binding.deform(posed))
    assert loaded.options == binding.options and loaded.cage.fingerprint() == binding.cage.fingerprint()


def test_load_against_another_cage_is_refused(woody, tmp_path):
    vertices, _, binding = woody
    path = tmp_path / "binding.npz"
    binding.save(path)
    with pytest.raises(lbc_core.CageError, match="another cage"):
        lbc_core.load_binding(path, vertices[:-1], None)
    (tmp_path / "junk.npz").write_bytes(b"not a binding")
    with pytest.raises(lbc_core.CageError, match="not an lbc binding"):
        lbc_core.load_binding(tmp_path / "junk.npz")


def test_points_outside_are_bound_and_counted():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    points = np.array([[0.5, 0.5], [1.5, 0.5], [0.25, -0.5]])
    binding = lbc_core.bind(square, None, points, cells=200)
    np.testing.assert_array_equal(binding.outside, [False, True, True])
    assert binding.outside_count == 2
    # Outside points follow their closest domain point: a translation moves them rigidly.
    np.testing.assert_allclose(binding.deform(square + [2.0, 3.0]), points + [2.0, 3.0], atol=1e-12)


def test_progress_is_monotonic_and_cancel_stops():
    house = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.5, 1.5], [0.0, 1.0]])
    fractions = []
    lbc_core.bind(house, None, np.array([[0.5, 0.5]]), cells=300,
                  progress=lambda fraction, message: fractions.append(fraction))
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    with pytest.raises(lbc_core.Cancelled):
        lbc_core.bind(house, None, np.array([[0.5, 0.5]]), cells=300, cancel=lambda: True)


def test_bad_points_are_refused():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    with pytest.raises(lbc_core.CageError, match="NaN"):
        lbc_core.bind(square, None, np.array([[np.nan, 0.5]]))
    with pytest.raises(lbc_core.CageError, match="2D"):
        lbc_core.bind(square, None, np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 0.7]]))


@pytest.mark.parametrize(
    "cage, faces",
    [("[[0, 0], [1, 0], [0, 1]]", "None"),
     ("[[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]", "[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]")],
    ids=["triangle", "tetrahedron"],
)
def test_simplex_cages_bind(cage, faces):
    # A simplex leaves the solver nothing to optimise; run in a child process so a crash fails the test, not the run.
    import subprocess
    import sys

    script = (
        "import numpy as np, lbc_core\n"
        f"cage = np.array({cage}, dtype=float)\n"
        f"b = lbc_core.bind(cage, {faces}, cage.mean(axis=0, keepdims=True), cells=300)\n"
        "w = b.weights.toarray()\n"
        "assert np.allclose(w, 1 / len(cage), atol=1e-9), w\n"
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, f"bind on a simplex cage failed (exit code {run.returncode}): {run.stderr[-2000:]}"
