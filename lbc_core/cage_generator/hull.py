"""The progressive hull (Sander, Gu, Gortler, Hoppe, Snyder 2000): edge collapses that bring a closed triangle surface
down to a vertex count, each enclosing the surface before it, so the last encloses the first.

Each collapse of an edge (a, b) puts the new vertex on the outer side of the planes of every triangle around a or b,
where it adds the least volume (:mod:`lbc_core.cage_generator.placement`); the cheapest collapse goes first. A
collapse is refused when the edge's ends share other neighbours than its two opposite corners (the link condition),
when it would leave a vertex with three neighbours or fewer, when placement refuses it (a fold, a sliver), when a new
triangle would meet the rest of the surface, or when a witness point (a mesh vertex) would end up outside: the planes
alone do not keep everything in where the triangles around the edge fold as seen from the new vertex. Costs are
brought up to date when an edge comes to the top of the queue (lazy updates); a refused edge is planned again when
the triangles around it change.
"""

import heapq

import numpy as np

from ..kernel.geometry import winding_numbers
from ..kernel.intersections import triangles_meet
from .placement import cross, place


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
        self.plans = 0
        self.refused = set()

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

    def ring_if_collapsible(self, a, b):
        """(ring, kept): the triangles around a or b, and those but the two on the edge; None when the collapse
        would break the surface's topology (the link condition, or a vertex left with three neighbours or fewer)."""
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
        return sorted(around_a | around_b), sorted((around_a | around_b) - shared)

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

    def push(self, edges):
        """Plan the collapses of ``edges`` and queue them; remember those refused until their neighbourhood changes."""
        planned, rings, kept = [], [], []
        for a, b in edges:
            found = self.ring_if_collapsible(a, b)
            if found is None:
                self.refused.add((a, b))
            else:
                planned.append((a, b)), rings.append(found[0]), kept.append(found[1])
        if not planned:
            return
        self.plans += len(planned)
        cost, position = place(self.points, self.faces, self.normals, np.array(planned), rings, kept)
        for (a, b), value, point in zip(planned, cost.tolist(), position):
            if value == np.inf:
                self.refused.add((a, b))
                continue
            self.pushes += 1
            heapq.heappush(self.queue, (value, a, b, self.pushes, int(self.stamp[a]), int(self.stamp[b]), point))

    def simplify(self, target, check=None):
        """Collapse the cheapest edges until ``target`` vertices are left or no edge can go; returns the count.
        A refused edge is planned again when a collapse changes the triangles around either of its ends."""
        self.push(sorted({edge for v in range(len(self.points)) for edge in self.edges_of(v)}))
        while self.vertex_count > target and self.queue:
            if check is not None:
                check()
            cost, a, b, _, stamp_a, stamp_b, position = heapq.heappop(self.queue)
            if not (self.alive_vertices[a] and self.alive_vertices[b]):
                continue
            if stamp_a != self.stamp[a] or stamp_b != self.stamp[b]:
                if b in self.neighbours(a):
                    self.push([(a, b)])
                continue
            if self.meets_rest(a, b, position):
                self.refused.add((a, b))
                continue
            changed = self.collapse(a, b, position)
            self._plan_again(changed)
        return self.vertex_count

    def _plan_again(self, changed):
        """Queue the edges of the collapsed vertex, and the refused edges around the vertices whose triangles changed."""
        again = set(self.edges_of(changed[0]))
        for vertex in changed[1:]:
            again.update(edge for edge in self.edges_of(vertex) if edge in self.refused)
        self.refused -= again
        self.refused = {edge for edge in self.refused if self.alive_vertices[edge[0]] and self.alive_vertices[edge[1]]} \
            if len(self.refused) > 4 * self.vertex_count else self.refused
        self.push(sorted(again))
