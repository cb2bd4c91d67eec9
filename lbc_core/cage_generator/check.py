"""The last word on a generated cage: lbc's own cage checks (:func:`lbc_core.cage.make.make_cage`) and enclosure, exactly.

Enclosure is checked without assuming anything of the mesh: no mesh edge crosses or touches a cage triangle, no cage
edge crosses or touches a mesh triangle, so each connected part of the mesh is wholly inside or wholly outside, and
one vertex of each part (every loose vertex too) has winding number 1. A grid of cells the cage passes through finds
the few edges and triangles near it, so the exact tests run on those only."""

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..cage import make_cage
from ..kernel.geometry import winding_numbers
from .voxels import surface_samples


@dataclass(frozen=True)
class Enclosure:
    """How a cage encloses a mesh.

    crossings : int, mesh edges crossing or touching a cage triangle plus cage edges crossing a mesh triangle
    parts_outside : int, connected parts of the mesh (loose vertices included) outside the cage
    clearance : float, about the least distance from a mesh vertex to the cage (0 when they cross)
    mean_distance : float, about the mean distance from the cage's vertices to the mesh's
    """

    crossings: int
    parts_outside: int
    clearance: float
    mean_distance: float

    @property
    def encloses(self):
        return self.crossings == 0 and self.parts_outside == 0


def orientation(p, a, b, c):
    """Six times the signed volume of tetrahedra (p, a, b, c), each (P, 3)."""
    u, v, w = a - p, b - p, c - p
    return (u[:, 0] * (v[:, 1] * w[:, 2] - v[:, 2] * w[:, 1]) + u[:, 1] * (v[:, 2] * w[:, 0] - v[:, 0] * w[:, 2])
            + u[:, 2] * (v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0]))


def segments_meet_triangles(p, q, a, b, c):
    """(P,) bool: segment p-q meets triangle a-b-c, touching included (each (P, 3))."""
    low = np.minimum(p, q)
    high = np.maximum(p, q)
    boxes = np.all(low <= np.maximum(np.maximum(a, b), c), axis=1) & np.all(high >= np.minimum(np.minimum(a, b), c), axis=1)
    s1, s2 = orientation(p, a, b, c), orientation(q, a, b, c)
    t1, t2, t3 = orientation(p, q, a, b), orientation(p, q, b, c), orientation(p, q, c, a)
    sides = (s1 * s2 <= 0)
    around = ((t1 >= 0) & (t2 >= 0) & (t3 >= 0)) | ((t1 <= 0) & (t2 <= 0) & (t3 <= 0))
    return boxes & sides & around


def _cell_keys(points, cell):
    index = np.floor(points / cell).astype(np.int64) + (1 << 20)
    return (index[:, 0] << 42) | (index[:, 1] << 21) | index[:, 2]


def _near_cells(points, cell):
    """Sorted keys of the cells holding ``points`` and of their 26 neighbours."""
    index = np.unique(np.floor(points / cell).astype(np.int64), axis=0)
    shifts = np.stack(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij"), axis=-1).reshape(-1, 3)
    around = (index[:, None, :] + shifts[None]).reshape(-1, 3)
    return np.unique(_cell_keys((around + 0.5) * cell, cell))


def _pairs_meeting(starts, ends, corners, check):
    """Count of segments meeting triangles among all pairs whose boxes overlap (both sets small)."""
    count = 0
    low, high = corners.min(axis=1), corners.max(axis=1)
    for chunk in np.array_split(np.arange(len(starts)), max(1, len(starts) * len(corners) // 2_000_000)):
        check()
        seg_low, seg_high = np.minimum(starts[chunk], ends[chunk]), np.maximum(starts[chunk], ends[chunk])
        i, j = np.nonzero(np.all(seg_low[:, None] <= high[None], axis=2) & np.all(seg_high[:, None] >= low[None], axis=2))
        i = chunk[i]
        count += int(np.count_nonzero(segments_meet_triangles(starts[i], ends[i], corners[j, 0], corners[j, 1], corners[j, 2])))
    return count


def _edges(triangles):
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    return np.unique(edges, axis=0)


def crossings(mesh_vertices, mesh_triangles, cage_vertices, cage_triangles, cell, check):
    """Mesh edges meeting cage triangles plus cage edges meeting mesh triangles, tested exactly near the cage."""
    near = _near_cells(surface_samples(cage_vertices, cage_triangles, cell / 2), cell)
    edges = _edges(mesh_triangles)
    lengths = np.linalg.norm(mesh_vertices[edges[:, 1]] - mesh_vertices[edges[:, 0]], axis=1)
    steps = np.maximum(1, np.ceil(lengths / (cell / 2))).astype(np.int64)
    owner = np.repeat(np.arange(len(edges)), steps + 1)
    t = np.arange(len(owner)) - np.repeat(np.cumsum(steps + 1) - steps - 1, steps + 1)
    t = t / np.repeat(steps, steps + 1)
    samples = mesh_vertices[edges[owner, 0]] * (1 - t[:, None]) + mesh_vertices[edges[owner, 1]] * t[:, None]
    close = np.unique(owner[np.isin(_cell_keys(samples, cell), near)])
    cage_corners = cage_vertices[cage_triangles]
    found = _pairs_meeting(mesh_vertices[edges[close, 0]], mesh_vertices[edges[close, 1]], cage_corners, check)
    triangle_samples, triangle_owner = _triangle_samples(mesh_vertices, mesh_triangles, cell / 2)
    close = np.unique(triangle_owner[np.isin(_cell_keys(triangle_samples, cell), near)])
    cage_edges = _edges(cage_triangles)
    found += _pairs_meeting(cage_vertices[cage_edges[:, 0]], cage_vertices[cage_edges[:, 1]],
                            mesh_vertices[mesh_triangles[close]], check)
    return found


def _triangle_samples(vertices, triangles, spacing):
    """(points, owning triangle) with every triangle sampled no sparser than ``spacing`` (its corners at least)."""
    corners = vertices[triangles]
    longest = np.max(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2), axis=1)
    big = np.flatnonzero(longest > spacing)
    points = [corners.reshape(-1, 3)]
    owners = [np.repeat(np.arange(len(triangles)), 3)]
    if len(big):
        points.append(surface_samples(vertices, triangles[big], spacing)[len(vertices):])
        steps = np.maximum(1, np.ceil(longest[big] / spacing)).astype(np.int64)
        counts = (steps + 1) * (steps + 2) // 2
        # surface_samples lists the lattice points grouped by step count, in order of the steps' values.
        order = np.argsort(steps, kind="stable")
        owners.append(np.repeat(big[order], counts[order]))
    return np.concatenate(points), np.concatenate(owners)


def parts_outside(mesh_vertices, mesh_triangles, cage_vertices, cage_triangles, check):
    """How many connected parts of the mesh (a loose vertex is one) have a first vertex outside the cage."""
    n = len(mesh_vertices)
    edges = np.concatenate([mesh_triangles[:, [0, 1]], mesh_triangles[:, [1, 2]]])
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    first = np.full(count, n)
    np.minimum.at(first, label, np.arange(n))
    winding = winding_numbers(cage_vertices, cage_triangles, mesh_vertices[first], check)
    return int(np.count_nonzero(winding < 0.5))


def distances(mesh_vertices, cage_vertices, cage_triangles, spacing):
    """(clearance, mean distance): about the least distance from a mesh vertex to the cage's surface, and the mean
    distance from a cage vertex to the nearest mesh vertex."""
    cage_points = surface_samples(cage_vertices, cage_triangles, spacing)
    clearance = float(cKDTree(cage_points).query(mesh_vertices)[0].min())
    mean = float(cKDTree(mesh_vertices).query(cage_vertices)[0].mean())
    return clearance, mean


def enclosure(mesh, cage_vertices, cage_triangles, cell, check=None):
    """An :class:`Enclosure` of the InputMesh ``mesh`` by the closed, outward cage, near-cage tests on a grid of
    ``cell``."""
    check = check or (lambda: None)
    crossed = crossings(mesh.vertices, mesh.triangles, cage_vertices, cage_triangles, cell, check)
    outside = parts_outside(mesh.vertices, mesh.triangles, cage_vertices, cage_triangles, check)
    clearance, mean = distances(mesh.vertices, cage_vertices, cage_triangles, cell / 4)
    return Enclosure(crossed, outside, 0.0 if crossed else clearance, mean)


def checked_cage(vertices, faces):
    """lbc's :func:`~lbc_core.cage.make.make_cage` on the cage: raises CageError when lbc would refuse it."""
    return make_cage(vertices, faces)
