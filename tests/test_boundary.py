"""Boundary values: 1 at the own control point, linear on cage facets, 0 elsewhere."""

import numpy as np

from lbc_core.solve.boundary import boundary_weights
from lbc_core.cage.make import make_cage
from lbc_core.meshing import mesh_domain

CUBE = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
CUBE_QUADS = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]


def exact_weights(cage, domain):
    """The boundary values and the boundary vertices' positions, checked: partition of unity, reproduction and
    non-negativity."""
    weights = boundary_weights(domain, cage)
    positions = domain.vertices[domain.boundary_vertices]
    assert np.abs(weights.sum(axis=1) - 1).max() < 1e-12
    assert np.abs(weights @ cage.vertices - positions).max() < 1e-12
    assert weights.min() >= 0
    return weights, positions


def check(cage, domain):
    weights, _ = exact_weights(cage, domain)
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


def hexagonal_prism(lift=0.0):
    """A prism over an irregular convex hexagon (z 0 and 1), its top vertex 7 lifted by ``lift``: (vertices, faces)."""
    angles = np.radians([0, 50, 120, 180, 230, 300])
    radii = np.array([1.0, 0.8, 1.1, 0.9, 1.0, 0.7])
    outline = np.c_[radii * np.cos(angles), radii * np.sin(angles)]
    vertices = np.concatenate([np.c_[outline, np.zeros(6)], np.c_[outline, np.ones(6)]])
    vertices[7, 2] += lift
    faces = [list(range(6))[::-1], list(range(6, 12))] + [[i, (i + 1) % 6, 6 + (i + 1) % 6, 6 + i] for i in range(6)]
    return vertices, faces


def test_a_flat_convex_n_gon_takes_its_outlines_mean_value_coordinates():
    """Smooth across the face, where values linear on the poke's triangles crease along each spoke; linear on the
    edges, 1 at each vertex, and every guarantee kept."""
    from lbc_core.kernel.geometry import polygon_mean_value_coordinates

    cage = make_cage(*hexagonal_prism())
    assert len(cage.centres) == 2
    weights, positions = exact_weights(cage, mesh_domain(cage, cells=1500))
    top = np.flatnonzero(np.abs(positions[:, 2] - 1.0) < 1e-12)
    ring = np.arange(6, 12)
    expected = polygon_mean_value_coordinates(cage.vertices[ring, :2], positions[top, :2], 1e-12)
    np.testing.assert_allclose(weights[np.ix_(top, ring)], expected, atol=1e-12)
    inside = top[(weights[top][:, ring] > 1e-9).sum(axis=1) > 2]  # off the outline: every vertex feels it
    assert len(inside) > 20 and np.all(weights[inside][:, ring] > 0)


def test_a_bent_convex_n_gon_keeps_values_that_reproduce_the_poked_surface():
    """One top vertex lifted: the outline's mean value coordinates, corrected on their support, reproduce the points
    of the poke's triangles (or the poke's own linear values do), non-negative."""
    cage = make_cage(*hexagonal_prism(lift=0.15))
    weights, positions = exact_weights(cage, mesh_domain(cage, cells=1500))
    lifted = np.abs(positions[:, 2] - 1.0) > 1e-9  # on the bent cap's triangles next to the lifted vertex
    assert np.count_nonzero(lifted & (positions[:, 2] > 0.5)) > 10
