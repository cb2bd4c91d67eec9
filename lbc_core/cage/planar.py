"""Flat cages: a cage whose vertices lie in one plane, with the points in that plane too, binds in 2D on its outline.

Image planes and flat meshes are such cages. The command line and the Blender add-on both ask :func:`flatten`, so a
flat cage with faces binds the same way in both: the outline (the edges used by one face) is the 2D polygon, the
vertices inside it control nothing, and the points are bound in the plane's coordinates.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import CageError
from ..kernel.frame import principal_extents
from .make import check_coordinates

# A cage is flat when its thickness is below this fraction of its bounding-box diagonal; points lie in the cage's
# plane when every one is this close to it. Image planes and flat meshes are exactly flat, so this is generous.
FLAT_TOLERANCE = 1e-5


@dataclass
class FlatCage:
    """A flat 3D cage and points, expressed in its plane for a 2D bind.

    Attributes
    ----------
    polygon : (k, 2) float array
        The outline's vertices in order, in the plane's coordinates: the 2D cage.
    points : (m, 2) float array
        The points in the plane's coordinates.
    loop : (k,) int array
        The input cage vertex of each polygon vertex.
    origin : (3,) float array
    axes : (2, 3) float array
        Orthonormal; ``(x - origin) @ axes.T`` are a 3D point's plane coordinates.
    """

    polygon: np.ndarray
    points: np.ndarray
    loop: np.ndarray
    origin: np.ndarray
    axes: np.ndarray


def flat_frame(cage_points, points):
    """The plane of a flat cage when the points lie in it too, else None.

    Parameters
    ----------
    cage_points : (n, 3) float array
    points : (m, 3) float array

    Returns
    -------
    None or (origin (3,), axes (2, 3))
        ``(points - origin) @ axes.T`` gives 2D coordinates in the plane.
    """
    origin = cage_points.mean(axis=0)
    diagonal = np.linalg.norm(np.ptp(cage_points, axis=0))
    if diagonal == 0:
        return None
    axes = principal_extents(cage_points)[0]  # columns: the plane's two directions, then its normal
    normal = axes[:, 2]
    if np.abs((cage_points - origin) @ normal).max() > FLAT_TOLERANCE * diagonal:
        return None
    if len(points) and np.abs((points - origin) @ normal).max() > FLAT_TOLERANCE * diagonal:
        return None
    return origin, axes[:, :2].T.copy()


def boundary_loop(faces, edges=None):
    """The vertices of a flat cage's outline in order, for a 2D bind.

    The outline is the edges used by exactly one face (``edges`` when the cage has no faces, a wire polygon). It must
    be one closed loop; vertices off it (inside a filled grid) do not control anything.

    Parameters
    ----------
    faces : sequence of index sequences
    edges : (E, 2) int array, optional
        The cage's edges, used when it has no faces.

    Returns
    -------
    (k,) int array

    Raises
    ------
    CageError
        When the outline is not a single closed loop.
    """
    if len(faces):
        face_edges = np.concatenate([np.stack([f, np.roll(f, -1)], axis=1) for f in map(np.asarray, faces)])
        face_edges.sort(axis=1)
        unique, counts = np.unique(face_edges, axis=0, return_counts=True)
        edges = unique[counts == 1]
    edges = np.zeros((0, 2), dtype=np.int64) if edges is None else np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if len(edges) < 3:
        raise CageError("the flat cage has no outline: give it a face, or edges forming one closed loop")
    vertices, degree = np.unique(edges, return_counts=True)
    if np.any(degree != 2):
        raise CageError(
            f"the flat cage's outline is not one closed loop ({int(np.count_nonzero(degree != 2))} vertices where it "
            "branches or ends): make its border a single closed polygon"
        )
    neighbours = {int(v): [] for v in vertices}
    for a, b in edges:
        neighbours[int(a)].append(int(b))
        neighbours[int(b)].append(int(a))
    loop = [int(edges[0, 0])]
    previous, current = None, loop[0]
    while True:
        a, b = neighbours[current]
        following = b if a == previous else a
        if following == loop[0]:
            break
        loop.append(following)
        previous, current = current, following
    if len(loop) != len(vertices):
        raise CageError(
            f"the flat cage's outline has several loops ({len(vertices)} outline vertices, {len(loop)} in the first "
            "loop): keep one closed outline"
        )
    return np.array(loop, dtype=np.int64)


def flatten(cage_vertices, cage_faces, points, edges=None):
    """A flat cage and its points as a 2D bind, or None when the cage is not flat or the points leave its plane.

    Parameters
    ----------
    cage_vertices : (n, 3) float array
    cage_faces : sequence of index sequences
    points : (m, 3) float array
    edges : (E, 2) int array, optional
        The cage's edges, for a cage without faces (a wire polygon).

    Returns
    -------
    FlatCage or None

    Raises
    ------
    CageError
        When the cage has NaN, infinite or far-off coordinates (:func:`~lbc_core.cage.make.check_coordinates`), or is
        flat but its outline is not one closed loop.
    """
    cage_vertices = np.asarray(cage_vertices, dtype=float)
    points = np.asarray(points, dtype=float)
    check_coordinates(cage_vertices)  # before the plane's fit, which NaN breaks and a far-off vertex fools
    frame = flat_frame(cage_vertices, points)
    if frame is None:
        return None
    origin, axes = frame
    loop = boundary_loop(cage_faces, edges)
    return FlatCage((cage_vertices[loop] - origin) @ axes.T, (points - origin) @ axes.T, loop, origin, axes)


def reframed(flat, cage_vertices, points, origin, axes):
    """``flat`` with its cage and points in another frame of their plane, or None when they leave that plane.

    A re-bind of an edited flat cage uses the previous binding's frame: the plane's own (:func:`flat_frame`, from the
    cage's mean and principal axes) shifts with every vertex moved, and every control point would move with it.

    Parameters
    ----------
    flat : FlatCage
    cage_vertices : (n, 3) float array
    points : (m, 3) float array
        As given to :func:`flatten`.
    origin : (3,) float array
    axes : (2, 3) float array
        Orthonormal, as :class:`FlatCage` holds them.

    Returns
    -------
    FlatCage or None
    """
    cage_vertices, points = np.asarray(cage_vertices, dtype=float), np.asarray(points, dtype=float)
    normal = np.cross(axes[0], axes[1])
    diagonal = np.linalg.norm(np.ptp(cage_vertices, axis=0))
    for array in (cage_vertices, points):
        if len(array) and np.abs((array - origin) @ normal).max() > FLAT_TOLERANCE * diagonal:
            return None
    return FlatCage((cage_vertices[flat.loop] - origin) @ axes.T, (points - origin) @ axes.T, flat.loop, origin, axes)
