"""Cage checks: one test per entry of the bad-input catalogue (docs/what-can-go-wrong.md), plus the repairs
(welding, orientation) and the triangulation of quads and n-gons."""

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

import lbc_core.cage.make as cage_module
import lbc_core.kernel.intersections as intersections
from lbc_core.cage.make import MAX_CONTROL_POINTS, make_cage
from lbc_core.cage.record import Cage
from lbc_core.errors import CageError, CageVertexError
from lbc_core.kernel.intersections import intersecting_triangles, overlapping_boxes
from lbc_core.io import read_cage
from helpers.random_cages import draw_dented_sphere, lengths, sphere_directions, star_polygon, subdivided_cube

DATA = Path(__file__).parent / "data"

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
CUBE = np.array([[x, y, z] for z in (0.0, 1.0) for y in (0.0, 1.0) for x in (0.0, 1.0)])
CUBE_QUADS = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]  # outward
TETRA = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
TETRA_FACES = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]  # outward


def read_obj(path):
    """Vertices (n, 3) and faces (lists of 0-based indices) of an OBJ file."""
    vertices, faces = [], []
    for line in Path(path).read_text().splitlines():
        parts = line.split()
        if parts and parts[0] == "v":
            vertices.append([float(x) for x in parts[1:4]])
        elif parts and parts[0] == "f":
            faces.append([int(p.split("/")[0]) - 1 for p in parts[1:]])
    return np.array(vertices), faces


def sphere(n_points, seed=0):
    """A triangulated sphere (star-shaped, radii in [0.7, 1.3]): vertices (n, 3), triangles (2n - 4, 3)."""
    index = np.arange(n_points) + 0.5
    polar, azimuth = np.arccos(1 - 2 * index / n_points), np.pi * (1 + 5**0.5) * index
    directions = np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)
    radii = np.random.default_rng(seed).uniform(0.7, 1.3, n_points)
    return directions * radii[:, None], ConvexHull(directions).simplices


# A message that cites cage vertices by number ("vertex 3", "vertices (1, 2", "vertices 0-4"): what the add-on told
# apart by this text before the refusals that do so became CageVertexError.
CITES_VERTICES = re.compile(r"\bvert(ex|ices) \(?\d")


def assert_refused(vertices, faces, *words, **options):
    """make_cage raises CageError whose message contains every word (case-insensitive); a CageVertexError exactly
    when the message cites vertices by number."""
    with pytest.raises(CageError) as caught:
        make_cage(vertices, faces, **options)
    message = str(caught.value).lower()
    for word in words:
        assert word.lower() in message, message
    assert isinstance(caught.value, CageVertexError) == bool(CITES_VERTICES.search(message)), message
    return message


# ----------------------------------------------------------------------------------------------- catalogue: inputs


def test_wrong_shape_is_refused():
    assert_refused(np.zeros((4, 4)), None, "(n, 2) or (n, 3)")


@pytest.mark.parametrize("vertices", [[[0, 0], [1, 0, 0], [1, 1]], [["a", "b"], ["c", "d"], ["e", "f"]]])
def test_vertices_that_are_not_numbers(vertices):
    assert_refused(vertices, None, "must be real numbers")


def test_faces_from_a_generator():
    cage = make_cage(CUBE, (face for face in CUBE_QUADS))
    assert cage.measure == pytest.approx(1.0)


def test_convexity_is_the_share_of_the_convex_hull_the_cage_encloses():
    assert make_cage(CUBE, CUBE_QUADS).convexity == pytest.approx(1.0)
    hollow = make_cage(*hollow_cube())
    assert hollow.convexity == pytest.approx((8.0 - 0.4**3) / 8.0)
    gargoyle = make_cage(*read_cage(DATA / "cages-3d" / "gargoyle" / "cage_L10.obj"))
    assert 0.5 < gargoyle.convexity < 0.8


def test_too_few_polygon_vertices():
    assert_refused(SQUARE[:2], None, "at least 3 vertices", "got 2")


def test_too_few_distinct_polygon_vertices_after_welding():
    assert_refused(np.array([[0.0, 0], [1, 0], [1, 1e-12]]), None, "at least 3 distinct vertices")


def test_too_few_3d_vertices():
    assert_refused(TETRA[:3], [[0, 1, 2]], "at least 4 vertices")
    assert_refused(TETRA[:3], [], "the 3D cage has no faces")  # what is missing first: three edges, no face


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_or_inf_coordinates(bad):
    vertices = CUBE.copy()
    vertices[5, 1] = bad
    assert_refused(vertices, CUBE_QUADS, "nan or infinite", "(5)")
    polygon = SQUARE.copy()
    polygon[2, 0] = bad
    assert_refused(polygon, None, "nan or infinite")


@pytest.mark.parametrize("far", [3.4028234663852886e38, 1e30, -1e12])
def test_a_vertex_a_million_times_farther_than_the_others_is_named(far):
    # Blender stores an infinite coordinate as its largest float; welding at 1e-9 of that diagonal merged the rest.
    vertices = CUBE.copy()
    vertices[2, 0] = far
    assert_refused(vertices, CUBE_QUADS, "cage vertex 2 lies", "move it back")
    vertices[5, 1] = far
    assert_refused(vertices, CUBE_QUADS, "cage vertices 2, 5 lie", "move them back")
    polygon = SQUARE.copy()
    polygon[1, 1] = far
    assert_refused(polygon, None, "cage vertex 1 lies")


def test_a_long_thin_cage_is_no_far_off_vertex():
    needle = CUBE * [1e4, 1.0, 1.0]
    assert make_cage(needle, CUBE_QUADS).n_control_points == 8


def test_polygon_not_in_a_plane_z_constant():
    assert_refused(np.c_[SQUARE, [0, 0, 1, 0]], None, "z = constant")


def test_faces_with_2d_vertices():
    assert_refused(SQUARE, [[0, 1, 2], [0, 2, 3]], "3d vertices")


def test_no_faces():
    assert_refused(CUBE, [], "no faces")


@pytest.mark.parametrize("face", [[0, 1], [0, 1, 8], [0, -1, 2]])
def test_invalid_face_indices(face):
    assert_refused(CUBE, CUBE_QUADS + [face], "face 6", "invalid")


def test_non_integer_face_indices():
    assert_refused(CUBE, CUBE_QUADS[:-1] + [[1.0, 3.0, 7.0, 5.0]], "integer vertex indices")


def test_million_faces_refused_up_front(monkeypatch):
    """Refused by the counts alone: welding, the first pass over the vertices, never starts."""
    faces = np.zeros((1_000_000, 3), dtype=np.int64)
    vertices = np.random.default_rng(0).random((500_000, 3))
    monkeypatch.setattr(cage_module, "_weld", lambda *arguments: pytest.fail("welded a cage refused by its size"))
    message = assert_refused(vertices, faces, "1000000 faces", str(MAX_CONTROL_POINTS))
    assert "coarser cage" in message


def test_too_many_vertices_refused_up_front():
    assert_refused(np.random.default_rng(0).random((10**6, 2)), None, "1000000 vertices", "coarser cage")


def test_too_many_control_points():
    vertices, triangles = sphere(300)
    assert_refused(vertices, triangles, "300 distinct vertices", "at most 160 control points", max_control_points=160)
    angles = np.linspace(0, 2 * np.pi, 300, endpoint=False)
    assert_refused(np.c_[np.cos(angles), np.sin(angles)], None, "300 distinct", max_control_points=100)


# ---------------------------------------------------------------------------------------------- catalogue: polygons


def test_polygon_duplicates_are_welded_and_reported():
    closed = np.r_[SQUARE[:2], SQUARE[1:2] + 1e-13, SQUARE[2:], SQUARE[:1]]  # a doubled corner and a closing copy
    cage = make_cage(closed)
    assert len(cage.vertices) == 4
    assert cage.warnings == ["welded 2 duplicate cage vertices"]
    np.testing.assert_array_equal(cage.vertex_map, [0, 1, 1, 2, 3, 0])


def test_polygon_visiting_a_vertex_twice():
    figure = np.array([[0.0, 0], [1, 0], [1, 1], [0.5, 0.5], [0, 1], [-1, 1], [-1, 0], [0.5, 0.5]])
    assert_refused(figure, None, "passes twice through vertex 3", "touches itself")


def test_collinear_polygon_has_zero_area():
    assert_refused(np.array([[0.0, 0], [1, 1], [2, 2], [3, 3]]), None, "zero area", "collinear")


def test_polygon_spike():
    spiked = np.array([[0.0, 0], [2, 0], [2, 2], [2, 3], [2, 2.5], [0, 2]])  # out to (2, 3) and back on itself
    assert_refused(spiked, None, "doubles back", "vertex 3")


def test_self_intersecting_polygon():
    bowtie = np.array([[0.0, 0], [1, 1], [1, 0], [0, 1]])
    assert_refused(bowtie, None, "intersects itself", "1 pair of crossing or touching edges", "0-1 with 2-3")


def test_polygon_touching_itself():
    touching = np.array([[0.0, 0], [4, 0], [4, 4], [2, 0], [0, 4]])  # vertex 3 lies on edge 0-1
    assert_refused(touching, None, "intersects itself", "touch")


def test_collinear_edges_that_do_not_meet_are_fine():
    comb = np.array([[0.0, 0], [5, 0], [5, 2], [4, 2], [4, 1], [3, 1], [3, 2], [2, 2], [2, 1], [1, 1], [1, 2], [0, 2]])
    cage = make_cage(comb)
    assert cage.measure == pytest.approx(8.0)


@pytest.mark.parametrize("direction", [1, -1])
def test_polygon_orientation_either_way(direction):
    polygon = SQUARE[::direction]
    cage = make_cage(polygon)
    np.testing.assert_array_equal(cage.vertices, polygon)  # control points keep the input order
    assert cage.measure == pytest.approx(1.0)
    assert sorted(cage.facets[:, 0]) == [0, 1, 2, 3]  # each control point starts one edge
    assert cage.warnings == []


def test_polygon_given_with_constant_z():
    cage = make_cage(np.c_[SQUARE, np.full(4, 2.5)])
    assert cage.dim == 2 and cage.measure == pytest.approx(1.0)


# ---------------------------------------------------------------------------------------------- catalogue: 3D cages


def test_flat_cage_has_zero_volume():
    flat = CUBE.copy()
    flat[:, 2] = 0.0
    flat[4:, 0] += 2.0  # keep the two squares apart so that nothing welds
    assert_refused(flat, CUBE_QUADS, "flat", "zero volume")


def test_open_cage_names_its_boundary_edges():
    assert_refused(CUBE, CUBE_QUADS[:-1], "not closed", "4 boundary edges, each in only one face")


def test_non_manifold_edges():
    # A second cube sharing the edge x = y = 0 with the first: four faces meet at that edge.
    vertices = np.r_[CUBE, CUBE - [1.0, 1.0, 0.0]]
    faces = CUBE_QUADS + [[k + 8 for k in face] for face in CUBE_QUADS]
    assert_refused(vertices, faces, "1 non-manifold edge ", "0-4")


def test_non_manifold_vertex():
    # Two tetrahedra touching at vertex 0.
    vertices = np.r_[TETRA, -TETRA[1:]]
    faces = TETRA_FACES + [[0, 4, 5], [0, 6, 4], [0, 5, 6], [4, 6, 5]]
    assert_refused(vertices, faces, "1 non-manifold vertex ", "vertex 0")


def test_several_parts():
    vertices = np.r_[TETRA, TETRA + 5.0]
    faces = TETRA_FACES + [[a + 4, b + 4, c + 4] for a, b, c in TETRA_FACES]
    assert_refused(vertices, faces, "2 separate parts", "own cage")


def hollow_cube(inner_faces_into_cavity=True, inner_scale=0.4):
    """A cube of side 2 with a cubic cavity at its middle (as Solidify makes a shell): vertices, quads."""
    inner = [face[::-1] if inner_faces_into_cavity else face for face in CUBE_QUADS]
    vertices = np.r_[2.0 * CUBE - 0.5, 0.5 + inner_scale * (CUBE - 0.5)]
    return vertices, CUBE_QUADS + [[k + 8 for k in face] for face in inner]


def test_a_cage_with_a_cavity_is_one_region():
    """An outer surface and an inner one facing into the cavity bound one region (the pipeline binds it: see
    test_pipeline); faces all reversed are turned round, the inner ones into the cavity again."""
    vertices, faces = hollow_cube()
    cage = make_cage(vertices, faces)
    assert cage.warnings == [] and cage.measure == pytest.approx(8.0 - 0.4**3)
    reversed_cage = make_cage(vertices, [face[::-1] for face in faces])
    assert reversed_cage.warnings == ["reversed all cage faces: they pointed inward"]
    assert reversed_cage.measure == pytest.approx(cage.measure)  # both outward: the outer part out, the inner in


def test_an_inner_surface_facing_the_same_way_as_the_outer_one_is_refused_as_such():
    vertices, faces = hollow_cube(inner_faces_into_cavity=False)
    message = assert_refused(vertices, faces, "1 inner surface inside its outer one facing the same way",
                             "(face 6, 7, 8, 9, 10, ...)", "Normals > Flip", "Separate > By Loose Parts")
    assert "separate parts" not in message


def test_a_part_inside_a_cavity_is_a_separate_part():
    vertices, faces = hollow_cube()
    island = 0.5 + 0.1 * (CUBE - 0.5)
    assert_refused(np.r_[vertices, island], faces + [[k + 16 for k in face] for face in CUBE_QUADS],
                   "3 separate parts", "own cage")


def test_duplicated_face():
    message = assert_refused(CUBE, CUBE_QUADS + [CUBE_QUADS[2][::-1]], "1 duplicated face", "2 and 6",
                             "delete one face of each pair, not both")
    assert "kinds of defect" not in message  # one copy kept: the cage is otherwise closed


def test_every_defect_is_reported_at_once():
    # A user's cage: 5 duplicated faces and a hole elsewhere were told one at a time (first one pair, then, after
    # deleting, "open"); every kind, with its count, comes in one message now.
    vertices, triangles = sphere(60)
    top = int(np.argmax(vertices[:, 2]))
    fan = np.flatnonzero(np.any(triangles == top, axis=1))  # the faces around the top vertex: a hole and a loose one
    kept = [t for k, t in enumerate(triangles.tolist()) if k not in fan]
    duplicates = [t[::-1] for t in kept[:5]]
    message = assert_refused(vertices, kept + duplicates, "3 kinds of defect", "5 duplicated faces",
                             f"1 loose vertex, in no face (vertex {top})",
                             f"not closed: it has {len(fan)} boundary edges")
    assert message.index("duplicated") < message.index("loose") < message.index("not closed")
    # Following the advice (one copy of each pair deleted, the hole filled) gives a valid cage.
    assert make_cage(vertices, triangles).n_control_points == len(vertices)


def test_defects_of_topology_and_geometry_together():
    vertices = np.r_[CUBE, [[3.0, 3.0, 3.0]]]
    faces = CUBE_QUADS[:-1] + [[1, 3, 7, 5], [0, 2, 3, 1]]
    assert_refused(vertices, faces, "2 kinds of defect", "1 duplicated face", "1 loose vertex")


def test_loose_vertex():
    assert_refused(np.r_[CUBE, [[3.0, 3.0, 3.0]]], CUBE_QUADS, "1 loose vertex, in no face", "vertex 8")


def test_face_visiting_a_vertex_twice():
    message = assert_refused(CUBE, CUBE_QUADS[:-1] + [[1, 3, 7, 3, 5]], "face 5", "twice through vertex 3")
    assert "not closed" not in message  # its edges close once it is split as advised


def test_zero_area_face():
    # Vertex 8 sits on the middle of edge 0-1: the sliver triangle 0-8-1 closes the cage but has zero area.
    vertices = np.r_[CUBE, [[0.5, 0.0, 0.0]]]
    faces = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 8, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 8]]
    assert_refused(vertices, faces, "1 face of zero area", "face 6", "degenerate dissolve")


def test_n_gon_with_zero_area():
    vertices = np.r_[CUBE, [[0.2, 0.0, 0.0], [0.4, 0.0, 0.0]]]
    faces = CUBE_QUADS + [[0, 8, 9, 10, 1]]  # five points on the line y = z = 0
    assert_refused(np.r_[vertices, [[0.7, 0.0, 0.0]]], faces, "face 6 has zero area")


def test_n_gon_without_an_ear():
    # A self-crossing hexagon whose every convex corner holds another corner: the base of a pyramid.
    outline = np.array([[0.18, 0.86], [0.54, 0.3], [0.42, 0.03], [0.12, 0.67], [0.65, 0.62], [0.38, 1.0]])
    vertices = np.r_[np.c_[outline, np.zeros(6)], [[0.4, 0.5, 1.0]]]
    faces = [list(range(6))] + [[k, (k + 1) % 6, 6] for k in range(6)]
    assert_refused(vertices, faces, "face 0 cannot be triangulated", "crosses itself")


def test_inconsistent_orientation_is_fixed_and_reported():
    faces = [face[::-1] if k in (1, 4) else face for k, face in enumerate(CUBE_QUADS)]
    cage = make_cage(CUBE, faces)
    assert cage.warnings == ["flipped 2 cage faces to make the orientation consistent and outward"]
    assert cage.measure == pytest.approx(1.0)


def test_inward_cage_is_reversed_and_reported():
    cage = make_cage(CUBE, [face[::-1] for face in CUBE_QUADS])
    assert cage.warnings == ["reversed all cage faces: they pointed inward"]
    assert cage.measure == pytest.approx(1.0)


def test_non_orientable_surface():
    # The 6-vertex projective plane (hemi-icosahedron): closed and manifold, but one-sided.
    faces = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5], [0, 5, 1],
             [1, 2, 4], [2, 3, 5], [3, 4, 1], [4, 5, 2], [5, 1, 3]]
    vertices = np.random.default_rng(1).random((6, 3))
    assert_refused(vertices, faces, "not orientable")


def test_3d_duplicates_are_welded_and_reported():
    soup = np.concatenate([CUBE[face] for face in CUBE_QUADS])  # every quad with its own 4 vertices
    faces = np.arange(24).reshape(6, 4)
    cage = make_cage(soup + np.random.default_rng(0).normal(scale=1e-12, size=soup.shape), faces)
    assert len(cage.vertices) == 8
    assert cage.warnings == ["welded 16 duplicate cage vertices"]
    assert cage.measure == pytest.approx(1.0)


def test_faces_collapsed_by_welding_are_dropped_and_reported():
    vertices = np.r_[CUBE, CUBE[:1] + 1e-13]
    cage = make_cage(vertices, CUBE_QUADS + [[0, 8, 0]])
    assert cage.warnings[1] == "dropped 1 cage face that welding collapsed to an edge or a point"


def test_self_intersecting_cage_names_the_faces():
    vertices, triangles = sphere(200)
    top = np.argmax(vertices[:, 2])
    vertices[top] = [0.0, 0.0, -2.0]  # pull the top vertex down through the bottom of the surface
    message = assert_refused(vertices, triangles, "intersects itself", "crossing or touching faces", "3d-print toolbox")
    faces_around_top = {str(f) for f in np.flatnonzero(np.any(triangles == top, axis=1))}
    named = message.split("(faces ")[1].split(")")[0].replace(" and ", ",").replace(", ...", "").split(",")
    assert faces_around_top & {name.strip() for name in named}


def test_twisted_quad_is_refused():
    twisted = CUBE.copy()
    twisted[[6, 7]] = twisted[[7, 6]]  # the top face becomes a bow-tie
    assert_refused(twisted, CUBE_QUADS, "intersects itself")


# ---------------------------------------------------------------------------------------------- accepted cages


@pytest.mark.parametrize("path", sorted((DATA / "cages-3d").glob("*/cage*.obj")), ids=lambda p: p.stem)
def test_real_3d_cages_are_accepted(path):
    vertices, faces = read_obj(path)
    cage = make_cage(vertices, faces)
    assert cage.warnings == [] and cage.measure > 0


@pytest.mark.parametrize("path", sorted(DATA.glob("*-control-edgeset.obj")), ids=lambda p: p.stem)
def test_real_2d_cages_are_accepted(path):
    vertices, _ = read_obj(path)
    cage = make_cage(vertices[:, :2])
    assert cage.measure > 0 and len(cage.vertices) == len(vertices)


def test_subdivided_flat_sides_are_not_self_intersections():
    # A 2 × 2 × 2 box whose sides are 2 × 2 grids of quads: coplanar triangles sharing only edges or vertices.
    points, quads = [], []
    for axis in range(3):
        for side in (0.0, 2.0):
            grid = np.array([[u, v] for u in range(3) for v in range(3)], dtype=float)
            points.append(np.insert(grid, axis, side, axis=1))
            base = 9 * (len(points) - 1)
            quads += [[base + 3 * u + v, base + 3 * u + v + 3, base + 3 * u + v + 4, base + 3 * u + v + 1]
                      for u in range(2) for v in range(2)]
    cage = make_cage(np.concatenate(points), quads)
    assert len(cage.vertices) == 26 and len(cage.facets) == 48
    assert cage.measure == pytest.approx(8.0)


def test_self_intersection_check_tests_only_nearby_triangles(monkeypatch):
    """The broad phase hands the exact test the pairs whose boxes overlap: a few per triangle on a sphere of 1000
    triangles, not the 499,500 pairs of all of them."""
    vertices, triangles = sphere(502)  # 1000 triangles
    assert len(triangles) == 1000
    found = []
    broad_phase = intersections.overlapping_boxes
    monkeypatch.setattr(intersections, "overlapping_boxes",
                        lambda *arguments: found.append(broad_phase(*arguments)) or found[-1])
    make_cage(vertices, triangles)
    assert len(found) == 1 and len(found[0]) < 20 * len(triangles)


# ---------------------------------------------------------------------------------------------- triangulation


def test_quads_split_on_the_shorter_diagonal():
    skewed = CUBE * [3.0, 1.0, 1.0]
    skewed[0] += [0.4, 0.0, 0.0]  # bottom quad 0-2-3-1: diagonal 0-3 now shorter than 2-1
    cage = make_cage(skewed, CUBE_QUADS)
    bottom = cage.facets[cage.facet_face == 0]
    assert len(bottom) == 2 and all({0, 3} <= set(t) for t in bottom.tolist())
    assert len(cage.facets) == 12


def test_non_convex_quad_splits_inside():
    # A prism over a dart a, c, b, r (r the reflex corner): the short diagonal a-b runs outside the dart, so the split
    # is along r-c.
    dart = np.array([[0.0, 1], [10, 0], [0, -1], [1, 0]])
    vertices = np.r_[np.c_[dart, np.zeros(4)], np.c_[dart, np.ones(4)]]
    faces = [[3, 2, 1, 0], [4, 5, 6, 7]] + [[k, (k + 1) % 4, (k + 1) % 4 + 4, k + 4] for k in range(4)]
    cage = make_cage(vertices, faces)
    assert all({1, 3} <= set(t) for t in cage.facets[cage.facet_face == 0].tolist())
    assert cage.measure == pytest.approx(9.0)


def test_n_gons_are_ear_clipped_consistently():
    # An L-shaped prism: two non-convex hexagon caps and six quad sides.
    outline = np.array([[0.0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]])
    vertices = np.r_[np.c_[outline, np.zeros(6)], np.c_[outline, np.ones(6)]]
    faces = [list(range(5, -1, -1)), list(range(6, 12))] + [[k, (k + 1) % 6, (k + 1) % 6 + 6, k + 6] for k in range(6)]
    first = make_cage(vertices, faces)
    again = make_cage(vertices, faces)
    np.testing.assert_array_equal(first.facets, again.facets)
    assert np.count_nonzero(first.facet_face == 0) == 4 and np.count_nonzero(first.facet_face == 1) == 4
    assert first.measure == pytest.approx(3.0)
    # Every triangle of a cap lies inside the L: the caps' triangle areas add up to the L's area.
    corners = first.vertices[first.facets[first.facet_face == 1]]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    assert areas.sum() == pytest.approx(3.0)
    assert first.warnings == []


# ---------------------------------------------------------------------------------------------- intersection tests


def _pair(first, second):
    vertices = np.r_[first, second]
    return np.array([[0, 1, 2], [3, 4, 5]]), vertices


@pytest.mark.parametrize(
    "second, meets",
    [
        ([[0.2, 0.2, -1], [0.2, 0.2, 1], [0.3, 0.3, 1]], True),  # crosses the first one's interior
        ([[0.2, 0.2, 0.1], [0.2, 0.2, 1], [0.3, 0.3, 1]], False),  # above it
        ([[0.5, 0.5, 0.0], [0.2, 0.2, 1], [0.3, 0.3, 1]], True),  # touches it on its edge
        ([[0.2, 0.2, 0.0], [0.4, 0.2, 0.0], [0.2, 0.4, 0.0]], True),  # coplanar, inside it
        ([[1.0, 1.0, 0.0], [2.0, 1.0, 0.0], [1.0, 2.0, 0.0]], False),  # coplanar, apart
    ],
)
def test_disjoint_triangle_pairs(second, meets):
    triangles, vertices = _pair([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]], second)
    assert len(intersecting_triangles(vertices, triangles, 1e-12)) == int(meets)


@pytest.mark.parametrize(
    "corners, meets",
    [
        # Sharing vertex 0 (at the origin) with the triangle (0, 0, 0), (1, 0, 0), (0, 1, 0):
        ([[0, 0, 0], [1, 1, -1], [1, 1, 1]], True),  # passes through it
        ([[0, 0, 0], [-1, -1, -1], [-1, -1, 1]], False),  # crosses its plane, but on the far side of the vertex
        ([[0, 0, 0], [1, 1, 0.5], [1, 0.5, 1]], False),  # above it
        ([[0, 0, 0], [1, 0.2, 0], [1, 1, 0]], True),  # coplanar wedges overlap
        ([[0, 0, 0], [-1, 0, 0], [0, -1, 0]], False),  # coplanar wedges apart
        # Sharing the edge 0-1:
        ([[0, 0, 0], [1, 0, 0], [0.5, 0.5, 0]], True),  # folded flat onto it
        ([[0, 0, 0], [1, 0, 0], [0.5, -0.5, 0]], False),  # flat continuation
        ([[0, 0, 0], [1, 0, 0], [0.5, 0.5, 0.01]], False),  # a sharp but real fold
    ],
)
def test_neighbouring_triangle_pairs(corners, meets):
    first = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    corners = np.array(corners, dtype=float)
    extra = [c for c in corners if not any(np.array_equal(c, f) for f in first)]
    vertices = np.r_[first, extra]
    index = [next(k for k, v in enumerate(vertices) if np.array_equal(v, c)) for c in corners]
    triangles = np.array([[0, 1, 2], index])
    assert len(intersecting_triangles(vertices, triangles, 1e-12)) == int(meets)


def test_broad_phase_finds_every_overlapping_box_pair():
    rng = np.random.default_rng(3)
    low = rng.random((300, 3))
    high = low + rng.random((300, 3)) ** 4 * 0.5  # mostly small boxes, a few large ones
    overlap = np.all((low[:, None] <= high[None]) & (low[None] <= high[:, None]), axis=2)
    expected = {tuple(p) for p in np.argwhere(np.triu(overlap, k=1)).tolist()}
    for chunk in (7, 2_000_000):  # several chunks, and one
        assert {tuple(p) for p in overlapping_boxes(low, high, chunk).tolist()} == expected


def test_every_invalid_face_is_named():
    assert_refused(CUBE, CUBE_QUADS + [[0, 1], [0, 1, 8]], "cage faces 6 ([0, 1]), 7 ([0, 1, 8]) are invalid")


def test_complex_coordinates_are_refused():
    assert_refused(CUBE + 1j, CUBE_QUADS, "must be real numbers")


# ------------------------------------------------------------------------------------------ posing a checked cage


def test_welded_copies_follow_their_first_copy_and_may_not_be_posed_apart():
    # Vertices 8 and 9 repeat 6 and 7 (as in a real cage with a seam): one control point each.
    vertices = np.r_[CUBE, CUBE[[6, 7]]]
    faces = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 8, 9, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    cage = make_cage(vertices, faces)
    assert cage.n_control_points == 8 and cage.warnings[0] == "welded 2 duplicate cage vertices"
    moved = vertices * 2.0  # an affine pose keeps the copies together
    np.testing.assert_array_equal(cage.control_points_from_input(moved), CUBE * 2.0)
    alone = vertices.copy()
    alone[6] += [0.0, 0.5, 0.0]  # one copy moved, the other left behind
    with pytest.raises(CageVertexError, match=r"cage vertices 6/8 coincided when bound .* are posed apart"):
        cage.control_points_from_input(alone)


def test_a_2d_cage_may_be_posed_with_its_constant_z():
    cage = make_cage(np.c_[SQUARE, np.full(4, 5.0)])
    np.testing.assert_array_equal(cage.control_points_from_input(np.c_[SQUARE * 2, np.full(4, 7.0)]), SQUARE * 2)
    with pytest.raises(CageError, match=r"got positions of shape \(4, 3\)"):
        cage.control_points_from_input(np.c_[SQUARE, [0.0, 0.0, 0.0, 1.0]])
    with pytest.raises(CageVertexError, match="NaN or infinite positions of cage vertex 2"):
        cage.control_points_from_input(np.where([[0], [0], [1], [0]], np.nan, SQUARE))


def test_a_posed_cage_must_keep_the_bound_faces():
    cage = make_cage(CUBE, CUBE_QUADS)
    cage.check_faces(CUBE_QUADS)
    cage.check_faces([face[::-1] for face in CUBE_QUADS])  # orientation is the cage check's business
    with pytest.raises(CageError, match="other faces"):
        cage.check_faces(CUBE_QUADS[1:2] + CUBE_QUADS[:1] + CUBE_QUADS[2:])  # same faces, other numbers
    with pytest.raises(CageError, match="this cage has no faces"):
        cage.check_faces(None)
    with pytest.raises(CageError, match="not among its 8 vertices"):
        cage.check_faces(CUBE_QUADS[:-1] + [[1, 3, 7, 9]])
    with pytest.raises(CageError, match="2D polygon cage, but this cage has faces"):
        make_cage(SQUARE).check_faces([[0, 1, 2]])


def test_a_polygon_spike_and_a_crossing_are_reported_together():
    # A spike at vertex 2 (3 lies behind it on the line 1-2) and edges 3-4 and 5-0 crossing.
    polygon = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [2.0, 1.0], [0.5, 3.0], [1.0, 3.0]])
    assert_refused(polygon, None, "2 kinds of defect", "doubles back on itself at vertex 2", "intersects itself")


# Property-based tests: random cages give a Cage or a CageError, never another exception. Star-shaped
# cages (2D polygons with angularly sorted vertices, 3D radial surfaces over a sphere triangulation) are simple by
# construction, so they must be accepted; perturbed ones (concave, possibly self-intersecting) may be refused, but
# only with a CageError. Runs are kept small (a few seconds in all).

SMALL = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])


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
    found = len(intersecting_triangles(vertices, triangles, 1e-12)) == 1
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


def test_an_ngon_cap_left_out_of_plane_by_float32_rounding_is_not_a_self_intersection():
    """Blender's Cylinder after G Z .3 then G Z -.3 on four cap vertices: float32 leaves them 6e-8 below the cap's
    plane, and the 32-gon's triangles were reported as crossing each other (found trying the add-on)."""
    from helpers import cage_corpus

    vertices, faces = cage_corpus.load("cylinder-32-ngon")
    vertices = np.array(vertices, dtype=np.float32)
    cap = np.flatnonzero(vertices[:, 2] > 0.5)[:4]
    vertices[cap, 2] += np.float32(0.3)
    vertices[cap, 2] -= np.float32(0.3)
    assert np.any(vertices[cap, 2] != 1.0)  # the round trip is not exact
    cage = make_cage(vertices.astype(float), faces)
    assert cage.n_control_points == 64 and len(cage.centres) == 2 and not cage.warnings


def prism(outline, height=0.3):
    """A prism over a counter-clockwise outline (k, 2): bottom face, top face, then the sides as quads."""
    k = len(outline)
    vertices = np.concatenate([np.c_[outline, np.zeros(k)], np.c_[outline, np.full(k, height)]])
    faces = [list(range(k))[::-1], list(range(k, 2 * k))] + [[i, (i + 1) % k, k + (i + 1) % k, k + i] for i in range(k)]
    return vertices, faces


def test_n_gons_are_poked_at_their_mean_whose_boundary_values_are_its_vertices_mean():
    """Blender's Cylinder: each 32-gon cap was ear-clipped into a fan from one vertex, whose coordinate then moved the
    whole cap (its weights summed to 466 over the points inside, the other rim vertices' to 18-166). Now each cap is
    split from a centre, the mean of its vertices, which is no control point: its boundary values are 1/32 for each,
    so values and positions on the cap are one linear map of the control points (partition of unity, reproduction)."""
    from helpers import cage_corpus

    cage = make_cage(*cage_corpus.load("cylinder-32-ngon"))
    assert cage.n_control_points == 64 and not cage.warnings
    assert [len(corners) for corners in cage.centres] == [32, 32]
    surface = cage.surface_vertices
    assert surface.shape == (66, 3)
    for c, corners in enumerate(cage.centres):
        assert np.allclose(surface[64 + c], cage.vertices[corners].mean(axis=0))
        assert np.count_nonzero(np.any(cage.facets == 64 + c, axis=1)) == 32
    values = cage.surface_values.toarray()
    assert np.allclose(values[64][cage.centres[0]], 1 / 32) and np.allclose(values.sum(axis=1), 1)
    assert np.allclose(values @ cage.vertices, surface)
    assert cage.measure > 0 and np.isclose(cage.measure, make_cage(*cage_corpus.load("cylinder-32-fan")).measure)
    # A five-pointed star's caps (not convex: their mean sees every side) are poked as well.
    angles = np.pi / 2 + np.arange(10) * np.pi / 5
    radii = np.where(np.arange(10) % 2 == 0, 1.0, 0.382)
    star = make_cage(*prism(np.c_[radii * np.cos(angles), radii * np.sin(angles)]))
    assert len(star.centres) == 2 and not star.warnings


def test_an_n_gon_its_mean_cannot_poke_is_ear_clipped_and_named_if_it_fans_out():
    """A crescent (an arc of 220° of the unit circle, hollowed by another): its vertices' mean lies outside it, so it
    is ear-clipped; one cap's ear clipping fans out from one vertex, and the warning names that face, the vertex and
    a fix that helps (Blender's Triangulate Faces fans such a face too). Thin convex n-gons, whose mean stands at
    least POKE_HEIGHT_CONVEX inside (a lens 0.08 of its reach, a circle segment 0.09), are poked."""
    outer = np.radians(np.linspace(-110.0, 110.0, 8))
    tip = np.array([np.cos(outer[-1]), np.sin(outer[-1])])
    radius = np.linalg.norm(tip - [-0.35, 0.0])
    inner = np.linspace(np.arctan2(tip[1], tip[0] + 0.35), -np.arctan2(tip[1], tip[0] + 0.35), 8)[1:-1]
    crescent = np.r_[np.c_[np.cos(outer), np.sin(outer)], np.c_[radius * np.cos(inner) - 0.35, radius * np.sin(inner)]]
    cage = make_cage(*prism(crescent, height=0.2))
    assert cage.centres == ()
    assert cage.warnings == [
        "cage face 1 (an n-gon of 14 sides) is split into a fan of triangles from vertex 17, which moves most of the "
        "face while its other vertices barely do, and its middle lies outside it or too near a side to split it from "
        "there: split it into rounder faces (in Blender, Select > Select All by Trait > Faces by Sides, greater than "
        "7, finds it; select two vertices across such a face and press J, Connect Vertex Path)"]
    angles = np.radians(np.linspace(-10.0, 10.0, 9))
    lens = make_cage(*prism(np.c_[np.cos(angles), np.sin(angles)], height=0.05))
    assert len(lens.centres) == 2 and not lens.warnings


@pytest.mark.parametrize("cuts", [3, 9])
def test_a_subdivided_cube_rotated_and_applied_in_float32_is_not_a_self_intersection(cuts):
    """A new user's Cube subdivided 9 times, rotated, scaled unevenly and applied, was refused as crossing itself
    between neighbouring quads: float32 leaves their triangles up to 1e-7 out of one plane, and two meeting at a vertex
    were judged as crossing planes (10 of 10 random such poses at 9 cuts, 4 of 10 at 3 cuts)."""
    vertices, faces = subdivided_cube(cuts)
    turn = Rotation.random(random_state=9).as_matrix()
    posed = (vertices * [2.9, 0.4, 1.7]) @ turn.T + [3.2, -4.1, 0.7]
    cage = make_cage(posed.astype(np.float32).astype(float), faces)
    assert cage.n_control_points == len(vertices) and not cage.warnings
