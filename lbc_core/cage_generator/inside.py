"""Which points lie inside a closed triangle surface, for many points at once: the parity of a ray's crossings.

The generalised winding number (:func:`lbc_core.kernel.geometry.winding_numbers`) sums every triangle's solid angle
for every point; for the tens of thousands of witness points of a 64k-vertex mesh against a surface of a thousand
triangles that is 20 s of numpy (bench/RESULTS.md, "Cage generator"). On a closed surface a ray from the point
crosses it an odd number of times exactly when the point is inside, and a ray meets only the few triangles whose
shadow covers the point: binned on a 2D grid across the ray, the test costs about (points + triangles) × a few.

The ray's direction is fixed and generic (no axis, no grid diagonal), so that a ray through an edge or a corner,
where one crossing would count twice, needs a coincidence no real input has; the answer is the same on every run."""

import numpy as np

# The rays' direction: generic, so that no ray of a grid-aligned input runs along an edge or through a corner.
DIRECTION = np.array([0.2718281828, 0.1414213562, 0.9526279441])
# Triangles per bin, about, on the 2D grid across the ray.
PER_BIN = 2.0


def _frame():
    """(3, 3): two unit vectors across the ray and the ray's direction, as rows."""
    ray = DIRECTION / np.linalg.norm(DIRECTION)
    across = np.cross(ray, [1.0, 0.0, 0.0])
    across /= np.linalg.norm(across)
    return np.stack([across, np.cross(ray, across), ray])


def inside_surface(vertices, triangles, points):
    """(P,) bool: whether each point is inside the closed, consistently oriented surface (either orientation), by
    the parity of the crossings of a ray from it. A point on the surface may go either way."""
    points = np.asarray(points, dtype=float)
    if len(points) == 0 or len(triangles) == 0:
        return np.zeros(len(points), dtype=bool)
    frame = _frame()
    corners = (vertices @ frame.T)[triangles]  # (T, 3, 3): across, across, along the ray
    seen = points @ frame.T
    low, high = corners[..., :2].min(axis=1), corners[..., :2].max(axis=1)
    span = np.maximum(high.max(axis=0), seen[:, :2].max(axis=0)) - np.minimum(low.min(axis=0), seen[:, :2].min(axis=0))
    origin = np.minimum(low.min(axis=0), seen[:, :2].min(axis=0))
    cell = max(float(np.sqrt(span[0] * span[1] * PER_BIN / len(triangles))), 1e-300)
    first, last = np.floor((low - origin) / cell).astype(np.int64), np.floor((high - origin) / cell).astype(np.int64)
    width = int(max(last[:, 0].max(), np.floor((seen[:, 0] - origin[0]) / cell).max())) + 1
    owner, keys = _covered_bins(first, last, width)
    order = np.argsort(keys, kind="stable")
    owner, keys = owner[order], keys[order]
    point_bins = np.floor((seen[:, :2] - origin) / cell).astype(np.int64)
    point_keys = point_bins[:, 1] * width + point_bins[:, 0]
    start, stop = np.searchsorted(keys, point_keys, side="left"), np.searchsorted(keys, point_keys, side="right")
    counts = stop - start
    which = np.repeat(np.arange(len(points)), counts)
    slot = np.arange(len(which)) - np.repeat(np.cumsum(counts) - counts, counts) + np.repeat(start, counts)
    hits = _crossings(seen[which], corners[owner[slot]])
    return np.bincount(which[hits], minlength=len(points)) % 2 == 1


def _covered_bins(first, last, width):
    """(owner, key) per (triangle, bin its box covers), bins numbered row by row."""
    columns, rows = last[:, 0] - first[:, 0] + 1, last[:, 1] - first[:, 1] + 1
    counts = columns * rows
    owner = np.repeat(np.arange(len(first)), counts)
    local = np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)
    x = first[owner, 0] + local % columns[owner]
    y = first[owner, 1] + local // columns[owner]
    return owner, y * width + x


def _crossings(points, corners):
    """(K,) bool: whether the ray from each point (in the ray's frame) crosses its triangle (K, 3, 3) ahead of it."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    p = points

    def side(u, v):
        return (u[:, 0] - p[:, 0]) * (v[:, 1] - p[:, 1]) - (u[:, 1] - p[:, 1]) * (v[:, 0] - p[:, 0])

    s1, s2, s3 = side(a, b), side(b, c), side(c, a)
    total = s1 + s2 + s3  # twice the triangle's signed area across the ray
    within = ((s1 > 0) & (s2 > 0) & (s3 > 0)) | ((s1 < 0) & (s2 < 0) & (s3 < 0))
    safe = np.where(total == 0, 1.0, total)
    height = (s2 * a[:, 2] + s3 * b[:, 2] + s1 * c[:, 2]) / safe
    return within & (height > p[:, 2])
