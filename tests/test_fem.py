"""P1 finite elements: gradients, measures, stiffness and mass matrices, boundary facets."""

import numpy as np
import pytest

from lbc_core.kernel import fem


def random_cells(dim, rng, n_vertices=60, n_cells=200):
    """Random vertices in the unit box and random (non-degenerate) cells on them."""
    vertices = rng.random((n_vertices, dim))
    cells = np.array([rng.choice(n_vertices, dim + 1, replace=False) for _ in range(n_cells)])
    return vertices, cells


@pytest.mark.parametrize("dim", [2, 3])
def test_gradients_of_a_linear_function_are_exact(dim):
    rng = np.random.default_rng(1)
    vertices, cells = random_cells(dim, rng)
    slope, offset = rng.normal(size=dim), 0.7
    G, measures = fem.gradient_operator(vertices, cells)
    gradients = (G @ (vertices @ slope + offset)).reshape(len(cells), dim)
    assert np.allclose(gradients, slope, rtol=1e-8, atol=1e-8)
    assert G.shape == (dim * len(cells), len(vertices))


@pytest.mark.parametrize("dim", [2, 3])
def test_measures_are_unsigned_simplex_volumes(dim):
    rng = np.random.default_rng(2)
    vertices, cells = random_cells(dim, rng)
    edges = vertices[cells[:, 1:]] - vertices[cells[:, :1]]
    expected = np.abs(np.linalg.det(edges)) / (2.0 if dim == 2 else 6.0)
    _, measures = fem.cell_gradients(vertices, cells)
    assert np.allclose(measures, expected, rtol=1e-12, atol=0)


@pytest.mark.parametrize("dim", [2, 3])
def test_flat_cells_get_zero_gradients_and_measure(dim):
    rng = np.random.default_rng(3)
    vertices = rng.random((dim + 2, dim))
    cells = np.array([np.arange(dim + 1), np.r_[0, 1, np.arange(1, dim)]])  # the second repeats corner 1
    gradients, measures = fem.cell_gradients(vertices, cells)
    assert measures[0] > 0 and np.all(np.isfinite(gradients))
    assert measures[1] == 0 and np.all(gradients[1] == 0)


def test_gradients_sum_to_zero_over_corners():
    rng = np.random.default_rng(4)
    vertices, cells = random_cells(3, rng)
    gradients, _ = fem.cell_gradients(vertices, cells)
    assert np.abs(gradients.sum(axis=1)).max() < 1e-9 * np.abs(gradients).max()


@pytest.mark.parametrize("dim", [2, 3])
def test_stiffness_is_symmetric_with_constants_in_its_kernel(dim):
    rng = np.random.default_rng(5)
    vertices, cells = random_cells(dim, rng)
    L = fem.stiffness_matrix(vertices, cells)
    assert abs(L - L.T).max() < 1e-12 * abs(L).max()
    assert np.abs(L @ np.ones(len(vertices))).max() < 1e-9 * abs(L).max()
    x = rng.normal(size=len(vertices))
    assert x @ (L @ x) >= 0


def test_lumped_mass_shares_the_total_measure():
    rng = np.random.default_rng(6)
    vertices, cells = random_cells(3, rng)
    _, measures = fem.cell_gradients(vertices, cells)
    mass = fem.lumped_mass(cells, measures, len(vertices))
    assert mass.sum() == pytest.approx(measures.sum(), rel=1e-12)
    assert np.all(mass[np.unique(cells)] > 0)


def test_boundary_facets_of_two_triangles_are_the_outer_square():
    cells = np.array([[0, 1, 2], [0, 2, 3]])
    facets = fem.boundary_facets(cells)
    assert sorted(map(tuple, facets)) == [(0, 1), (0, 3), (1, 2), (2, 3)]


def test_boundary_facets_of_a_split_cube_are_its_twelve_triangles():
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=float)
    cells = np.array([[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]])
    facets = fem.boundary_facets(cells)
    assert len(facets) == 12
    # Every boundary triangle lies in a face of the cube: one coordinate is constant on it.
    assert all(np.any(np.ptp(corners[facet], axis=0) == 0) for facet in facets)
    _, measures = fem.cell_gradients(corners, cells)
    assert measures.sum() == pytest.approx(1.0)
