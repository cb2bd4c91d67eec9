"""Boundary values: 1 at the own control point, linear on cage facets, 0 elsewhere."""

import numpy as np

from lbc_core.boundary import boundary_weights
from lbc_core.cage import make_cage
from lbc_core.meshing import mesh_domain

CUBE = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
CUBE_QUADS = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]


def check(cage, domain):
    weights = boundary_weights(domain, cage)
    positions = domain.vertices[domain.boundary_vertices]
    assert np.abs(weights.sum(axis=1) - 1).max() < 1e-12
    assert np.abs(weights @ cage.vertices - positions).max() < 1e-12
    assert weights.min() >= 0
    # At most d non-zeros per row: the corners of one facet.
    assert (np.count_nonzero(weights, axis=1) <= cage.dim).all()
    position = {vertex: row for row, vertex in enumerate(domain.boundary_vertices)}
    rows = [position[vertex] for vertex in domain.control_vertices]
    np.testing.assert_array_equal(weights[rows], np.eye(cage.n_control_points))


def test_polygon_boundary_values():
    cage = make_cage(np.array([[0, 0], [2, 0], [2, 1], [1, 2], [0, 1]], dtype=float))
    check(cage, mesh_domain(cage, cells=300))


def test_quad_cage_boundary_values():
    cage = make_cage(CUBE, CUBE_QUADS)
    check(cage, mesh_domain(cage, cells=800))
