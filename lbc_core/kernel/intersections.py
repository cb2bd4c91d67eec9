"""Which triangles of a surface cross or touch other than along a shared edge or corner, exactly up to a length
treated as zero: a broad phase of overlapping bounding boxes, then the exact tests (edges through triangles,
coplanar overlaps, the neighbours that fold onto each other); and 2D segments that touch. The cage's
self-intersection check and the cage generator's final check use them.
"""

import numpy as np

from .geometry import cross2, in_triangle_2d, triangle_normals, unit

# Two triangles meeting at a vertex count as coplanar within this share of the largest coordinate (Blender's float32
# rounding, generously) if also within NEARLY_FLAT radians of each other's plane (bench/RESULTS.md, "A rotated
# subdivided cube is no self-intersection").
FLOAT32_ROUNDING = 1e-6
NEARLY_FLAT = 1e-3


def intersecting_triangles(vertices, triangles, zero):
    """Pairs of triangles that meet anywhere besides the edge or vertex they share.

    Parameters
    ----------
    vertices : (n, 3) float array
    triangles : (T, 3) int array
        Welded, no zero-area or duplicated triangles.
    zero : float
        Length that counts as zero: touching within it counts as intersecting.

    Returns
    -------
    (P, 2) int array of triangle indices, i < j
    """
    corners = vertices[triangles]
    pairs = overlapping_boxes(corners.min(axis=1) - zero, corners.max(axis=1) + zero)
    return pairs[triangles_meet(vertices, triangles[pairs[:, 0]], triangles[pairs[:, 1]], zero)]


def triangles_meet(vertices, first, second, zero):
    """(P,) bool: whether triangles ``first[p]`` and ``second[p]`` (P, 3) meet anywhere besides the edge or vertex
    they share (touching within ``zero`` counts); the pairs test of :func:`intersecting_triangles`."""
    equal = first[:, :, None] == second[:, None, :]  # (P, 3, 3): corner k of the first is corner l of the second
    shared = np.count_nonzero(equal, axis=(1, 2))
    hit = np.zeros(len(first), dtype=bool)
    for count, test in ((0, _disjoint_meet), (1, _vertex_neighbours_meet), (2, _edge_neighbours_fold)):
        chosen = shared == count
        if np.any(chosen):
            hit[chosen] = test(vertices, first[chosen], second[chosen], equal[chosen], zero)
    return hit


def overlapping_boxes(low, high, chunk=2_000_000):
    """Index pairs (i < j) of axis-aligned boxes that overlap, touching included: sort and sweep on the longest axis.

    Parameters
    ----------
    low, high : (B, d) float arrays
        Box corners.
    chunk : int
        Candidate pairs generated at a time, to bound memory.

    Returns
    -------
    (P, 2) int array
    """
    axis = int(np.argmax(high.max(axis=0) - low.min(axis=0)))
    across = np.delete(np.arange(low.shape[1]), axis)
    order = np.argsort(low[:, axis], kind="stable")
    low, high = low[order], high[order]
    # Boxes after s in sweep order start before s ends, so they overlap s along the sweep axis.
    counts = np.searchsorted(low[:, axis], high[:, axis], side="right") - np.arange(len(low)) - 1
    cumulative = np.cumsum(counts)
    found = []
    start = 0
    while start < len(low):
        done = cumulative[start - 1] if start else 0
        stop = max(int(np.searchsorted(cumulative, done + chunk, side="right")), start + 1)
        own = counts[start:stop]
        i = np.repeat(np.arange(start, stop), own)
        j = i + 1 + np.arange(len(i)) - np.repeat(np.cumsum(own) - own, own)
        keep = np.all((low[j][:, across] <= high[i][:, across]) & (low[i][:, across] <= high[j][:, across]), axis=1)
        found.append(np.stack([order[i[keep]], order[j[keep]]], axis=1))
        start = stop
    pairs = np.concatenate(found) if found else np.empty((0, 2), dtype=np.int64)
    return np.sort(pairs, axis=1)


def _disjoint_meet(vertices, first, second, equal, zero):
    """(P,) bool: triangles with no shared vertex that cross or touch."""
    a, b = vertices[first], vertices[second]  # (P, 3, 3)
    normal_a, normal_b = unit(triangle_normals(a)), unit(triangle_normals(b))
    height_a = _zeroed(np.einsum("pkj,pj->pk", a - b[:, :1], normal_b), zero)  # a's corners over b's plane
    height_b = _zeroed(np.einsum("pkj,pj->pk", b - a[:, :1], normal_a), zero)
    apart = np.zeros(len(a), dtype=bool)
    for height in (height_a, height_b):
        apart |= np.all(height > 0, axis=1) | np.all(height < 0, axis=1)
    coplanar = ~apart & (np.all(height_a == 0, axis=1) | np.all(height_b == 0, axis=1))
    crossing = ~apart & ~coplanar
    hit = np.zeros(len(a), dtype=bool)
    hit[coplanar] = _coplanar_overlap(a[coplanar], b[coplanar], normal_b[coplanar], zero)
    # Not coplanar: the two meet in a segment whose ends lie on an edge of one of them, inside the other.
    hit[crossing] = _edges_meet_triangle(
        a[crossing], height_a[crossing], b[crossing], normal_b[crossing], zero
    ) | _edges_meet_triangle(b[crossing], height_b[crossing], a[crossing], normal_a[crossing], zero)
    return hit


def _edges_meet_triangle(a, height, b, normal, zero):
    """(P,) bool: an edge of triangle ``a`` meets triangle ``b`` (boundary included).

    Parameters
    ----------
    a, b : (P, 3, 3) float arrays
    height : (P, 3) float array
        Signed distances of a's corners from b's plane, zeroed within ``zero``; not all zero.
    normal : (P, 3) float array
        b's unit normal.
    """
    hit = np.zeros(len(a), dtype=bool)
    for k in range(3):
        p, q = a[:, k], a[:, (k + 1) % 3]
        hp, hq = height[:, k], height[:, (k + 1) % 3]
        # An edge lying in the plane has its ends tested by the edges joining them to the corner off the plane.
        meets_plane = (hp * hq <= 0) & ~((hp == 0) & (hq == 0))
        t = np.divide(hp, hp - hq, out=np.zeros_like(hp), where=meets_plane)
        hit |= meets_plane & _in_triangle_3d(p + t[:, None] * (q - p), b, normal, zero)
    return hit


def _in_triangle_3d(x, b, normal, zero):
    """(P,) bool: points x (P, 3), on the plane of triangles b (P, 3, 3), lie in them or within ``zero`` of them."""
    inside = np.ones(len(x), dtype=bool)
    for k in range(3):
        edge = b[:, (k + 1) % 3] - b[:, k]
        side = np.einsum("pj,pj->p", np.cross(edge, x - b[:, k]), normal) / np.linalg.norm(edge, axis=1)
        inside &= side >= -zero
    return inside


def _coplanar_overlap(a, b, normal, zero):
    """(P,) bool: coplanar triangles a, b (P, 3, 3) without a shared vertex that overlap or touch."""
    axis_u = unit(b[:, 1] - b[:, 0])
    axis_v = np.cross(normal, axis_u)

    def flatten(points):
        relative = points - b[:, :1]
        return np.stack([np.einsum("pkj,pj->pk", relative, axis_u), np.einsum("pkj,pj->pk", relative, axis_v)], axis=2)

    a, b = flatten(a), flatten(b)
    hit = np.zeros(len(a), dtype=bool)
    for k in range(3):
        for m in range(3):
            hit |= segments_touch(a[:, k], a[:, (k + 1) % 3], b[:, m], b[:, (m + 1) % 3], zero)
    # Boundaries apart: they overlap only if one contains the other.
    hit |= in_triangle_2d(a[:, 0], *_ccw(b).transpose(1, 0, 2), zero)
    hit |= in_triangle_2d(b[:, 0], *_ccw(a).transpose(1, 0, 2), zero)
    return hit


def _vertex_neighbours_meet(vertices, first, second, equal, zero):
    """(P,) bool: triangles sharing exactly one vertex that meet anywhere else."""
    # Rotate both so that the shared vertex is corner 0: (v, a, b) and (v, c, d).
    first = _rotate_rows(first, np.argmax(np.any(equal, axis=2), axis=1))
    second = _rotate_rows(second, np.argmax(np.any(equal, axis=1), axis=1))
    v = vertices[first[:, 0]]
    a, b = vertices[first[:, 1]] - v, vertices[first[:, 2]] - v
    c, d = vertices[second[:, 1]] - v, vertices[second[:, 2]] - v
    normal_1, normal_2 = unit(np.cross(a, b)), unit(np.cross(c, d))
    ha, hb = (_zeroed(np.einsum("pj,pj->p", x, normal_2), zero) for x in (a, b))
    hc, hd = (_zeroed(np.einsum("pj,pj->p", x, normal_1), zero) for x in (c, d))
    rounding = FLOAT32_ROUNDING * float(np.abs(vertices).max(initial=0.0))

    def flat(height, corner):
        return np.abs(height) <= np.maximum(zero, np.minimum(rounding, NEARLY_FLAT * np.linalg.norm(corner, axis=1)))

    coplanar = (flat(ha, a) & flat(hb, b)) | (flat(hc, c) & flat(hd, d))
    # Not coplanar: each triangle meets the other's plane in a segment from v (or only in v); both segments lie on the
    # planes' common line, and the triangles meet beyond v when the segments leave v in the same direction.
    reach_1 = _segment_on_plane(a, b, ha, hb)
    reach_2 = _segment_on_plane(c, d, hc, hd)
    length_1, length_2 = np.linalg.norm(reach_1, axis=1), np.linalg.norm(reach_2, axis=1)
    same_way = np.einsum("pj,pj->p", reach_1, reach_2) > 0
    hit = ~coplanar & (ha * hb <= 0) & (hc * hd <= 0) & same_way & (np.minimum(length_1, length_2) > zero)
    # Coplanar: they overlap exactly when their angular wedges at v do.
    wedges = np.flatnonzero(coplanar)
    if len(wedges):
        hit[wedges] = _wedges_overlap(a[wedges], b[wedges], c[wedges], d[wedges], normal_1[wedges])
    return hit


def _segment_on_plane(a, b, ha, hb):
    """(P, 3): the point of segment a-b on the plane where the heights ha, hb change sign (a where both are 0)."""
    t = np.divide(ha, ha - hb, out=np.zeros_like(ha), where=ha != hb)
    return a + t[:, None] * (b - a)


def _wedges_overlap(a, b, c, d, normal, tolerance=1e-9):
    """(P,) bool: the wedges a-v-b and c-v-d (directions from v, in the plane of ``normal``) overlap."""
    axis_u = unit(a)
    axis_v = np.cross(normal, axis_u)
    def flatten(x):  # unit directions in the plane's (u, v) frame
        return unit(np.stack([np.einsum("pj,pj->p", x, axis_u), np.einsum("pj,pj->p", x, axis_v)], axis=1))

    a, b, c, d = (flatten(x) for x in (a, b, c, d))
    # Order each wedge counter-clockwise; wedges of triangles are narrower than a half-turn.
    swap = cross2(a, b) < 0
    a, b = np.where(swap[:, None], b, a), np.where(swap[:, None], a, b)
    swap = cross2(c, d) < 0
    c, d = np.where(swap[:, None], d, c), np.where(swap[:, None], c, d)

    def strictly_inside(x, start, end):
        return (cross2(start, x) > tolerance) & (cross2(x, end) > tolerance)

    def same(x, y):
        return (np.abs(cross2(x, y)) <= tolerance) & (np.einsum("pj,pj->p", x, y) > 0)

    return (
        strictly_inside(c, a, b) | strictly_inside(d, a, b) | strictly_inside(a, c, d) | strictly_inside(b, c, d)
        | (same(a, c) & same(b, d))
    )


def _edge_neighbours_fold(vertices, first, second, equal, zero):
    """(P,) bool: triangles sharing an edge that fold flat onto each other (same plane, same side of the edge)."""
    # Rotate both so that the corner off the shared edge is corner 0: (a, u, v) and (b, ., .).
    first = _rotate_rows(first, np.argmin(np.any(equal, axis=2), axis=1))
    second = _rotate_rows(second, np.argmin(np.any(equal, axis=1), axis=1))
    u, v = vertices[first[:, 1]], vertices[first[:, 2]]
    a, b = vertices[first[:, 0]] - u, vertices[second[:, 0]] - u
    edge = unit(v - u)
    a_across = a - np.einsum("pj,pj->p", a, edge)[:, None] * edge
    b_across = b - np.einsum("pj,pj->p", b, edge)[:, None] * edge
    # The out-of-plane offset of one far corner from the other's plane.
    offset = np.linalg.norm(np.cross(unit(a_across), b_across), axis=1)
    return (offset <= zero) & (np.einsum("pj,pj->p", a_across, b_across) > 0)


def segments_touch(p1, q1, p2, q2, zero):
    """(P,) bool: 2D segments p1-q1 and p2-q2 (P, 2) cross or come within ``zero`` of each other's ends."""

    def side(p, q, r):  # signed distance of r from the line p-q
        return _zeroed(cross2(q - p, r - p) / np.linalg.norm(q - p, axis=1), zero)

    def within(p, q, r):  # r's projection falls on the segment p-q
        along = q - p
        length = np.linalg.norm(along, axis=1)
        t = np.einsum("pj,pj->p", r - p, along) / length
        return (t >= -zero) & (t <= length + zero)

    d1, d2, d3, d4 = side(p1, q1, p2), side(p1, q1, q2), side(p2, q2, p1), side(p2, q2, q1)
    proper = (d1 * d2 < 0) & (d3 * d4 < 0)
    touching = (
        ((d1 == 0) & within(p1, q1, p2)) | ((d2 == 0) & within(p1, q1, q2))
        | ((d3 == 0) & within(p2, q2, p1)) | ((d4 == 0) & within(p2, q2, q1))
    )
    return proper | touching


def _ccw(triangles):
    """(P, 3, 2): 2D triangles reordered counter-clockwise."""
    clockwise = cross2(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]) < 0
    return np.where(clockwise[:, None, None], triangles[:, ::-1], triangles)


def _rotate_rows(triangles, start):
    """(T, 3): each row rotated to begin at its column ``start``."""
    return np.take_along_axis(triangles, (start[:, None] + np.arange(3)) % 3, axis=1)


def _zeroed(values, zero):
    return np.where(np.abs(values) <= zero, 0.0, values)
