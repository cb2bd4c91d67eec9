"""Heat-method geodesic distances and the TV weights built from them."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import Delaunay

from lbc_core.cage.make import make_cage
from lbc_core.kernel.frame import UnitFrame
from lbc_core.solve.geodesics import geodesic_distances, heat_distances_sound, tv_weights
from lbc_core.meshing import mesh_domain


def grid_mesh(d, n):
    axis = np.linspace(-1.0, 1.0, n)
    points = np.stack(np.meshgrid(*[axis] * d, indexing="ij"), axis=-1).reshape(-1, d)
    points += np.random.default_rng(0).normal(0, 0.1 / n, points.shape)
    cells = Delaunay(points).simplices
    # Drop the long slivers Delaunay adds along the nearly flat hull: they would bridge the notch below.
    corners = points[cells]
    longest = np.max([np.linalg.norm(corners[:, i] - corners[:, j], axis=1)
                      for i in range(d + 1) for j in range(i)], axis=0)
    return points, cells[longest < 4.0 / n]


@pytest.mark.parametrize("d, n, tolerance", [(2, 41, 0.05), (3, 15, 0.08)])
def test_distances_approximate_euclidean_in_a_convex_domain(d, n, tolerance):
    points, cells = grid_mesh(d, n)
    source = np.argmin(np.linalg.norm(points, axis=1))
    distances = geodesic_distances(points, cells, np.array([source]))[:, 0]
    exact = np.linalg.norm(points - points[source], axis=1)
    inner = np.linalg.norm(points, axis=1) < 0.7  # the heat method's Neumann bias sits at the boundary
    assert distances[source] == 0
    assert np.abs(distances - exact)[inner].mean() < tolerance


def test_distances_go_around_a_notch():
    # A C-shaped 2D domain: from one arm's tip to the other, the geodesic runs around the inner wall.
    points, cells = grid_mesh(2, 41)
    in_notch = (points[:, 0] > -0.2) & (np.abs(points[:, 1]) < 0.2)
    cells = cells[~in_notch[cells].any(axis=1)]
    used = np.unique(cells)
    remap = -np.ones(len(points), dtype=int)
    remap[used] = np.arange(len(used))
    points, cells = points[used], remap[cells]
    a = np.argmin(np.linalg.norm(points - [0.9, 0.3], axis=1))
    b = np.argmin(np.linalg.norm(points - [0.9, -0.3], axis=1))
    distance = geodesic_distances(points, cells, np.array([a]))[b, 0]
    assert distance > 1.5 * np.linalg.norm(points[a] - points[b])


def thin_plate_domain(thickness, cells=2000):
    """The meshed interior of a 2 × 2 × ``thickness`` box cage (unit frame) and its control vertices."""
    corners = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-thickness / 2, thickness / 2)])
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    cage = make_cage(corners, faces)
    domain = mesh_domain(UnitFrame.of(cage).cage_to_unit(cage), cells, "auto")
    return domain.vertices, domain.cells, domain.control_vertices


def test_a_thin_plate_gets_distances_no_shorter_than_the_straight_line():
    """A new user's bent plate cage (1/50 as thick as wide) bulged out of the cage: on the flattened tetrahedra of so
    thin a mesh the heat step oscillates in sign and its distances collapsed to a few percent of the straight line, so
    every coordinate weighed nothing far from its vertex and spread over the whole plate. Whether the heat step
    collapses depends on the mesh: at 3000 cells it does (at 2000 the mesher's counted size now gives tetrahedra it
    copes with, median 0.96 of the straight line)."""
    vertices, cells, sources = thin_plate_domain(0.04, cells=3000)
    straight = np.linalg.norm(vertices[:, None] - vertices[sources][None], axis=2)
    distances = geodesic_distances(vertices, cells, sources)
    assert np.all(distances >= straight - 1e-12)
    far = straight > 0.25 * straight.max()
    assert np.median(distances[far] / straight[far]) < 1.1  # the plate is convex: nearly straight paths
    # The heat method's own distances fail the check there, and pass it on a thick box.
    import lbc_core.solve.geodesics as geodesics

    heat = geodesics._heat_distances_tetrahedra(vertices, cells, sources, geodesics.Progress.of(None))
    assert not heat_distances_sound(vertices, sources, heat)
    vertices, cells, sources = thin_plate_domain(1.0)
    assert heat_distances_sound(vertices, sources, geodesic_distances(vertices, cells, sources))


def test_a_thin_strip_gets_distances_no_shorter_than_the_straight_line():
    """The 2D counterpart: a strip 1/500 as wide as long fails the heat method's check (a third of its far pairs
    under 0.8 × the straight line), so its distances run along the edges too."""
    import lbc_core

    xs = np.linspace(-1.0, 1.0, 7)
    strip = np.r_[np.c_[xs, np.full(7, -0.001)], np.c_[xs[::-1], np.full(7, 0.001)]]
    domain = lbc_core.bind(strip, None, np.zeros((1, 2))).domain
    vertices, sources = domain.vertices, domain.control_vertices
    straight = np.linalg.norm(vertices[:, None] - vertices[sources][None], axis=2)
    assert np.all(geodesic_distances(vertices, domain.cells, sources) >= straight - 1e-12)


def test_tv_weights_shapes_and_choices():
    points, cells = grid_mesh(2, 11)
    distances = geodesic_distances(points, cells, np.array([0, len(points) - 1]))
    quadratic = tv_weights(cells, distances)
    linear = tv_weights(cells, distances, "linear")
    assert quadratic.shape == (len(cells), 2)
    assert 0 <= quadratic.min() and quadratic.max() <= 1
    np.testing.assert_allclose(quadratic, linear ** 2)
    np.testing.assert_allclose(tv_weights(cells, distances, "constant"), 1.0)
    np.testing.assert_allclose(tv_weights(cells, distances, lambda x: 2 * x), 2 * linear)
    with pytest.raises(ValueError, match="unknown weighting"):
        tv_weights(cells, distances, "cubic")
    with pytest.raises(ValueError, match="non-negative"):
        tv_weights(cells, distances, lambda x: -x)


@pytest.mark.parametrize("d, n", [(2, 11), (3, 6)])
def test_progress_is_reported_and_cancel_stops_between_sources(d, n, monkeypatch):
    import lbc_core.solve.geodesics as geodesics
    from lbc_core.errors import Cancelled

    monkeypatch.setattr(geodesics, "SOURCES_PER_CHUNK", 2)
    points, cells = grid_mesh(d, n)
    sources = np.arange(0, len(points), len(points) // 6)[:6]
    fractions = []
    distances = geodesic_distances(points, cells, sources,
                                   progress=lambda fraction, message: fractions.append(fraction))
    assert fractions == sorted(fractions) and fractions[-1] == 1.0 and len(fractions) >= 4
    assert np.all(distances[sources, np.arange(len(sources))] == 0)
    # Computed by chunks of two sources, the same distances as all at once.
    monkeypatch.setattr(geodesics, "SOURCES_PER_CHUNK", 8)
    np.testing.assert_allclose(geodesic_distances(points, cells, sources), distances, rtol=0, atol=1e-12)
    polls = []
    with pytest.raises(Cancelled):
        geodesic_distances(points, cells, sources, cancel=lambda: polls.append(1) or len(polls) > 2)


def test_tv_weights_of_the_paper_packs_match_the_reference():
    pack = dict(np.load(Path(__file__).parent / "data" / "LBClogo.npz"))
    distances = geodesic_distances(pack["vertices"], pack["triangles"], pack["control_vertex"])
    weights = tv_weights(pack["triangles"], distances)
    assert weights.shape == pack["tv_weights"].shape
    assert np.abs(weights - pack["tv_weights"]).mean() < 0.01
