"""Cages: closed 2D polygons and closed 3D polygon meshes, checked and put into one form.

A :class:`Cage` always has its control points (``vertices``, welded) and its boundary ``facets``: the polygon's edges
in 2D, an outward-oriented triangulation of the faces in 3D. Boundary values are linear on each facet, so a quad or
n-gon face is linear on each triangle of its triangulation. The triangulation is a documented, consistent choice that
keeps the Lagrange and linearity properties on every edge of the input:

* a quad is split along its shorter diagonal, or, when the two are within :data:`QUAD_SPLIT_TIE` of each other,
  along the one from its first vertex, unless that diagonal leaves the quad (a non-convex quad) or makes a zero-area
  triangle; then along the other one;
* an n-gon of :data:`POKE_SIDES` sides or more is poked: split into triangles from a centre, the mean of its
  vertices, when that centre sees each of its sides from at least :data:`POKE_HEIGHT` of its reach (any convex
  n-gon, a star). The centre is no control point: it is a surface vertex whose boundary values are 1/k for each of
  the face's k control points, so values linear on the poke's triangles and the surface are one linear construction
  (partition of unity and reproduction hold on the face), and no vertex of the face is favoured (a convex n-gon
  takes its outline's smooth mean value coordinates instead, :mod:`lbc_core.solve.boundary`). The cage's surface
  vertices (``surface_vertices``) are its control points followed by these centres;
* any other n-gon is ear-clipped in the plane of its Newell normal, always cutting the first ear in the face's vertex
  order.

Checks, in this order (each failure raises :class:`~lbc_core.errors.CageError`, a ValueError, whose message names the
problem and what to do; repairs are reported in ``Cage.warnings``):

* shape, NaN/inf, too few vertices, too many faces or vertices (:data:`MAX_CONTROL_POINTS`), invalid face indices;
* duplicates closer than ``weld_tolerance`` × bounding-box diagonal are welded (warning);
* 2D: the polygon must not revisit a vertex, be collinear, double back on itself, or cross or touch itself;
* 3D: the cage must not be flat; faces must have no repeated vertex or zero area, and not be twisted;
  no loose vertices; no duplicated faces; closed; manifold at edges and vertices; orientable (inconsistent
  orientation is fixed, with a warning); one connected surface, or an outer surface with cavities: inner surfaces
  inside it, not inside each other, facing into the cavity (its faces pointing away from the region, as Solidify
  makes them); no two faces may cross or touch except along their shared edge or vertex.

Lengths below :data:`ZERO_LENGTH` × bounding-box diagonal count as zero in every geometric test.
"""

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import CageError, CageVertexError
from ..kernel.geometry import cross2, enclosed_measure
from ..kernel.intersections import overlapping_boxes, segments_touch
from .messages import NamesVertices, count_of, first_inputs, raise_all, real_array, some_indices, some_items
from .record import Cage
from .topology import check_closed_manifold, check_self_intersection, orient_outward
from .triangulate import collapse_welded, face_list, fans, poke, report_degenerate, triangulate_faces

DEFAULT_WELD_TOLERANCE = 1e-9  # relative to the bounding-box diagonal
# A vertex a million times farther from the cage's middle than the rest of the cage is wide is no part of it: it would
# set the welding tolerance (DEFAULT_WELD_TOLERANCE of the diagonal) and weld every other vertex into one.
FAR_OFF = 1e6
ZERO_LENGTH = 1e-9  # relative to the bounding-box diagonal
# Control points at most: larger cages are refused before any work, as no machine would bind them in reasonable time
# (bench/RESULTS.md, "The control-point limit"); pipeline.check_request refuses smaller ones that do not fit memory.
MAX_CONTROL_POINTS = 2000
# Closed triangle meshes have about 2 triangles per vertex; 4 leaves room for handles and unwelded input.
_FACES_PER_CONTROL_POINT = 4
# Unwelded triangle soups repeat each vertex about 6 times.
_INPUT_VERTICES_PER_CONTROL_POINT = 8


def make_cage(vertices, faces=None, weld_tolerance=DEFAULT_WELD_TOLERANCE, max_control_points=MAX_CONTROL_POINTS):
    """Check and normalise a cage.

    Parameters
    ----------
    vertices : (n, 2) or (n, 3) float array
        2D polygon vertices in boundary order (either orientation), or 3D mesh vertices. A 2D polygon may also be
        given as (n, 3) with a constant z when ``faces`` is None.
    faces : None, (F, k) int array or sequence of index sequences
        None for a 2D polygon; else the 3D faces (triangles, quads, n-gons), any orientation.
    weld_tolerance : float
        Vertices closer than this fraction of the bounding-box diagonal are merged (and reported).
    max_control_points : int
        Larger cages are refused before any work (see :data:`MAX_CONTROL_POINTS`).

    Returns
    -------
    Cage

    Raises
    ------
    CageError
        With a message that names the problem and what to do.
    """
    vertices = real_array(vertices, "cage vertices", "(n, 2) or (n, 3)")
    if vertices.ndim != 2 or vertices.shape[1] not in (2, 3):
        raise CageError(f"cage vertices must be an (n, 2) or (n, 3) array, got shape {vertices.shape}")
    if faces is not None and not hasattr(faces, "__len__"):
        faces = list(faces)
    _check_size(len(vertices), None if faces is None else len(faces), max_control_points)
    check_coordinates(vertices)
    if faces is None:
        return _make_polygon_cage(vertices, weld_tolerance, max_control_points)
    return _make_mesh_cage(vertices, faces, weld_tolerance, max_control_points)


def check_coordinates(vertices):
    """Refuse cage vertices with NaN or infinite coordinates, or lying FAR_OFF times farther from the cage's middle
    than the size of the rest of it (at most a quarter of the vertices).

    Parameters
    ----------
    vertices : (n, d) float array
        The cage's vertices, in any units.

    Raises
    ------
    CageError
        Naming the vertices and what to do.
    """
    finite = np.all(np.isfinite(vertices), axis=1)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise CageVertexError(
            f"NaN or infinite coordinates at {count_of(len(bad), 'cage vertex', 'cage vertices')} "
            f"({some_indices(bad)}): "
            "fix or delete them"
        )
    distances = np.linalg.norm(vertices - np.median(vertices, axis=0), axis=1)
    order = np.argsort(distances)
    for count in range(len(vertices) // 4, 0, -1):  # the most far-off vertices first
        rest = np.linalg.norm(np.ptp(vertices[order[:-count]], axis=0))
        if rest > 0 and distances[order[-count]] > FAR_OFF * rest:
            break
    else:
        return
    far = np.sort(order[-count:])
    which, verb, pronoun = (f"cage vertex {some_indices(far)}", "lies", "it") if len(far) == 1 else (
        f"cage vertices {some_indices(far)}", "lie", "them")
    raise CageVertexError(
        f"{which} {verb} {distances[far].max():.3g} from the cage's middle, over a million times the size of the "
        "rest of it (a coordinate typed wrong, or an infinite one, which Blender stores as its largest number, "
        f"3.4e+38): move {pronoun} back"
    )


def _check_size(n_vertices, n_faces, max_control_points):
    """Refuse, before any work, inputs that cannot give a cage of at most ``max_control_points``."""
    if n_faces is not None and n_faces > _FACES_PER_CONTROL_POINT * max_control_points:
        _refuse_size(f"{n_faces} faces", max_control_points)
    if n_vertices > _INPUT_VERTICES_PER_CONTROL_POINT * max_control_points:
        _refuse_size(f"{n_vertices} vertices", max_control_points)


def _check_control_points(n, max_control_points):
    if n > max_control_points:
        _refuse_size(f"{n} distinct vertices (control points)", max_control_points)


def _refuse_size(what, max_control_points):
    raise CageError(
        f"the cage has {what}; lbc binds cages of at most {max_control_points} control points (the solve's memory "
        "grows with control points × cells and its time with mesh vertices × control points²): use a coarser cage, "
        "e.g. with a Decimate modifier or a low-poly retopology"
    )


def _welded_warning(count):
    return f"welded {count_of(count, 'duplicate cage vertex', 'duplicate cage vertices')}"


def _weld(vertices, weld_tolerance):
    """Merge vertices closer than ``weld_tolerance`` × diagonal.

    Returns
    -------
    welded : (n, d) float array
        The first input vertex of each group, in input order.
    vertex_map : (n_input,) int array
        Index in ``welded`` of each input vertex.
    """
    diagonal = np.linalg.norm(np.ptp(vertices, axis=0))
    pairs = cKDTree(vertices).query_pairs(weld_tolerance * diagonal, output_type="ndarray")
    if not len(pairs):
        return vertices.copy(), np.arange(len(vertices))
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(vertices),) * 2)
    _, labels = connected_components(graph, directed=False)
    _, first, vertex_map = np.unique(labels, return_index=True, return_inverse=True)
    # Number the groups in the input order of their first vertex.
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    return vertices[np.sort(first)], rank[vertex_map]


def _flatness(points):
    """Largest distance of the points from their best-fit line (2D) or plane (3D), in the points' units."""
    centred = points - points.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
    return float(np.max(np.abs(centred @ normal)))


def _make_polygon_cage(vertices, weld_tolerance, max_control_points):
    if vertices.shape[1] == 3:
        if np.ptp(vertices[:, 2]) > ZERO_LENGTH * max(np.ptp(vertices[:, :2]), 1e-300):
            raise CageError("a 2D polygon cage must lie in a plane z = constant; pass faces for a 3D cage")
        vertices = vertices[:, :2]
    if len(vertices) < 3:
        raise CageError(
            f"a polygon cage needs at least 3 vertices, got {len(vertices)}: give the outline's corners in order"
        )
    warnings = []
    welded, vertex_map = _weld(vertices, weld_tolerance)
    if len(welded) < len(vertices):
        warnings.append(_welded_warning(len(vertices) - len(welded)))
        # Consecutive duplicates collapse; the polygon order follows the first occurrences.
        order = vertex_map[np.r_[True, vertex_map[1:] != vertex_map[:-1]]]
        if len(order) > 1 and order[0] == order[-1]:
            order = order[:-1]
        if len(np.unique(order)) != len(order):
            twice = np.flatnonzero(np.bincount(order) > 1)
            raise CageVertexError(
                f"the polygon cage passes twice through vertex {some_indices(first_inputs(vertex_map)[twice])}: it "
                "touches itself; separate the touching parts"
            )
        welded, vertex_map = welded[order], np.argsort(order)[vertex_map]
    if len(welded) < 3:
        raise CageError(f"a polygon cage needs at least 3 distinct vertices, got {len(welded)} after welding")
    _check_control_points(len(welded), max_control_points)
    zero = ZERO_LENGTH * np.linalg.norm(np.ptp(welded, axis=0))
    if _flatness(welded) <= zero:
        raise CageError("the polygon cage encloses zero area: its vertices are collinear; spread them out")
    names = first_inputs(vertex_map)
    _check_polygon_simple(welded, zero, names)
    n = len(welded)
    edges = np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1)
    if enclosed_measure(welded, edges) < 0:
        edges = edges[:, ::-1]
    return Cage(welded, edges, np.arange(n), vertex_map, warnings)


def _check_polygon_simple(vertices, zero, names):
    """Raise one CageError if the closed polygon doubles back at vertices or non-adjacent edges cross or touch.

    Parameters
    ----------
    vertices : (n, 2) float array
        Welded, in boundary order.
    zero : float
        Length that counts as zero.
    names : (n,) int array
        Input index of each vertex, for messages.
    """
    n = len(vertices)
    start, end = vertices, np.roll(vertices, -1, axis=0)
    # A spike: the next vertex lies on the line of the incoming edge, behind the corner.
    incoming, outgoing = end - start, np.roll(end - start, -1, axis=0)
    spike = (np.abs(cross2(incoming, outgoing)) <= zero * np.linalg.norm(incoming, axis=1)) & (
        np.einsum("ij,ij->i", incoming, outgoing) < 0
    )
    defects = []
    if np.any(spike):
        corner = names[(np.flatnonzero(spike) + 1) % n]
        defects.append(NamesVertices(
            f"the polygon cage doubles back on itself at vertex {some_indices(corner)} (a zero-width spike): delete "
            "that vertex or move it off the line of its neighbours"
        ))
    low, high = np.minimum(start, end) - zero, np.maximum(start, end) + zero
    i, j = overlapping_boxes(low, high).T
    distance = (j - i) % n
    i, j = i[(distance != 1) & (distance != n - 1)], j[(distance != 1) & (distance != n - 1)]
    crossing = segments_touch(start[i], end[i], start[j], end[j], zero)
    if np.any(crossing):
        i, j = i[crossing], j[crossing]
        pairs = some_items([f"{names[a]}-{names[(a + 1) % n]} with {names[b]}-{names[(b + 1) % n]}"
                            for a, b in zip(i, j)])
        defects.append(NamesVertices(
            f"the polygon cage intersects itself at {count_of(len(i), 'pair')} of crossing or touching edges (between "
            f"input vertices {pairs}); move its vertices so that the outline does not cross itself"
        ))
    raise_all(defects)


def _make_mesh_cage(vertices, faces, weld_tolerance, max_control_points):
    if vertices.shape[1] != 3:
        raise CageError("a cage with faces must have 3D vertices; for a 2D polygon pass faces=None")
    faces = face_list(faces, len(vertices))  # first: a cage without faces is told so, whatever its vertex count
    if len(vertices) < 4:
        raise CageError(f"a 3D cage needs at least 4 vertices (a tetrahedron), got {len(vertices)}")
    warnings = []
    welded, vertex_map = _weld(vertices, weld_tolerance)
    if len(welded) < len(vertices):
        warnings.append(_welded_warning(len(vertices) - len(welded)))
    if len(welded) < 4:
        raise CageError(
            f"a 3D cage needs at least 4 distinct vertices (a tetrahedron), got {len(welded)} after welding"
        )
    _check_control_points(len(welded), max_control_points)
    diagonal = np.linalg.norm(np.ptp(welded, axis=0))
    zero = ZERO_LENGTH * diagonal
    if _flatness(welded) <= zero:
        raise CageError(
            "the cage is flat (all its vertices lie in one plane) and encloses zero volume: give it thickness, "
            "or bind in 2D with a polygon cage"
        )
    names = first_inputs(vertex_map)
    # Every defect below is collected and reported at once, so that fixing what the message lists gives a valid
    # cage; each check runs on what the earlier ones leave (one copy of a duplicated face, non-degenerate triangles).
    defects = []
    faces, collapsed, excused = collapse_welded(faces, vertex_map, names, defects)
    if collapsed:
        warnings.append(f"dropped {count_of(collapsed, 'cage face')} that welding collapsed to an edge or a point")
    unused = np.setdiff1d(np.arange(len(welded)), [corner for _, face in faces for corner in face])
    if len(unused):
        defects.append(NamesVertices(
            f"the cage has {count_of(len(unused), 'loose vertex', 'loose vertices')}, in no face (vertex "
            f"{some_indices(names[unused])}): delete them from the cage (in Blender: Mesh > Clean Up > Delete Loose)"
        ))
    triangles, triangle_face, clean = triangulate_faces(welded, faces, zero, defects)
    clean &= ~report_degenerate(welded, triangles, triangle_face, zero, defects)
    pairing = check_closed_manifold(triangles, names, defects, excused)
    if pairing is not None:
        oriented = orient_outward(welded, triangles, pairing, triangle_face, defects)
        if oriented is not None:
            triangles, flipped = oriented
            if np.all(flipped):
                warnings.append("reversed all cage faces: they pointed inward")
            elif np.any(flipped):
                warnings.append(
                    f"flipped {count_of(len(np.unique(triangle_face[flipped])), 'cage face')} to make the orientation "
                    "consistent and outward"
                )
    triangles, triangle_face, clean, centres = poke(welded, triangles, triangle_face, clean, faces)
    cage = Cage(welded, triangles, triangle_face, vertex_map, warnings, tuple(centres))
    check_self_intersection(cage.surface_vertices, triangles[clean], triangle_face[clean], zero, defects)
    raise_all(defects)
    if cage.measure <= ZERO_LENGTH * diagonal**3:
        raise CageError("the cage encloses zero volume: give it thickness, or bind in 2D with a polygon cage")
    cage.warnings += fans(triangles, triangle_face, faces, names)
    return cage
