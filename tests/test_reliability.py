"""Property-based tests (issue 6, item 2): random cages give a Cage or a CageError, never another exception.

Star-shaped cages (2D polygons with angularly sorted vertices, 3D radial surfaces over a sphere triangulation) are
simple by construction, so they must be accepted; perturbed ones (concave, possibly self-intersecting) may be refused,
but only with a CageError. Runs are kept small (a few seconds in all).
"""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog
from scipy.spatial import ConvexHull

import lbc_core
from lbc_core.cage import Cage, _intersecting_triangles, make_cage
from lbc_core.errors import CageError
from lbc_core.io import read_mesh

DATA = Path(__file__).parent / "data"

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


def draw_dented_sphere(data, n_points, min_radius, max_push, shrink):
    """A sphere triangulation with random radii whose drawn subset of vertices is scaled by ``shrink`` and pushed by
    one random vector of components up to ``max_push``; returns (vertices (n, 3), triangles (T, 3))."""
    directions, triangles = sphere_directions(n_points)
    radii = np.array(data.draw(st.lists(st.floats(min_radius, 1.0), min_size=n_points, max_size=n_points)))
    vertices = directions * radii[:, None]
    dented = np.array(data.draw(st.lists(st.booleans(), min_size=n_points, max_size=n_points)))
    push = np.array(data.draw(st.tuples(*[st.floats(-max_push, max_push)] * 3)))
    vertices[dented] = vertices[dented] * shrink + push
    return vertices, triangles


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
    # Push some vertices along one direction, deep enough to dent the surface or push it through itself.
    vertices, triangles = draw_dented_sphere(data, n_points, min_radius=0.3, max_push=1.5, shrink=1.0)
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
    for triangle in (first, second):
        assume(np.linalg.norm(np.cross(triangle[1] - triangle[0], triangle[2] - triangle[0])) > 1e-3)
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


# ------------------------------------------------------------------------------------------- bound weights (bind)

# Quality bounds of lbc_core's results (issue 2, item 7), relative to the cage's bounding-box diagonal for lengths.
UNITY, REPRODUCTION, NEGATIVE = 1e-9, 1e-9, -1e-6
TINY = settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def bind_or_cage_error(vertices, faces, points, cells):
    """lbc_core.bind's Binding, or None when it raised CageError; any other exception fails the test."""
    try:
        binding = lbc_core.bind(vertices, faces, points, cells=cells)
    except CageError as error:
        assert str(error), "a CageError must say what is wrong"
        event(f"refused: {str(error).split(':')[0].split(' at ')[0]}")
        return None
    event("bound")
    return binding


def assert_quality(binding, points, inside):
    """The binding meets the quality bounds at the domain's vertices and at the points.

    Parameters
    ----------
    binding : lbc_core.Binding
    points : (m, d) float array
    inside : (m,) bool array
        Points known to lie inside the cage (away from its boundary): they must not be counted outside, and their
        weights reproduce them.
    """
    diagonal = binding.cage.bbox_diagonal
    controls = binding.cage.vertices
    # At the domain's vertices: the solve's own result.
    W = binding.domain_weights
    assert np.max(np.abs(W.sum(axis=1) - 1)) <= UNITY
    assert np.max(np.abs(W @ controls - binding.domain.vertices)) <= REPRODUCTION * diagonal
    assert W.min() >= NEGATIVE
    np.testing.assert_array_equal(W[binding.domain.control_vertices], np.eye(len(controls)))  # Lagrange
    # At the points: reduced sparse weights, bound exactly at the rest pose.
    weights = binding.weights.toarray()
    assert weights.shape == (len(points), len(controls))
    assert np.max(np.abs(weights.sum(axis=1) - 1), initial=0) <= UNITY
    assert weights.min(initial=0) >= NEGATIVE
    assert np.max(np.abs(weights[inside] @ controls - points[inside]), initial=0) <= REPRODUCTION * diagonal
    assert not np.any(binding.outside[inside])
    np.testing.assert_allclose(binding.deform(binding.cage.vertices[binding.cage.vertex_map]), points, rtol=0,
                               atol=1e-12 * diagonal)


def inside_polygon(polygon, points, margin):
    """Where points lie relative to a closed polygon (n, 2).

    Returns
    -------
    inside : (m,) bool array
        Inside by the even-odd rule.
    clear : (m,) bool array
        Farther than ``margin`` from every edge (where inside or outside is beyond doubt).
    """
    start, end = polygon, np.roll(polygon, -1, axis=0)
    # Even-odd rule: count the edges a ray towards +x crosses.
    straddle = (start[None, :, 1] > points[:, None, 1]) != (end[None, :, 1] > points[:, None, 1])
    t = (points[:, None, 1] - start[None, :, 1]) / np.where(end[:, 1] == start[:, 1], 1.0, end[:, 1] - start[:, 1])
    crossing_x = start[None, :, 0] + t * (end[None, :, 0] - start[None, :, 0])
    odd = np.count_nonzero(straddle & (crossing_x > points[:, None, 0]), axis=1) % 2 == 1
    along = end - start
    s = np.clip(np.einsum("mnj,nj->mn", points[:, None] - start[None], along) / np.sum(along**2, axis=1), 0, 1)
    distance = np.linalg.norm(points[:, None] - (start[None] + s[..., None] * along[None]), axis=2).min(axis=1)
    return odd, distance > margin


@TINY
@given(
    st.lists(lengths, min_size=4, max_size=12),  # triangles: test_simplex_cages_bind
    st.lists(lengths, min_size=4, max_size=12),
    st.floats(0.0, 0.4),
    st.integers(0, 2**32 - 1),
)
def test_random_polygons_bind_within_the_quality_bounds(gaps, radii, roughness, seed):
    rng = np.random.default_rng(seed)
    polygon, _ = star_polygon(gaps, radii)
    polygon = polygon + roughness * rng.uniform(-1, 1, polygon.shape)  # concave, sometimes self-intersecting
    points = rng.uniform(polygon.min(axis=0) - 0.1, polygon.max(axis=0) + 0.1, (100, 2))
    binding = bind_or_cage_error(polygon, None, points, cells=300)
    if binding is not None:
        inside, clear = inside_polygon(polygon, points, 1e-6)
        assert_quality(binding, points, inside & clear)
        np.testing.assert_array_equal(binding.outside[clear], ~inside[clear])  # outside points found and counted


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(6, 24), st.data())
def test_random_polyhedra_bind_within_the_quality_bounds(n_points, data):
    # Dent some vertices: towards the centre (still star-shaped) or sideways (concave, maybe self-intersecting).
    vertices, triangles = draw_dented_sphere(data, n_points, min_radius=0.4, max_push=0.4, shrink=0.6)
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    # Points near the centre (inside when the cage stays star-shaped around it) and anywhere around the cage.
    points = np.r_[rng.normal(scale=0.02, size=(50, 3)), rng.uniform(-1.2, 1.2, (50, 3))]
    binding = bind_or_cage_error(vertices, triangles, points, cells=2000)
    if binding is not None:
        # A point on the inner side of every facet's plane sees every facet from inside: it is inside the cage.
        inside = np.all(_inner_distances(binding.cage, points) > 1e-6, axis=1)
        assert_quality(binding, points, inside)


def _inner_distances(cage, points):
    """(m, E): distance of each point from each outward facet's plane, positive on the inner side."""
    a, b, c = (cage.vertices[cage.facets[:, k]] for k in range(3))
    normals = np.cross(b - a, c - a)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return np.einsum("ej,ej->e", a, normals)[None] - points @ normals.T


# ------------------------------------------------------------------------------- nothing lost; points outside; empty

STAR = star_polygon([1.0] * 8, [1.0, 0.5] * 4)[0]  # an 8-pointed concave star
GRID = np.stack(np.meshgrid(np.linspace(-1.2, 1.2, 13), np.linspace(-1.2, 1.2, 13)), axis=-1).reshape(-1, 2)


@pytest.fixture(scope="module")
def star_binding():
    return lbc_core.bind(STAR, None, GRID, cells=300)


@pytest.fixture(scope="module")
def clothing():
    """The clothing cage, its deformed pose and a binding of the garment's vertices (some outside the cage)."""
    folder = DATA / "cages-3d" / "clothing"
    cage, faces = read_mesh(folder / "cage.obj")
    posed, _ = read_mesh(folder / "cage_deformed.obj")
    mesh, _ = read_mesh(folder / "mesh.obj")
    return cage, faces, posed, lbc_core.bind(cage, faces, mesh, cells=2000)


def test_saved_polygon_binding_deforms_identically(tmp_path, star_binding):
    star_binding.save(tmp_path / "star.npz")
    loaded = lbc_core.load_binding(tmp_path / "star.npz", STAR)
    posed = STAR + np.random.default_rng(0).normal(scale=0.1, size=STAR.shape)
    np.testing.assert_array_equal(loaded.deform(posed), star_binding.deform(posed))
    np.testing.assert_array_equal(loaded.outside, star_binding.outside)


def test_saved_3d_binding_deforms_identically(tmp_path, clothing):
    cage, faces, posed, binding = clothing
    binding.save(tmp_path / "clothing.npz")
    loaded = lbc_core.load_binding(tmp_path / "clothing.npz", posed, faces)  # the posed cage has the same topology
    np.testing.assert_array_equal(loaded.deform(posed), binding.deform(posed))


def test_load_against_another_cage_is_refused(tmp_path, clothing):
    _, _, _, binding = clothing
    binding.save(tmp_path / "clothing.npz")
    # The gargoyle's L13 cage has as many vertices (18) and triangles (32) as the clothing cage, but other faces.
    other, other_faces = read_mesh(DATA / "cages-3d" / "gargoyle" / "cage_L13.obj")
    with pytest.raises(CageError, match="bound to another cage"):
        lbc_core.load_binding(tmp_path / "clothing.npz", other, other_faces)


def test_load_of_a_file_that_is_not_a_binding_is_refused(tmp_path):
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(CageError, match="not an lbc binding"):
        lbc_core.load_binding(tmp_path / "other.npz")


def test_deforming_with_a_cage_of_another_size_is_refused(star_binding):
    with pytest.raises(CageError, match="bind again"):
        star_binding.deform(STAR[:-1])


def test_mesh_partly_outside_is_bound_and_counted(star_binding):
    inside, clear = inside_polygon(STAR, GRID, 1e-6)
    assert 0 < star_binding.outside_count < len(GRID)
    np.testing.assert_array_equal(star_binding.outside[clear], ~inside[clear])
    # Bound: every point, outside ones included, follows an affine map of the cage exactly.
    affine = np.array([[1.2, 0.3], [-0.2, 0.9]])
    moved = star_binding.deform(STAR @ affine.T + [0.5, -1.0])
    np.testing.assert_allclose(moved[inside & clear], GRID[inside & clear] @ affine.T + [0.5, -1.0], atol=1e-9)
    np.testing.assert_array_equal(star_binding.deform(STAR), GRID)  # the rest pose is exact, outside too


def test_mesh_wholly_outside_is_bound_and_counted():
    far = np.array([[5.0, 0.0], [0.0, -4.0], [3.0, 3.0]])
    binding = lbc_core.bind(STAR, None, far, cells=300)
    assert binding.outside_count == 3
    np.testing.assert_allclose(binding.weights.sum(axis=1), 1.0, atol=UNITY)
    np.testing.assert_allclose(binding.deform(STAR + [1.0, 2.0]), far + [1.0, 2.0], atol=1e-12)


def test_empty_mesh_gives_an_empty_binding():
    binding = lbc_core.bind(STAR, None, np.zeros((0, 2)), cells=300)
    assert binding.weights.shape == (0, len(STAR)) and binding.outside_count == 0
    assert binding.deform(STAR).shape == (0, 2)


@pytest.mark.parametrize(
    "points, message",
    [
        (np.zeros((3, 4)), "must be an \\(m, 2\\) or \\(m, 3\\) array"),
        (np.array([[np.nan, 0.0]]), "NaN or infinite"),
    ],
)
def test_bad_points_are_refused(points, message):
    with pytest.raises(CageError, match=message):
        lbc_core.bind(STAR, None, points, cells=300)


def test_points_of_another_dimension_are_refused(clothing):
    cage, faces, _, _ = clothing
    with pytest.raises(CageError, match="the cage is 3D but the points are 2D"):
        lbc_core.bind(cage, faces, np.zeros((2, 2)))


def test_cancelled_bind_raises_cancelled():
    with pytest.raises(lbc_core.Cancelled):
        lbc_core.bind(STAR, None, GRID, cells=300, cancel=lambda: True)


def test_2d_points_given_with_a_z_coordinate():
    # File data: 2D points as (m, 3) with a constant z are bound; a varying z is refused.
    binding = lbc_core.bind(STAR, None, np.c_[GRID, np.full(len(GRID), 2.0)], cells=300)
    assert binding.weights.shape == (len(GRID), len(STAR))
    with pytest.raises(CageError, match="z varies"):
        lbc_core.bind(STAR, None, np.zeros((2, 3)) + [[0, 0, 0], [0, 0, 1]], cells=300)
