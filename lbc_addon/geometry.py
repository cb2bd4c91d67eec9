"""Reading meshes and cages out of Blender into numpy arrays, on the main thread.

Everything the solve needs is copied here, so the worker thread never touches ``bpy``. Positions are expressed in
the bound mesh's local space, the space the Geometry Nodes deformer works in (Object Info in relative mode).
"""

import hashlib

import numpy as np

from .core import CageError

# A cage is flat when its thickness is below this fraction of its bounding-box diagonal; a mesh lies in the cage's
# plane when every vertex is this close to it. Image planes and flat meshes are exactly flat, so this is generous.
FLAT_TOLERANCE = 1e-5


def vertex_positions(mesh):
    """The vertex positions of a ``bpy.types.Mesh`` as an (m, 3) float64 array."""
    positions = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", positions)
    return positions.reshape(-1, 3).astype(np.float64)


def polygon_faces(mesh):
    """The faces of a ``bpy.types.Mesh`` as a list of vertex index arrays."""
    corners = np.empty(len(mesh.loops), dtype=np.int64)
    mesh.loops.foreach_get("vertex_index", corners)
    sizes = np.empty(len(mesh.polygons), dtype=np.int64)
    mesh.polygons.foreach_get("loop_total", sizes)
    return np.split(corners, np.cumsum(sizes)[:-1]) if len(sizes) else []


def edge_pairs(mesh):
    """The edges of a ``bpy.types.Mesh`` as an (E, 2) int array."""
    edges = np.empty(len(mesh.edges) * 2, dtype=np.int64)
    mesh.edges.foreach_get("vertices", edges)
    return edges.reshape(-1, 2)


def topology_fingerprint(mesh):
    """A hash of a mesh's vertex count, edges and faces; positions do not enter it.

    The weights index the cage's vertices, so any change here (vertices added, removed or reordered, faces
    rebuilt) makes them meaningless; moving vertices does not.
    """
    digest = hashlib.sha256()
    digest.update(np.int64(len(mesh.vertices)).tobytes())
    digest.update(edge_pairs(mesh).tobytes())
    corners = np.empty(len(mesh.loops), dtype=np.int64)
    mesh.loops.foreach_get("vertex_index", corners)
    sizes = np.empty(len(mesh.polygons), dtype=np.int64)
    mesh.polygons.foreach_get("loop_total", sizes)
    digest.update(corners.tobytes())
    digest.update(sizes.tobytes())
    return digest.hexdigest()[:16]


def to_local(matrix, positions):
    """Apply a 4×4 ``mathutils.Matrix`` (or array) to (k, 3) positions."""
    matrix = np.array(matrix, dtype=np.float64)
    return positions @ matrix[:3, :3].T + matrix[:3, 3]


def cage_to_mesh_matrix(cage_obj, mesh_obj):
    """The matrix taking the cage's local coordinates to the mesh's: what Object Info (relative) applies."""
    return mesh_obj.matrix_world.inverted_safe() @ cage_obj.matrix_world


def flat_frame(cage_points, mesh_points):
    """The plane of a flat cage when the mesh lies in it too, else None.

    Returns
    -------
    None or (origin (3,), axes (2, 3))
        ``(points - origin) @ axes.T`` gives 2D coordinates in the plane.
    """
    origin = cage_points.mean(axis=0)
    diagonal = np.linalg.norm(np.ptp(cage_points, axis=0))
    if diagonal == 0:
        return None
    _, singular, basis = np.linalg.svd(cage_points - origin, full_matrices=False)
    normal = basis[2]
    if np.abs((cage_points - origin) @ normal).max() > FLAT_TOLERANCE * diagonal:
        return None
    if len(mesh_points) and np.abs((mesh_points - origin) @ normal).max() > FLAT_TOLERANCE * diagonal:
        return None
    return origin, basis[:2]


def boundary_loop(mesh):
    """The vertices of a flat cage's outline in order, for a 2D bind.

    The outline is the edges used by exactly one face (every edge when the cage has no faces, a wire polygon). It
    must be one closed loop; vertices off it (inside a filled grid) do not control anything.

    Raises
    ------
    CageError
        When the outline is not a single closed loop.
    """
    edges = edge_pairs(mesh)
    faces = polygon_faces(mesh)
    if faces:
        face_edges = np.concatenate([np.stack([f, np.roll(f, -1)], axis=1) for f in faces])
        face_edges.sort(axis=1)
        unique, counts = np.unique(face_edges, axis=0, return_counts=True)
        edges = unique[counts == 1]
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
