"""Where an edge collapse of the progressive hull puts its new vertex, and what the collapse costs: for many edges at
once, as one set of array operations (a Python loop per edge cost a millisecond each).

The new vertex must lie on the outer side of the plane of every triangle around the edge's two ends; of those points
it takes the one adding the least volume (a linear program in 3 variables, solved by enumerating the polytope's
vertices among the triples of planes, with a few points pushed out from the edge along the volume's gradient for flat
regions, where no three planes meet in a point); ties go to the point nearest the edge's middle. A collapse is refused
(cost infinite) when no point is feasible, when the point is far off (a thin polytope's corner), or when a new
triangle would turn over (against the one it replaces) or be a sliver."""

from dataclasses import dataclass
from itertools import combinations

import numpy as np

# The share of an edge's length cubed added to its collapse's volume, so that among free collapses (flat regions)
# the shorter edges go first (bench/RESULTS.md, "Cage generator").
LENGTH_WEIGHT = 0.02
# A new triangle's normal must stay within this cosine of the one it replaces (bench/RESULTS.md, "Cage generator").
MIN_NORMAL_COSINE = -0.3
# Smallest sine of a new triangle's smallest angle: sharper ones are slivers (bench/RESULTS.md, "Cage generator").
MIN_ANGLE_SINE = 0.01
# The new vertex may lie at most this many edge lengths from the edge's middle.
FARTHEST = 4.0
# Edges planned in one batch: bounds the (edges × triples × planes) arrays.
BATCH = 48
# Ring sizes that bound the groups of edges planned together.
RING_SIZES = (8, 10, 12, 14, 17, 21)
# Fewer edges than this go in one batch: each batch costs about a millisecond of numpy calls.
GROUPED = 24
_TRIPLES = {}


def cross(u, v):
    """Cross products of (..., 3) arrays (numpy's ``cross`` costs more than the product on small arrays)."""
    return np.stack([u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1], u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
                     u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]], axis=-1)


def dot(u, v):
    """Dot products over the last axis of broadcast (..., 3) arrays (einsum costs more on these shapes)."""
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1] + u[..., 2] * v[..., 2]


def _triples(count):
    """(M, 3) int array: every triple of range(count), cached per count."""
    if count not in _TRIPLES:
        _TRIPLES[count] = np.array(list(combinations(range(count), 3)), dtype=np.int64).reshape(-1, 3)
    return _TRIPLES[count]


def _padded(lists):
    """(m, K) int array of the lists, each padded with its first item, and the (m, K) mask of real items."""
    width = max(len(items) for items in lists)
    rows = np.array([items + items[:1] * (width - len(items)) for items in lists], dtype=np.int64)
    mask = np.arange(width)[None, :] < np.array([len(items) for items in lists])[:, None]
    return rows, mask


@dataclass(frozen=True)
class Limits:
    """Halfspaces a new vertex must also keep to, besides the planes of its ring, for each planned edge: up to two
    per edge (a mirror plane's two sides pin a vertex to it; one keeps it on its side).

    normals : (m, 2, 3) float array
    offsets : (m, 2) float array, so that normal · v >= offset
    used : (m, 2) bool array
    """

    normals: np.ndarray
    offsets: np.ndarray
    used: np.ndarray

    @staticmethod
    def none(count):
        return Limits(np.zeros((count, 2, 3)), np.zeros((count, 2)), np.zeros((count, 2), dtype=bool))

    def __getitem__(self, chosen):
        return Limits(self.normals[chosen], self.offsets[chosen], self.used[chosen])


def place(points, faces, normals, ends, rings, kept, limits=None):
    """Plan the collapses of edges ``ends`` (m, 2), in batches.

    Parameters
    ----------
    points : (n, 3) float array
    faces : (T, 3) int array
    normals : (T, 3) float array, the faces' unit normals
    ends : (m, 2) int array
    rings : list of m lists of face indices, the triangles around either end
    kept : list of m lists, those triangles but the two on the edge
    limits : Limits or None
        More halfspaces per edge (a mirror plane).

    Returns
    -------
    cost : (m,) float array, inf where the collapse is refused
    position : (m, 3) float array
    relaxed : (m,) bool array, where no point outside every ring plane was near: the position cuts into them least
        (the move then keeps only the witness points inside, and goes after every other)
    """
    limits = Limits.none(len(ends)) if limits is None else limits
    cost = np.full(len(ends), np.inf)
    position = np.zeros((len(ends), 3))
    relaxed = np.zeros(len(ends), dtype=bool)
    # Edges with rings of like sizes go together: a batch pads every ring to its largest, and the work grows with
    # the cube of that size (the triples of planes).
    sizes = np.array([len(ring) for ring in rings])
    order = np.argsort(sizes, kind="stable")
    groups = np.searchsorted(RING_SIZES, sizes[order], side="left") if len(ends) > GROUPED else np.zeros(len(ends))
    for group in np.unique(groups):
        members = order[groups == group]
        for start in range(0, len(members), BATCH):
            chosen = members[start:start + BATCH]
            cost[chosen], position[chosen], relaxed[chosen] = _place_batch(
                points, faces, normals, ends[chosen], [rings[k] for k in chosen], [kept[k] for k in chosen],
                limits[chosen])
    return cost, position, relaxed


def _place_batch(points, faces, normals, ends, rings, kept, limits):
    a, b = ends[:, 0], ends[:, 1]
    middle = 0.5 * (points[a] + points[b])
    length = np.linalg.norm(points[a] - points[b], axis=1)
    ring, ring_mask = _padded(rings)
    kept, kept_mask = _padded(kept)
    plane_normals = normals[ring]
    offsets = dot(plane_normals, points[faces[ring, 0]] - middle[:, None])
    if limits.used.any():  # a limit not used repeats the ring's first plane: no constraint, no solvable triple
        plane_normals = np.concatenate([plane_normals, np.where(limits.used[..., None], limits.normals,
                                                                plane_normals[:, :1])], axis=1)
        offsets = np.concatenate([offsets, np.where(limits.used, limits.offsets - dot(limits.normals, middle[:, None]),
                                                    offsets[:, :1])], axis=1)
    corners = points[faces[kept]] - middle[:, None, None]  # (m, K, 3, 3)
    moved = (faces[kept] == a[:, None, None]) | (faces[kept] == b[:, None, None])
    first = np.argmax(moved, axis=2)
    p = np.take_along_axis(corners, ((first + 1) % 3)[..., None, None], axis=2)[:, :, 0]
    q = np.take_along_axis(corners, ((first + 2) % 3)[..., None, None], axis=2)[:, :, 0]
    gradient = (cross(p, q) * kept_mask[..., None]).sum(axis=1)  # the new volume is gradient · v / 6
    candidates, feasible, starts = _candidates(plane_normals, offsets, gradient, points[ends] - middle[:, None],
                                               _pins(limits))
    position = _cheapest(candidates, feasible, gradient, length)
    relaxed = ~np.isfinite(position[:, 0])
    position[relaxed] = _least_cutting(starts[relaxed], plane_normals[relaxed], offsets[relaxed], ring.shape[1])
    new = np.where(moved[..., None], position[:, None, None, :], corners)
    fine = np.isfinite(position[:, 0]) & shapes_fine(new, normals[kept], kept_mask)
    old_corners = points[faces[ring]] - middle[:, None, None]
    added = (_volumes(new) * kept_mask).sum(axis=1) - (_volumes(old_corners) * ring_mask).sum(axis=1)
    cost = np.where(fine, np.maximum(added, 0.0) + LENGTH_WEIGHT * length ** 3, np.inf)
    return cost, np.where(fine[:, None], middle + np.nan_to_num(position), 0.0), relaxed


def _least_cutting(starts, plane_normals, offsets, ring_size):
    """(m, 3): for edges whose ring's planes leave no point outside them all (a thin part, its two sheets both in
    the ring) or only far ones: of the edge's ends and middle, the one that cuts least into those planes while
    keeping to the limits (the planes after the ring's); NaN where none keeps to them."""
    slack = starts @ plane_normals.transpose(0, 2, 1) - offsets[:, None, :]  # (m, 3, planes)
    cut = np.maximum(-slack[..., :ring_size], 0.0).max(axis=2)
    tolerance = 1e-12 * (1.0 + np.abs(offsets).max(axis=1))
    within = np.all(slack[..., ring_size:] >= -tolerance[:, None, None], axis=2)
    cut = np.where(within, cut, np.inf)
    best = np.argmin(cut, axis=1)
    chosen = starts[np.arange(len(starts)), best]
    return np.where(np.isfinite(cut[np.arange(len(starts)), best])[:, None], chosen, np.nan)


def _pins(limits):
    """(m, 3): the normal of the plane an edge's new vertex is pinned to (two opposite limits), else zero."""
    pinned = limits.used.all(axis=1) & (dot(limits.normals[:, 0], limits.normals[:, 1]) < -0.5)
    return np.where(pinned[:, None], limits.normals[:, 0], 0.0)


def _volumes(corners):
    return dot(corners[..., 0, :], cross(corners[..., 1, :], corners[..., 2, :])) / 6.0


def _candidates(plane_normals, offsets, gradient, ends, pins):
    """(m, C, 3) candidate points and (m, C) which satisfy every plane: the polytope's vertices, and the edge's ends
    and middle pushed out along the gradient (within the plane a vertex is pinned to, ``pins``)."""
    triples = _triples(plane_normals.shape[1])
    n1, n2, n3 = (plane_normals[:, triples[:, k]] for k in range(3))
    c23, c31, c12 = cross(n2, n3), cross(n3, n1), cross(n1, n2)
    determinant = dot(n1, c23)
    solvable = np.abs(determinant) > 1e-6
    c = offsets[:, triples]
    denominator = np.where(solvable, determinant, 1.0)[..., None]
    corner_points = (c[..., :1] * c23 + c[..., 1:2] * c31 + c[..., 2:] * c12) / denominator
    direction = gradient - dot(gradient, pins)[:, None] * pins
    direction = direction / np.maximum(np.linalg.norm(direction, axis=1), 1e-300)[:, None]
    starts = np.concatenate([ends, np.zeros((len(ends), 1, 3))], axis=1)  # (m, 3, 3)
    # A pinned vertex's starts go onto its plane first (the plane through 0 of the pins' frame, offset by its limit).
    pin_offset = np.where(np.any(pins != 0, axis=1), offsets[:, -2], 0.0)
    starts = starts - (dot(starts, pins[:, None]) - pin_offset[:, None])[..., None] * pins[:, None]
    rate = dot(plane_normals, direction[:, None])  # (m, K)
    transposed = plane_normals.transpose(0, 2, 1)
    deficit = offsets[:, None, :] - starts @ transposed
    climbing = rate[:, None, :] > 1e-9
    needed = np.where(climbing, deficit / np.where(climbing, rate[:, None, :], 1.0), np.where(deficit > 0, np.inf, 0.0))
    steps = np.maximum(needed.max(axis=2), 0.0) * (1.0 + 1e-9)
    pushed = starts + np.where(np.isfinite(steps), steps, 0.0)[..., None] * direction[:, None]
    candidates = np.concatenate([corner_points, pushed], axis=1)
    tolerance = 1e-12 * (1.0 + np.abs(offsets).max(axis=1))
    slack = candidates @ transposed - offsets[:, None, :]
    feasible = np.all(slack >= -tolerance[:, None, None], axis=2)
    feasible &= np.concatenate([solvable, np.isfinite(steps)], axis=1)
    return candidates, feasible, starts


def _cheapest(candidates, feasible, gradient, length):
    """(m, 3): per edge the feasible candidate of least gradient · v, the nearest the middle among near-ties; NaN
    where none is feasible or it lies farther than FARTHEST edge lengths."""
    value = np.where(feasible, dot(candidates, gradient[:, None]), np.inf)
    best = value.min(axis=1)
    tie = 1e-9 * np.abs(gradient).sum(axis=1) * length + 1e-300
    near = feasible & (value <= (best + tie)[:, None])
    distance = np.where(near, dot(candidates, candidates), np.inf)
    chosen = candidates[np.arange(len(candidates)), np.argmin(distance, axis=1)]
    bad = ~np.isfinite(best) | (np.linalg.norm(chosen, axis=1) > FARTHEST * length)
    return np.where(bad[:, None], np.nan, chosen)


def shapes_fine(corners, old_normals, mask):
    """(m,) bool: no new triangle of zero area, turned over against its old normal, or a sliver."""
    normal = cross(corners[..., 1, :] - corners[..., 0, :], corners[..., 2, :] - corners[..., 0, :])
    area2 = np.linalg.norm(normal, axis=-1)
    lengths = np.sort(np.linalg.norm(corners - np.roll(corners, 1, axis=-2), axis=-1), axis=-1)
    good = (area2 > 1e-300) & (dot(normal, old_normals) >= MIN_NORMAL_COSINE * area2)
    good &= area2 >= MIN_ANGLE_SINE * lengths[..., 1] * lengths[..., 2]
    return np.all(good | ~mask, axis=1)
