"""The first, fast simplification: the marching-cubes surface (tens of thousands of vertices) down to the progressive
hull's start (hundreds to a few thousand) by quadric error collapses (fast-simplification, MIT). It may return a
non-manifold, self-intersecting or short surface, and does not promise to enclose the mesh: each result is checked,
its vertices pushed out along their normals past the mesh's witness points it left outside, and a few nearby targets
are tried before giving up (None), so the caller can start from a larger surface."""

import numpy as np

from ..cage import edge_pairing
from ..kernel.geometry import closest_on_triangles, winding_numbers
from ..kernel.intersections import intersecting_triangles
from .extraction import compact, signed_volume

# Targets tried, as factors of the vertex count asked, when a result fails its checks (bench/RESULTS.md,
# "Cage generator").
TARGET_FACTORS = (1.0, 1.07, 1.15, 1.25)
# Rounds of pushing vertices out past the witness points the simplification left outside.
PUSH_ROUNDS = 6


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


def quadric_simplified(vertices, triangles, target, witnesses, clearance, zero):
    """(vertices, triangles) of about ``target`` vertices: closed, manifold, outward, not self-intersecting, with
    every witness point inside (vertices pushed out where the simplification cut into the mesh); or None when no
    target tried gives one."""
    import fast_simplification

    for factor in TARGET_FACTORS:
        count = int(round(2 * target * factor))
        if count >= len(triangles):
            return vertices, triangles
        points, faces = fast_simplification.simplify(vertices.astype(np.float64), triangles.astype(np.int64),
                                                     target_count=count)
        points, faces = compact(np.asarray(points, dtype=float), np.asarray(faces, dtype=np.int64))
        if not is_surface(points, faces, zero):
            continue
        points = pushed_out(points, faces, witnesses, clearance)
        if points is not None and is_surface(points, faces, zero):
            return points, faces
    return None


def is_surface(vertices, triangles, zero):
    """Whether the surface is closed, manifold, outward and without self-intersection."""
    if len(triangles) < 4 or not is_closed_manifold(triangles) or signed_volume(vertices, triangles) <= 0:
        return False
    return not len(intersecting_triangles(vertices, triangles, zero))


def vertex_normals(vertices, triangles):
    """(n, 3) unit normals: each vertex's triangles' area-weighted normals summed."""
    corners = vertices[triangles]
    face = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, triangles[:, k], face)
    return normals / np.maximum(np.linalg.norm(normals, axis=1), 1e-300)[:, None]


def pushed_out(vertices, triangles, witnesses, clearance, rounds=PUSH_ROUNDS):
    """The vertices moved out until every witness is inside: the corners of the triangle nearest a witness outside
    go out along that triangle's normal past it by ``clearance`` (the nearest vertex may lie on another sheet of a
    thin part); None after ``rounds`` tries."""
    vertices = vertices.copy()
    for _ in range(rounds):
        outside = witnesses[winding_numbers(vertices, triangles, witnesses) <= 0.5]
        if not len(outside):
            return vertices
        corners = vertices[triangles]
        nearest = _nearest_triangles(outside, corners)
        normal = np.cross(corners[nearest, 1] - corners[nearest, 0], corners[nearest, 2] - corners[nearest, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
        lift = np.maximum(np.einsum("ij,ij->i", outside - corners[nearest, 0], normal), 0.0) + clearance
        push = np.zeros((len(vertices), 3))
        for k in range(3):  # each vertex goes as far as its farthest push asks, along that push's normal
            moved = lift[:, None] * normal
            order = np.argsort(lift)
            push[triangles[nearest[order], k]] = moved[order]
        vertices += push
    return None


def _nearest_triangles(points, corners):
    """(P,) index of the triangle nearest each point (all pairs, a chunk of points at a time)."""
    found = np.zeros(len(points), dtype=np.int64)
    for chunk in np.array_split(np.arange(len(points)), max(1, len(points) * len(corners) // 500_000)):
        repeated = np.repeat(points[chunk], len(corners), axis=0)
        tiled = np.tile(corners, (len(chunk), 1, 1))
        squared, _ = closest_on_triangles(repeated, tiled[:, 0], tiled[:, 1], tiled[:, 2])
        found[chunk] = np.argmin(squared.reshape(len(chunk), len(corners)), axis=1)
    return found
