"""The mesh as an obstacle for the progressive hull: whether new cage triangles meet any mesh edge, or new cage edges
any mesh triangle, tested exactly (the final check's test,
:func:`lbc_core.cage_generator.check.segments_meet_triangles`) on the mesh's edges and triangles near them.

Witness points alone (one mesh vertex per voxel) let a collapse cut a mesh edge between two of them, which the final
check then refuses (bench/RESULTS.md, "Cage generator"). Edges and triangles are sorted by the x of their middle, so
those near a box are found by bisection within their longest half-extent; the few much longer than the rest are
tested every time."""

import numpy as np

from .check import segments_meet_triangles

# Edges and triangles longer than this many times the median are kept apart and tested every time, so that the
# bisection's reach stays short.
LONG = 8.0


class Sorted:
    """Items (segments (k, 2, 3) or triangles (k, 3, 3)) sorted along x by their middle, with their boxes."""

    def __init__(self, corners):
        low, high = corners.min(axis=1), corners.max(axis=1)
        extent = (high - low).max(axis=1)
        long = extent > LONG * max(float(np.median(extent)), 1e-300)
        self.long = corners[long]
        corners, low, high = corners[~long], low[~long], high[~long]
        middle = 0.5 * (low[:, 0] + high[:, 0])
        order = np.argsort(middle, kind="stable")
        self.corners, self.low, self.high, self.middle = corners[order], low[order], high[order], middle[order]
        self.reach = float(0.5 * (high[:, 0] - low[:, 0]).max()) if len(order) else 0.0

    def near(self, low, high):
        """(k, m, 3) corners of the items whose boxes overlap the box (low, high), the long ones included."""
        first = np.searchsorted(self.middle, low[0] - self.reach, side="left")
        last = np.searchsorted(self.middle, high[0] + self.reach, side="right")
        inside = np.all(self.low[first:last] <= high, axis=1) & np.all(self.high[first:last] >= low, axis=1)
        found = self.corners[first:last][inside]
        return np.concatenate([found, self.long]) if len(self.long) else found


class MeshGuard:
    """A mesh's edges and triangles, for testing new cage triangles and edges against them.

    Parameters
    ----------
    vertices : (n, 3) float array
    triangles : (T, 3) int array
    """

    def __init__(self, vertices, triangles):
        edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
        base = len(vertices) + 1
        keys = np.unique(edges[:, 0].astype(np.int64) * base + edges[:, 1])
        self.edges = Sorted(vertices[np.stack([keys // base, keys % base], axis=1)])
        self.triangles = Sorted(vertices[triangles])

    def meets(self, cage_triangles):
        """Whether any of the cage triangles (k, 3, 3) meets a mesh edge, or any of their edges a mesh triangle."""
        low, high = cage_triangles.min(axis=(0, 1)), cage_triangles.max(axis=(0, 1))
        segments = self.edges.near(low, high)
        if len(segments) and _any_meet(segments, cage_triangles):
            return True
        triangles = self.triangles.near(low, high)
        if not len(triangles):
            return False
        cage_edges = np.stack([cage_triangles, np.roll(cage_triangles, -1, axis=1)], axis=2).reshape(-1, 2, 3)
        return _any_meet(cage_edges, triangles)


def _any_meet(segments, triangles):
    """Whether any segment (s, 2, 3) meets any triangle (t, 3, 3), among the pairs whose boxes overlap."""
    seg_low, seg_high = segments.min(axis=1), segments.max(axis=1)
    low, high = triangles.min(axis=1), triangles.max(axis=1)
    i, j = np.nonzero(np.all(seg_low[:, None] <= high[None], axis=2) & np.all(seg_high[:, None] >= low[None], axis=2))
    if not len(i):
        return False
    corners = triangles[j]
    return bool(np.any(segments_meet_triangles(segments[i, 0], segments[i, 1], corners[:, 0], corners[:, 1],
                                               corners[:, 2])))
