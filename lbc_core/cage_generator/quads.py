"""Quads for the generated cage: pairs of its triangles that make a good quad, merged, so that the artist edits a
quad-dominant cage (hand-made character cages are mostly quads).

Two triangles sharing an edge make a quad when they are nearly coplanar (folded by at most MAX_FOLD), the quad's
corners are neither sharp nor flat (MIN_CORNER to MAX_CORNER degrees, so it is convex), and the shared edge is the
diagonal lbc's own cage checks split the quad along (the shorter one, :func:`lbc_core.cage.triangulate`): lbc then
binds exactly the triangles that were checked. Pairs are taken greedily, flattest and squarest first; with a mirror
plane, a pair and its mirror image together, so that the cage stays symmetric."""

import numpy as np

from ..cage.triangulate import QUAD_SPLIT_TIE

# Largest angle between the two triangles' normals, in degrees (bench/RESULTS.md, "Cage generator", quads).
MAX_FOLD = 40.0
# The quad's corner angles, in degrees: within these it is convex and not a sliver.
MIN_CORNER, MAX_CORNER = 35.0, 155.0


def quad_faces(vertices, triangles, mirror=None):
    """The faces (tuples, quads and triangles, facing out) of the triangles with good pairs merged.

    Parameters
    ----------
    vertices : (n, 3) float array
    triangles : (T, 3) int array, a closed outward surface
    mirror : (n,) int array or None
        Each vertex's mirror image, for a symmetric surface: pairs are merged with their images.
    """
    candidates = _candidates(vertices, triangles)
    image = None if mirror is None else _triangle_images(triangles, mirror)
    used = np.zeros(len(triangles), dtype=bool)
    faces = []
    for first, second, quad in candidates:
        pairs = [(first, second, quad)]
        if image is not None:
            pairs.append((image[first], image[second], tuple(int(mirror[quad[k]]) for k in (0, 3, 2, 1))))
            if {pairs[1][0], pairs[1][1]} == {first, second}:
                pairs.pop()
        touched = {t for pair in pairs for t in pair[:2]}
        if len(touched) != 2 * len(pairs) or used[list(touched)].any():
            continue
        used[list(touched)] = True
        faces.extend(pair[2] for pair in pairs)
    faces.extend(tuple(int(v) for v in triangle) for triangle in triangles[~used])
    return faces


def _candidates(vertices, triangles):
    """[(first, second, quad)] of the triangle pairs that make a good quad, best first; quad is (a, b, c, d) with
    a-c the shared edge, in the triangles' orientation."""
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    owner = np.tile(np.arange(len(triangles)), 3)
    opposite = np.concatenate([triangles[:, 2], triangles[:, 0], triangles[:, 1]])
    n = len(vertices)
    key = edges[:, 0].astype(np.int64) * n + edges[:, 1]
    reverse = edges[:, 1].astype(np.int64) * n + edges[:, 0]
    order = np.argsort(key)
    where = order[np.searchsorted(key[order], reverse)]
    one = np.flatnonzero(edges[:, 0] < edges[:, 1])  # each shared edge once
    other = where[one]
    # Triangle (a, c, b') and (c, a, d): the quad a, b', c, d... written with a-c its diagonal.
    a, c = edges[one, 0], edges[one, 1]
    quads = np.stack([a, opposite[other], c, opposite[one]], axis=1)
    score, good = _quality(vertices, quads)
    chosen = np.flatnonzero(good)
    chosen = chosen[np.lexsort((chosen, score[chosen]))]
    return [(int(owner[one[k]]), int(owner[other[k]]), tuple(int(v) for v in quads[k])) for k in chosen]


def _quality(vertices, quads):
    """(score, good) per quad (q, 4) whose diagonal is corners 0-2: the fold plus the corners' distance from a right
    angle, in degrees (lower is better), and whether it is a good quad."""
    points = vertices[quads]
    first = np.cross(points[:, 1] - points[:, 0], points[:, 2] - points[:, 0])
    second = np.cross(points[:, 2] - points[:, 0], points[:, 3] - points[:, 0])
    cosine = np.einsum("ij,ij->i", first, second) / np.maximum(
        np.linalg.norm(first, axis=1) * np.linalg.norm(second, axis=1), 1e-300)
    fold = np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))
    before, after = np.roll(points, 1, axis=1) - points, np.roll(points, -1, axis=1) - points
    corner = np.degrees(np.arccos(np.clip(np.einsum("qkj,qkj->qk", before, after) / np.maximum(
        np.linalg.norm(before, axis=2) * np.linalg.norm(after, axis=2), 1e-300), -1.0, 1.0)))
    shared = np.linalg.norm(points[:, 0] - points[:, 2], axis=1)
    across = np.linalg.norm(points[:, 1] - points[:, 3], axis=1)
    # lbc splits a quad along its shorter diagonal, along 0-2 on a tie: it must be the shared edge.
    split_here = (shared < across) | (np.abs(shared - across) <= QUAD_SPLIT_TIE * np.maximum(shared, across))
    good = (fold <= MAX_FOLD) & np.all((corner >= MIN_CORNER) & (corner <= MAX_CORNER), axis=1) & split_here
    return fold + np.abs(corner - 90.0).max(axis=1), good


def _triangle_images(triangles, mirror):
    """(T,) int array: each triangle's mirror image among the triangles."""
    n = int(triangles.max()) + 1
    keys = np.sort(triangles, axis=1)
    images = np.sort(mirror[triangles], axis=1)
    flat = lambda rows: (rows[:, 0] * n + rows[:, 1]) * n + rows[:, 2]  # noqa: E731
    order = np.argsort(flat(keys))
    return order[np.searchsorted(flat(keys)[order], flat(images))]
