"""The progressive hull (Sander, Gu, Gortler, Hoppe, Snyder 2000): edge collapses that bring a closed triangle surface
down to a vertex count, each enclosing the surface before it, so the last encloses the first.

Each collapse of an edge (a, b) puts the new vertex on the outer side of the planes of every triangle around a or b,
at the point of that polytope adding the least volume (a 3-variable linear program, solved by enumerating the
polytope's vertices among the triples of planes, and a few points pushed out from the edge). The cheapest collapse
goes first (its added volume plus a share of its length cubed, so that flat regions are not left with slivers). A
collapse is refused when the edge's ends share other neighbours than its two opposite corners (the link condition),
when it would leave a vertex with fewer than three neighbours, turn a triangle over or make it a sliver, or when a
new triangle would meet the rest of the surface. Costs are brought up to date when an edge comes to the top of the
queue (lazy updates), so the work per collapse stays small.
"""

import heapq
from itertools import combinations

import numpy as np

from ..geometry import triangles_meet, winding_numbers

# The share of an edge's length cubed added to its collapse's volume, so that among free collapses (flat regions)
# the shorter edges go first (bench/RESULTS.md, "Cage generator").
LENGTH_WEIGHT = 0.02
# A new triangle's normal must stay within this cosine of the one it replaces (no fold, no flip).
MIN_NORMAL_COSINE = 0.2
# Smallest sine of a new triangle's angles: sharper ones are slivers that the binding's mesher meets badly.
MIN_ANGLE_SINE = 0.05
_TRIPLES = {}


def cross(u, v):
    """Cross products of (..., 3) arrays (numpy's ``cross`` costs more than the product on small arrays)."""
    return np.stack([u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1], u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
                     u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]], axis=-1)


def _triples(count):
    """(M, 3) int array: every triple of range(count), cached per count."""
    if count not in _TRIPLES:
        _TRIPLES[count] = np.array(list(combinations(range(count), 3)), dtype=np.int64).reshape(-1, 3)
    return _TRIPLES[count]


class ProgressiveHull:
    """A closed, outward triangle surface under enclosing edge collapses.

    Parameters
    ----------
    vertices : (n, 3) float array
    triangles : (T, 3) int array
        Closed, manifold, outward, not self-intersecting.
    zero : float
        Length that counts as zero in the intersection tests.
    witnesses : (m, 3) float array or None
        Points inside the surface that every collapse must keep inside (the mesh's vertices): the planes alone do
        not keep them in where the triangles around an edge fold, seen from the new vertex.
    """

    def __init__(self, vertices, triangles, zero, witnesses=None):
        self.points = np.array(vertices, dtype=float)
        self.faces = np.array(triangles, dtype=np.int64)
        self.alive_faces = np.ones(len(self.faces), dtype=bool)
        self.alive_vertices = np.ones(len(self.points), dtype=bool)
        self.vertex_faces = [set() for _ in range(len(self.points))]
        for face, corners in enumerate(self.faces.tolist()):
            for corner in corners:
                self.vertex_faces[corner].add(face)
        self.stamp = np.zeros(len(self.points), dtype=np.int64)
        self.zero = float(zero)
        self.witnesses = None if witnesses is None else np.asarray(witnesses, dtype=float)
        self.low = np.empty((len(self.faces), 3))
        self.high = np.empty((len(self.faces), 3))
        self.normals = np.empty((len(self.faces), 3))
        self._update_faces(np.arange(len(self.faces)))
        self.queue = []
        self.vertex_count = len(self.points)
        self.collapses = 0
        self.pushes = 0

    # ------------------------------------------------------------------------------------------------ the surface

    def _update_faces(self, faces):
        corners = self.points[self.faces[faces]]
        self.low[faces] = corners.min(axis=1)
        self.high[faces] = corners.max(axis=1)
        normal = cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        self.normals[faces] = normal / np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]

    def neighbours(self, vertex):
        """The set of vertices sharing a triangle with ``vertex``."""
        found = set(self.faces[list(self.vertex_faces[vertex])].ravel().tolist())
        found.discard(vertex)
        return found

    def edges_of(self, vertex):
        return [(min(vertex, other), max(vertex, other)) for other in sorted(self.neighbours(vertex))]

    def result(self):
        """(vertices, triangles) of the surface now, renumbered."""
        used = np.flatnonzero(self.alive_vertices)
        renumber = np.full(len(self.points), -1, dtype=np.int64)
        renumber[used] = np.arange(len(used))
        return self.points[used].copy(), renumber[self.faces[self.alive_faces]]

    # ------------------------------------------------------------------------------------------------ one collapse

    def plan(self, a, b):
        """(cost, position) of collapsing edge (a, b) into one vertex, or None when it cannot be collapsed."""
        around_a, around_b = self.vertex_faces[a], self.vertex_faces[b]
        shared = around_a & around_b
        if len(shared) != 2:
            return None
        near_a, near_b = self.neighbours(a), self.neighbours(b)
        opposite = set(self.faces[list(shared)].ravel().tolist()) - {a, b}
        if near_a & near_b != opposite or len(near_a | near_b) - 2 < 3:
            return None
        if any(len(self.vertex_faces[corner]) <= 3 for corner in opposite):
            return None
        ring = np.array(sorted(around_a | around_b), dtype=np.int64)
        kept = np.array(sorted((around_a | around_b) - shared), dtype=np.int64)
        middle = 0.5 * (self.points[a] + self.points[b])
        position = self._best_position(a, b, ring, kept, middle)
        if position is None:
            return None
        new_corners = self._moved_corners(a, b, kept, position)
        if not self._shapes_fine(new_corners, kept):
            return None
        added = self._volume(new_corners - middle) - self._volume(self.points[self.faces[ring]] - middle)
        length = np.linalg.norm(self.points[a] - self.points[b])
        return max(added, 0.0) + LENGTH_WEIGHT * length ** 3, position

    def _moved_corners(self, a, b, kept, position):
        corners = self.points[self.faces[kept]]
        moved = (self.faces[kept] == a) | (self.faces[kept] == b)
        corners[moved] = position
        return corners

    @staticmethod
    def _volume(corners):
        return float(np.einsum("ij,ij->", corners[:, 0], cross(corners[:, 1], corners[:, 2]))) / 6.0

    def _shapes_fine(self, corners, kept):
        normal = cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        area2 = np.linalg.norm(normal, axis=1)
        if np.any(area2 <= 1e-300):
            return False
        if np.any(np.einsum("ij,ij->i", normal, self.normals[kept]) < MIN_NORMAL_COSINE * area2):
            return False
        lengths = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
        # sin of the smallest angle = 2·area / (the two longest sides' product)
        ordered = np.sort(lengths, axis=1)
        return bool(np.all(area2 >= MIN_ANGLE_SINE * ordered[:, 1] * ordered[:, 2]))

    def _best_position(self, a, b, ring, kept, middle):
        """The point outside every plane of ``ring`` adding the least volume to the triangles ``kept`` once a and b
        move there, relative positions taken from ``middle``; None when no candidate is feasible."""
        normals = self.normals[ring]
        offsets = np.einsum("ij,ij->i", normals, self.points[self.faces[ring, 0]] - middle)
        corners = self.points[self.faces[kept]] - middle
        moved = (self.faces[kept] == a) | (self.faces[kept] == b)
        # The kept triangles rotated so that the moved corner is first: (v, p, q) has volume v·(p × q) / 6.
        first = np.argmax(moved, axis=1)
        rows = np.arange(len(kept))
        p, q = corners[rows, (first + 1) % 3], corners[rows, (first + 2) % 3]
        gradient = cross(p, q).sum(axis=0)
        candidates = [self._polytope_vertices(normals, offsets), self._pushed_out(normals, offsets, gradient,
                                                                                   self.points[[a, b]] - middle)]
        candidates = np.concatenate([c for c in candidates if len(c)]) if any(len(c) for c in candidates) else []
        if not len(candidates):
            return None
        scale = float(np.linalg.norm(self.points[a] - self.points[b]))
        cost = candidates @ gradient
        best = cost.min()
        near_best = cost <= best + 1e-9 * abs(gradient).sum() * scale + 1e-300
        chosen = candidates[near_best]
        position = chosen[np.argmin(np.einsum("ij,ij->i", chosen, chosen))]
        if np.linalg.norm(position) > 4.0 * scale:  # a far-off corner of a thin polytope: no good collapse
            return None
        return middle + position

    @staticmethod
    def _polytope_vertices(normals, offsets):
        """The feasible points where three of the planes meet (Cramer's rule on every triple)."""
        triples = _triples(len(normals))
        n1, n2, n3 = normals[triples[:, 0]], normals[triples[:, 1]], normals[triples[:, 2]]
        c23, c31, c12 = cross(n2, n3), cross(n3, n1), cross(n1, n2)
        determinant = np.einsum("ij,ij->i", n1, c23)
        solvable = np.abs(determinant) > 1e-6
        if not np.any(solvable):
            return np.empty((0, 3))
        c = offsets[triples[solvable]]
        solutions = (c[:, :1] * c23[solvable] + c[:, 1:2] * c31[solvable] + c[:, 2:] * c12[solvable]) / \
            determinant[solvable, None]
        slack = solutions @ normals.T - offsets
        return solutions[np.all(slack >= -1e-12 * (1.0 + np.abs(offsets).max()), axis=1)]

    @staticmethod
    def _pushed_out(normals, offsets, gradient, ends):
        """Candidates along the gradient's direction from the edge's ends and middle, each the least distance out
        that clears every plane."""
        norm = np.linalg.norm(gradient)
        if norm == 0.0:
            return np.empty((0, 3))
        direction = gradient / norm
        starts = np.vstack([ends, [[0.0, 0.0, 0.0]]])
        rate = normals @ direction
        deficit = offsets[None, :] - starts @ normals.T  # how far each start is below each plane
        needed = np.where(rate[None, :] > 1e-9, deficit / np.maximum(rate[None, :], 1e-9), np.where(deficit > 0, np.inf, 0))
        steps = np.maximum(needed.max(axis=1), 0.0) * (1.0 + 1e-9)
        found = starts + steps[:, None] * direction
        return found[np.isfinite(steps)]

    def meets_rest(self, a, b, position):
        """Whether the triangles around a and b, moved to ``position``, would meet any other triangle or each other,
        or leave a witness point outside."""
        around = self.vertex_faces[a] | self.vertex_faces[b]
        ring = np.array(sorted(around), dtype=np.int64)
        kept = np.array(sorted(around - (self.vertex_faces[a] & self.vertex_faces[b])), dtype=np.int64)
        new = self.faces[kept].copy()
        new[new == b] = a
        saved = self.points[a].copy()
        self.points[a] = position
        try:
            corners = self.points[new]
            low, high = corners.min(axis=(0, 1)) - self.zero, corners.max(axis=(0, 1)) + self.zero
            near = self.alive_faces & np.all(self.low <= high, axis=1) & np.all(self.high >= low, axis=1)
            near[ring] = False
            others = np.vstack([self.faces[near], new])
            other_corners = self.points[others]
            # Pairs whose boxes overlap: each new triangle against the others and the later new ones.
            i, j = np.nonzero(np.all(corners.min(axis=1)[:, None] - self.zero <= other_corners.max(axis=1)[None], axis=2)
                              & np.all(corners.max(axis=1)[:, None] + self.zero >= other_corners.min(axis=1)[None], axis=2))
            keep = j < len(others) - len(new) + i  # a new triangle is tested against the new ones after it only
            keep &= j != len(others) - len(new) + i
            keep = (j < len(others) - len(new)) | (j > len(others) - len(new) + i)
            if np.any(triangles_meet(self.points, new[i[keep]], others[j[keep]], self.zero)):
                return True
        finally:
            self.points[a] = saved
        return self._leaves_witness(ring, new, position, a)

    def _leaves_witness(self, ring, new, position, a):
        """Whether a witness point inside the old triangles lies outside the new ones: its winding number about the
        shell between them (the old triangles and the new ones turned inward) is 1."""
        if self.witnesses is None:
            return False
        old_corners = self.points[self.faces[ring]]
        new_corners = self.points[new]
        new_corners[new == a] = position
        corners = np.concatenate([old_corners, new_corners[:, ::-1]])
        low, high = corners.min(axis=(0, 1)), corners.max(axis=(0, 1))
        near = np.all((self.witnesses >= low) & (self.witnesses <= high), axis=1)
        if not np.any(near):
            return False
        shell = corners.reshape(-1, 3)
        winding = winding_numbers(shell, np.arange(len(shell)).reshape(-1, 3), self.witnesses[near])
        return bool(np.any(winding > 0.5))

    def collapse(self, a, b, position):
        """Collapse edge (a, b) into vertex a at ``position``."""
        shared = self.vertex_faces[a] & self.vertex_faces[b]
        for face in shared:
            self.alive_faces[face] = False
            for corner in self.faces[face].tolist():
                self.vertex_faces[corner].discard(face)
            self.low[face], self.high[face] = np.inf, -np.inf
        for face in self.vertex_faces[b]:
            self.faces[face][self.faces[face] == b] = a
        self.vertex_faces[a] |= self.vertex_faces[b]
        self.vertex_faces[b] = set()
        self.alive_vertices[b] = False
        self.points[a] = position
        self._update_faces(np.array(sorted(self.vertex_faces[a]), dtype=np.int64))
        self.vertex_count -= 1
        self.collapses += 1
        changed = [a] + sorted(self.neighbours(a))
        self.stamp[changed] += 1
        return changed

    # ------------------------------------------------------------------------------------------------ the queue

    def push(self, a, b):
        planned = self.plan(a, b)
        if planned is not None:
            cost, position = planned
            self.pushes += 1
            heapq.heappush(self.queue, (cost, a, b, self.pushes, int(self.stamp[a]), int(self.stamp[b]), position))

    def simplify(self, target, check=None):
        """Collapse the cheapest edges until ``target`` vertices are left or no edge can go; returns the count. Edges
        refused once are planned again in a new pass over every edge, while a pass still collapses some."""
        while self.vertex_count > target:
            before = self.collapses
            self.queue = []
            for a, b in sorted({edge for v in np.flatnonzero(self.alive_vertices) for edge in self.edges_of(v)}):
                self.push(a, b)
            self._run_queue(target, check)
            if self.collapses == before:
                break
        return self.vertex_count

    def _run_queue(self, target, check):
        while self.vertex_count > target and self.queue:
            if check is not None:
                check()
            cost, a, b, _, stamp_a, stamp_b, position = heapq.heappop(self.queue)
            if not (self.alive_vertices[a] and self.alive_vertices[b]):
                continue
            if stamp_a != self.stamp[a] or stamp_b != self.stamp[b]:
                if b in self.neighbours(a):
                    self.push(a, b)
                continue
            if self.meets_rest(a, b, position):
                continue
            self.collapse(a, b, position)
            for edge in self.edges_of(a):
                self.push(*edge)
