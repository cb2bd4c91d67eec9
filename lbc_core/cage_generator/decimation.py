"""Quadric edge collapses that keep a closed surface a closed manifold, in rounds of many collapses at once.

fast-simplification (the quadric simplification the start surface comes from) does not test the link condition: on
a thin part of the solid (a leg, a tentacle) it collapses edges whose ends share a third neighbour, and the surface
pinches at a vertex (pgc_giraffe and pgc_octopus found no start at their first two attempts; bench/RESULTS.md, "Cage
generator", the third round). Here each round takes, among the edges whose collapse
keeps the surface manifold (the ends share exactly their two opposite corners, and those keep four neighbours or
more) and turns no triangle over or into a sliver, the cheapest of each neighbourhood: an edge whose quadric error is
the least of every edge at its ends' neighbours, so no two collapses of a round touch the same triangles and each
one's tests still hold when all are made. Each round is a handful of array operations over the surface."""

import numpy as np
import scipy.sparse as sp

from .placement import MIN_ANGLE_SINE, cross, dot

# A collapse may turn a triangle by at most this much: the cosine between its normals before and after.
MIN_TURN_COSINE = 0.2
# Quadric systems with a determinant below this share of their scale (cubed) are singular: the new vertex is then the
# best of the edge's ends and middle.
SINGULAR = 1e-9
# Passes of a round that choose again around the edges its shape test refused.
SHAPE_PASSES = 3


def face_quadrics(vertices, triangles):
    """(T, 4, 4): each triangle's plane quadric, weighted by its area."""
    corners = vertices[triangles]
    normal = cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = np.linalg.norm(normal, axis=1)
    unit_normal = normal / np.maximum(area, 1e-300)[:, None]
    plane = np.concatenate([unit_normal, -dot(unit_normal, corners[:, 0])[:, None]], axis=1)
    return 0.5 * area[:, None, None] * plane[:, :, None] * plane[:, None, :]


def vertex_quadrics(vertices, triangles):
    """(n, 4, 4): each vertex's quadric, the sum of its triangles'."""
    quadrics = np.zeros((len(vertices), 4, 4))
    per_face = face_quadrics(vertices, triangles)
    for k in range(3):
        np.add.at(quadrics, triangles[:, k], per_face)
    return quadrics


def decimated(vertices, triangles, target, check=None):
    """(vertices, triangles) of a closed, manifold, outward surface brought down to about ``target`` vertices (or as
    near as manifold collapses go), closed and manifold still; the unused vertices dropped."""
    check = check or (lambda: None)
    points = np.array(vertices, dtype=float)
    faces = np.array(triangles, dtype=np.int64)
    quadrics = vertex_quadrics(points, faces)
    alive = np.zeros(len(points), dtype=bool)
    alive[faces.ravel()] = True
    while np.count_nonzero(alive) > target:
        check()
        edges, position, cost = _candidates(points, faces, quadrics)
        chosen = _chosen(points, faces, edges, position, cost)[:np.count_nonzero(alive) - target]
        if not len(chosen):
            break
        kept, gone = edges[chosen, 0], edges[chosen, 1]
        points[kept] = position[chosen]
        quadrics[kept] += quadrics[gone]
        alive[gone] = False
        renumber = np.arange(len(points))
        renumber[gone] = kept
        faces = renumber[faces]
        faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    used = np.flatnonzero(alive)
    renumber = np.full(len(points), -1, dtype=np.int64)
    renumber[used] = np.arange(len(used))
    return points[used], renumber[faces]


def _edges(faces, count):
    """(E, 2) edges (low end first) of a closed manifold surface, and (E, 2) the corners opposite each edge."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    apex = np.concatenate([faces[:, 2], faces[:, 0], faces[:, 1]])
    key = directed[:, 0] * count + directed[:, 1]
    order = np.argsort(key)
    twin = order[np.searchsorted(key[order], directed[:, 1] * count + directed[:, 0])]
    low = directed[:, 0] < directed[:, 1]
    return directed[low], np.stack([apex[low], apex[twin[low]]], axis=1)


def _candidates(points, faces, quadrics):
    """(edges (E, 2), new positions (E, 3), costs (E,), inf where the collapse would not keep the surface manifold) of
    every edge."""
    count = len(points)
    edges, opposite = _edges(faces, count)
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    adjacency = sp.csr_matrix((np.ones(len(directed)), (directed[:, 0], directed[:, 1])), shape=(count, count))
    valence = np.asarray(adjacency.sum(axis=1)).ravel()
    common = np.asarray(adjacency[edges[:, 0]].multiply(adjacency[edges[:, 1]]).sum(axis=1)).ravel()
    manifold = (common == 2) & np.all(valence[opposite] > 3, axis=1)
    position, cost = _placed(points, quadrics[edges[:, 0]] + quadrics[edges[:, 1]], edges)
    return edges, position, np.where(manifold, cost, np.inf)


def _chosen(points, faces, edges, position, cost):
    """The edges (indices, cheapest first) a round collapses: the cheapest of each neighbourhood whose collapse keeps
    the triangles' shapes. The shapes are tested on the chosen edges, which are chosen again around those refused, a
    few passes; then on every edge at once (where the cheapest edges are all refused: a flat region's slivers)."""
    cost = cost.copy()
    for _ in range(SHAPE_PASSES):
        chosen = _independent(edges, cost, faces, len(points))
        fine = _shapes_kept(points, faces, edges[chosen], position[chosen])
        if fine.all():
            return chosen
        cost[chosen[~fine]] = np.inf
    finite = np.flatnonzero(np.isfinite(cost))
    cost[finite[~_shapes_kept(points, faces, edges[finite], position[finite])]] = np.inf
    return _independent(edges, cost, faces, len(points))


def _placed(points, quadric, edges):
    """(E, 3) the point of least quadric error for each edge's summed quadric (E, 4, 4) (the best of its ends and
    middle where the system is singular), and (E,) that error."""
    system, right = quadric[:, :3, :3], -quadric[:, :3, 3]
    scale = np.abs(system).sum(axis=(1, 2)) + 1e-300
    solvable = np.abs(np.linalg.det(system)) > SINGULAR * scale ** 3
    optimum = np.zeros((len(edges), 3))
    optimum[solvable] = np.linalg.solve(system[solvable], right[solvable][..., None])[..., 0]
    a, b = points[edges[:, 0]], points[edges[:, 1]]
    options = np.stack([optimum, a, b, 0.5 * (a + b)], axis=1)  # (E, 4, 3)
    homogeneous = np.concatenate([options, np.ones(options.shape[:2] + (1,))], axis=2)
    error = np.einsum("eki,eij,ekj->ek", homogeneous, quadric, homogeneous)
    error[~solvable, 0] = np.inf
    best = np.argmin(error, axis=1)
    return options[np.arange(len(edges)), best], np.maximum(error[np.arange(len(edges)), best], 0.0)


def _shapes_kept(points, faces, edges, position):
    """(E,) bool: whether moving both ends of each edge to its new position turns no triangle around them (but the
    two on the edge) by more than MIN_TURN_COSINE allows, or makes it a sliver."""
    corner_face = np.repeat(np.arange(len(faces)), 3)
    corner_vertex = faces.ravel()
    order = np.argsort(corner_vertex, kind="stable")
    end = np.cumsum(np.bincount(corner_vertex, minlength=len(points)))
    start = end - np.bincount(corner_vertex, minlength=len(points))
    ok = np.ones(len(edges), dtype=bool)
    for side in (0, 1):
        ends = edges[:, side]
        counts = end[ends] - start[ends]
        owner = np.repeat(np.arange(len(edges)), counts)
        slot = start[ends][owner] + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        face = corner_face[order[slot]]
        other = edges[owner, 1 - side]
        keep = ~np.any(faces[face] == other[:, None], axis=1)  # the edge's own two triangles vanish
        owner, face = owner[keep], face[keep]
        old = points[faces[face]]
        new = old.copy()
        moved = faces[face] == edges[owner, side][:, None]
        new[moved] = np.repeat(position[owner], np.count_nonzero(moved, axis=1), axis=0)
        bad = ~_turned_fine(old, new)
        ok &= np.bincount(owner[bad], minlength=len(edges)) == 0
    return ok


def _turned_fine(old, new):
    """(K,) bool: triangles ``new`` (K, 3, 3) not turned from ``old`` by more than MIN_TURN_COSINE allows, and no
    slivers."""
    normal_old = cross(old[:, 1] - old[:, 0], old[:, 2] - old[:, 0])
    normal_new = cross(new[:, 1] - new[:, 0], new[:, 2] - new[:, 0])
    area_old, area_new = np.linalg.norm(normal_old, axis=1), np.linalg.norm(normal_new, axis=1)
    lengths = np.sort(np.linalg.norm(new - np.roll(new, 1, axis=1), axis=2), axis=1)
    turned = dot(normal_old, normal_new) >= MIN_TURN_COSINE * area_old * area_new
    return turned & (area_new > 0.0) & (area_new >= MIN_ANGLE_SINE * lengths[:, 1] * lengths[:, 2])


def _independent(edges, cost, faces, count):
    """The edges (indices, cheapest first) of finite cost that are the cheapest of every edge at their ends'
    neighbours (ties broken by index): collapses that share no triangle and leave each other's tests true."""
    finite = np.isfinite(cost)
    rank = np.empty(len(edges), dtype=np.int64)
    rank[np.lexsort((np.arange(len(edges)), np.where(finite, cost, np.inf)))] = np.arange(len(edges))
    rank[~finite] = len(edges)
    least = np.full(count, len(edges), dtype=np.int64)
    np.minimum.at(least, edges[:, 0], rank)
    np.minimum.at(least, edges[:, 1], rank)
    around = least.copy()  # the least rank at a vertex or any of its neighbours
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    np.minimum.at(around, directed[:, 0], least[directed[:, 1]])
    chosen = np.flatnonzero(finite & (rank == around[edges[:, 0]]) & (rank == around[edges[:, 1]]))
    return chosen[np.argsort(rank[chosen])]
