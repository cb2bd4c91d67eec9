"""The last word on a generated cage: lbc's own cage checks (:func:`lbc_core.cage.make.make_cage`) and enclosure,
exactly.

Enclosure is checked without assuming anything of the mesh: no mesh edge crosses or touches a cage triangle, no cage
edge crosses or touches a mesh triangle, so each connected part of the mesh is wholly inside or wholly outside, and
one vertex of each part (every loose vertex too) has winding number 1. The distance from each mesh vertex to samples
of the cage bounds its distance to the cage from below, so the exact tests run only on the edges and triangles that
could reach it (bench/RESULTS.md, "Cage generator")."""

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..cage import make_cage
from ..kernel.geometry import closest_on_triangles, winding_numbers

# Mesh edges longer than this many sample spacings are tested against the cage's triangles by their boxes.
LONG_EDGE = 8.0
# Mesh vertices whose exact distance to the cage is computed at a time, nearest first, for the clearance.
CLEARANCE_CHUNK = 256


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
    boxes = (np.all(low <= np.maximum(np.maximum(a, b), c), axis=1)
             & np.all(high >= np.minimum(np.minimum(a, b), c), axis=1))
    s1, s2 = orientation(p, a, b, c), orientation(q, a, b, c)
    t1, t2, t3 = orientation(p, q, a, b), orientation(p, q, b, c), orientation(p, q, c, a)
    sides = (s1 * s2 <= 0)
    around = ((t1 >= 0) & (t2 >= 0) & (t3 >= 0)) | ((t1 <= 0) & (t2 <= 0) & (t3 <= 0))
    return boxes & sides & around


def pairs_meeting(starts, ends, corners, check):
    """(i, j) index arrays of the segments and triangles that meet, among all pairs whose boxes overlap (both sets
    small)."""
    found_i, found_j = [np.empty(0, dtype=np.int64)], [np.empty(0, dtype=np.int64)]
    low, high = corners.min(axis=1), corners.max(axis=1)
    for chunk in np.array_split(np.arange(len(starts)), max(1, len(starts) * len(corners) // 2_000_000)):
        check()
        seg_low, seg_high = np.minimum(starts[chunk], ends[chunk]), np.maximum(starts[chunk], ends[chunk])
        i, j = np.nonzero(np.all(seg_low[:, None] <= high[None], axis=2)
                          & np.all(seg_high[:, None] >= low[None], axis=2))
        i = chunk[i]
        meet = segments_meet_triangles(starts[i], ends[i], corners[j, 0], corners[j, 1], corners[j, 2])
        found_i.append(i[meet]), found_j.append(j[meet])
    return np.concatenate(found_i), np.concatenate(found_j)


def mesh_edges(triangles):
    """(E, 2) int array: each edge of the triangles once, lower index first."""
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    base = int(triangles.max()) + 1
    keys = np.unique(edges[:, 0].astype(np.int64) * base + edges[:, 1])
    return np.stack([keys // base, keys % base], axis=1)


class CageSamples:
    """Points on each cage triangle, no two neighbours farther apart than ``spacing`` (its corners and a barycentric
    lattice), in a k-d tree: every point of a triangle lies within ``spacing`` of one of its own samples, which
    bounds distances to the cage from below and finds the triangles near a point."""

    def __init__(self, vertices, triangles, spacing):
        corners = vertices[triangles]
        longest = np.max(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2), axis=1)
        steps = np.maximum(1, np.ceil(longest / spacing)).astype(np.int64)
        points, owners = [], []
        for k in np.unique(steps):
            i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
            keep = i + j <= k
            bary = np.stack([i[keep], j[keep], k - i[keep] - j[keep]], axis=1) / k
            chosen = np.flatnonzero(steps == k)
            points.append(np.einsum("sk,tkd->tsd", bary, corners[chosen]).reshape(-1, 3))
            owners.append(np.repeat(chosen, len(bary)))
        self.owners = np.concatenate(owners)
        self.tree = cKDTree(np.concatenate(points))
        self.spacing = float(spacing)

    def lower(self, points):
        """((P,) lower bounds of each point's distance to the cage, (P,) its distance to the nearest sample)."""
        near, _ = self.tree.query(points)
        return near - self.spacing, near

    def triangles_near(self, points, radius):
        """(i, j): the pairs of point i and cage triangle j with a sample within ``radius`` (P,) of the point."""
        found = self.tree.query_ball_point(points, radius + self.spacing)
        counts = np.array([len(items) for items in found], dtype=np.int64)
        if not counts.sum():
            return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
        owners = self.owners[np.concatenate(found).astype(np.int64)]
        pairs = np.stack([np.repeat(np.arange(len(points)), counts), owners], axis=1)
        pairs = np.unique(pairs, axis=0)
        return pairs[:, 0], pairs[:, 1]


def crossings(mesh_vertices, mesh_triangles, cage_vertices, cage_triangles, samples, lower, check):
    """Mesh edges meeting cage triangles plus cage edges meeting mesh triangles, tested exactly on the mesh's edges
    and triangles that can reach the cage: those with a point nearer their corners than the corners' ``lower``
    bounds of their distance to the cage (any point of an edge lies within half its length of an end, any point of a
    triangle within its longest edge of a corner)."""
    edges = mesh_edges(mesh_triangles)
    edge_hits, _ = edges_crossing(mesh_vertices, edges, cage_vertices, cage_triangles, samples, lower)
    corners = mesh_vertices[mesh_triangles]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    close = np.flatnonzero(lower[mesh_triangles].min(axis=1) <= longest)
    cage_edges = mesh_edges(cage_triangles)
    hits, _ = pairs_meeting(cage_vertices[cage_edges[:, 0]], cage_vertices[cage_edges[:, 1]], corners[close], check)
    return len(edge_hits) + len(hits)


def edges_crossing(mesh_vertices, edges, cage_vertices, cage_triangles, samples, lower):
    """(i, j): the pairs of mesh edge i (of ``edges``, (E, 2)) and cage triangle j that meet, among the edges that
    can reach the cage (``lower``: bounds of the vertices' distances to it) and the triangles with a sample (of
    ``samples``, a CageSamples) within half the edge's length and the sampling's spacing of the edge's middle."""
    starts, ends = mesh_vertices[edges[:, 0]], mesh_vertices[edges[:, 1]]
    lengths = np.linalg.norm(ends - starts, axis=1)
    close = np.minimum(lower[edges[:, 0]], lower[edges[:, 1]]) <= 0.5 * lengths
    # A long edge has too many samples within its reach (their count grows with its length squared): it is tested
    # against every triangle whose box its box overlaps instead.
    long = np.flatnonzero(close & (lengths > LONG_EDGE * samples.spacing))
    close = np.flatnonzero(close & (lengths <= LONG_EDGE * samples.spacing))
    i, j = samples.triangles_near(0.5 * (starts[close] + ends[close]), 0.5 * lengths[close])
    corners = cage_vertices[cage_triangles[j]]
    i = close[i]
    meet = segments_meet_triangles(starts[i], ends[i], corners[:, 0], corners[:, 1], corners[:, 2])
    long_i, long_j = pairs_meeting(starts[long], ends[long], cage_vertices[cage_triangles], lambda: None)
    return np.concatenate([i[meet], long[long_i]]), np.concatenate([j[meet], long_j])


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


def distances(mesh_vertices, cage_vertices, cage_triangles, near, spacing):
    """(clearance, mean distance): the least distance from a mesh vertex to the cage's surface (exact, among the
    vertices whose distance ``near`` to the cage's samples ``spacing`` apart could make them the nearest), and the
    mean distance from a cage vertex to the nearest mesh vertex."""
    corners = cage_vertices[cage_triangles]
    order = np.argsort(near, kind="stable")
    best = np.inf
    for start in range(0, len(order), CLEARANCE_CHUNK):
        chosen = order[start:start + CLEARANCE_CHUNK]
        if near[chosen[0]] - spacing > best:
            break
        repeated = np.repeat(mesh_vertices[chosen], len(corners), axis=0)
        tiled = np.tile(corners, (len(chosen), 1, 1))
        squared, _ = closest_on_triangles(repeated, tiled[:, 0], tiled[:, 1], tiled[:, 2])
        best = min(best, float(np.sqrt(squared.min())))
    mean = float(cKDTree(mesh_vertices).query(cage_vertices)[0].mean())
    return best, mean


def enclosure(mesh, cage_vertices, cage_triangles, cell, check=None):
    """An :class:`Enclosure` of the InputMesh ``mesh`` by the closed, outward cage; the cage sampled ``cell`` apart
    to find the parts of the mesh near it."""
    check = check or (lambda: None)
    samples = CageSamples(cage_vertices, cage_triangles, cell)
    lower, near = samples.lower(mesh.vertices)
    crossed = crossings(mesh.vertices, mesh.triangles, cage_vertices, cage_triangles, samples, lower, check)
    outside = parts_outside(mesh.vertices, mesh.triangles, cage_vertices, cage_triangles, check)
    clearance, mean = distances(mesh.vertices, cage_vertices, cage_triangles, near, cell)
    return Enclosure(crossed, outside, 0.0 if crossed else clearance, mean)


def checked_cage(vertices, faces):
    """lbc's :func:`~lbc_core.cage.make.make_cage` on the cage: raises CageError when lbc would refuse it."""
    return make_cage(vertices, faces)
