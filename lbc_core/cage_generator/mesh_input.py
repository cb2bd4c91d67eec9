"""The mesh to cage, checked and put into one form before any long work: finite (n, 3) vertices, faces of three or
more corners triangulated as fans, triangles with a repeated corner dropped. Refused, with what to do: no vertices,
no faces (a point cloud), a flat or zero-size mesh. Anything else is cageable: several parts, holes, open surfaces,
self-intersections and non-manifold edges are all welcome."""

from dataclasses import dataclass

import numpy as np

from ..errors import CageError

# A mesh whose thinnest side is below this share of its bounding-box diagonal is flat: a cage around it would be a
# slab no thicker than its margin.
FLAT_SHARE = 1e-4


class NothingToCage(CageError):
    """The mesh has no surface to put a cage around: no vertices, no faces, or all of it in a plane or a point."""


@dataclass(frozen=True)
class InputMesh:
    """The mesh as the generator uses it.

    vertices : (n, 3) float array, as given
    triangles : (T, 3) int array, every face fanned from its first corner, none with a repeated corner
    diagonal : float, the bounding box's diagonal
    """

    vertices: np.ndarray
    triangles: np.ndarray
    diagonal: float


def input_mesh(vertices, faces):
    """Check ``vertices`` (n, 3) and ``faces`` (an (F, k) int array or a sequence of index sequences) and return an
    :class:`InputMesh`; raise :class:`NothingToCage` or :class:`~lbc_core.errors.CageError` saying what to do."""
    try:
        vertices = np.array(vertices, dtype=float)
    except (TypeError, ValueError) as error:
        raise CageError(f"the mesh's vertices are not an (n, 3) array of numbers ({error})") from error
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise CageError(f"the mesh's vertices must be an (n, 3) array, got shape {vertices.shape}")
    if len(vertices) == 0:
        raise NothingToCage("the mesh has no vertices: give a mesh with faces to put a cage around")
    if not np.all(np.isfinite(vertices)):
        raise CageError("the mesh has NaN or infinite coordinates: fix or delete those vertices")
    triangles = _triangles(faces, len(vertices))
    if len(triangles) == 0:
        raise NothingToCage("the mesh has no faces, only points: a cage needs a surface to go around (in Blender: "
                            "give the points faces, or cage a mesh that has them)")
    used = vertices[np.unique(triangles)]
    sides = used.max(axis=0) - used.min(axis=0)
    diagonal = float(np.linalg.norm(sides))
    if diagonal == 0.0 or sides.min() < FLAT_SHARE * diagonal:
        raise NothingToCage("the mesh is flat (all of it in one plane): a cage must enclose a volume; give it "
                            "thickness first (in Blender: the Solidify modifier, applied), or bind it to a 2D cage")
    return InputMesh(vertices, triangles, diagonal)


def _triangles(faces, n_vertices):
    """(T, 3) int array: each face fanned from its first corner; faces with a bad index refused."""
    if faces is None:
        return np.empty((0, 3), dtype=np.int64)
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        rows = [faces]
    else:  # one array per face size, so that a big mesh is not fanned face by face
        faces = [np.asarray(face, dtype=np.int64).ravel() for face in faces]
        sizes = np.array([len(face) for face in faces], dtype=np.int64)
        rows = [np.array([faces[i] for i in np.flatnonzero(sizes == size)]) for size in np.unique(sizes)]
    found = []
    for row in rows:
        row = np.asarray(row, dtype=np.int64)
        if row.shape[1] < 3:
            raise CageError("the mesh has a face with fewer than 3 corners: delete it (or its loose edges)")
        for k in range(1, row.shape[1] - 1):
            found.append(np.stack([row[:, 0], row[:, k], row[:, k + 1]], axis=1))
    triangles = np.concatenate(found) if found else np.empty((0, 3), dtype=np.int64)
    if len(triangles) and (triangles.min() < 0 or triangles.max() >= n_vertices):
        raise CageError(f"the mesh has a face whose corner is not one of its {n_vertices} vertices: fix the faces")
    distinct = (triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2]) & \
        (triangles[:, 2] != triangles[:, 0])
    return triangles[distinct]
