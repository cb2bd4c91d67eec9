"""The voxel solid's surface as a triangle mesh: marching tetrahedra at level 0 on the grid's Kuhn triangulation (six
tetrahedra per cube around its main diagonal, the same split in every cube, so neighbouring cubes agree on their
shared faces and the surface is closed and manifold), in the mesh's units, triangles facing out. Written here rather
than taken from a library: PyMCubes has no wheels for Python 3.13 and scikit-image weighs 12-14 MB
(bench/RESULTS.md, "Cage generator")."""

from itertools import permutations

import numpy as np

from .voxels import VoxelSolid

# Grid values within this share of a voxel of the level are moved off it: a corner exactly on the level would put
# several surface vertices at one place.
OFF_LEVEL = 1e-4
# The six tetrahedra of a cube: from corner (0, 0, 0) to (1, 1, 1) by unit steps along the axes in each order.
KUHN_TETRAHEDRA = tuple(
    np.array([(0, 0, 0), tuple(int(a == order[0]) for a in range(3)),
              tuple(int(a in order[:2]) for a in range(3)), (1, 1, 1)]) for order in permutations(range(3)))


def iso_surface(solid):
    """(vertices (n, 3), triangles (T, 3)) of the level 0 of ``solid.field`` (a VoxelSolid), facing out (towards
    negative values)."""
    field = solid.field.copy()
    field[np.abs(field) < OFF_LEVEL * solid.spacing] = -OFF_LEVEL * solid.spacing
    inside = field > 0
    shape = np.array(field.shape)
    cubes = _mixed_cubes(inside)
    starts, ends, triangles = [], [], []
    for tetrahedron in KUHN_TETRAHEDRA:
        corners = cubes[:, None, :] + tetrahedron[None]  # (M, 4, 3) grid indices
        flat = np.ravel_multi_index(tuple(corners.transpose(2, 0, 1)), field.shape)  # (M, 4)
        edges_start, edges_end = _tetrahedron_edges(flat, inside.ravel()[flat])
        base = sum(len(s) for s in starts)
        starts.append(edges_start)
        ends.append(edges_end)
        triangles.append(base + np.arange(len(edges_start)).reshape(-1, 3))
    start, end = np.concatenate(starts), np.concatenate(ends)  # start inside, end outside, per triangle corner
    key = np.minimum(start, end) * field.size + np.maximum(start, end)
    _, first, corner_vertex = np.unique(key, return_index=True, return_inverse=True)
    values = field.ravel()
    t = values[start[first]] / (values[start[first]] - values[end[first]])
    position = lambda flat_index: np.stack(np.unravel_index(flat_index, tuple(shape)), axis=1).astype(float)  # noqa: E731
    grid_points = position(start[first]) * (1 - t[:, None]) + position(end[first]) * t[:, None]
    vertices = solid.origin + grid_points * solid.spacing
    triangles = corner_vertex.ravel()[np.concatenate(triangles)]
    outward = position(end) - position(start)  # inside to outside, per corner
    return vertices, _facing(vertices, triangles, outward.reshape(-1, 3, 3).sum(axis=1))


def _mixed_cubes(inside):
    """(M, 3) int array: the cubes (by their lowest corner) with corners on both sides of the level."""
    count = np.zeros(tuple(s - 1 for s in inside.shape), dtype=np.int8)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                count += inside[dx:inside.shape[0] - 1 + dx, dy:inside.shape[1] - 1 + dy, dz:inside.shape[2] - 1 + dz]
    return np.argwhere((count > 0) & (count < 8))


def _tetrahedron_edges(corners, inside):
    """For tetrahedra (M, 4) of grid points and which are inside: (start, end) of the cut edges, three per
    triangle, the start inside and the end outside."""
    count = inside.sum(axis=1)
    starts, ends = [], []
    for lone_inside in (True, False):  # one corner apart from the other three: one triangle
        chosen = count == (1 if lone_inside else 3)
        lone = np.argmax(inside[chosen] == lone_inside, axis=1)
        rows = corners[chosen]
        alone = rows[np.arange(len(rows)), lone]
        others = np.stack([rows[np.arange(len(rows)), (lone + k) % 4] for k in (1, 2, 3)], axis=1)
        if lone_inside:
            starts.append(np.repeat(alone, 3)), ends.append(others.ravel())
        else:
            starts.append(others.ravel()), ends.append(np.repeat(alone, 3))
    chosen = count == 2  # two and two: a quad, as two triangles
    order = np.argsort(~inside[chosen], axis=1, kind="stable")
    rows = np.take_along_axis(corners[chosen], order, axis=1)  # p, q inside; r, s outside
    p, q, r, s = rows.T
    starts.append(np.stack([p, p, q, p, q, q], axis=1).ravel())
    ends.append(np.stack([r, s, s, r, s, r], axis=1).ravel())
    return np.concatenate(starts), np.concatenate(ends)


def _facing(vertices, triangles, outward):
    """The triangles turned so that their normals point along ``outward`` (T, 3)."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    normal = np.cross(b - a, c - a)
    flip = np.einsum("ij,ij->i", normal, outward) < 0
    triangles = triangles.copy()
    triangles[flip] = triangles[flip][:, ::-1]
    return triangles


def compact(vertices, triangles):
    """The vertices the triangles use, in order of index, and the triangles renumbered."""
    used = np.unique(triangles)
    renumber = np.full(len(vertices), -1, dtype=np.int64)
    renumber[used] = np.arange(len(used))
    return vertices[used], renumber[triangles]


def signed_volume(vertices, triangles):
    """The volume a closed triangle surface encloses, positive when it faces out."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)


def half_iso_surface(solid, axis):
    """The level 0 of a field symmetric about the plane through 0 normal to ``axis`` (a VoxelSolid whose voxel layer
    ``k`` lies on it, ``k`` voxels from each end) on the half beyond the plane: an open surface whose boundary lies
    in the plane, its vertices there exactly on it. With its mirror image (:func:`mirrored_whole`) it is the whole
    level, exactly symmetric: the Kuhn triangulation is not symmetric, but the mirror images of its faces in the
    plane are those faces, so the halves meet edge to edge."""
    k = solid.field.shape[axis] // 2
    half = np.take(solid.field, np.arange(k, solid.field.shape[axis]), axis=axis)
    origin = solid.origin.copy()
    origin[axis] = 0.0
    return iso_surface(VoxelSolid(half, origin, solid.spacing, solid.parts_joined))


def mirrored_whole(vertices, triangles, axis):
    """A surface with its boundary in the plane through 0 normal to ``axis`` (on the side x > 0 of it) and its mirror
    image, as one closed surface: the vertices on the plane shared, the image's triangles turned to face out."""
    on_plane = vertices[:, axis] == 0.0
    image_index = np.arange(len(vertices))
    image_index[~on_plane] = len(vertices) + np.arange(np.count_nonzero(~on_plane))
    image = vertices[~on_plane].copy()
    image[:, axis] = -image[:, axis]
    whole = np.vstack([vertices, image])
    return whole, np.vstack([triangles, image_index[triangles][:, ::-1]])

