"""Tests of lbc_core.evaluate.interpolation: barycentric interpolation matrix and binding of outside points."""

import numpy as np
import pytest
from scipy.spatial import Delaunay

from lbc_core.kernel import fem
from lbc_core.errors import CageError, Cancelled
from lbc_core.evaluate.interpolation import interpolation_matrix

# Kuhn split of a unit cube (corner index = 4 x + 2 y + z) into 6 tetrahedra around its diagonal 0-7: conforming
# across cubes, so grids of cubes give valid tetrahedral meshes.
CUBE_TETS = np.array([[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]])
SQUARE_TRIANGLES = np.array([[0, 1, 3], [0, 3, 2]])  # corner index = 2 x + y


def cube_grid_mesh(blocks, n):
    """Unit blocks (lists of integer lower corners, d = 2 or 3), each split into n^d cubes of simplices.

    Returns
    -------
    vertices : (N, d) float array, exact multiples of 1 / n
    cells : (F, d+1) int array
    """
    blocks = np.asarray(blocks)
    d = blocks.shape[1]
    local = np.stack(np.meshgrid(*[np.arange(n)] * d, indexing="ij"), axis=-1).reshape(-1, d)
    lower = (blocks[:, None, :] * n + local[None]).reshape(-1, d)  # integer lower corners of the small cubes
    offsets = np.array(np.meshgrid(*[[0, 1]] * d, indexing="ij")).reshape(d, -1).T  # corner c = binary digits
    split = CUBE_TETS if d == 3 else SQUARE_TRIANGLES
    corners = lower[:, None, :] + offsets[None]  # (cubes, 2^d, d)
    integer_vertices, inverse = np.unique(corners.reshape(-1, d), axis=0, return_inverse=True)
    cells = inverse.reshape(len(lower), 2**d)[:, split].reshape(-1, d + 1)
    return integer_vertices / n, cells


def delaunay_box_mesh(d, n_points, rng):
    """A Delaunay mesh of the unit square / cube: its corners plus random interior points."""
    corners = np.array(np.meshgrid(*[[0.0, 1.0]] * d, indexing="ij")).reshape(d, -1).T
    vertices = np.concatenate([corners, rng.uniform(0.05, 0.95, (n_points, d))])
    return vertices, Delaunay(vertices).simplices


def box_distance(points, lo, hi):
    """Euclidean distance from points (m, d) to the box [lo, hi]."""
    return np.linalg.norm(np.maximum(np.maximum(np.asarray(lo) - points, points - np.asarray(hi)), 0.0), axis=1)


def l_shape(d):
    """The L-shaped domain [0, 2]^2 minus [1, 2]^2 (times [0, 1] in 3D) as two boxes, and its mesh."""
    if d == 2:
        boxes = [([0, 0], [2, 1]), ([0, 0], [1, 2])]
        blocks = [[0, 0], [1, 0], [0, 1]]
    else:
        boxes = [([0, 0, 0], [2, 1, 1]), ([0, 0, 0], [1, 2, 1])]
        blocks = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    return boxes, cube_grid_mesh(blocks, 4 if d == 2 else 3)


def union_distance(points, boxes):
    return np.min([box_distance(points, lo, hi) for lo, hi in boxes], axis=0)


def outward_normals(vertices, cells, facets):
    """Unit normals of boundary facets, pointing away from the cell they bound."""
    d = vertices.shape[1]
    cell_of = {}
    for cell in cells:
        for k in range(d + 1):
            cell_of[tuple(sorted(np.delete(cell, k)))] = cell
    corners = vertices[facets]
    if d == 2:
        edge = corners[:, 1] - corners[:, 0]
        normals = np.stack([-edge[:, 1], edge[:, 0]], axis=1)
    else:
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    inner = np.array([vertices[cell_of[tuple(f)]].mean(axis=0) for f in facets])
    flip = np.einsum("ij,ij->i", normals, inner - corners[:, 0]) > 0
    normals[flip] *= -1
    return normals


def assert_convex_rows(P, d):
    """Every row: non-negative entries summing to 1, at most d+1 of them."""
    assert np.all(P.data >= 0)
    np.testing.assert_allclose(np.asarray(P.sum(axis=1)).ravel(), 1.0, atol=1e-14)
    assert np.diff(P.indptr).max() <= d + 1


def assert_supported_on_simplices(P, simplices, rows):
    """Each of the given rows uses only the vertices of one of the simplices (cells or facets)."""
    simplices = [set(simplex) for simplex in simplices]
    for row in rows:
        used = set(P.indices[P.indptr[row] : P.indptr[row + 1]])
        assert any(used <= simplex for simplex in simplices), f"row {row} is not on one simplex: {used}"


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("offset", [0.0, 1e4])
def test_linear_functions_are_reproduced_at_interior_points(d, offset):
    rng = np.random.default_rng(d)
    vertices, cells = delaunay_box_mesh(d, 300, rng)
    points = rng.uniform(0.0, 1.0, (2000, d))
    vertices, points = vertices + offset, points + offset  # far from the origin: rounding must not lose points
    P, outside, distance = interpolation_matrix(vertices, cells, points)
    linear = rng.normal(size=(d, 4))
    constant = rng.normal(size=4)
    assert P.shape == (len(points), len(vertices))
    np.testing.assert_allclose(P @ (vertices @ linear + constant), points @ linear + constant, atol=1e-9)
    np.testing.assert_allclose(P @ vertices, points, atol=1e-10 * (1 + offset))
    assert not outside.any()
    assert np.all(distance == 0)
    assert_convex_rows(P, d)
    assert_supported_on_simplices(P, cells, range(100))


@pytest.mark.parametrize("d", [2, 3])
def test_points_on_vertices_edges_and_faces(d):
    _, (vertices, cells) = l_shape(d)
    corners = vertices[cells]  # (F, d+1, d)
    edge_midpoints = np.concatenate([(corners[:, i] + corners[:, j]) / 2 for i in range(d + 1) for j in range(i)])
    facet_centroids = np.concatenate([np.delete(corners, k, axis=1).mean(axis=1) for k in range(d + 1)])
    points = np.concatenate([vertices, edge_midpoints, facet_centroids])
    P, outside, distance = interpolation_matrix(vertices, cells, points)
    assert not outside.any()
    assert np.all(distance == 0)
    np.testing.assert_allclose(P @ vertices, points, atol=1e-14)
    assert_convex_rows(P, d)
    # A vertex is its own interpolant: one entry, 1, at that vertex.
    on_vertices = P[: len(vertices)]
    assert np.all(np.diff(on_vertices.indptr) == 1)
    np.testing.assert_array_equal(on_vertices.indices, np.arange(len(vertices)))
    np.testing.assert_allclose(on_vertices.data, 1.0)
    # A point on an edge uses only that edge's two vertices.
    on_edges = P[len(vertices) : len(vertices) + len(edge_midpoints)]
    assert np.diff(on_edges.indptr).max() == 2


@pytest.mark.parametrize("d", [2, 3])
def test_points_on_interior_facets_of_an_unstructured_mesh_are_inside(d):
    """Inexact coordinates on facets shared by two cells: the tolerance must give them a cell."""
    rng = np.random.default_rng(10 + d)
    vertices, cells = delaunay_box_mesh(d, 200, rng)
    facets = np.concatenate([np.delete(cells, k, axis=1) for k in range(d + 1)])
    weights = rng.dirichlet(np.ones(d), size=len(facets))
    points = np.einsum("fk,fkj->fj", weights, vertices[facets])
    P, outside, distance = interpolation_matrix(vertices, cells, points)
    assert not outside.any()
    assert np.all(distance == 0)
    np.testing.assert_allclose(P @ vertices, points, atol=1e-14)
    assert_convex_rows(P, d)


@pytest.mark.parametrize("d", [2, 3])
def test_points_in_the_notch_are_bound_to_the_closest_boundary_point(d):
    boxes, (vertices, cells) = l_shape(d)
    rng = np.random.default_rng(20 + d)
    notch = rng.uniform(1.0, 2.0, (500, d))
    around = rng.uniform(-1.0, 3.0, (500, d))
    if d == 3:
        notch[:, 2] = rng.uniform(0.0, 1.0, 500)
    points = np.concatenate([notch, around])
    P, outside, distance = interpolation_matrix(vertices, cells, points)
    expected = union_distance(points, boxes)
    np.testing.assert_array_equal(outside, expected > 1e-9)
    np.testing.assert_allclose(distance, expected, atol=1e-12)
    assert outside[: len(notch)].all()
    assert_convex_rows(P, d)
    bound = P @ vertices
    # The bound point is in the domain, at exactly the distance found, on one boundary facet.
    np.testing.assert_allclose(union_distance(bound, boxes), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(bound - points, axis=1)[outside], distance[outside], atol=1e-12)
    assert np.diff(P.indptr)[outside].max() <= d
    assert_supported_on_simplices(P, fem.boundary_facets(cells), np.flatnonzero(outside)[:100])
    inside = ~outside
    np.testing.assert_allclose(bound[inside], points[inside], atol=1e-14)


@pytest.mark.parametrize("d", [2, 3])
def test_points_on_the_boundary_are_inside_within_the_tolerance(d):
    _, (vertices, cells) = l_shape(d)
    rng = np.random.default_rng(30 + d)
    facets = fem.boundary_facets(cells)
    weights = rng.dirichlet(np.ones(d), size=len(facets))
    on_boundary = np.einsum("fk,fkj->fj", weights, vertices[facets])
    # Pushed outward by much less, then much more, than the tolerance (1e-12 of the diagonal).
    normals = outward_normals(vertices, cells, facets)
    diagonal = np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))
    tiny = on_boundary + 1e-14 * diagonal * normals
    small = on_boundary + 1e-8 * diagonal * normals
    P, outside, distance = interpolation_matrix(vertices, cells, np.concatenate([on_boundary, tiny, small]))
    n = len(facets)
    assert not outside[: 2 * n].any()
    assert np.all(distance[: 2 * n] == 0)
    np.testing.assert_allclose(P[:n] @ vertices, on_boundary, atol=1e-14)
    assert outside[2 * n :].all()
    np.testing.assert_allclose(distance[2 * n :], 1e-8 * diagonal, rtol=1e-5)


def test_points_on_a_flat_cell_are_inside():
    """A zero-area cell (a fin along x = 1 above the unit square) is part of the domain but locates nothing: its
    points are found through the boundary facets, and count as inside within the tolerance."""
    vertices = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [1.0, 2.0]])
    cells = np.array([[0, 1, 2], [0, 2, 3], [1, 2, 4]])
    points = np.array([[1.0, 1.5], [1.0 + 1e-15, 1.3], [1.0 + 1e-6, 1.5]])
    P, outside, distance = interpolation_matrix(vertices, cells, points)
    np.testing.assert_array_equal(outside, [False, False, True])
    np.testing.assert_allclose(distance, [0.0, 0.0, 1e-6], rtol=1e-9)
    np.testing.assert_allclose(P @ vertices, [[1.0, 1.5], [1.0, 1.3], [1.0, 1.5]], atol=1e-14)


def test_points_in_an_internal_void_are_outside():
    blocks = [[x, y, z] for x in range(3) for y in range(3) for z in range(3) if (x, y, z) != (1, 1, 1)]
    vertices, cells = cube_grid_mesh(blocks, 1)
    rng = np.random.default_rng(40)
    points = rng.uniform(1.05, 1.95, (300, 3))  # inside the void [1, 2]^3
    P, outside, distance = interpolation_matrix(vertices, cells, points)
    assert outside.all()
    expected = np.minimum(points - 1.0, 2.0 - points).min(axis=1)
    np.testing.assert_allclose(distance, expected, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(P @ vertices - points, axis=1), expected, atol=1e-12)


@pytest.mark.parametrize("d", [2, 3])
def test_closest_facet_is_exact_with_facets_of_very_different_sizes(d):
    """A Delaunay box mesh has a few large hull facets and small inner cells; distances to the box are exact."""
    rng = np.random.default_rng(50 + d)
    vertices, cells = delaunay_box_mesh(d, 400, rng)
    if d == 2:  # many short boundary edges along the bottom, one long edge elsewhere on each side
        bottom = np.stack([np.sort(rng.uniform(0.0, 1.0, 200)), np.zeros(200)], axis=1)
        vertices = np.concatenate([vertices, bottom])
        cells = Delaunay(vertices).simplices
    points = rng.uniform(-0.5, 1.5, (3000, d))
    P, outside, distance = interpolation_matrix(vertices, cells, points)
    expected = box_distance(points, np.zeros(d), np.ones(d))
    np.testing.assert_allclose(distance, expected, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(P @ vertices - points, axis=1), expected, atol=1e-12)
    np.testing.assert_array_equal(outside, expected > 1e-9)


def test_segment_boundary_brute_force_2d():
    """Against a brute-force point-segment distance over all boundary edges of a non-convex mesh."""
    rng = np.random.default_rng(60)
    vertices, cells = delaunay_box_mesh(2, 300, rng)
    centroids = vertices[cells].mean(axis=1)
    keep = ~((np.abs(centroids[:, 0] - 0.5) < 0.25) & (centroids[:, 1] > 0.3))  # a jagged slot from the top
    cells = cells[keep]
    points = rng.uniform(-0.2, 1.2, (2000, 2))
    P, outside, distance = interpolation_matrix(vertices, cells, points)
    a, b = (vertices[fem.boundary_facets(cells)[:, k]] for k in range(2))
    ab = (b - a)[None]
    t = np.clip(np.einsum("mej,mej->me", points[:, None] - a[None], ab) / np.einsum("mej,mej->me", ab, ab), 0, 1)
    brute = np.linalg.norm(points[:, None] - (a[None] + t[..., None] * ab), axis=2).min(axis=1)
    np.testing.assert_allclose(distance[outside], brute[outside], atol=1e-12)
    # Inside points: reproduced exactly, whatever their distance to the boundary.
    np.testing.assert_allclose((P @ vertices)[~outside], points[~outside], atol=1e-14)
    assert np.all(brute[outside] > 0)


def test_performance_smoke_200k_points_3d():
    rng = np.random.default_rng(70)
    vertices, cells = delaunay_box_mesh(3, 2000, rng)
    points = rng.uniform(-0.1, 1.1, (200_000, 3))
    P, outside, distance = interpolation_matrix(vertices, cells, points)
    assert P.shape == (200_000, len(vertices))
    np.testing.assert_allclose(np.asarray(P.sum(axis=1)).ravel(), 1.0, atol=1e-14)
    np.testing.assert_allclose(distance, box_distance(points, np.zeros(3), np.ones(3)), atol=1e-12)


def test_progress_is_reported_and_cancel_raises():
    rng = np.random.default_rng(80)
    vertices, cells = delaunay_box_mesh(2, 50, rng)
    points = rng.uniform(0.0, 1.0, (200_000, 2))  # several batches
    fractions = []
    interpolation_matrix(vertices, cells, points, progress=lambda fraction, message: fractions.append(fraction))
    assert fractions[0] == 0.0 and fractions[-1] == 1.0
    assert np.all(np.diff(fractions) >= 0) and len(fractions) > 3
    calls = []
    with pytest.raises(Cancelled):
        interpolation_matrix(vertices, cells, points, cancel=lambda: calls.append(1) or len(calls) > 2)


def test_no_points_and_invalid_inputs():
    vertices, cells = cube_grid_mesh([[0, 0]], 2)
    P, outside, distance = interpolation_matrix(vertices, cells, np.zeros((0, 2)))
    assert P.shape == (0, len(vertices)) and outside.shape == (0,) and distance.shape == (0,)
    with pytest.raises(ValueError):
        interpolation_matrix(vertices, cells, np.zeros((3, 3)))
    with pytest.raises(ValueError):
        interpolation_matrix(vertices, cells[:, :2], np.zeros((3, 2)))
    with pytest.raises(CageError):
        interpolation_matrix(vertices, cells, np.array([[0.5, np.nan]]))
