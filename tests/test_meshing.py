"""Domain meshing: the DomainMesh contract, exactly, on the paper's 2D cages and on real 3D cages.

The checks here are independent of lbc_core.meshing's internals: which cage facet a mesh boundary facet lies on is
found geometrically, and coverage is checked by summing areas per cage facet.
"""

import itertools
import time
import types
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import Delaunay

from lbc_core import meshing
from lbc_core.cage.make import make_cage
from lbc_core.cage.record import Cage
from lbc_core.kernel.geometry import closest_on_triangles, orient_positive, radius_ratios, signed_measures
from lbc_core.kernel.geometry import signed_radius_ratios_by_coordinate
from lbc_core.meshing import lattice, polygon, sizing, tetrahedra
from lbc_core.kernel.progress import Progress
from lbc_core.errors import CageError, Cancelled
from lbc_core.kernel.fem import boundary_facets
from lbc_core.io import read_cage

from helpers import random_cages

DATA = Path(__file__).parent / "data"
CAGES_2D = sorted(DATA.glob("*-control-edgeset.obj"))
CAGES_3D = {
    "gargoyle L12": DATA / "cages-3d" / "gargoyle" / "cage_L12.obj",
    "gargoyle L08": DATA / "cages-3d" / "gargoyle" / "cage_L08.obj",
    "clothing": DATA / "cages-3d" / "clothing" / "cage.obj",
}
# Fingers boxed side by side: slots 0.11 % of the diagonal wide between the finger boxes (tests/data/cages-3d).
HAND_CAGE = DATA / "cages-3d" / "hand" / "cage.obj"
CUBE_VERTICES = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
CUBE_QUADS = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]

has_triangle = polygon.triangle_module() is not None
METHODS_2D = ["delaunay", pytest.param("triangle", marks=pytest.mark.skipif(not has_triangle, reason="no triangle"))]


def load_cage(path):
    vertices, faces = read_cage(path)
    return make_cage(vertices, faces)


def cube_cage(scale=1.0, offset=0.0):
    """The unit cube given as six quads: make_cage splits each into two triangles (merged again by the artist)."""
    return make_cage(CUBE_VERTICES * scale + offset, CUBE_QUADS)


@pytest.fixture(scope="module")
def meshes_3d():
    """Each 3D test cage and its default mesh, made once for the module."""
    cages = {name: load_cage(path) for name, path in CAGES_3D.items()}
    cages["cube quads"] = cube_cage()
    return {name: (cage, meshing.mesh_domain(cage)) for name, cage in cages.items()}


# ------------------------------------------------------------------------------------------------ contract checks


def facet_measures(points, facets):
    """Length (2D) or area (3D) of each facet given by point indices."""
    corners = points[facets]
    if points.shape[1] == 2:
        return np.linalg.norm(corners[:, 1] - corners[:, 0], axis=1)
    return 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)


def on_facets(cage, points, tolerance):
    """(P, E) bool: whether each point lies on each cage facet, within ``tolerance`` (a length).

    A point lies on a facet when its barycentric coordinates there are all >= -tolerance / edge scale and its
    distance to the facet's line / plane is at most ``tolerance``.
    """
    corners = cage.surface_vertices[cage.facets]  # (E, d, d)
    origin, spans = corners[:, 0], corners[:, 1:] - corners[:, :1]  # spans: (E, d-1, d)
    offset = points[:, None, :] - origin[None]  # (P, E, d)
    gram = np.einsum("ekd,eld->ekl", spans, spans)
    coefficients = np.einsum("ekl,pel->pek", np.linalg.inv(gram), np.einsum("ekd,ped->pek", spans, offset))
    residual = offset - np.einsum("pek,ekd->ped", coefficients, spans)
    bary = np.concatenate([1.0 - coefficients.sum(axis=2, keepdims=True), coefficients], axis=2)
    scale = np.sqrt(np.einsum("ekd,ekd->e", spans, spans))
    inside = np.all(bary >= -tolerance / scale[None, :, None], axis=2)
    return inside & (np.linalg.norm(residual, axis=2) <= tolerance)


def check_contract(cage, mesh):
    """Every clause of the DomainMesh contract, exactly where it promises exactness.

    3D boundary triangles may straddle the split lines inside a planar region (coplanar facets, or facets bent by
    less than meshing.COPLANAR_ANGLE), never an edge between regions: each one's centroid lies on the cage, within
    round-off where the region is flat and within the bend otherwise.
    """
    d = cage.dim
    n_vertices = len(mesh.vertices)
    assert mesh.vertices.shape == (n_vertices, d) and mesh.cells.shape[1] == d + 1
    # Lagrange property: control point i is a mesh vertex at exactly its position, bit for bit.
    assert mesh.control_vertices.shape == (cage.n_control_points,)
    assert mesh.vertices[mesh.control_vertices].tobytes() == cage.vertices.tobytes()
    # Boundary vertices: barycentric coordinates valid, positions exactly their combination (summed from k = 0).
    bary, facet = mesh.boundary_bary, mesh.boundary_facet
    assert bary.shape == (len(mesh.boundary_vertices), d)
    assert np.all(bary >= 0.0) and np.allclose(bary.sum(axis=1), 1.0, rtol=0, atol=4e-16)
    corners = cage.surface_vertices[cage.facets[facet]]
    combination = bary[:, 0, None] * corners[:, 0]
    for k in range(1, d):
        combination = combination + bary[:, k, None] * corners[:, k]
    assert np.array_equal(mesh.vertices[mesh.boundary_vertices], combination)
    # The boundary vertices are exactly the vertices of the mesh's boundary, each listed once.
    boundary = boundary_facets(mesh.cells)
    assert len(np.unique(mesh.boundary_vertices)) == len(mesh.boundary_vertices)
    assert np.array_equal(np.unique(boundary), np.sort(mesh.boundary_vertices))
    # Every cell positively oriented, every vertex used; together they fill the cage's area / volume.
    measures = signed_measures(mesh.vertices, mesh.cells)
    assert measures.min() > 0
    assert len(np.unique(mesh.cells)) == n_vertices
    bend = bent_angle(cage) if d == 3 else 0.0
    # Far from the origin, coordinates themselves are only this precise (relative to the cage's size).
    offset = np.abs(cage.vertices).max() / cage.bbox_diagonal * np.finfo(float).eps
    assert measures.sum() == pytest.approx(cage.measure, rel=1e-11 + 10 * bend + 1e3 * offset)
    if d == 2:
        # Each mesh boundary edge lies on one cage edge, and per cage edge they add up to its length.
        tolerance = (1e-12 + 8 * offset) * cage.bbox_diagonal
        on = np.logical_and.reduce([on_facets(cage, mesh.vertices[boundary[:, k]], tolerance) for k in range(d)])
        assert on.any(axis=1).all(), "a mesh boundary edge straddles a cage corner or lies off the cage"
        covered = np.bincount(np.argmax(on, axis=1), facet_measures(mesh.vertices, boundary),
                              minlength=len(cage.facets))
        np.testing.assert_allclose(covered, facet_measures(cage.surface_vertices, cage.facets), rtol=1e-10)
        return
    # 3D: each boundary triangle on the cage (none straddles a feature edge), together as large as the cage.
    corners = mesh.vertices[boundary]
    size = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    gap = surface_distance(cage, corners.mean(axis=1))
    tolerance = (1e-12 + 8 * offset) * cage.bbox_diagonal + bend * size
    assert np.all(gap <= tolerance), "a boundary triangle straddles a feature edge"
    assert facet_measures(mesh.vertices, boundary).sum() == pytest.approx(
        facet_measures(cage.surface_vertices, cage.facets).sum(), rel=1e-11 + 10 * bend + 1e3 * offset)


def bent_angle(cage):
    """The largest angle (radians) between the normals of two facets sharing an edge, among those bent by less
    than meshing.COPLANAR_ANGLE (0 when the cage's planar parts are all exactly flat)."""
    corners = cage.surface_vertices[cage.facets]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    edges = np.sort(np.concatenate([cage.facets[:, [0, 1]], cage.facets[:, [1, 2]], cage.facets[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(len(cage.facets)), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    pairs = owner[order].reshape(-1, 2)
    first, second = normals[pairs[:, 0]], normals[pairs[:, 1]]
    # atan2 of sine and cosine: arccos of the cosine reads a bend below about 1e-8 rad as 0.
    angles = np.arctan2(np.linalg.norm(np.cross(first, second), axis=1), np.einsum("ij,ij->i", first, second))
    bent = angles[(angles < meshing.COPLANAR_ANGLE) & (angles > 1e-12)]
    return float(bent.max()) if len(bent) else 0.0


def surface_distance(cage, points):
    """Distance from each 3D point to the cage surface."""
    corners = cage.surface_vertices[cage.facets]
    best = np.full(len(points), np.inf)
    for k in range(len(corners)):
        squared, _ = closest_on_triangles(points, *np.broadcast_to(corners[k], (len(points), 3, 3)).transpose(1, 0, 2))
        best = np.minimum(best, np.sqrt(squared))
    return best


def min_angles(vertices, triangles):
    """Smallest angle of each triangle, in degrees."""
    corners = vertices[triangles]
    angles = []
    for k in range(3):
        u = corners[:, (k + 1) % 3] - corners[:, k]
        v = corners[:, (k + 2) % 3] - corners[:, k]
        cosine = np.einsum("ij,ij->i", u, v) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
        angles.append(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))
    return np.min(angles, axis=0)


# ----------------------------------------------------------------------------------------------------------- 2D


@pytest.mark.parametrize("vertices, faces", [
    ([[0, 0], [1, 0], [0.2, 1]], None),
    ([[0, 0], [0.2, 1], [1, 0]], None),  # clockwise
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
    ([[0, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1]], [[0, 1, 2], [0, 2, 3], [0, 3, 1], [2, 1, 3]]),  # mirrored
], ids=["triangle", "clockwise triangle", "tetrahedron", "mirrored tetrahedron"])
def test_simplex_domain_is_the_cage_itself(vertices, faces):
    cage = make_cage(np.array(vertices, dtype=float), faces)
    mesh = meshing.simplex_domain(cage)
    check_contract(cage, mesh)
    assert len(mesh.cells) == 1 and len(mesh.vertices) == cage.dim + 1


def test_simplex_domain_refuses_other_cages():
    with pytest.raises(ValueError, match="simplex cage has 3 control points, this one 4"):
        meshing.simplex_domain(make_cage(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float), None))


@pytest.mark.parametrize("method", METHODS_2D)
@pytest.mark.parametrize("path", CAGES_2D, ids=lambda p: p.name.split("-")[0])
def test_2d_contract_and_size(path, method):
    cage = load_cage(path)
    mesh = meshing.mesh_domain(cage, method=method)
    check_contract(cage, mesh)
    assert len(mesh.cells) == pytest.approx(meshing.DEFAULT_CELLS_2D, rel=0.1)


@pytest.mark.parametrize("path", CAGES_2D, ids=lambda p: p.name.split("-")[0])
def test_2d_delaunay_quality_matches_triangle(path):
    """Smallest angle per triangle, measured on the four cages: Triangle 25.8° to 28.0° at worst (1st percentile 33°,
    mean 46.7°, 3156 to 3224 triangles); Delaunay 28.5° to 32.2° (1st percentile 34.6° to 35.8°, mean 55.5° to
    57.4°, 2990 to 2998 triangles)."""
    cage = load_cage(path)
    delaunay = meshing.mesh_domain(cage, method="delaunay")
    angles = min_angles(delaunay.vertices, delaunay.cells)
    assert angles.min() > 27.0 and np.percentile(angles, 1) > 33.0 and angles.mean() > 54.0
    if has_triangle:
        reference = meshing.mesh_domain(cage, method="triangle")
        assert angles.min() >= min_angles(reference.vertices, reference.cells).min() - 1.0
        # Same boundary samples as Triangle: the boundary values see the same resolution.
        assert len(delaunay.boundary_vertices) == len(reference.boundary_vertices)


def test_2d_same_boundary_samples_as_the_reference_solver():
    """The reference packs' boundary vertex counts are those of its sizing rule, which both methods follow."""
    for path in CAGES_2D:
        reference = np.load(path.with_name(path.name.replace("-control-edgeset.obj", ".npz")))
        mesh = meshing.mesh_domain(load_cage(path), method="delaunay")
        assert len(mesh.boundary_vertices) == len(reference["boundary_vertex"])


def test_2d_auto_is_the_bundled_mesher_with_or_without_triangle(monkeypatch):
    """"auto" gives the same mesh (so the same weights) in the CLI, where Triangle may be installed, and in Blender,
    where it never is; Triangle only when asked for by name."""
    cage = load_cage(CAGES_2D[0])
    auto = meshing.mesh_domain(cage, method="auto")
    delaunay = meshing.mesh_domain(cage, method="delaunay")
    assert np.array_equal(auto.cells, delaunay.cells) and np.array_equal(auto.vertices, delaunay.vertices)
    monkeypatch.setattr(polygon, "triangle_module", lambda: None)
    with pytest.raises(ImportError, match="delaunay"):
        meshing.mesh_domain(cage, method="triangle")
    without = meshing.mesh_domain(cage, method="auto")
    assert np.array_equal(auto.cells, without.cells) and np.array_equal(auto.vertices, without.vertices)


@pytest.mark.parametrize("method", METHODS_2D)
def test_2d_few_cells_and_negative_zero(method):
    """A coarse mesh of a square with a -0.0 coordinate: the control point keeps its sign bit."""
    cage = make_cage(np.array([[-0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))
    mesh = meshing.mesh_domain(cage, cells=10, method=method)
    check_contract(cage, mesh)
    assert np.signbit(mesh.vertices[mesh.control_vertices[0], 0])


@pytest.mark.parametrize("cells", [500, 20000])
def test_2d_delaunay_cell_count_follows_the_target(cells):
    cage = load_cage(CAGES_2D[0])
    mesh = meshing.mesh_domain(cage, cells=cells, method="delaunay")
    check_contract(cage, mesh)
    assert len(mesh.cells) == pytest.approx(cells, rel=0.1)


# ----------------------------------------------------------------------------------------------------------- 3D


@pytest.mark.slow
@pytest.mark.parametrize("name", list(CAGES_3D) + ["cube quads"])
def test_3d_contract_and_size(meshes_3d, name):
    cage, mesh = meshes_3d[name]
    check_contract(cage, mesh)
    assert len(mesh.cells) == pytest.approx(meshing.DEFAULT_CELLS_3D, rel=0.2)


@pytest.mark.parametrize("name", list(CAGES_3D) + ["cube quads"])
def test_3d_tetrahedra_quality(meshes_3d, name):
    """Radius ratios (3 inradius / circumradius, 1 for a regular tetrahedron). Measured at the default size: mean
    0.78 to 0.85, 1st percentile 0.24 to 0.28; below 0.1: 1 to 6 (0.08 % at most), of which at most 4 have a corner
    off the cage (clothing)."""
    _, mesh = meshes_3d[name]
    corners = mesh.vertices[mesh.cells]
    edges = corners[:, 1:] - corners[:, :1]
    volume = np.linalg.det(edges) / 6.0
    area = sum(np.linalg.norm(np.cross(corners[:, b] - corners[:, a], corners[:, c] - corners[:, a]), axis=1) / 2
               for a, b, c in [(1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)])
    lengths2 = np.einsum("tkd,tkd->tk", edges, edges)
    numerator = (lengths2[:, 0, None] * np.cross(edges[:, 1], edges[:, 2])
                 + lengths2[:, 1, None] * np.cross(edges[:, 2], edges[:, 0])
                 + lengths2[:, 2, None] * np.cross(edges[:, 0], edges[:, 1]))
    ratio = 9.0 * volume / (area * np.linalg.norm(numerator, axis=1) / (12.0 * volume))
    assert ratio.mean() > 0.75 and np.percentile(ratio, 1) > 0.2
    slivers = mesh.cells[ratio < 0.1]
    assert len(slivers) <= 3e-3 * len(ratio)
    with_free_corner = ~np.all(np.isin(slivers, mesh.boundary_vertices), axis=1)
    assert np.count_nonzero(with_free_corner) <= 1e-3 * len(ratio)


@pytest.mark.slow
def test_3d_cell_count_follows_the_target():
    cage = load_cage(CAGES_3D["gargoyle L12"])
    for cells in (2000, 30000):
        mesh = meshing.mesh_domain(cage, cells=cells)
        assert len(mesh.cells) == pytest.approx(cells, rel=0.2)
    check_contract(cage, mesh)


def test_signed_radius_ratios():
    regular = np.array([[1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]])
    flat = regular.copy()
    flat[3] = regular[:3].mean(axis=0)
    corners = np.stack([regular, regular[[1, 0, 2, 3]], flat])  # (T, 4, 3)
    ratios = signed_radius_ratios_by_coordinate(np.ascontiguousarray(corners.transpose(2, 1, 0)))
    assert ratios[:2] == pytest.approx([1.0, -1.0]) and abs(ratios[2]) < 1e-12


def test_polish_raises_the_worst_tetrahedra_and_keeps_the_surface():
    """Moving the free corners of poor tetrahedra (the tetrahedra kept) never lowers the least radius ratio, never
    inverts a tetrahedron and never moves a fixed vertex; on random points (slivers everywhere) it removes some."""
    rng = np.random.default_rng(3)
    fixed = np.array(np.meshgrid([0.0, 1.0], [0.0, 1.0], [0.0, 1.0])).reshape(3, -1).T
    points = np.concatenate([fixed, rng.uniform(0.1, 0.9, (300, 3))])
    tets = orient_positive(points, Delaunay(points).simplices)
    polished = tetrahedra.polish(points, tets, np.arange(len(points)) >= len(fixed), 0.15, rng,
                                 Progress.of(None, None))
    assert np.array_equal(polished[:len(fixed)], fixed)
    assert np.all(signed_measures(polished, tets) > 0)
    before, after = radius_ratios(points, tets), radius_ratios(polished, tets)
    assert after.min() > before.min()
    assert np.count_nonzero(after < 0.1) < np.count_nonzero(before < 0.1)


def test_depth_in_convex_cage_is_the_distance_to_its_surface():
    """Inside a convex cage the least distance to the facets' planes is the distance to the surface, negative
    outside; a cage dented by 1e-3 is not convex, one dented by up to 1e-4 of its size still counts as convex."""
    cage = cube_cage()
    points = np.random.default_rng(0).uniform(-0.5, 1.5, (500, 3))
    depth = lattice._depth_in_convex(cage, points)
    corners = cage.surface_vertices[cage.facets]
    squared = np.min([closest_on_triangles(points, *np.broadcast_to(c[:, None], (3, len(points), 3)))[0]
                      for c in corners], axis=0)
    inside = np.all((points > 0.0) & (points < 1.0), axis=1)
    assert depth[inside] == pytest.approx(np.sqrt(squared[inside]), abs=1e-12)
    assert np.all(depth[~inside] < 0.0)
    for dent, convex in ((1e-3, False), (1e-5, True), (1e-9, True)):
        vertices = CUBE_VERTICES.copy()
        vertices[7] -= dent  # the corner (1, 1, 1) moved towards the centre
        assert (lattice._depth_in_convex(make_cage(vertices, CUBE_QUADS), points) is not None) == convex


@pytest.mark.parametrize("cage", [cube_cage(), make_cage(CUBE_VERTICES[[0, 1, 2, 4]], [[0, 2, 1], [0, 1, 3],
                                                                                          [0, 3, 2], [1, 2, 3]])],
                         ids=["cube", "tetrahedron"])
def test_convex_cages_lattice_as_the_general_band_test(cage, monkeypatch):
    """The plane-distance shortcut for convex cages keeps exactly the lattice points the general band and inside
    tests keep: the same mesh, bit for bit."""
    fast = meshing.mesh_domain(cage, cells=2000)
    monkeypatch.setattr(lattice, "_depth_in_convex", lambda cage, points: None)
    general = meshing.mesh_domain(cage, cells=2000)
    assert np.array_equal(fast.vertices, general.vertices) and np.array_equal(fast.cells, general.cells)


def test_small_cages_lattice_as_the_general_band_test(monkeypatch):
    """A small non-convex cage (a cube with a corner pushed in by a tenth) measures the lattice band against its
    facets directly; it keeps exactly the points the search through the regions' small triangles keeps."""
    vertices = CUBE_VERTICES.copy()
    vertices[7] -= 0.1
    cage = make_cage(vertices, CUBE_QUADS)
    assert lattice._depth_in_convex(cage, vertices) is None and len(cage.facets) <= lattice._FEW_FACETS
    few = meshing.mesh_domain(cage, cells=2000)
    monkeypatch.setattr(lattice, "_FEW_FACETS", 0)
    general = meshing.mesh_domain(cage, cells=2000)
    assert np.array_equal(few.vertices, general.vertices) and np.array_equal(few.cells, general.cells)


def test_3d_coarse_cube_and_deterministic():
    """Ten cells for a cube: almost only the cage itself; the same input always gives the same mesh."""
    cage = cube_cage(scale=3.0, offset=-1.0)
    first = meshing.mesh_domain(cage, cells=10)
    check_contract(cage, first)
    second = meshing.mesh_domain(cage, cells=10)
    assert np.array_equal(first.vertices, second.vertices) and np.array_equal(first.cells, second.cells)


def subdivided_cube_cage(cuts):
    """Blender's Cube subdivided ``cuts`` times, as a Cage."""
    return make_cage(*random_cages.subdivided_cube(cuts))


@pytest.mark.slow
@pytest.mark.parametrize("cuts", [6, 7, 9, 12])
def test_3d_subdivided_cube_meshes_at_the_default_cells(cuts):
    """A new user's subdivided cubes were refused: four grid samples of a face lie on a circle, and the tetrahedra
    kept ended on the other diagonal of their quad than the surface's triangles (6, 7 cuts); four across a cube edge
    left a flat cell (9 cuts); refining tied quads cascaded past the sample budget (12 cuts, 16 s)."""
    cage = subdivided_cube_cage(cuts)
    check_contract(cage, meshing.mesh_domain(cage))


def test_3d_tied_quads_take_the_tetrahedralisation_split():
    """Two surface triangles splitting a quad along a-b, missing from a tetrahedralisation that splits it along p-q,
    are replaced by that split, oriented alike; a missing pair whose other split is absent is kept."""
    a, b, p, q, x, y = range(6)
    points = np.array([[0, 0, 0], [1, 1, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [-1, -1, 0]], dtype=float)
    triangles = np.array([[a, b, p], [b, a, q], [x, y, a]])
    samples = types.SimpleNamespace(points=points, triangles=triangles, triangle_region=np.zeros(3, dtype=np.int64))
    faces = np.sort(np.array([[a, q, p], [q, b, p], [x, y, a]]), axis=1)
    taken = tetrahedra._take_tied_splits(samples, np.array([True, True, False]), faces)
    assert taken.tolist() == [[a, q, p], [q, b, p], [x, y, a]]
    kept = tetrahedra._take_tied_splits(samples, np.array([True, True, False]), faces[2:])
    assert np.array_equal(kept, triangles)
    # A quad that is not convex: its other split would fold over the surface.
    samples.points = points + np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0], [2, 1.5, 0], [0, 0, 0], [0, 0, 0]])
    assert np.array_equal(tetrahedra._take_tied_splits(samples, np.array([True, True, False]), faces), triangles)


def test_3d_flat_cell_between_two_splits_is_flipped_away():
    """A flat cell between a square's two splits, a pyramid over the square on one side: the pyramid is split along
    the other diagonal, the flat cell goes, and the four cells left tile the octahedron conformingly."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1], [0.5, 0.5, -1]], dtype=float)
    a, b, c, d, top, bottom = range(6)
    tets = orient_positive(vertices, np.array([[top, a, b, c], [top, a, c, d], [bottom, a, b, d], [bottom, b, c, d],
                                               [a, b, c, d]]))
    flipped = tetrahedra._flip_flat(vertices, tets, n_surface=6)
    assert len(flipped) == 4 and np.all(signed_measures(vertices, flipped) > 0)
    assert np.isclose(signed_measures(vertices, flipped).sum(), 2.0 / 3.0)
    faces = np.sort(np.concatenate([np.delete(flipped, k, axis=1) for k in range(4)]), axis=1)
    _, count = np.unique(faces, axis=0, return_counts=True)
    assert np.count_nonzero(count == 2) == 4 and np.count_nonzero(count == 1) == 8


@pytest.mark.slow
def test_3d_a_fine_cage_refused_at_few_cells_is_told_to_try_more():
    """12 cuts (1016 vertices) at 2000 cells still leave a flat cell, among surface samples alone with no pyramid on
    either side; the refusal says to try more cells, which mesh it."""
    cage = subdivided_cube_cage(12)
    with pytest.raises(CageError, match=r"^this cage has 1016 vertices for about 2000 cells, few for so fine a cage: "
                                        r"try more cells \(4000\)\. The mesher said: the mesh has flat"):
        meshing.mesh_domain(cage, cells=2000)
    check_contract(cage, meshing.mesh_domain(cage, cells=4000))


def test_3d_overlapping_cage_is_refused():
    """Two interpenetrating cubes enclose their overlap twice. make_cage refuses such a cage (self-intersection,
    two parts); a Cage assembled by hand gets past it, and meshing names the problem instead of meshing garbage."""
    first, second = cube_cage(), cube_cage(offset=0.5)
    cage = Cage(
        vertices=np.concatenate([first.vertices, second.vertices]),
        facets=np.concatenate([first.facets, second.facets + len(first.vertices)]),
        facet_face=np.concatenate([first.facet_face, second.facet_face + 6]),
        vertex_map=np.arange(16),
    )
    with pytest.raises(CageError, match="pass through itself"):
        meshing.mesh_domain(cage, cells=2000)


def count_tetrahedralisations(monkeypatch, events=None):
    """Count the mesher's Delaunay tetrahedralisations (appended to ``events`` as they happen)."""
    calls = []

    def counted(points, qhull_options=None):
        calls.append(len(points))
        if events is not None:
            events.append("tetrahedralisation")
        return Delaunay(points, qhull_options=qhull_options)

    monkeypatch.setattr(tetrahedra, "Delaunay", counted)
    return calls


def test_3d_fingers_close_together_mesh_in_few_rounds(monkeypatch):
    """A hand's cage with its finger boxes 0.11 % of the diagonal apart. Refining one missing surface triangle at a
    time along the slots between them took 12 and 14 rounds, each a tetrahedralisation (28 in all, the second pass
    correcting the cell count); the walls facing each other across a slot are now sampled finely from the start."""
    calls = count_tetrahedralisations(monkeypatch)
    cage = load_cage(HAND_CAGE)
    mesh = meshing.mesh_domain(cage)
    check_contract(cage, mesh)
    assert len(calls) <= 16, f"{len(calls)} tetrahedralisations"
    # Slivers along the slots: 4.7 % of the tetrahedra had a radius ratio below 0.1 that way, 2.3 % now.
    ratios = radius_ratios(mesh.vertices, mesh.cells)
    assert ratios.mean() > 0.5 and np.mean(ratios < 0.1) < 0.03


def test_3d_fingers_two_cube_sides_across_mesh_in_one_pass(monkeypatch):
    """The hand's fingers are about two lattice cube sides across and face each other across slots: its samples
    along the slots, and the band that leaves little lattice inside the fingers, made 44 % more cells than the
    volume asked for, and a second conforming tetrahedralisation corrected it. The side is now counted before: one
    pass, on target."""
    passes = []
    conforming = tetrahedra._conforming_delaunay
    monkeypatch.setattr(tetrahedra, "_conforming_delaunay", lambda *args: passes.append(1) or conforming(*args))
    cage = load_cage(HAND_CAGE)
    mesh = meshing.mesh_domain(cage)
    check_contract(cage, mesh)
    assert len(passes) == 1
    assert len(mesh.cells) == pytest.approx(meshing.DEFAULT_CELLS_3D, rel=0.1)


def test_3d_sizing_counts_towards_the_target_within_its_bounds():
    """The side counted next follows the count's power of the side, and stays within MOST_SIDE_CHANGE of the
    volume's side: a count that hardly falls (the samples of a narrow gap) does not send it far off."""
    target = sizing.Sizing(8000, 0.04)
    first = target.candidate(0.04, 800, 2500)  # 12,188 predicted, mostly surface samples
    second_side = target.next_side([first])
    assert 0.04 < second_side <= 0.04 * sizing.MOST_SIDE_CHANGE
    assert second_side == pytest.approx(0.04 * (first.predicted / 8000) ** (1 / 2.25), rel=0.05)
    floor = target.candidate(0.04 * sizing.MOST_SIDE_CHANGE, 10, 3000)  # at the bound, still 14 % over
    assert target.next_side([first, floor]) is None
    assert target.near(target.candidate(0.04, 0, 8000 / sizing.CELLS_PER_SAMPLE))


def notched_block(angle_degrees):
    """Two boxes joined by a web: a block with a V notch cut down to a crease, its two walls meeting there at
    ``angle_degrees`` and facing each other (the web between two fingers)."""
    half_width = 0.8 * np.tan(np.radians(angle_degrees) / 2.0)
    profile = np.array([[0, 0], [2, 0], [2, 1], [1 + half_width, 1], [1, 0.2], [1 - half_width, 1], [0, 1]])
    n = len(profile)
    vertices = np.concatenate([np.c_[profile, np.zeros(n)], np.c_[profile, np.ones(n)]])
    faces = [list(range(n))[::-1], list(range(n, 2 * n))] + [[i, (i + 1) % n, n + (i + 1) % n, n + i] for i in range(n)]
    return vertices, faces


def test_3d_forecast_tells_the_work_of_narrow_wedges():
    """Walls meeting at a small angle and facing each other (a finger web) make meshing refine round after round: the
    time told before a bind counts them (pgc_hand: 7 s of meshing told as under 1 s before), and no other cage's."""
    from lbc_core.binding.options import BindOptions
    from lbc_core.binding.pipeline import check_request

    cages = {angle: make_cage(*notched_block(angle)) for angle in (1.0, 2.0, 30.0)}
    work = {angle: sizing.wedge_work(cage.surface_vertices, cage.facets) for angle, cage in cages.items()}
    assert work[30.0] == 1.0 and work[1.0] > work[2.0] > 1.0
    cube = cube_cage()
    assert sizing.wedge_work(cube.surface_vertices, cube.facets) == 1.0
    told = []
    vertices, faces = notched_block(1.0)
    check_request(vertices, faces, np.array([[0.5, 0.5, 0.5]]), BindOptions(),
                  progress=lambda fraction, message: told.append(message))
    assert told[0].startswith("meshing roughly ") and " s, then solving" in told[0]


def test_3d_meshing_reads_no_clock(monkeypatch):
    """Meshing's budgets are counts of work: a clock that runs a thousand seconds between two readings (a machine
    under heavy load) gives the same mesh, bit for bit. A deadline used to end the refinement along the hand's slots,
    so a bind under load got other cells (11,549 against 8830 on a user's hand)."""
    cage = load_cage(HAND_CAGE)
    expected = meshing.mesh_domain(cage)
    ticks = itertools.count(0.0, 1000.0)
    monkeypatch.setattr(time, "perf_counter", lambda: next(ticks))
    monkeypatch.setattr(time, "monotonic", lambda: next(ticks))
    mesh = meshing.mesh_domain(cage)
    assert np.array_equal(mesh.vertices, expected.vertices) and np.array_equal(mesh.cells, expected.cells)


def test_3d_refinement_stops_when_its_work_budget_is_spent(monkeypatch):
    """The last guard is a count: the points handed to the tetrahedraliser in all. The hand's slots need a few
    rounds of refinement; a budget of two rounds' points refuses the cage, naming faces, as the deadline did."""
    calls = count_tetrahedralisations(monkeypatch)
    monkeypatch.setattr(sizing, "WORK_PER_CELL", 0)
    monkeypatch.setattr(sizing, "WORK_BASE", 12_000)
    with pytest.raises(CageError, match="could not make the tetrahedra follow the cage surface near its faces"):
        meshing.mesh_domain(load_cage(HAND_CAGE))
    assert sum(calls) <= 12_000


def test_3d_progress_is_reported_between_any_two_tetrahedralisations(monkeypatch):
    """Each refinement round tells how many surface triangles are left: the hand's rounds ran with the bar standing
    still (9 reports for 28 tetrahedralisations, up to 2.5 s apart)."""
    events = []
    count_tetrahedralisations(monkeypatch, events)
    meshing.mesh_domain(load_cage(HAND_CAGE), progress=lambda fraction, message: events.append(fraction))
    assert "tetrahedralisation" in events
    assert all(not (a == b == "tetrahedralisation") for a, b in zip(events, events[1:]))
    fractions = [event for event in events if event != "tetrahedralisation"]
    assert fractions == sorted(fractions)


def test_3d_only_walls_facing_across_a_narrow_gap_are_sampled_finer():
    """A slot 1e-3 wide in a prism: its two walls face each other and are sampled finer from the start; the slot's
    end, the faces around its mouth (beside each other, not facing) and every other region keep the spacing, and a
    cube, facing nothing near, is sampled as before."""
    from lbc_core.meshing.surface import GAP_SPACING, Surface

    from test_meshing_corpus import slotted_prism

    def surface(cage, band):
        return Surface(cage, 0.05, np.random.default_rng(0), 10**6, band=band)

    slotted = surface(slotted_prism(1e-3), 0.035)
    walls = np.unique(slotted.region[np.isin(slotted.cage.facet_face, [4, 6])])  # the faces at y = 0.5 ± gap / 2
    assert sorted(np.flatnonzero(slotted.near)) == sorted(walls)
    assert np.allclose(slotted.region_spacing[walls], GAP_SPACING * np.sqrt(1e-3 * 0.035), rtol=1e-6)
    cube = cube_cage()
    assert not surface(cube, 0.035).near.any()
    plain, again = surface(cube, None), surface(cube, 0.035)
    assert np.array_equal(plain.samples(Progress()).points, again.samples(Progress()).points)


def test_3d_walls_facing_across_a_wedge_that_meets_at_their_edge_are_sampled_finer():
    """Two fingers of one cage meet at the web between them: their facing walls share a vertex or an edge there and
    open slowly towards the tips (a 43-vertex hand cage: 0.1 % of its diagonal across half a finger's length). Walls
    sharing a vertex were never taken as facing, so refinement found the gap one round at a time (40 rounds, twice,
    then a third attempt); they are sampled finer from the start, as a slot's walls are."""
    from lbc_core.meshing.surface import Surface

    profile = np.array([[0, 0], [1, 0], [1, 0.495], [0.3, 0.5], [1, 0.505], [1, 1], [0, 1]], dtype=float)
    n = len(profile)
    vertices = np.concatenate([np.c_[profile, np.zeros(n)], np.c_[profile, np.ones(n)]])
    faces = [list(range(n))[::-1], list(range(n, 2 * n))] + [[i, (i + 1) % n, n + (i + 1) % n, n + i] for i in range(n)]
    cage = make_cage(vertices, faces)  # faces 4 and 5 are the wedge's walls, meeting along x = 0.3, y = 0.5
    wedge = Surface(cage, 0.05, np.random.default_rng(0), 10**6, band=0.035)
    walls = np.unique(wedge.region[np.isin(cage.facet_face, [4, 5])])
    assert sorted(np.flatnonzero(wedge.near)) == sorted(walls)
    check_contract(cage, meshing.mesh_domain(cage, cells=2000))


# ----------------------------------------------------------------------------------------------- API behaviour


@pytest.mark.parametrize("cage", [load_cage(CAGES_2D[0]), cube_cage()], ids=["2D", "3D"])
def test_progress_and_cancel(cage):
    reports = []
    meshing.mesh_domain(cage, cells=500, progress=lambda fraction, message: reports.append((fraction, message)))
    fractions = [fraction for fraction, _ in reports]
    assert len(reports) >= 3 and fractions == sorted(fractions) and 0.0 <= fractions[0] and fractions[-1] == 1.0
    assert all(isinstance(message, str) and message for _, message in reports)
    with pytest.raises(Cancelled):
        meshing.mesh_domain(cage, cells=500, cancel=lambda: True)
    polls = []
    with pytest.raises(Cancelled):  # cancelled half-way, between two later steps
        meshing.mesh_domain(cage, cells=500, cancel=lambda: polls.append(1) or len(polls) > len(reports) // 2)


def test_bad_arguments():
    cage_2d, cage_3d = load_cage(CAGES_2D[0]), cube_cage()
    with pytest.raises(ValueError, match="triangle"):
        meshing.mesh_domain(cage_3d, method="triangle")  # Triangle is 2D only
    with pytest.raises(ValueError, match="'tetgen' is an unknown meshing method: use one of auto, delaunay, triangle"):
        meshing.mesh_domain(cage_2d, method="tetgen")
    with pytest.raises(ValueError, match="at least"):
        meshing.mesh_domain(cage_2d, cells=0)


def test_well_shaped_quads_are_surface_regions_triangle_by_triangle():
    """A quad's triangles are regions of their own where both are well shaped for the spacing (its diagonal a
    feature the mesh follows: a warm re-bind can carry the mesh onto the quad bent); skinny or small quads, n-gons and
    triangles keep merging with their coplanar neighbours."""
    from lbc_core.meshing.surface import SPLIT_MIN_EDGE, split_facets

    cube = make_cage(CUBE_VERTICES, CUBE_QUADS)
    assert split_facets(cube, 0.1).all()
    assert not split_facets(cube, 1.01 / SPLIT_MIN_EDGE).any()  # edges shorter than SPLIT_MIN_EDGE spacings
    flat_box = make_cage(CUBE_VERTICES * [1.0, 1.0, 0.3], CUBE_QUADS)  # sides with 16.7° at their diagonals
    assert split_facets(flat_box, 0.01).tolist() == [face in (4, 5) for face in flat_box.facet_face]  # z = 0, 1
    # No quad among an n-gon-capped prism's caps, poked into triangles: only the sides (the mesher sees the surface).
    angles = np.linspace(0.0, 2.0 * np.pi, 6, endpoint=False)
    ring = np.c_[np.cos(angles), np.sin(angles)]
    prism = make_cage(np.concatenate([np.c_[ring, np.zeros(6)], np.c_[ring, np.ones(6)]]),
                      [list(range(6))[::-1], list(range(6, 12))] + [[i, (i + 1) % 6, 6 + (i + 1) % 6, 6 + i]
                                                                    for i in range(6)])
    assert split_facets(prism.surface(), 0.01).tolist() == [face >= 2 for face in prism.facet_face]
    # The cube's mesh follows the diagonals: every boundary triangle lies within one cage facet.
    mesh = meshing.mesh_domain(cube, cells=2000)
    triangles = boundary_facets(mesh.cells)
    corners = cube.vertices[cube.facets]
    within = np.zeros(len(triangles), dtype=bool)
    for facet in range(len(cube.facets)):
        inside = np.ones(len(triangles), dtype=bool)
        for k in range(3):
            points = mesh.vertices[triangles[:, k]]
            squared, _ = closest_on_triangles(points, *[np.broadcast_to(c, points.shape) for c in corners[facet]])
            inside &= squared <= 1e-24
        within |= inside
    assert within.all()
