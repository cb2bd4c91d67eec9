"""The first, fast simplification: the marching-cubes surface (tens of thousands of vertices) down to the progressive
hull's start (hundreds to a few thousand) by quadric error collapses (fast-simplification, MIT). It may return a
non-manifold, self-intersecting or short surface, and does not promise to enclose the mesh: each result is checked,
and a few nearby targets are tried before giving up (None), so the caller can start from a larger surface."""

import numpy as np

from ..cage import edge_pairing
from ..geometry import intersecting_triangles, winding_numbers
from .extraction import compact, signed_volume

# Targets tried, as factors of the vertex count asked, when a result fails its checks (bench/RESULTS.md,
# "Cage generator").
TARGET_FACTORS = (1.0, 1.07, 1.15, 1.25)


def is_closed_manifold(triangles):
    """Every edge in exactly two triangles, each way once, and one fan of triangles around every vertex."""
    directed, order, counts = edge_pairing(triangles)
    if not np.all(counts == 2):
        return False
    # Each directed edge once: the two copies of an edge run opposite ways (consistently oriented).
    pairs = directed[order].reshape(-1, 2, 2)
    if not np.all(pairs[:, 0, 0] == pairs[:, 1, 1]):
        return False
    # One fan per vertex: on a closed oriented manifold, Euler counts agree vertex by vertex through corners = edges.
    n = triangles.max() + 1
    corners = np.bincount(triangles.ravel(), minlength=n)
    out_edges = np.bincount(directed[:, 0], minlength=n)
    return bool(np.all(corners == out_edges)) and _fans_single(triangles, directed, n)


def _fans_single(triangles, directed, n):
    """Each vertex's outgoing edges form one cycle (next edge around the vertex by the triangle before it)."""
    t = len(triangles)
    # The directed edge (v -> w) of triangle f is followed around v by the edge (v -> u) where (u -> v) is f's edge
    # before it; the opposite triangle's copy of (v -> u) continues the fan.
    key = directed[:, 0] * n + directed[:, 1]
    position = np.argsort(key)
    previous = (np.arange(3 * t) + 2 * t) % (3 * t)  # the edge before, in the same triangle: (u -> v)
    reverse_key = directed[previous, 1] * n + directed[previous, 0]  # (v -> u)
    following = position[np.searchsorted(key[position], reverse_key)]
    seen = np.zeros(3 * t, dtype=bool)
    cycles = np.zeros(n, dtype=np.int64)
    for start in range(3 * t):
        if seen[start]:
            continue
        cycles[directed[start, 0]] += 1
        edge = start
        while not seen[edge]:
            seen[edge] = True
            edge = following[edge]
    return bool(np.all(cycles[np.unique(triangles)] == 1))


def quadric_simplified(vertices, triangles, target, witnesses, zero):
    """(vertices, triangles) of about ``target`` vertices: closed, manifold, outward, not self-intersecting, with
    every witness point inside; or None when no target tried gives one."""
    import fast_simplification

    for factor in TARGET_FACTORS:
        count = int(round(2 * target * factor))
        if count >= len(triangles):
            return vertices, triangles
        points, faces = fast_simplification.simplify(vertices.astype(np.float64), triangles.astype(np.int64),
                                                     target_count=count)
        points, faces = compact(np.asarray(points, dtype=float), np.asarray(faces, dtype=np.int64))
        if good_start(points, faces, witnesses, zero):
            return points, faces
    return None


def good_start(vertices, triangles, witnesses, zero):
    """Whether the surface is closed, manifold, outward, without self-intersection, and has every witness inside."""
    if len(triangles) < 4 or not is_closed_manifold(triangles) or signed_volume(vertices, triangles) <= 0:
        return False
    if len(intersecting_triangles(vertices, triangles, zero)):
        return False
    return bool(np.all(winding_numbers(vertices, triangles, witnesses) > 0.5))
