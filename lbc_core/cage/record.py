"""The checked cage: :class:`Cage`, what :func:`~lbc_core.cage.make.make_cage` returns and every later stage takes.
"""

import hashlib
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp

from ..errors import CageError, CageVertexError
from ..kernel.geometry import (
    enclosed_measure,
    hull_share,
)
from .messages import first_inputs, real_array, some_indices, some_items

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
        return first_inputs(self.vertex_map)

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
        first = first_inputs(self.vertex_map)
        points = input_vertices[first]
        if len(first) < len(self.vertex_map):
            offset = np.linalg.norm(input_vertices - points[self.vertex_map], axis=1)
            size = np.linalg.norm(np.ptp(input_vertices, axis=0))
            apart = np.flatnonzero(offset > POSED_APART * size)
            if len(apart):
                pairs = some_items([f"{first[self.vertex_map[k]]}/{k}" for k in apart])
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
