"""The shared LBC objective: exact on linear functions, and the same number the reference packs report."""

from pathlib import Path

import numpy as np
import pytest

from lbc_core.solve.objective import tv_objective

DATA = Path(__file__).parent / "data"
PACKS = ["woody", "Gil_Gecko", "cactus", "LBClogo"]


def _square_mesh():
    """Unit square split into two triangles."""
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    return square, triangles


def _cube_mesh():
    """Unit cube split into six tetrahedra."""
    cube = np.array([[x, y, z] for z in (0.0, 1.0) for y in (0.0, 1.0) for x in (0.0, 1.0)])
    # Kuhn triangulation: the six tetrahedra along the main diagonal 0-7.
    tetrahedra = np.array([[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]])
    return cube, tetrahedra


@pytest.mark.parametrize("mesh", [_square_mesh, _cube_mesh])
def test_linear_functions_give_weighted_measure_times_gradient_norm(mesh):
    vertices, cells = mesh()
    rng = np.random.default_rng(0)
    d, n = vertices.shape[1], 3
    slopes = rng.normal(size=(d, n))
    weights = vertices @ slopes + rng.normal(size=n)
    tv_weights = rng.uniform(0.1, 2.0, size=(len(cells), n))
    measures = np.abs([np.linalg.det(vertices[c[1:]] - vertices[c[0]]) for c in cells]) / (2 if d == 2 else 6)
    expected = np.sum(tv_weights * measures[:, None] * np.linalg.norm(slopes, axis=0))
    assert tv_objective(vertices, cells, weights, tv_weights) == pytest.approx(expected, rel=1e-12)


def test_constant_functions_cost_nothing():
    vertices, cells = _square_mesh()
    assert tv_objective(vertices, cells, np.full((4, 2), 0.3), np.ones((2, 2))) == 0.0


@pytest.mark.parametrize("name", PACKS)
@pytest.mark.parametrize("setting", ["default", "tight"])
def test_reproduces_the_reference_packs_objective(name, setting):
    pack = np.load(DATA / f"{name}.npz")
    objective = tv_objective(pack["vertices"], pack["triangles"], pack[f"weights_{setting}"], pack["tv_weights"])
    assert objective == pytest.approx(float(pack[f"objective_{setting}"]), rel=1e-9)
