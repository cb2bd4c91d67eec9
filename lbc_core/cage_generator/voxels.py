"""The solid a cage must enclose, on a voxel grid: the mesh's surface marked in voxels, its distance field, the
outside flood-filled from the grid's border through the voxels farther than the margin (plus the closing radius)
from the surface, and that outside grown back by the closing radius. Whatever the outside cannot reach is solid, so
open, self-intersecting, non-manifold and multi-part meshes all give a solid; parts the margin leaves apart are
joined by thin bridges, since a cage is one surface.

The field is a signed distance in the mesh's units, positive inside the solid, whose level 0 is the cage's first
surface (``lbc_core.cage_generator.extraction``)."""

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

# Surface samples per voxel side along a triangle's longest edge: two leave no voxel the triangle crosses unmarked.
SAMPLES_PER_VOXEL = 2
# The bridge joining two parts of the solid: its radius in voxels (enough for marching cubes to see a tube).
BRIDGE_RADIUS = 1.6


@dataclass(frozen=True)
class VoxelSolid:
    """A scalar field on a regular grid: > 0 inside the solid, its level 0 the surface to extract.

    field : (X, Y, Z) float array, in the mesh's units
    origin : (3,) float array, the position of voxel (0, 0, 0)'s centre
    spacing : float, the voxels' side
    parts_joined : int, how many bridges were added to make the solid one part
    """

    field: np.ndarray
    origin: np.ndarray
    spacing: float
    parts_joined: int


def surface_samples(vertices, triangles, spacing):
    """(P, 3) points on the triangles, no two neighbours farther apart than ``spacing``: the corners, and a
    barycentric lattice on each triangle whose longest edge is longer than ``spacing``."""
    corners = vertices[triangles]
    longest = np.max(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2), axis=1)
    steps = np.maximum(1, np.ceil(longest / spacing)).astype(np.int64)
    found = [vertices]
    for k in np.unique(steps):
        if k == 1:
            continue
        i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
        keep = i + j <= k
        bary = np.stack([i[keep], j[keep], k - i[keep] - j[keep]], axis=1) / k
        chosen = corners[steps == k]
        found.append(np.einsum("sk,tkd->tsd", bary, chosen).reshape(-1, 3))
    return np.concatenate(found)


def voxel_solid(vertices, triangles, spacing, margin, closing, check=None, axis=None):
    """The solid around the mesh whose surface lies about ``margin`` from it, gaps narrower than twice ``closing``
    filled (a morphological closing), as a :class:`VoxelSolid`.

    Parameters
    ----------
    vertices : (n, 3) float array
    triangles : (T, 3) int array
    spacing : float
        The voxels' side.
    margin, closing : float
        In the mesh's units; ``closing`` at least one voxel.
    check : callable() or None
        Polled between steps (a Progress's ``check``).
    axis : int or None
        Make the solid exactly symmetric about the plane through 0 normal to this axis: the grid symmetric about it
        with a layer of voxels on it, the mesh and its mirror image voxelized, the field the larger of its value and
        its mirror image's (after the bridges, so that those come in mirror pairs too).
    """
    check = check or (lambda: None)
    if axis is not None:
        image = vertices.copy()
        image[:, axis] = -image[:, axis]
        vertices, triangles = np.vstack([vertices, image]), np.vstack([triangles, triangles + len(vertices)])
    reach = margin + closing
    pad = int(np.ceil(reach / spacing)) + 3
    low = vertices.min(axis=0) - pad * spacing
    if axis is not None:  # voxel layer k on the plane: low = -k spacing
        low[axis] = -(np.ceil(np.abs(vertices[:, axis]).max() / spacing) + pad) * spacing
    shape = np.ceil((vertices.max(axis=0) - low) / spacing).astype(np.int64) + pad + 1
    if axis is not None:
        shape[axis] = 2 * int(round(-low[axis] / spacing)) + 1
    marked = np.zeros(tuple(int(side) for side in shape), dtype=bool)
    cells = np.floor((surface_samples(vertices, triangles, spacing / SAMPLES_PER_VOXEL) - low) / spacing + 0.5)
    marked[tuple(cells.astype(np.int64).T)] = True
    check()
    distance = ndimage.distance_transform_edt(~marked) * spacing
    check()
    outside = _reached_from_border(distance > reach)
    check()
    field = ndimage.distance_transform_edt(~outside) * spacing - closing
    check()
    field, bridges = join_parts(field, spacing)
    if axis is not None:
        field = np.maximum(field, np.flip(field, axis=axis))
    return VoxelSolid(field, low, float(spacing), bridges)


def _reached_from_border(free):
    """(X, Y, Z) bool: the voxels of ``free`` connected (by faces) to the grid's border."""
    labels, _ = ndimage.label(free)
    border = np.unique(np.concatenate([labels[0].ravel(), labels[-1].ravel(), labels[:, 0].ravel(),
                                       labels[:, -1].ravel(), labels[:, :, 0].ravel(), labels[:, :, -1].ravel()]))
    return np.isin(labels, border[border > 0])


def join_parts(field, spacing):
    """The field with each part of the solid (> 0) joined to its nearest other part by a tube, until one part is
    left; returns (field, bridges added). A minimum spanning tree over the parts' closest voxel pairs, so the result
    is the same whatever order the parts are found in."""
    labels, count = ndimage.label(field > 0)
    if count <= 1:
        return field, 0
    voxels = [np.argwhere(labels == part) for part in range(1, count + 1)]
    trees = [cKDTree(points) for points in voxels]
    joined = {0}
    field = field.copy()
    bridges = 0
    while len(joined) < count:
        best = None
        for inside in sorted(joined):
            for other in range(count):
                if other in joined:
                    continue
                gap, nearest = trees[other].query(voxels[inside])
                k = int(np.argmin(gap))
                if best is None or gap[k] < best[0]:
                    best = (gap[k], voxels[inside][k], voxels[other][nearest[k]], other)
        _, start, end, other = best
        _add_tube(field, start, end, BRIDGE_RADIUS, spacing)
        joined.add(other)
        bridges += 1
    return field, bridges


def _add_tube(field, start, end, radius, spacing):
    """Raise ``field`` (in place) to the signed distance inside a tube of ``radius`` voxels from voxel ``start`` to
    voxel ``end``."""
    low = np.maximum(np.minimum(start, end) - int(np.ceil(radius)) - 1, 0)
    high = np.minimum(np.maximum(start, end) + int(np.ceil(radius)) + 2, field.shape)
    grid = np.stack(np.meshgrid(*[np.arange(a, b) for a, b in zip(low, high)], indexing="ij"), axis=-1)
    axis = (end - start).astype(float)
    t = np.clip(((grid - start) @ axis) / max(axis @ axis, 1e-12), 0.0, 1.0)
    inside = (radius - np.linalg.norm(grid - start - t[..., None] * axis, axis=-1)) * spacing
    box = tuple(slice(a, b) for a, b in zip(low, high))
    field[box] = np.maximum(field[box], inside)
