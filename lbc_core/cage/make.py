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
  takes its outline's smooth mean value coordinates instead, :mod:`lbc_core.solve.boundary`). The cage's surface vertices
  (``surface_vertices``) are its control points followed by these centres;
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

import hashlib
import operator
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, connected_components
from scipy.spatial import cKDTree

from ..errors import CageError, CageVertexError
from ..kernel.geometry import (
    cross2,
    enclosed_measure,
    hull_share,
    in_triangle_2d,
    intersecting_triangles,
    is_convex_polygon,
    newell_normal,
    overlapping_boxes,
    plane_axes,
    segments_touch,
    triangle_normals,
    unit,
    winding_numbers,
)

DEFAULT_WELD_TOLERANCE = 1e-9  # relative to the bounding-box diagonal
# A vertex a million times farther from the cage's middle than the rest of the cage is wide is no part of it: it would
# set the welding tolerance (DEFAULT_WELD_TOLERANCE of the diagonal) and weld every other vertex into one.
FAR_OFF = 1e6
ZERO_LENGTH = 1e-9  # relative to the bounding-box diagonal
# n-gons from this many sides are poked at their vertices' mean (the module docstring). Ear-clipped, Blender's
# Cylinder's 32-gon caps fanned out from one vertex, whose coordinate summed to 466 over the points inside against
# 18-166 for the others (bench/RESULTS.md).
POKE_SIDES = 5
# Least distance of an n-gon's centre inside each side's line to poke it, a share of its largest distance to a vertex
# (bench/RESULTS.md, "n-gons poked at their vertices' mean"); a convex n-gon's, less (bench/RESULTS.md, "A convex
# poked n-gon's values").
POKE_HEIGHT = 0.1
POKE_HEIGHT_CONVEX = 0.02
# n-gons from this many sides that could not be poked and whose ear clipping fans out from one vertex are named in the
# cage's warnings.
FAN_NOTICE_SIDES = 8
# Share by which a quad's diagonals may differ and still split it from its first vertex, so that a small edit keeps
# its split (bench/RESULTS.md, "Warm re-bind of Blender's quad cages").
QUAD_SPLIT_TIE = 0.25
# Control points at most: larger cages are refused before any work, as no machine would bind them in reasonable time
# (bench/RESULTS.md, "The control-point limit"); pipeline.check_request refuses smaller ones that do not fit memory.
MAX_CONTROL_POINTS = 2000
# Closed triangle meshes have about 2 triangles per vertex; 4 leaves room for handles and unwelded input.
_FACES_PER_CONTROL_POINT = 4
# Unwelded triangle soups repeat each vertex about 6 times.
_INPUT_VERTICES_PER_CONTROL_POINT = 8
_LISTED = 5  # how many offending items a message names
# Welded copies of a vertex posed farther apart than this fraction of the cage's size are refused in a deform: far
# below anything visible, far above the round-off of transforming coincident points alike.
POSED_APART = 1e-6


@dataclass
class Cage:
    """A checked cage.

    Attributes
    ----------
    vertices : (n, d) float array
        Control points after welding, d = 2 or 3, in the input's units.
    facets : (E, d) int array
        2D: polygon edges (i, i+1) or (i+1, i), oriented counter-clockwise; every control point starts exactly one
        edge. 3D: triangles of ``surface_vertices`` (control points, then poked n-gons' centres), outward-oriented.
    facet_face : (E,) int array
        Index of the input face each facet comes from (2D: the edge index).
    vertex_map : (n_input,) int array
        Index in ``vertices`` of each input vertex (welding merges some).
    warnings : list of str
        What was repaired (welded vertices, flipped faces), for the user to read.
    centres : tuple of int arrays
        The control points of each poked n-gon (3D); its centre, surface vertex n + c, is their mean.
    """

    vertices: np.ndarray
    facets: np.ndarray
    facet_face: np.ndarray
    vertex_map: np.ndarray
    warnings: list = field(default_factory=list)
    centres: tuple = ()

    @property
    def dim(self):
        return self.vertices.shape[1]

    @property
    def n_control_points(self):
        return len(self.vertices)

    @property
    def first_inputs(self):
        """(n,) int array: an input vertex for each control point, the first of those welded into it."""
        return _first_inputs(self.vertex_map)

    @property
    def is_simplex(self):
        """A triangle (2D) or tetrahedron (3D): its coordinates are the barycentric ones, nothing to solve."""
        return self.n_control_points == self.dim + 1

    @property
    def centre_values(self):
        """(C, n) scipy.sparse.csr_matrix: each poked n-gon's centre as a combination of the control points (1/k
        for each of its k vertices), its boundary values and its position (``centre_values @ vertices``)."""
        sizes = np.array([len(corners) for corners in self.centres], dtype=np.int64)
        columns = np.concatenate(self.centres).astype(np.int64) if self.centres else np.zeros(0, np.int64)
        indptr = np.r_[0, np.cumsum(sizes)]
        return sp.csr_matrix((np.repeat(1.0 / np.maximum(sizes, 1), sizes), columns, indptr),
                             shape=(len(self.centres), self.n_control_points))

    @property
    def surface_vertices(self):
        """(n + C, d) float array: the vertices of ``facets``, the control points and then the poked n-gons' centres."""
        if not self.centres:
            return self.vertices
        return np.vstack([self.vertices, self.centre_values @ self.vertices])

    @property
    def surface_values(self):
        """(n + C, n) scipy.sparse.csr_matrix: the boundary values at each surface vertex (a unit row at a control
        point, :attr:`centre_values` at a centre)."""
        return sp.vstack([sp.identity(self.n_control_points, format="csr"), self.centre_values], format="csr")

    def surface(self):
        """The cage as the mesher sees it: every surface vertex a vertex of its own, no centres."""
        return replace(self, vertices=self.surface_vertices, centres=())

    @property
    def bbox_diagonal(self):
        return float(np.linalg.norm(self.vertices.max(axis=0) - self.vertices.min(axis=0)))

    @property
    def measure(self):
        """Signed area (2D) or volume (3D) enclosed; positive for the stored orientation."""
        return float(enclosed_measure(self.surface_vertices, self.facets))

    @property
    def convexity(self):
        """The enclosed area or volume over its convex hull's: 1 for a convex cage (whose coordinates spread wider,
        so that its solve costs more: :mod:`lbc_core.solve.forecast`)."""
        return hull_share(self.surface_vertices, self.measure)

    def fingerprint(self):
        """A hash of the topology (vertex count and facets); positions do not enter it.

        Returns
        -------
        str, 16 hex digits
        """
        digest = hashlib.sha256()
        digest.update(np.int64(len(self.vertex_map)).tobytes())
        digest.update(np.ascontiguousarray(self.vertex_map, dtype=np.int64).tobytes())
        digest.update(np.ascontiguousarray(self.facets, dtype=np.int64).tobytes())
        return digest.hexdigest()[:16]

    def face_corners(self):
        """The control points of each input face that has facets, however it was split: a list of (face index,
        frozenset of int), in face order."""
        n = self.n_control_points
        faces = {}
        for facet, face in zip(self.facets.tolist(), self.facet_face.tolist()):
            faces.setdefault(face, set()).update(corner for corner in facet if corner < n)
        return [(face, frozenset(corners)) for face, corners in sorted(faces.items())]

    def control_points_from_input(self, input_vertices):
        """Map positions given per input vertex (e.g. a posed cage) to the welded control points.

        Input vertices welded into one control point must stay together: each control point takes its first input
        vertex's position, and copies posed apart (by more than :data:`POSED_APART` × the cage's size) are refused
        with their numbers, never ignored.

        Parameters
        ----------
        input_vertices : (n_input, d) float array
            A 2D cage's positions may also be (n_input, 3) with a constant z, as it was bound.

        Returns
        -------
        (n, d) float array

        Raises
        ------
        CageError
            Another vertex count or dimension, NaN/inf, or welded copies posed apart.
        """
        input_vertices = real_array(input_vertices, "cage positions", f"(n, {self.dim})")
        given_with_z = self.dim == 2 and input_vertices.ndim == 2 and input_vertices.shape[1] == 3
        if given_with_z and len(input_vertices) and np.all(input_vertices[:, 2] == input_vertices[0, 2]):
            input_vertices = input_vertices[:, :2]
        if input_vertices.shape != (len(self.vertex_map), self.dim):
            raise CageError(
                f"the cage has {len(self.vertex_map)} vertices in {self.dim}D, got positions of shape "
                f"{input_vertices.shape}: deform with the cage the binding was made for, or bind again"
            )
        if not np.all(np.isfinite(input_vertices)):
            bad = np.flatnonzero(~np.all(np.isfinite(input_vertices), axis=1))
            raise CageVertexError(f"NaN or infinite positions of cage vertex {some_indices(bad)}: fix or delete them")
        first = _first_inputs(self.vertex_map)
        points = input_vertices[first]
        if len(first) < len(self.vertex_map):
            offset = np.linalg.norm(input_vertices - points[self.vertex_map], axis=1)
            size = np.linalg.norm(np.ptp(input_vertices, axis=0))
            apart = np.flatnonzero(offset > POSED_APART * size)
            if len(apart):
                pairs = _listed([f"{first[self.vertex_map[k]]}/{k}" for k in apart])
                raise CageVertexError(
                    f"cage vertices {pairs} coincided when bound and were welded into one control point, but are "
                    "posed apart: move each such pair together (in Blender: Mesh > Clean Up > Merge by Distance on "
                    "the cage), or separate them and bind again"
                )
        return points

    def check_faces(self, faces):
        """Refuse faces that are not the ones this cage was made from (a posed copy must keep its faces).

        Parameters
        ----------
        faces : None or sequence of index sequences
            The posed cage's faces as read (None for a polygon).

        Raises
        ------
        CageError
        """
        if self.dim == 2:
            if faces is not None:
                raise CageError("the binding is for a 2D polygon cage, but this cage has faces: pose the polygon "
                                "that was bound (vertices only)")
            return
        if faces is None:
            raise CageError("the binding is for a 3D cage, but this cage has no faces: pose the cage that was bound, "
                            "with its faces")
        faces = [np.asarray(face, dtype=np.int64) for face in faces]
        if any(face.size and (face.min() < 0 or face.max() >= len(self.vertex_map)) for face in faces):
            raise CageError(f"this cage has faces with corners that are not among its {len(self.vertex_map)} "
                            "vertices: pose the cage that was bound")
        for face, bound in self.face_corners():
            if face >= len(faces) or not bound <= set(self.vertex_map[faces[face]].tolist()):
                raise CageError(
                    f"this cage's faces differ from the bound cage's (face {face} and on): same vertex count, other "
                    "faces; pose the cage that was bound, or bind this one again"
                )


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
            f"NaN or infinite coordinates at {_count(len(bad), 'cage vertex', 'cage vertices')} ({some_indices(bad)}): "
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


def real_array(values, what, shape):
    """``values`` as a float array; CageError when they are not real numbers (text, complex numbers, ragged rows).

    Parameters
    ----------
    values : array-like
    what : str
        What the values are, for the message ("cage vertices").
    shape : str
        The expected shape, for the message ("(n, 2) or (n, 3)").
    """
    try:
        array = np.asarray(values)
        if array.dtype.kind in "cSUV" or (array.dtype.kind == "O" and any(isinstance(v, complex) for v in array.flat)):
            raise TypeError(array.dtype)
        return array.astype(float)
    except (TypeError, ValueError):
        raise CageError(f"{what} must be real numbers in an {shape} array") from None


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


def _count(number, singular, plural=None):
    """'1 edge', '4 edges': a count with its noun, for messages."""
    return f"{number} {singular if number == 1 else plural or singular + 's'}"


def some_indices(indices):
    """'3, 7, 9' or '3, 7, 9, 12, 15, ...': a few of the offending indices for a message."""
    return _listed([str(int(i)) for i in np.ravel(indices)])


def _listed(items):
    """The first few of the strings ``items``, comma-separated, with ', ...' when some are left out."""
    return ", ".join(items[:_LISTED]) + (", ..." if len(items) > _LISTED else "")


class _NamesVertices(str):
    """A defect message that names cage vertices by their input numbers (:func:`_raise_all` raises it as a
    CageVertexError)."""


def _raise_all(defects):
    """Raise one CageError listing every defect message found (nothing when there is none); a CageVertexError when
    one of them names cage vertices."""
    error = CageVertexError if any(isinstance(defect, _NamesVertices) for defect in defects) else CageError
    if len(defects) == 1:
        raise error(str(defects[0]))
    if defects:
        raise error(f"the cage has {len(defects)} kinds of defect, all listed here: "
                    + "; ".join(f"({k}) {defect}" for k, defect in enumerate(defects, 1)))


def _welded_warning(count):
    return f"welded {_count(count, 'duplicate cage vertex', 'duplicate cage vertices')}"


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


def _first_inputs(vertex_map):
    """(n,) int array: the first input vertex of each welded vertex, to name vertices as the user numbers them."""
    return np.unique(vertex_map, return_index=True)[1]


def _flatness(points):
    """Largest distance of the points from their best-fit line (2D) or plane (3D), in the points' units."""
    centred = points - points.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
    return float(np.max(np.abs(centred @ normal)))


# ---------------------------------------------------------------------------------------------------------- 2D polygon


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
                f"the polygon cage passes twice through vertex {some_indices(_first_inputs(vertex_map)[twice])}: it "
                "touches itself; separate the touching parts"
            )
        welded, vertex_map = welded[order], np.argsort(order)[vertex_map]
    if len(welded) < 3:
        raise CageError(f"a polygon cage needs at least 3 distinct vertices, got {len(welded)} after welding")
    _check_control_points(len(welded), max_control_points)
    zero = ZERO_LENGTH * np.linalg.norm(np.ptp(welded, axis=0))
    if _flatness(welded) <= zero:
        raise CageError("the polygon cage encloses zero area: its vertices are collinear; spread them out")
    names = _first_inputs(vertex_map)
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
        defects.append(_NamesVertices(
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
        pairs = _listed([f"{names[a]}-{names[(a + 1) % n]} with {names[b]}-{names[(b + 1) % n]}" for a, b in zip(i, j)])
        defects.append(_NamesVertices(
            f"the polygon cage intersects itself at {_count(len(i), 'pair')} of crossing or touching edges (between "
            f"input vertices {pairs}); move its vertices so that the outline does not cross itself"
        ))
    _raise_all(defects)


# ------------------------------------------------------------------------------------------------------------ 3D mesh


def _make_mesh_cage(vertices, faces, weld_tolerance, max_control_points):
    if vertices.shape[1] != 3:
        raise CageError("a cage with faces must have 3D vertices; for a 2D polygon pass faces=None")
    faces = _face_list(faces, len(vertices))  # first: a cage without faces is told so, whatever its vertex count
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
    names = _first_inputs(vertex_map)
    # Every defect below is collected and reported at once, so that fixing what the message lists gives a valid
    # cage; each check runs on what the earlier ones leave (one copy of a duplicated face, non-degenerate triangles).
    defects = []
    faces, collapsed, excused = _collapse_welded(faces, vertex_map, names, defects)
    if collapsed:
        warnings.append(f"dropped {_count(collapsed, 'cage face')} that welding collapsed to an edge or a point")
    unused = np.setdiff1d(np.arange(len(welded)), [corner for _, face in faces for corner in face])
    if len(unused):
        defects.append(_NamesVertices(
            f"the cage has {_count(len(unused), 'loose vertex', 'loose vertices')}, in no face (vertex "
            f"{some_indices(names[unused])}): delete them from the cage (in Blender: Mesh > Clean Up > Delete Loose)"
        ))
    triangles, triangle_face, clean = _triangulate(welded, faces, zero, defects)
    clean &= ~_report_degenerate(welded, triangles, triangle_face, zero, defects)
    pairing = _check_closed_manifold(triangles, names, defects, excused)
    if pairing is not None:
        oriented = _orient_outward(welded, triangles, pairing, triangle_face, defects)
        if oriented is not None:
            triangles, flipped = oriented
            if np.all(flipped):
                warnings.append("reversed all cage faces: they pointed inward")
            elif np.any(flipped):
                warnings.append(
                    f"flipped {_count(len(np.unique(triangle_face[flipped])), 'cage face')} to make the orientation "
                    "consistent and outward"
                )
    triangles, triangle_face, clean, centres = _poke(welded, triangles, triangle_face, clean, faces)
    cage = Cage(welded, triangles, triangle_face, vertex_map, warnings, tuple(centres))
    _check_self_intersection(cage.surface_vertices, triangles[clean], triangle_face[clean], zero, defects)
    _raise_all(defects)
    if cage.measure <= ZERO_LENGTH * diagonal**3:
        raise CageError("the cage encloses zero volume: give it thickness, or bind in 2D with a polygon cage")
    cage.warnings += _fans(triangles, triangle_face, faces, names)
    return cage


def _poke(vertices, triangles, triangle_face, clean, faces):
    """The n-gons of :data:`POKE_SIDES` sides or more whose mean sees every side (:data:`POKE_HEIGHT`) split into
    triangles from it instead of their ear clipping, in the orientation their ear clipping was given.

    Returns
    -------
    triangles (T', 3) int array, triangle_face (T',) int array, clean (T',) bool array
        As given, the poked faces' triangles replaced (centre c is vertex n + c), in input face order.
    centres : list of (k,) int arrays
        The vertices of each poked face, in its outward order.
    """
    n = len(vertices)
    centres, replaced, added = [], [], []
    for index, face in faces:
        low, high = np.searchsorted(triangle_face, [index, index + 1])  # triangles come in input face order
        if len(face) < POKE_SIDES or not clean[low:high].all():
            continue
        ring = np.array(face)
        if _reversed(triangles[low], face):
            ring = ring[::-1]
        if _sees_every_side(vertices[ring]):
            replaced.append(np.arange(low, high))
            added.append((index, np.column_stack([np.full(len(ring), n + len(centres)), ring, np.roll(ring, -1)])))
            centres.append(ring)
    if not centres:
        return triangles, triangle_face, clean, centres
    kept = np.ones(len(triangles), dtype=bool)
    kept[np.concatenate(replaced)] = False
    triangles = np.vstack([triangles[kept]] + [pieces for _, pieces in added])
    triangle_face = np.concatenate([triangle_face[kept]] + [np.full(len(pieces), index) for index, pieces in added])
    clean = np.r_[clean[kept], np.ones(len(triangles) - np.count_nonzero(kept), dtype=bool)]
    order = np.argsort(triangle_face, kind="stable")
    return triangles[order], triangle_face[order], clean[order], centres


def _reversed(triangle, face):
    """Whether a triangle cut from ``face`` (its corners in the face's cyclic order or against it) runs against it."""
    position = {corner: k for k, corner in enumerate(face)}
    a, b, c = (position[corner] for corner in triangle.tolist())
    return (b - a) % len(face) + (c - b) % len(face) + (a - c) % len(face) > len(face)


def _sees_every_side(points):
    """Whether the mean of an n-gon's points (k, 3), in outward order, stands at least POKE_HEIGHT (a convex n-gon:
    POKE_HEIGHT_CONVEX) of its largest distance to them inside the line of each side, in the plane of the n-gon's
    Newell normal."""
    normal = newell_normal(points)
    centre = points.mean(axis=0)
    if not np.linalg.norm(normal) > 0:
        return False
    normal /= np.linalg.norm(normal)
    sides = np.roll(points, -1, axis=0) - points
    lengths = np.linalg.norm(sides, axis=1)
    heights = np.einsum("ij,j->i", np.cross(sides, centre - points), normal) / np.maximum(lengths, np.finfo(float).tiny)
    reach = np.max(np.linalg.norm(points - centre, axis=1))
    least = POKE_HEIGHT_CONVEX if is_convex_polygon(points @ plane_axes(normal).T) else POKE_HEIGHT
    return bool(np.all(lengths > 0) and np.all(heights >= least * reach))


def _fans(triangles, triangle_face, faces, names):
    """A notice (a list of at most one string) naming the n-gons of :data:`FAN_NOTICE_SIDES` sides or more, not
    poked, whose triangles fan out from one vertex: its boundary values span the whole face, the others' slivers."""
    fans = []
    for index, face in faces:
        own = triangles[triangle_face == index]
        if len(face) >= FAN_NOTICE_SIDES and np.all(own < len(names)):  # not poked: no centre among its corners
            counts = np.bincount(own.ravel())
            apex = int(np.argmax(counts))
            if counts[apex] > (len(face) - 2) / 2:
                fans.append((index, len(face), int(names[apex])))
    if not fans:
        return []
    sides = sorted({count for _, count, _ in fans})
    size = f"{sides[0]} sides" if len(sides) == 1 else f"{sides[0]} to {sides[-1]} sides"
    which = " and ".join(some_indices([index for index, _, _ in fans]).rsplit(", ", 1))
    apexes = " and ".join(some_indices([apex for _, _, apex in fans]).rsplit(", ", 1))
    if len(fans) == 1:
        said = (f"cage face {which} (an n-gon of {size}) is split into a fan of triangles from vertex {apexes}, which "
                "moves most of the face while its other vertices barely do")
    else:
        said = (f"cage faces {which} (n-gons of {size}) are split into fans of triangles from vertices {apexes}, "
                "which move most of their faces while the other vertices barely do")
    # Triangulating in Blender does not help: its Beauty split of such a face is a fan as well (a new user's check).
    them, whose = ("it", "its") if len(fans) == 1 else ("them", "their")
    return [f"{said}, and {whose} middle lies outside {them} or too near a side to split {them} from there: split "
            f"{them} into rounder faces (in Blender, Select > Select All by Trait > Faces by Sides, greater than "
            f"{FAN_NOTICE_SIDES - 1}, finds {them}; select two vertices across such a face and press J, Connect Vertex "
            "Path)"]


def _face_list(faces, n_vertices):
    """The faces as lists of Python ints, checked against the vertex count."""
    if isinstance(faces, np.ndarray):
        faces = faces.tolist()
    try:
        faces = [[operator.index(corner) for corner in face] for face in faces]
    except TypeError:
        raise CageError("cage faces must be sequences of integer vertex indices") from None
    if not faces:
        raise CageError("the 3D cage has no faces: pass its faces, or faces=None for a 2D polygon")
    invalid = [index for index, face in enumerate(faces) if len(face) < 3 or min(face) < 0 or max(face) >= n_vertices]
    if invalid:
        listed = _listed([f"{index} ({faces[index]})" for index in invalid])
        raise CageError(
            f"cage face{'s' if len(invalid) > 1 else ''} {listed} {'are' if len(invalid) > 1 else 'is'} invalid: a "
            f"face needs 3 or more indices of the cage's {n_vertices} vertices"
        )
    return faces


def _collapse_welded(faces, vertex_map, names, defects):
    """Faces in welded indices without the corners welding merged; faces reduced below 3 corners are dropped;
    faces passing twice through a vertex and duplicated faces (the same corners, in any order) are reported in
    ``defects`` and left out (duplicates: all copies but the first).

    Returns
    -------
    faces : list of (index, list of int)
        Input face index and corners of each kept face.
    dropped : int
    excused : list of sets of int
        The corners of each face passing twice through a vertex: edges between them, left open by leaving those
        faces out, close when the faces are split as advised, so they are not reported as holes.
    """
    vertex_map = vertex_map.tolist()
    kept, dropped, seen, twice, copies = [], 0, {}, [], []
    for index, face in enumerate(faces):
        face = [vertex_map[corner] for corner in face]
        face = [corner for k, corner in enumerate(face) if corner != face[k - 1]]
        if len(face) < 3:
            dropped += 1
            continue
        if len(set(face)) != len(face):
            twice.append((index, sorted({corner for corner in face if face.count(corner) > 1})))
            continue
        copy = seen.setdefault(tuple(sorted(face)), index)
        if copy != index:
            copies.append((copy, index))
            continue
        kept.append((index, face))
    if twice:
        listed = _listed([f"face {index} twice through vertex {some_indices(names[corners])}"
                          for index, corners in twice])
        defects.append(_NamesVertices(
            f"{_count(len(twice), 'cage face passes', 'cage faces pass')} through a vertex twice ({listed}): split "
            "each into faces that visit a vertex once"
        ))
    if copies:
        listed = _listed([f"{a} and {b}" for a, b in copies])
        defects.append(
            f"the cage has {_count(len(copies), 'duplicated face')} (faces using the same vertices as another: "
            f"{listed}): delete one face of each pair, not both (deleting both opens the cage; in Blender, Select "
            "All by Trait > Interior Faces selects both)"
        )
    excused = [{vertex_map[corner] for corner in faces[index]} for index, _ in twice]
    return kept, dropped, excused


def _triangulate(vertices, faces, zero, defects):
    """Triangles of all faces (see the module docstring for the choice).

    An n-gon that cannot be triangulated is reported in ``defects`` and split as a fan, so that the checks of the
    surface's topology still see it.

    Returns
    -------
    triangles : (T, 3) int array
        In the faces' own orientation, in input face order.
    triangle_face : (T,) int array
        Input face index of each triangle.
    clean : (T,) bool array
        False for the fans of the n-gons that could not be triangulated.
    """
    if not faces and not defects:
        raise CageError("every face of the cage collapsed when welding its vertices: the cage has no faces left")
    triangles = [(index, [face]) for index, face in faces if len(face) == 3]
    fans = set()
    for index, face in faces:
        if len(face) == 4:
            triangles.append((index, _split_quad(vertices, np.array(face), zero)))
        elif len(face) > 4:
            try:
                triangles.append((index, _ear_clip(vertices, np.array(face), index, zero)))
            except CageError as error:
                defects.append(str(error))
                triangles.append((index, [[face[0], face[k], face[k + 1]] for k in range(1, len(face) - 1)]))
                fans.add(index)
    triangles.sort(key=lambda item: item[0])
    triangle_face = np.array([index for index, pieces in triangles for _ in pieces], dtype=np.int64)
    triangles = np.array([list(t) for _, pieces in triangles for t in pieces], dtype=np.int64).reshape(-1, 3)
    return triangles, triangle_face, ~np.isin(triangle_face, list(fans))


def _split_quad(vertices, quad, zero):
    """(2, 3) int array: the quad's two triangles along the shorter diagonal that stays inside it (the one from its
    first vertex when the two tie within QUAD_SPLIT_TIE)."""
    points = vertices[quad]
    options = (quad[[[0, 1, 2], [0, 2, 3]]], quad[[[0, 1, 3], [1, 2, 3]]])
    lengths = np.array([np.linalg.norm(points[0] - points[2]), np.linalg.norm(points[1] - points[3])])
    tie = abs(lengths[0] - lengths[1]) <= QUAD_SPLIT_TIE * lengths.max()
    preference = (0, 1) if tie else np.argsort(lengths, kind="stable")
    for choice in preference:
        normals = triangle_normals(vertices[options[choice]])
        if normals[0] @ normals[1] > 0 and not np.any(_degenerate(vertices[options[choice]], zero)):
            return options[choice]
    # A zero-area or bow-tie quad: the degenerate-face or self-intersection check names it.
    return options[preference[0]]


def _ear_clip(vertices, face, index, zero):
    """(k - 2, 3) int array: ear clipping of an n-gon in the plane of its Newell normal, first ear in face order."""
    points = vertices[face]
    normal = newell_normal(points)
    if np.linalg.norm(normal) <= zero * np.max(np.linalg.norm(points - points[0], axis=1)):
        raise CageError(f"cage face {index} has zero area: delete it or dissolve it into its neighbours")
    flat = points @ plane_axes(unit(normal)).T  # the face counter-clockwise
    remaining = np.arange(len(face))
    triangles = []
    while len(remaining) > 3:
        corner = flat[remaining]
        before, after = np.roll(corner, 1, axis=0), np.roll(corner, -1, axis=0)
        # Convex corners standing clear of the line through their neighbours (collinear ones make no ear).
        convex = cross2(corner - before, after - corner) > zero * np.linalg.norm(after - before, axis=1)
        ears = np.flatnonzero(convex)
        others = np.flatnonzero(~convex)  # only non-convex corners can lie inside a convex ear
        if len(others):
            count = len(remaining)
            blocked = in_triangle_2d(corner[others][None], before[ears][:, None], corner[ears][:, None],
                                     after[ears][:, None], zero)
            own = (others[None] == (ears[:, None] - 1) % count) | (others[None] == (ears[:, None] + 1) % count)
            ears = ears[~np.any(blocked & ~own, axis=1)]
        if not len(ears):
            raise CageError(
                f"cage face {index} cannot be triangulated: its outline crosses itself or is badly non-planar; "
                "split it into simpler faces (in Blender: Face > Triangulate Faces, then fix the result)"
            )
        ear = ears[0]
        triangles.append(face[remaining[[ear - 1, ear, (ear + 1) % len(remaining)]]])
        remaining = np.delete(remaining, ear)
    triangles.append(face[remaining])
    return np.array(triangles)


def _report_degenerate(vertices, triangles, triangle_face, zero, defects):
    """(T,) bool: the triangles of zero area; their input faces are reported in ``defects``."""
    bad = _degenerate(vertices[triangles], zero)
    if np.any(bad):
        faces = np.unique(triangle_face[bad])
        defects.append(
            f"the cage has {_count(len(faces), 'face')} of zero area (face {some_indices(faces)}): delete or dissolve "
            "them (in Blender: Mesh > Clean Up > Degenerate Dissolve)"
        )
    return bad


def _degenerate(corners, zero):
    """(T,) bool: triangles whose height over their longest edge is at most ``zero``.

    Parameters
    ----------
    corners : (T, 3, d) float array
    zero : float
        Length that counts as zero.
    """
    edges = np.roll(corners, -1, axis=1) - corners
    longest = np.max(np.linalg.norm(edges, axis=2), axis=1)
    if corners.shape[2] == 2:
        twice_area = np.abs(cross2(edges[:, 0], edges[:, 1]))
    else:
        twice_area = np.linalg.norm(np.cross(edges[:, 0], edges[:, 1]), axis=1)
    return twice_area <= zero * longest


def edge_pairing(triangles):
    """Directed edges and how they pair up across the mesh.

    Returns
    -------
    directed : (3T, 2) int array
        Edge k of triangle t is row k·T + t.
    order : (3T,) int array
        Directed edges sorted so that the copies of one undirected edge are consecutive.
    counts : (U,) int array
        Number of copies of each undirected edge, in ``order``.
    """
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    key = np.sort(directed, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    _, counts = np.unique(key[order], axis=0, return_counts=True)
    return directed, order, counts


def _check_closed_manifold(triangles, names, defects, excused=()):
    """Report open or non-manifold edges and vertices in ``defects``, and several parts of such a surface (those of a
    closed one may be cavities: :func:`_orient_outward` judges them); open edges in between corners of one set of
    ``excused`` are not reported.

    Returns
    -------
    (first, second, part) : two (3T / 2,) int arrays and a (T,) one, or None when the surface is not closed and
        manifold. The two directed edges (rows of the ``directed`` array of :func:`edge_pairing`) of each undirected
        edge, and each triangle's connected part.
    """
    if not len(triangles):
        return None
    found = len(defects)
    directed, order, counts = edge_pairing(triangles)
    edge_of = directed[order[np.cumsum(counts) - counts]]
    holes = counts == 1
    if excused:
        holes &= ~np.array([any(a in corners and b in corners for corners in excused) for a, b in edge_of.tolist()])
    if np.any(holes):
        where = _listed([f"{names[a]}-{names[b]}" for a, b in edge_of[holes]])
        open_edges = _count(np.count_nonzero(holes), "boundary edge")
        defects.append(_NamesVertices(
            f"the cage is not closed: it has {open_edges}, each in only one face (between vertices {where}); fill "
            "the holes (in Blender: select the boundary edges with Select > Select All by Trait > Non Manifold, and "
            "press F)"
        ))
    if np.any(counts > 2):
        where = _listed([f"{names[a]}-{names[b]}" for a, b in edge_of[counts > 2]])
        defects.append(_NamesVertices(
            f"the cage has {_count(np.count_nonzero(counts > 2), 'non-manifold edge')} shared by more than two faces "
            f"(between vertices {where}): make every edge belong to exactly two faces "
            "(in Blender: Select > Select All by Trait > Non Manifold)"
        ))
    n_tri = len(triangles)
    # Triangles sharing an edge are connected, whatever the edge's number of faces.
    group_head = order[np.repeat(np.cumsum(counts) - counts, counts)]
    adjacency = sp.coo_matrix((np.ones(len(order)), (order % n_tri, group_head % n_tri)), shape=(n_tri, n_tri))
    parts, label = connected_components(adjacency, directed=False)
    if np.any(counts != 2):
        if parts > 1:
            defects.append(_separate_parts(label))
        return None
    first, second = order[0::2], order[1::2]
    _check_manifold_vertices(triangles, directed, first, second, names, defects)
    return (first, second, label) if len(defects) == found else None


def _separate_parts(part):
    sizes = np.bincount(part)
    return (f"the cage has {len(sizes)} separate parts ({', '.join(str(s) for s in sizes[:_LISTED])} triangles): LBC "
            "needs one closed surface around one region; make the parts one surface (Bridge Edge Loops), or separate "
            "them (Mesh > Separate > By Loose Parts) and bind each part's meshes to its own cage")


def _check_manifold_vertices(triangles, directed, first, second, names, defects):
    """Report in ``defects`` where the faces around a vertex form more than one fan (surfaces touching at a point)."""
    n_tri = len(triangles)
    # Corners are (triangle, vertex) pairs; two corners at one vertex are linked when their triangles share an edge
    # there. A manifold vertex has all its corners in one linked fan.
    corner = np.arange(3 * n_tri)
    corner_start, corner_end = corner, (corner + n_tri) % (3 * n_tri)  # the corners at directed edge's two ends
    same = directed[first, 0] == directed[second, 0]
    links_a = np.r_[corner_start[first], corner_end[first]]
    links_b = np.r_[np.where(same, corner_start[second], corner_end[second]),
                    np.where(same, corner_end[second], corner_start[second])]
    graph = sp.coo_matrix((np.ones(len(links_a)), (links_a, links_b)), shape=(3 * n_tri,) * 2)
    _, fan = connected_components(graph, directed=False)
    corner_vertex = directed[:, 0]
    fans_per_vertex = np.bincount(np.unique(np.c_[corner_vertex, fan], axis=0)[:, 0])
    pinched = np.flatnonzero(fans_per_vertex > 1)
    if len(pinched):
        defects.append(_NamesVertices(
            f"the cage has {_count(len(pinched), 'non-manifold vertex', 'non-manifold vertices')} where separate "
            f"sheets of the surface touch at a point (vertex {some_indices(names[pinched])}): pull the sheets apart or "
            "merge them along an edge"
        ))


def _orient_outward(vertices, triangles, pairing, triangle_face, defects):
    """Make neighbouring triangles agree in orientation, then point the surface outward (from the region it bounds:
    into a cavity on an inner part).

    Parameters
    ----------
    vertices : (n, 3) float array
    triangles : (T, 3) int array
        A closed, edge-manifold surface of one or more connected parts.
    pairing : (first, second, part)
        From :func:`_check_closed_manifold`.
    triangle_face : (T,) int array
        Named in the messages about parts.

    Returns
    -------
    (triangles (T, 3) int array, flipped (T,) bool array), or None
        The oriented triangles and which of them changed orientation; None, reported in ``defects``, when the
        surface is not orientable or its parts do not bound one region.
    """
    first, second, part = pairing
    n_tri = len(triangles)
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    a, b = first % n_tri, second % n_tri
    # Neighbours agree when they run their shared edge in opposite directions.
    disagree = np.all(directed[first] == directed[second], axis=1)
    relation = dict(zip(zip(a.tolist(), b.tolist()), disagree.tolist()))
    relation.update(zip(zip(b.tolist(), a.tolist()), disagree.tolist()))
    adjacency = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(n_tri, n_tri)).tocsr()
    flip = np.zeros(n_tri, dtype=bool)
    for root in np.unique(part, return_index=True)[1]:  # each part from its first triangle
        nodes, predecessors = breadth_first_order(adjacency, root, directed=False)
        for node in nodes[1:].tolist():  # breadth-first order: a parent's flip is known before its children's
            parent = predecessors[node]
            flip[node] = flip[parent] ^ relation[(parent, node)]
    if np.any((flip[a] ^ flip[b]) != disagree):
        defects.append("the cage surface is not orientable (like a Möbius strip): it cannot enclose a volume")
        return None
    oriented = np.where(flip[:, None], triangles[:, ::-1], triangles)
    outer = _outer_part(vertices, oriented, part, triangle_face, defects)
    if outer is None:
        return None
    if enclosed_measure(vertices, oriented[part == outer]) < 0:
        oriented, flip = oriented[:, ::-1], ~flip
    return oriented, flip


def _outer_part(vertices, triangles, part, triangle_face, defects):
    """The part that holds the others, each a cavity: inside it, in no other part, and oriented against it (so that
    the winding number is 1 in the region and 0 in the cavities and outside); None, reported in ``defects``, for
    parts side by side or nested deeper, and for an inner part facing the same way as the outer one."""
    parts = part.max() + 1
    if parts == 1:
        return 0
    surfaces = [triangles[part == k] for k in range(parts)]
    probes = vertices[[surface[0, 0] for surface in surfaces]]  # no two parts cross (else reported later)
    inside = np.array([np.abs(winding_numbers(vertices, surface, probes)) > 0.5 for surface in surfaces]).T
    np.fill_diagonal(inside, False)  # inside[k, j]: part k lies inside part j
    depth = inside.sum(axis=1)
    if np.count_nonzero(depth == 0) > 1 or np.any(depth > 1):
        defects.append(_separate_parts(part))
        return None
    outer = int(np.argmin(depth))
    volumes = np.array([enclosed_measure(vertices, surface) for surface in surfaces])
    same_way = np.flatnonzero(np.sign(volumes) == np.sign(volumes[outer]))
    same_way = same_way[same_way != outer]
    if len(same_way):
        faces = np.unique(triangle_face[np.isin(part, same_way)])
        defects.append(
            f"the cage has {_count(len(same_way), 'inner surface')} inside its outer one facing the same way (face "
            f"{some_indices(faces)}): a cavity's faces point into it, away from the shell around it; flip the inner "
            "surface's normals (in Blender: select it with L, then Mesh > Normals > Flip) to bind the shell between "
            "them, or separate it (Mesh > Separate > By Loose Parts) and bind the meshes inside it to their own cage"
        )
        return None
    return outer


def _check_self_intersection(vertices, triangles, triangle_face, zero, defects):
    """Report in ``defects`` the pairs of faces whose triangles cross or touch."""
    if len(triangles) < 2:
        return
    pairs = intersecting_triangles(vertices, triangles, zero)
    # The ear-clipped triangles of one n-gon tile its outline in the plane of its normal without overlapping, so they
    # cannot cross in 3D (a crossing point would project into both): a hit between them is rounding, as in a cap left
    # 6e-8 out of plane by Blender's float32 positions.
    in_ngon = np.bincount(triangle_face)[triangle_face] > 2
    same_ngon = (triangle_face[pairs[:, 0]] == triangle_face[pairs[:, 1]]) & in_ngon[pairs[:, 0]]
    pairs = pairs[~same_ngon]
    if len(pairs):
        faces = np.unique(np.sort(triangle_face[pairs], axis=1), axis=0)
        listed = _listed([f"{a} and {b}" if a != b else f"{a} with itself" for a, b in faces])
        defects.append(
            f"the cage intersects itself at {_count(len(faces), 'pair')} of crossing or touching faces (faces "
            f"{listed}); move them apart so that the surface does not pass through itself (in Blender the 3D-Print "
            "Toolbox's Intersections check selects them)"
        )
