"""The geometry kernel (lbc_core/kernel/geometry.py) against independent references: determinants, brute-force sampling,
known shapes."""

import numpy as np
import pytest

from lbc_core.kernel.geometry import (
    circumspheres,
    closest_on_segments,
    closest_on_triangles,
    distance_to_segments,
    enclosed_measure,
    orient_positive,
    radius_ratios,
    signed_measures,
    winding_numbers,
)

RNG = np.random.default_rng(7)
CUBE = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
# The cube's faces as outward triangles.
CUBE_TRIANGLES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                           [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


@pytest.mark.parametrize("dim", [2, 3])
def test_signed_measures_are_the_determinant_over_d_factorial_and_orient_positive_makes_them_positive(dim):
    vertices = RNG.normal(size=(40, dim))
    cells = np.array([RNG.choice(40, dim + 1, replace=False) for _ in range(100)])
    determinant = np.linalg.det(vertices[cells[:, 1:]] - vertices[cells[:, :1]]) / (2.0 if dim == 2 else 6.0)
    np.testing.assert_allclose(signed_measures(vertices, cells), determinant, rtol=1e-12, atol=1e-14)
    oriented = orient_positive(vertices, cells)
    np.testing.assert_allclose(signed_measures(vertices, oriented), np.abs(determinant), rtol=1e-12, atol=1e-14)
    assert np.array_equal(np.sort(oriented, axis=1), np.sort(cells, axis=1))


def test_closest_points_on_triangles_and_segments_are_no_farther_than_any_sampled_point_and_lie_on_them():
    a, b, c = (RNG.normal(size=(50, 3)) for _ in range(3))
    points = RNG.normal(size=(50, 3)) * 2.0
    squared, bary = closest_on_triangles(points, a, b, c)
    assert np.all(bary >= -1e-12) and np.allclose(bary.sum(axis=1), 1.0)
    closest = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
    np.testing.assert_allclose(np.sum((points - closest) ** 2, axis=1), squared, rtol=1e-9, atol=1e-12)
    samples = RNG.dirichlet(np.ones(3), 4000)  # (S, 3) barycentric samples of every triangle
    sampled = samples[None, :, :1] * a[:, None] + samples[None, :, 1:2] * b[:, None] + samples[None, :, 2:] * c[:, None]
    assert np.all(squared <= np.min(np.sum((sampled - points[:, None]) ** 2, axis=2), axis=1) + 1e-12)

    squared, bary = closest_on_segments(points, a, b)
    t = np.linspace(0.0, 1.0, 2001)
    on_segments = a[:, None] + t[None, :, None] * (b - a)[:, None]
    assert np.all(squared <= np.min(np.sum((on_segments - points[:, None]) ** 2, axis=2), axis=1) + 1e-12)
    assert np.all(bary >= 0.0) and np.allclose(bary.sum(axis=1), 1.0)


def test_distance_to_segments_is_the_nearest_of_all_the_segments():
    starts, ends = RNG.normal(size=(30, 2)), RNG.normal(size=(30, 2))
    points = RNG.normal(size=(200, 2))
    each = np.stack([np.sqrt(closest_on_segments(points, np.repeat(s[None], 200, 0), np.repeat(e[None], 200, 0))[0])
                     for s, e in zip(starts, ends)], axis=1)
    np.testing.assert_allclose(distance_to_segments(points, starts, ends), each.min(axis=1), rtol=1e-12)
    assert np.all(np.isinf(distance_to_segments(points, starts[:0], ends[:0])))


def test_winding_numbers_and_enclosed_measures_of_a_cube_and_a_square_far_from_the_origin():
    inside, outside = np.array([[0.5, 0.5, 0.5], [0.1, 0.9, 0.2]]), np.array([[1.5, 0.5, 0.5], [-3.0, 2.0, 0.0]])
    np.testing.assert_allclose(winding_numbers(CUBE, CUBE_TRIANGLES, np.r_[inside, outside]), [1, 1, 0, 0],
                               atol=1e-12)
    far = np.array([1e6, -1e6, 1e6])
    assert enclosed_measure(CUBE + far, CUBE_TRIANGLES) == pytest.approx(1.0, rel=1e-9)
    assert enclosed_measure(CUBE, CUBE_TRIANGLES[:, ::-1]) == pytest.approx(-1.0)
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]) + 1e6
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])
    assert enclosed_measure(square, edges) == pytest.approx(4.0, rel=1e-9)
    np.testing.assert_allclose(winding_numbers(square, edges, square.mean(axis=0)[None]), [1.0])


def test_radius_ratios_are_one_for_a_regular_tetrahedron_and_near_zero_for_a_flat_one():
    regular = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 1e-6]])
    np.testing.assert_allclose(radius_ratios(np.r_[regular, flat], np.array([[0, 1, 2, 3], [4, 5, 6, 7]])),
                               [1.0, 0.0], atol=1e-5)


def test_radius_ratios_of_triangles_against_their_inradius_and_circumradius():
    corners = RNG.normal(size=(30, 3, 2))
    vertices, triangles = corners.reshape(-1, 2), np.arange(90).reshape(30, 3)
    a, b, c = (np.linalg.norm(corners[:, i] - corners[:, j], axis=1) for i, j in ((1, 2), (2, 0), (0, 1)))
    u, v = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    area = 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    inradius, circumradius = 2 * area / (a + b + c), a * b * c / (4 * area)
    np.testing.assert_allclose(radius_ratios(vertices, triangles), 2 * inradius / circumradius, rtol=1e-9)
    equilateral = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, np.sqrt(0.75)]])
    assert radius_ratios(equilateral, np.array([[0, 1, 2]]))[0] == pytest.approx(1.0)


def test_circumspheres_pass_through_every_corner_in_the_triangles_plane():
    points = RNG.normal(size=(60, 3))
    triangles = np.array([RNG.choice(60, 3, replace=False) for _ in range(40)])
    centres, radii = circumspheres(points, triangles)
    for k in range(3):
        np.testing.assert_allclose(np.linalg.norm(points[triangles[:, k]] - centres, axis=1), radii, rtol=1e-8)
    a, b, c = (points[triangles[:, k]] for k in range(3))
    np.testing.assert_allclose(np.einsum("ij,ij->i", centres - a, np.cross(b - a, c - a)), 0.0, atol=1e-8)


def test_polygon_mean_value_coordinates_reproduce_points_and_are_linear_on_edges_either_way_round():
    from lbc_core.kernel.geometry import polygon_mean_value_coordinates

    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    points = np.random.default_rng(4).uniform(0.05, 1.95, (50, 2))
    for polygon in (square, square[::-1]):
        weights = polygon_mean_value_coordinates(polygon, points, 1e-12)
        assert np.abs(weights.sum(axis=1) - 1).max() < 1e-12 and weights.min() > 0
        assert np.abs(weights @ polygon - points).max() < 1e-12
    centre_edge_corner = polygon_mean_value_coordinates(square, np.array([[1.0, 1.0], [0.5, 0.0], [2.0, 2.0]]), 1e-12)
    np.testing.assert_allclose(centre_edge_corner, [[0.25] * 4, [0.75, 0.25, 0, 0], [0, 0, 1, 0]], atol=1e-15)
