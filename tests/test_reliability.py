"""Property-based tests (issue 6, item 2): random cages give a Cage or a CageError, never another exception.

Star-shaped cages (2D polygons with angularly sorted vertices, 3D radial surfaces over a sphere triangulation) are
simple by construction, so they must be accepted; perturbed ones (concave, possibly self-intersecting) may be refused,
but only with a CageError. Runs are kept small (a few seconds in all).
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog
from scipy.spatial import ConvexHull

from lbc_core.cage import Cage, _intersecting_triangles, make_cage
from lbc_core.errors import CageError

SMALL = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
lengths = st.floats(0.05, 1.0, allow_nan=False)


def cage_or_cage_error(vertices, faces=None):
    """make_cage's result, or None when it raised CageError; any other exception fails the test."""
    try:
        return make_cage(vertices, faces)
    except CageError as error:
        assert str(error), "a CageError must say what is wrong"
        return None


def assert_well_formed(cage, dim):
    """A Cage's facets enclose a positive measure and (3D) form a closed, consistently oriented surface."""
    assert isinstance(cage, Cage) and cage.dim == dim and cage.measure > 0
    if dim == 3:
        directed = np.concatenate([cage.facets[:, [0, 1]], cage.facets[:, [1, 2]], cage.facets[:, [2, 0]]])
        # Closed and consistently oriented: every directed edge once, and its reverse once.
        assert len(np.unique(directed, axis=0)) == len(directed)
        assert {tuple(e) for e in directed.tolist()} == {tuple(e) for e in directed[:, ::-1].tolist()}
    else:
        assert sorted(cage.facets[:, 0]) == list(range(cage.n_control_points))


def star_polygon(gaps, radii):
    """Vertices (n, 2) at angles spaced in proportion to ``gaps`` (a full turn) and distances ``radii``."""
    n = min(len(gaps), len(radii))
    angles = 2 * np.pi * np.cumsum(gaps[:n]) / np.sum(gaps[:n])
    return np.c_[np.cos(angles), np.sin(angles)] * np.asarray(radii[:n])[:, None], angles


def sphere_directions(n_points):
    """(n, 3) unit vectors (a Fibonacci spiral) and their convex hull's triangles (2n - 4, 3), outward."""
    index = np.arange(n_points) + 0.5
    polar, azimuth = np.arccos(1 - 2 * index / n_points), np.pi * (1 + 5**0.5) * index
    directions = np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)
    triangles = ConvexHull(directions).simplices
    a, b, c = (directions[triangles[:, k]] for k in range(3))
    inward = np.einsum("ij,ij->i", a, np.cross(b, c)) < 0
    return directions, np.where(inward[:, None], triangles[:, ::-1], triangles)


# ------------------------------------------------------------------------------------------------------ 2D polygons


@SMALL
@given(st.lists(lengths, min_size=3, max_size=40), st.lists(lengths, min_size=3, max_size=40), st.booleans())
def test_star_shaped_polygons_are_accepted(gaps, radii, clockwise):
    vertices, angles = star_polygon(gaps, radii)
    assume(np.max(np.diff(np.r_[0.0, angles])) < 0.9 * np.pi)  # the centre sees every edge: star-shaped
    cage = make_cage(vertices[::-1] if clockwise else vertices)
    assert_well_formed(cage, 2)
    assert cage.measure == pytest.approx(abs(_shoelace(vertices)))


@SMALL
@given(
    st.lists(lengths, min_size=3, max_size=30),
    st.lists(lengths, min_size=3, max_size=30),
    st.lists(st.tuples(st.floats(-0.6, 0.6), st.floats(-0.6, 0.6)), min_size=30, max_size=30),
)
def test_perturbed_polygons_give_a_cage_or_a_cage_error(gaps, radii, offsets):
    vertices, _ = star_polygon(gaps, radii)
    vertices = vertices + np.array(offsets[: len(vertices)])
    cage = cage_or_cage_error(vertices)
    if cage is not None:
        assert_well_formed(cage, 2)


def _shoelace(vertices):
    x, y = vertices.T
    return 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)


# ------------------------------------------------------------------------------------------------------ 3D cages


@SMALL
@given(st.integers(6, 120), st.data())
def test_star_shaped_polyhedra_are_accepted(n_points, data):
    directions, triangles = sphere_directions(n_points)
    radii = np.array(data.draw(st.lists(st.floats(0.2, 1.0), min_size=n_points, max_size=n_points)))
    flips = np.array(data.draw(st.lists(st.booleans(), min_size=len(triangles), max_size=len(triangles))))
    faces = np.where(flips[:, None], triangles[:, ::-1], triangles)  # orientation not consistent
    cage = make_cage(directions * radii[:, None], faces)
    assert_well_formed(cage, 3)
    assert len(cage.facets) == len(triangles)


@SMALL
@given(st.integers(6, 120), st.data())
def test_dented_polyhedra_give_a_cage_or_a_cage_error(n_points, data):
    directions, triangles = sphere_directions(n_points)
    radii = np.array(data.draw(st.lists(st.floats(0.3, 1.0), min_size=n_points, max_size=n_points)))
    vertices = directions * radii[:, None]
    # Push some vertices along one direction, deep enough to dent the surface or push it through itself.
    dented = np.array(data.draw(st.lists(st.booleans(), min_size=n_points, max_size=n_points)))
    push = np.array(data.draw(st.tuples(*[st.floats(-1.5, 1.5)] * 3)))
    vertices[dented] += push
    # Merge some neighbouring triangles into quads, as artists' cages have them.
    faces = [list(t) for t in triangles]
    if data.draw(st.booleans()):
        faces = _merge_into_quads(triangles)
    cage = cage_or_cage_error(vertices, faces)
    if cage is not None:
        assert_well_formed(cage, 3)


def _merge_into_quads(triangles):
    """Faces where each triangle that can be paired with an unused neighbour across its first edge becomes a quad."""
    owner = {}
    for index, (a, b, c) in enumerate(triangles.tolist()):
        for u, v, w in ((a, b, c), (b, c, a), (c, a, b)):
            owner[(u, v)] = (index, w)
    used, faces = set(), []
    for index, (a, b, c) in enumerate(triangles.tolist()):
        if index in used:
            continue
        other, far = owner[(b, a)]
        if other in used or other == index:
            faces.append([a, b, c])
            used.add(index)
            continue
        faces.append([a, far, b, c])
        used.update((index, other))
    return faces


# ------------------------------------------------------------------------------------------ triangle intersections

coordinates = st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3)


@settings(max_examples=60, deadline=None)
@given(st.lists(coordinates, min_size=6, max_size=6), st.integers(0, 2))
def test_triangle_intersection_agrees_with_a_linear_program(corners, shared):
    """The self-intersection test against an independent one: is there a point in both triangles (beyond the shared
    vertex) — a small linear program over the two triangles' barycentric coordinates."""
    corners = np.array(corners)
    first, second = corners[:3], corners[3:]
    second[:shared] = first[:shared]
    normal = np.cross(first[1] - first[0], first[2] - first[0])
    assume(np.linalg.norm(normal) > 1e-3 and np.linalg.norm(np.cross(second[1] - second[0], second[2] - second[0])) > 1e-3)
    # Keep generic positions: no corner within reach of the tolerance of the other triangle's plane.
    for a, b in ((first, second), (second, first)):
        n = np.cross(a[1] - a[0], a[2] - a[0])
        heights = (b[shared:] - a[0]) @ (n / np.linalg.norm(n))
        assume(np.all(np.abs(heights) > 1e-6))
    vertices = np.r_[first, second[shared:]]
    triangles = np.array([[0, 1, 2], [0, 1, 2][:shared] + list(range(3, 6 - shared))])
    found = len(_intersecting_triangles(vertices, triangles, 1e-12)) == 1
    assert found == _meet_beyond_shared(first, second, shared)


def _meet_beyond_shared(first, second, shared):
    """Whether the triangles share a point that is not a convex combination of their shared corners alone."""
    # Unknowns: barycentric coordinates (3 + 3), with first · λ = second · μ; minimise the weight λ puts on the
    # shared corners: the triangles meet beyond them when it can drop below 1.
    equalities = np.zeros((5, 6))
    equalities[:3, :3], equalities[:3, 3:] = first.T, -second.T
    equalities[3, :3] = equalities[4, 3:] = 1.0
    cost = np.r_[np.ones(shared), np.zeros(6 - shared)] if shared else np.zeros(6)
    result = linprog(cost, A_eq=equalities, b_eq=[0, 0, 0, 1, 1], bounds=[(0, None)] * 6)
    if result.status != 0:
        return False
    return shared == 0 or result.fun < 1 - 1e-7
