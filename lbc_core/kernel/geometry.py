"""The geometry kernel: predicates, closest points, winding numbers, simplex measures and shape quality, points on
cage facets (triangles that cross or touch: :mod:`.intersections`).

One implementation of each, used by the cage checks (cage/), the domain meshers (meshing/), point location
(evaluate/interpolation.py), the boundary values and the warm re-bind. Every function works on numpy arrays, vectorised
over the leading axis; lengths are in the caller's units.
"""

import numpy as np
from scipy.spatial import ConvexHull, QhullError


def row_keys(rows, base):
    """One number per row of a non-negative int array (..., k) whose entries are below ``base``: the row read as a
    base-``base`` number, so equal rows get equal numbers (exact below 2^63). Returns a (...) int64 array."""
    key = rows[..., 0].astype(np.int64)
    for k in range(1, rows.shape[-1]):
        key = key * base + rows[..., k]
    return key


def cross2(u, v):
    """z component of the cross product of 2D vectors (..., 2): twice the signed area they span."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def unit(vectors):
    """Vectors (..., d) scaled to length 1."""
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def is_convex_polygon(points, slack=1e-12):
    """Whether a 2D polygon (k, 2) turns the same way at every vertex, either way round; collinear vertices (turns
    within ``slack`` × its size squared of 0) are allowed."""
    turns = cross2(points - np.roll(points, 1, axis=0), np.roll(points, -1, axis=0) - points)
    tolerance = slack * np.ptp(points, axis=0).max() ** 2
    return bool(np.all(turns >= -tolerance) or np.all(turns <= tolerance))


def newell_normal(points):
    """(3,) float array: the Newell normal of a polygon (k, 3) in order, twice its vector area (outward for a
    counter-clockwise polygon seen from outside); exact for planar polygons, a least-squares normal for others."""
    return np.sum(np.cross(points, np.roll(points, -1, axis=0)), axis=0)


def plane_axes(normal):
    """(2, 3) float array: unit vectors u, v spanning the plane of a unit ``normal`` (3,), with (u, v, normal)
    right-handed, so that a polygon counter-clockwise about the normal is counter-clockwise in (u, v)."""
    u = unit(np.cross(normal, np.eye(3)[np.argmin(np.abs(normal))]))
    return np.stack([u, np.cross(normal, u)])


def triangle_normals(corners):
    """(..., 3): area-weighted (twice the area) normals of 3D triangles given by their corners (..., 3, 3)."""
    return np.cross(corners[..., 1, :] - corners[..., 0, :], corners[..., 2, :] - corners[..., 0, :])


def in_triangle_2d(x, a, b, c, zero):
    """Points x inside counter-clockwise 2D triangles a, b, c or within ``zero`` of them (broadcasting, last axis 2).

    Returns
    -------
    bool array, the broadcast shape without the last axis
    """
    inside = True
    for p, q in ((a, b), (b, c), (c, a)):
        inside = inside & (cross2(q - p, x - p) >= -zero * np.linalg.norm(q - p, axis=-1))
    return inside


def closest_on_segments(points, a, b):
    """Closest point on segments ab (each point its own segment).

    Parameters
    ----------
    points, a, b : (n, d) float arrays

    Returns
    -------
    squared : (n,) float array, squared distance (length^2 units)
    bary : (n, 2) float array, barycentric coordinates of the closest point (for a, b)
    """
    ab, ap = b - a, points - a
    length2 = np.einsum("ij,ij->i", ab, ab)
    # A zero-length segment is its point a; the clip keeps rounding from leaving the segment.
    t = np.clip(np.einsum("ij,ij->i", ap, ab) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    offset = ap - t[:, None] * ab
    return np.einsum("ij,ij->i", offset, offset), np.stack([1.0 - t, t], axis=1)


def closest_on_triangles(points, a, b, c):
    """Closest point on 3D triangles abc (each point its own triangle).

    The closest point is the projection onto the triangle's plane when that falls inside, else the closest point of
    one of the three edges: taking the least of these four candidates also handles degenerate (flat) triangles,
    whose projection is simply skipped.

    Parameters
    ----------
    points, a, b, c : (n, 3) float arrays

    Returns
    -------
    squared : (n,) float array, squared distance (length^2 units)
    bary : (n, 3) float array, barycentric coordinates of the closest point (for a, b, c)
    """
    ab, ac, ap = b - a, c - a, points - a
    # Barycentrics and height from triple products with the normal, not from the Gram matrix of ab and ac: for a
    # skinny triangle (width 1e-4 of its length) the Gram route loses eight digits, these lose four.
    normal = np.cross(ab, ac)
    nn = np.einsum("ij,ij->i", normal, normal)
    proper = nn > 1e-24 * np.einsum("ij,ij->i", ab, ab) * np.einsum("ij,ij->i", ac, ac)
    safe = np.where(proper, nn, 1.0)
    v = np.einsum("ij,ij->i", np.cross(ap, ac), normal) / safe
    w = np.einsum("ij,ij->i", np.cross(ab, ap), normal) / safe
    height = np.einsum("ij,ij->i", ap, normal)
    inside = proper & (v >= 0) & (w >= 0) & (v + w <= 1)
    n = len(points)
    candidates_squared = np.empty((4, n))
    candidates_bary = np.zeros((4, n, 3))
    candidates_squared[0] = np.where(inside, height * height / safe, np.inf)
    candidates_bary[0] = np.stack([1.0 - v - w, v, w], axis=1)
    ends = (a, b, c)
    for slot, (i, j) in enumerate([(0, 1), (1, 2), (2, 0)], start=1):
        candidates_squared[slot], edge_bary = closest_on_segments(points, ends[i], ends[j])
        candidates_bary[slot, :, i] = edge_bary[:, 0]
        candidates_bary[slot, :, j] = edge_bary[:, 1]
    best = np.argmin(candidates_squared, axis=0)
    rows = np.arange(n)
    return candidates_squared[best, rows], candidates_bary[best, rows]


def closest_on_facets(points, corners):
    """Closest point of each segment (d = 2) or triangle (d = 3) to the matching point.

    Parameters
    ----------
    points : (n, d) float array
    corners : (n, d, d) float array, each facet's corners

    Returns
    -------
    squared : (n,) float array, squared distance (length^2 units)
    bary : (n, d) float array, barycentric coordinates of the closest point (non-negative, sum 1)
    """
    if points.shape[1] == 2:
        return closest_on_segments(points, corners[:, 0], corners[:, 1])
    return closest_on_triangles(points, corners[:, 0], corners[:, 1], corners[:, 2])


def distance_to_segments(points, starts, ends):
    """Distance from each point to the nearest of all the segments [starts, ends].

    Parameters
    ----------
    points : (P, d) float array
    starts, ends : (S, d) float arrays

    Returns
    -------
    (P,) float array
    """
    best = np.full(len(points), np.inf)
    if len(starts) == 0:
        return best
    for chunk in np.array_split(np.arange(len(points)), max(1, len(points) * len(starts) // 2_000_000)):
        pairs = np.broadcast_to(points[chunk, None, :], (len(chunk), len(starts), points.shape[1])).reshape(
            -1, points.shape[1])
        squared, _ = closest_on_segments(pairs, np.tile(starts, (len(chunk), 1)), np.tile(ends, (len(chunk), 1)))
        best[chunk] = np.sqrt(squared.reshape(len(chunk), len(starts)).min(axis=1))
    return best


def polygon_mean_value_coordinates(polygon, points, tolerance):
    """Mean value coordinates of 2D points with respect to a simple polygon (Hormann & Floater 2006).

    tan(α/2) is taken from whichever of its two equivalent forms does not cancel. Points within ``tolerance`` of an
    edge get the linear interpolant on it, within it of a vertex that vertex's unit row (the continuous limits).

    Parameters
    ----------
    polygon : (k, 2) float array
        The vertices in order around it, either way.
    points : (m, 2) float array
    tolerance : float, a length

    Returns
    -------
    (m, k) float array; rows sum to 1 and reproduce their point
    """
    spokes = polygon[None, :, :] - points[:, None, :]  # (m, k, 2): from each point to each vertex
    lengths = np.linalg.norm(spokes, axis=2)
    following, following_lengths = np.roll(spokes, -1, axis=1), np.roll(lengths, -1, axis=1)
    cross = cross2(spokes, following)  # the angle at the point from vertex j to j + 1
    dot = np.einsum("mkd,mkd->mk", spokes, following)
    product = lengths * following_lengths
    # tan(α/2) = cross / (r r' + dot) = (r r' - dot) / cross; the first cancels when α → π, the second when α → 0.
    with np.errstate(divide="ignore", invalid="ignore"):
        half_tangents = np.where(dot >= 0, cross / (product + dot), (product - dot) / cross)
        weights = (np.roll(half_tangents, 1, axis=1) + half_tangents) / lengths
        weights /= weights.sum(axis=1, keepdims=True)
    edge_lengths = np.linalg.norm(np.roll(polygon, -1, axis=0) - polygon, axis=1)
    on_edge = (np.abs(cross) <= tolerance * edge_lengths) & (dot < 0)
    for row, edge in zip(*np.nonzero(on_edge)):
        a, b = lengths[row, edge], following_lengths[row, edge]
        weights[row] = 0.0
        weights[row, edge], weights[row, (edge + 1) % len(polygon)] = b / (a + b), a / (a + b)
    rows, vertices = np.nonzero(lengths <= tolerance)
    weights[rows] = 0.0
    weights[rows, vertices] = 1.0
    return weights


def winding_numbers(vertices, facets, points, check=None):
    """Generalised winding number of a closed polygon (d = 2) or triangle surface (d = 3) around each point.

    2D: the sum of the signed angles the edges subtend; 3D: of the triangles' solid angles (Van Oosterom and
    Strackee). 1 inside a counter-clockwise polygon or an outward-oriented surface, 0 outside, 1/2 on it.

    Parameters
    ----------
    vertices : (n, d) float array
    facets : (E, d) int array, edges (d = 2) or triangles (d = 3)
    points : (P, d) float array
    check : callable() or None
        Called between chunks of work (a Progress's ``check``), so that a long evaluation can be cancelled.

    Returns
    -------
    (P,) float array
    """
    corners = vertices[facets]
    winding = np.zeros(len(points))
    for chunk in np.array_split(np.arange(len(points)), max(1, len(points) * len(corners) // 1_000_000)):
        if check is not None:
            check()
        relative = [corners[None, :, k] - points[chunk, None] for k in range(facets.shape[1])]
        if vertices.shape[1] == 2:
            a, b = relative
            angle = np.arctan2(cross2(a, b), np.einsum("psd,psd->ps", a, b))
        else:
            a, b, c = relative
            la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
            det = np.einsum("pfd,pfd->pf", a, np.cross(b, c))
            dot = lambda x, y: np.einsum("pfd,pfd->pf", x, y)  # noqa: E731
            angle = np.arctan2(det, la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb)
        winding[chunk] = angle.sum(axis=1) / (2.0 * np.pi)
    return winding


def enclosed_measure(vertices, facets):
    """Signed area (2D) or volume (3D) a closed polygon (edges (E, 2)) or surface (triangles (E, 3)) encloses.

    Summed relative to the vertices' centroid: about the origin, a cage far from it would lose every digit of its
    volume to cancellation (a unit cube at 1e6 has products of 1e18 summing to 1).
    """
    vertices = vertices - vertices.mean(axis=0)
    if vertices.shape[1] == 2:
        p, q = vertices[facets[:, 0]], vertices[facets[:, 1]]
        return float(0.5 * np.sum(cross2(p, q)))
    p, q, r = (vertices[facets[:, k]] for k in range(3))
    return float(np.sum(np.einsum("ij,ij->i", p, np.cross(q, r))) / 6.0)


def hull_share(points, measure):
    """``measure`` (an area or volume the points bound) over that of the points' convex hull: 1 for a convex
    shape; 0 where the hull is flat.

    Examples
    --------
    >>> import numpy as np
    >>> square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 0.9]])
    >>> round(hull_share(square, 0.95), 2)
    0.95
    """
    points = np.asarray(points, dtype=float)
    try:
        hull = ConvexHull(points - points.mean(axis=0)).volume  # an area in 2D
    except QhullError:
        return 0.0
    return float(abs(measure) / hull) if hull > 0 else 0.0


def signed_measures(vertices, cells):
    """Signed area (2D) or volume (3D) of each cell (F, d+1). Returns (F,) float array."""
    edges = vertices[cells[:, 1:]] - vertices[cells[:, :1]]
    if vertices.shape[1] == 3:  # the triple product: a tenth of the time of an LU factorisation per 3 x 3 matrix
        (ax, ay, az), (bx, by, bz), (cx, cy, cz) = edges[:, 0].T, edges[:, 1].T, edges[:, 2].T
        return (ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)) / 6.0
    return np.linalg.det(edges) / 2.0


def orient_positive(vertices, cells):
    """The cells (F, d+1) with two corners swapped where their signed measure is negative."""
    cells = cells.copy()
    flip = signed_measures(vertices, cells) < 0
    cells[flip, :2] = cells[flip, 1::-1]
    return cells


def circumcircles(corners):
    """Centres (T, 2) and radii (T,) of the circles through 2D triangles' corners (T, 3, 2); inf for flat ones."""
    a = corners[:, 0]
    ab, ac = corners[:, 1] - a, corners[:, 2] - a
    d = 2.0 * cross2(ab, ac)
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (ac[:, 1] * np.einsum("ij,ij->i", ab, ab) - ab[:, 1] * np.einsum("ij,ij->i", ac, ac)) / d
        uy = (ab[:, 0] * np.einsum("ij,ij->i", ac, ac) - ac[:, 0] * np.einsum("ij,ij->i", ab, ab)) / d
    offset = np.stack([ux, uy], axis=1)
    radius = np.hypot(ux, uy)
    flat = ~np.isfinite(radius)
    offset[flat], radius[flat] = 0.0, np.inf
    return a + offset, radius


def circumspheres(points, triangles):
    """Centre (in the triangle's plane) and radius of the smallest sphere through each 3D triangle's corners.

    Parameters
    ----------
    points : (P, 3) float array
    triangles : (T, 3) int array

    Returns
    -------
    centres : (T, 3) float array
    radii : (T,) float array
    """
    a, b, c = (points[triangles[:, k]] for k in range(3))
    ab, ac = b - a, c - a
    normal = np.cross(ab, ac)
    offset = (np.einsum("ij,ij->i", ac, ac)[:, None] * np.cross(normal, ab)
              + np.einsum("ij,ij->i", ab, ab)[:, None] * np.cross(ac, normal))
    offset /= 2.0 * np.einsum("ij,ij->i", normal, normal)[:, None]
    return a + offset, np.linalg.norm(offset, axis=1)


def radius_ratios(vertices, cells):
    """d × inradius / circumradius of each triangle (F, 3) or tetrahedron (F, 4): 1 for a regular one, 0 for a flat
    one. The shape quality the meshers and the warm re-bind compare cells by.

    Returns
    -------
    (F,) float array
    """
    if cells.shape[1] == 4:
        return np.abs(signed_radius_ratios_by_coordinate(vertices.T[:, cells.T]))
    a, b, c = (np.linalg.norm(vertices[cells[:, i]] - vertices[cells[:, j]], axis=1) for i, j in ((1, 2), (2, 0),
                                                                                              (0, 1)))
    # 2 × inradius / circumradius = (b + c - a)(c + a - b)(a + b - c) / (a b c)
    return (b + c - a) * (c + a - b) * (a + b - c) / np.maximum(a * b * c, np.finfo(float).tiny)


def signed_radius_ratios_by_coordinate(coordinates):
    """Radius ratios (see :func:`radius_ratios`) of tetrahedra, negative for the negatively oriented ones, from their
    corners by coordinate: (3, 4, T), coordinate d of corner k of every tetrahedron in one row. Every step works on
    whole rows of T numbers (4 to 8 times faster than on (T, 4, 3) corners, whose rows hold three numbers; one row at
    a time, as arrays of several rows cost more to allocate).

    Returns
    -------
    (T,) float array
    """
    tiny = np.finfo(float).tiny
    # edges[k] = (x, y, z) of the edge from corner 0 to corner k + 1
    edges = [[coordinates[d, k] - coordinates[d, 0] for d in range(3)] for k in (1, 2, 3)]
    # normals[k] = edge k+1 × edge k+2 (cyclically): the normals at corner 0 are twice the area vectors of three
    # faces; their sum is the fourth's.
    normals = []
    for k in range(3):
        (ax, ay, az), (bx, by, bz) = edges[(k + 1) % 3], edges[(k + 2) % 3]
        normals.append((ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx))
    signed = (edges[0][0] * normals[0][0] + edges[0][1] * normals[0][1] + edges[0][2] * normals[0][2]) / 6.0
    volume = np.abs(signed)
    area = 0.0
    fourth, numerator = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
    for (x, y, z), (nx, ny, nz) in zip(edges, normals):
        area = area + np.sqrt(nx * nx + ny * ny + nz * nz)
        length2 = x * x + y * y + z * z
        for d, n in enumerate((nx, ny, nz)):
            fourth[d] = fourth[d] + n
            numerator[d] = numerator[d] + length2 * n
    fx, fy, fz = fourth
    area = 0.5 * (np.sqrt(fx * fx + fy * fy + fz * fz) + area)
    ux, uy, uz = numerator
    circumradius = np.sqrt(ux * ux + uy * uy + uz * uz) / (12.0 * np.maximum(volume, tiny))
    return np.sign(signed) * 9.0 * volume / (area * np.maximum(circumradius, tiny))


def bary_positions(cage, facet, bary):
    """Positions sum_k bary[:, k] * corner_k of points given on cage facets, summed from k = 0 upward.

    Parameters
    ----------
    cage : Cage
        Anything with the cage's ``surface_vertices`` (S, d) and ``facets`` (E, d).
    facet : (P,) int array
    bary : (P, d) float array

    Returns
    -------
    (P, d) float array
    """
    corners = cage.surface_vertices[cage.facets[facet]]  # (P, d, d)
    points = bary[:, 0, None] * corners[:, 0]
    for k in range(1, bary.shape[1]):
        points = points + bary[:, k, None] * corners[:, k]
    # A one-hot bary gives the corner itself, but 1 * (-0.0) + 0 * c would turn -0.0 into +0.0: copy corners.
    at_corner = np.flatnonzero(np.max(bary, axis=1) == 1.0)
    points[at_corner] = corners[at_corner, np.argmax(bary[at_corner], axis=1)]
    return points
