"""Mirror symmetry for the cage generator: the plane the artist picks (normal to x, y or z, through the middle of the
mesh's bounding box), how far the mesh is from being symmetric about it, the frame in which that plane is the plane
through 0 (where a mirror image is one exact negation), and the mesh with its mirror image, which a symmetric cage
encloses.

A symmetric cage lets Blender's X-mirror editing work on it: the generator makes it exactly symmetric (each vertex's
image is a vertex, up to the rounding of the frame's shift), for a mesh that is not quite symmetric too, which the
cage then encloses with its mirror image; :func:`asymmetry` says how far the mesh is from its image, and above
SYMMETRY_TOLERANCE the generator warns that the cage is looser for it."""

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..errors import CageError
from .mesh_input import InputMesh

AXES = {"x": 0, "y": 1, "z": 2}
# A mesh whose mirror image lies within this share of its bounding-box diagonal of it (for 99 % of its vertices) is
# symmetric; beyond, the cage is still symmetric but the generator warns (bench/RESULTS.md, "Cage generator").
SYMMETRY_TOLERANCE = 0.02
# The share of the mesh's vertices whose distance to the mirror image must be within the tolerance: a few stray
# vertices (a logo, a seam) do not make a mesh asymmetric.
SYMMETRIC_SHARE = 0.99


@dataclass(frozen=True)
class MirrorFrame:
    """The plane normal to ``axis`` through ``centre`` (along that axis), in the mesh's units."""

    axis: int
    centre: float

    def into(self, points):
        """Points in the frame where the plane passes through 0."""
        moved = np.array(points, dtype=float)
        moved[:, self.axis] -= self.centre
        return moved

    def out_of(self, points):
        moved = np.array(points, dtype=float)
        moved[:, self.axis] += self.centre
        return moved


def checked_axis(symmetry):
    """The axis index of ``symmetry`` (None, "x", "y" or "z"), or None; CageError for anything else."""
    if symmetry is None:
        return None
    if not isinstance(symmetry, str) or symmetry.lower() not in AXES:
        raise CageError(f"symmetry must be None, 'x', 'y' or 'z' (the axis normal to the mirror plane), got "
                        f"{symmetry!r}")
    return AXES[symmetry.lower()]


def mirror_frame(mesh, axis):
    """The MirrorFrame of the plane normal to ``axis`` through the middle of the mesh's bounding box."""
    used = mesh.vertices[np.unique(mesh.triangles)]
    return MirrorFrame(axis, float(0.5 * (used[:, axis].min() + used[:, axis].max())))


def mirrored(vertices, axis):
    image = np.array(vertices, dtype=float)
    image[:, axis] = -image[:, axis]
    return image


def asymmetry(mesh, frame):
    """How far the mesh is from its mirror image: the distance from its vertices' images to its nearest vertices
    that 99 % of them keep within, over the bounding-box diagonal."""
    points = frame.into(mesh.vertices[np.unique(mesh.triangles)])
    distance, _ = cKDTree(points).query(mirrored(points, frame.axis))
    return float(np.quantile(distance, SYMMETRIC_SHARE)) / mesh.diagonal


def with_image(mesh, axis):
    """The InputMesh of the mesh (already in its mirror frame) and its mirror image, as one."""
    vertices = np.vstack([mesh.vertices, mirrored(mesh.vertices, axis)])
    triangles = np.vstack([mesh.triangles, mesh.triangles[:, ::-1] + len(mesh.vertices)])
    return InputMesh(vertices, triangles, mesh.diagonal)


def mirror_error(vertices, axis, centre):
    """The largest distance from a cage vertex's mirror image (about the plane normal to ``axis`` through
    ``centre``) to the nearest cage vertex: 0 for an exactly symmetric cage."""
    image = np.array(vertices, dtype=float)
    image[:, axis] = 2.0 * centre - image[:, axis]
    distance, _ = cKDTree(vertices).query(image)
    return float(distance.max())
