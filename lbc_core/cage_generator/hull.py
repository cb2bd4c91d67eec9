"""The progressive hull (Sander, Gu, Gortler, Hoppe, Snyder 2000): edge collapses that bring a closed triangle surface
down to a vertex count, each enclosing the surface before it, so the last encloses the first.

Each collapse of an edge (a, b) puts the new vertex on the outer side of the planes of every triangle around a or b,
where it adds the least volume (:mod:`lbc_core.cage_generator.placement`); the cheapest collapse goes first. A move
(one collapse, or a collapse and its mirror image) is applied, then tested, and undone when it fails: when an edge's
ends share other neighbours than its two opposite corners (the link condition), when a vertex would be left with
three neighbours or fewer, when a new triangle turns over, is a sliver or meets the rest of the surface, or when a
witness point (a mesh vertex) ends up outside: the planes alone do not keep everything in where the triangles around
the edge fold as seen from the new vertex. After each move every edge around the vertices whose triangles changed is
planned again, in one batch (bench/RESULTS.md, "Cage generator").

With a mirror plane (``axis``: the surface symmetric about the plane through 0 normal to that axis, vertices on the
plane exactly on it) the surface stays exactly symmetric: an edge off the plane collapses with its mirror image, its
new vertex kept on its side; an edge with an end on the plane collapses onto the plane (with its mirror image when
the other end is off it)."""

import heapq

import numpy as np

from .hull_tests import HullTests, mirror_map, pinned_limits, side_limits
from .placement import Limits, place

# Stale moves planned again in one batch, at most.
STALE_BATCH = 64


class ProgressiveHull(HullTests):
    """A closed, outward triangle surface under enclosing edge collapses.

    Parameters
    ----------
    vertices : (n, 3) float array
    triangles : (T, 3) int array
        Closed, manifold, outward, not self-intersecting.
    zero : float
        Length that counts as zero in the intersection tests.
    witnesses : (m, 3) float array or None
        Points inside the surface that every collapse must keep inside (the mesh's vertices).
    axis : int or None
        The mirror plane's normal axis (the plane through 0), for a surface symmetric about it.
    guard : MeshGuard or None
        The mesh, whose edges and triangles no new triangle of a relaxed move (one that cuts into the planes around
        its edge, see :func:`~lbc_core.cage_generator.placement.place`) may meet.
    clearance : float or None
        The least distance two triangles sharing no corner keep where they face each other across the outside
        (:func:`~lbc_core.cage_generator.clearance.cage_clearance`); None: not tested.
    """

    def __init__(self, vertices, triangles, zero, witnesses=None, axis=None, guard=None, clearance=None):
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
        # Sorted along x, so that those in a box are found by bisection.
        self.witnesses = None if witnesses is None else np.asarray(witnesses, dtype=float)
        if self.witnesses is not None:
            self.witnesses = self.witnesses[np.argsort(self.witnesses[:, 0], kind="stable")]
        self.low = np.empty((len(self.faces), 3))
        self.high = np.empty((len(self.faces), 3))
        self.normals = np.empty((len(self.faces), 3))
        self._update_faces(np.arange(len(self.faces)))
        self.axis = axis
        self.guard = guard
        self.clearance = clearance
        self.mirror = None if axis is None else mirror_map(self.points, axis)
        self.pinned = np.zeros(len(self.points), dtype=bool) if axis is None else self.points[:, axis] == 0.0
        self.queue = []
        self.vertex_count = len(self.points)
        self.collapses = 0
        self.pushes = 0
        self.plans = 0
        self.refusals = 0
        self.volume = _volume(self.points[self.faces], self.points.mean(axis=0))
        self.volume_limit = np.inf
        self.full = False  # the last move tried would have taken the volume past its limit

    # ------------------------------------------------------------------------------------------------ the surface

    def neighbours(self, vertex):
        """The set of vertices sharing a triangle with ``vertex``."""
        found = set(self.faces[list(self.vertex_faces[vertex])].ravel().tolist())
        found.discard(vertex)
        return found

    def result(self):
        """(vertices, triangles) of the surface now, renumbered."""
        used = np.flatnonzero(self.alive_vertices)
        renumber = np.full(len(self.points), -1, dtype=np.int64)
        renumber[used] = np.arange(len(used))
        return self.points[used].copy(), renumber[self.faces[self.alive_faces]]

    # ------------------------------------------------------------------------------------------------ planning

    def _move_of(self, a, b):
        """(collapses, limits, canonical key) of the move that collapses edge (a, b): one collapse (a, b) into a, or
        with a mirror plane also its image; None when the move cannot keep the surface symmetric."""
        if self.mirror is None:
            return ((a, b),), None, (a, b)
        if self.pinned[b] and not self.pinned[a]:
            a, b = b, a
        mirror_a, mirror_b = int(self.mirror[a]), int(self.mirror[b])
        key = min((min(a, b), max(a, b)), (min(mirror_a, mirror_b), max(mirror_a, mirror_b)))
        if self.pinned[a]:  # onto the plane: alone when b is on it too, else with b's mirror image
            collapses = ((a, b),) if self.pinned[b] else ((a, b), (a, mirror_b))
            return collapses, pinned_limits(self.axis), key
        side = np.sign(self.points[a, self.axis])
        if side != np.sign(self.points[b, self.axis]) or mirror_a in (a, b):
            return None
        return ((a, b), (mirror_a, mirror_b)), side_limits(self.axis, side, self.zero), key

    def plan(self, edges):
        """Plan the moves of ``edges`` (each edge or its mirror image) and queue those that can be made."""
        chosen, keys, rings, kept, limits = [], set(), [], [], []
        for a, b in edges:
            move = self._move_of(a, b)
            if move is None or move[2] in keys:
                continue
            keys.add(move[2])
            (first, second), move_limits = move[0][0], move[1]
            found = self._ring_if_collapsible(first, second)
            if found is None:
                continue
            chosen.append(move[0]), rings.append(found[0]), kept.append(found[1]), limits.append(move_limits)
        if not chosen:
            return
        self.plans += len(chosen)
        ends = np.array([collapses[0] for collapses in chosen])
        cost, position, relaxed = place(self.points, self.faces, self.normals, ends, rings, kept, _stacked(limits))
        for collapses, value, point, last in zip(chosen, cost.tolist(), position, relaxed.tolist()):
            if value == np.inf:
                continue
            if self.mirror is not None and self.pinned[collapses[0][0]]:
                point[self.axis] = 0.0  # on the plane exactly
            involved = sorted({v for edge in collapses for v in edge})
            self.pushes += 1
            heapq.heappush(self.queue, (last, value, self.pushes, collapses, point,
                                        tuple(self.stamp[involved].tolist())))

    def _ring_if_collapsible(self, a, b):
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

    # ------------------------------------------------------------------------------------------------ the queue

    def simplify(self, target, check=None, volume_limit=np.inf):
        """Make the cheapest moves until ``target`` vertices are left, none can be made, or the next would take the
        enclosed volume past ``volume_limit``; returns the count.

        A move planned before its neighbourhood changed is planned again when it comes to the top of the queue,
        together with the others that come up stale before the next valid one (one batch instead of one each)."""
        self.volume_limit = volume_limit
        made = None
        while self.vertex_count > target and made != self.collapses and not self.full:
            # Every edge planned: at the start, and again when the queue runs dry, since a move refused for what
            # lay near it (not its own ring) may pass now (clothing stopped at 26 vertices for 18 asked).
            made = self.collapses
            self._plan_all()
            self._run(target, check)
        return self.vertex_count

    def _plan_all(self):
        faces = self.faces[self.alive_faces]
        edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        self.queue = []
        self.plan(sorted({(min(a, b), max(a, b)) for a, b in edges.tolist()}))

    def _run(self, target, check):
        """Make moves from the queue until ``target`` vertices are left or the queue runs dry."""
        stale = []
        while self.vertex_count > target and self.queue and not self.full:
            if check is not None:
                check()
            entry = heapq.heappop(self.queue)
            _, _, _, collapses, point, stamps = entry
            involved = sorted({v for edge in collapses for v in edge})
            if not self.alive_vertices[involved].all():
                continue
            if tuple(self.stamp[involved].tolist()) != stamps:
                stale.append(collapses[0])
                if len(stale) < STALE_BATCH and self.queue:
                    continue
            elif stale:
                heapq.heappush(self.queue, entry)
            if stale:
                self.plan(stale)
                stale = []
                continue
            if len(collapses) == 2 and self.vertex_count - 2 < target:
                continue
            changed = self.make(collapses, point, entry[0])
            if changed is None:
                self.refusals += 1
                continue
            self.stamp[changed] += 1
            self._plan_around(collapses)

    def _plan_around(self, collapses):
        """Plan the edges of the vertices the move kept at once: the likeliest next moves."""
        kept = {a for a, _ in collapses}
        self.plan(sorted({(min(v, w), max(v, w)) for v in kept for w in self.neighbours(v)}))

    def make(self, collapses, point, relaxed=False):
        """Apply the collapses (the first's kept vertex to ``point``, the second's to its mirror image), test the
        result (a ``relaxed`` move against the mesh too), and undo it when it fails; returns the vertices whose
        triangles changed, or None."""
        before = sorted(set().union(*(self.vertex_faces[v] for edge in collapses for v in edge)))
        old_corners = self.points[self.faces[before]]
        old_normals = self.normals[before].copy()
        undo = []
        for number, (a, b) in enumerate(collapses):
            if self._ring_if_collapsible(a, b) is None:
                self._undo(undo)
                return None
            position = point if number == 0 else self._mirrored(point)
            undo.append(self._collapse(a, b, position))
        kept = sorted({a for a, _ in collapses})
        changed_faces = np.array(sorted(set().union(*(self.vertex_faces[a] for a in kept))), dtype=np.int64)
        if not self.passes(changed_faces, before, old_corners, old_normals, relaxed):
            self._undo(undo)
            return None
        added = _volume(self.points[self.faces[np.asarray(before)[self.alive_faces[before]]]], old_corners[0, 0]) \
            - _volume(old_corners, old_corners[0, 0])
        if self.volume + added > self.volume_limit:
            self._undo(undo)
            self.full = True
            return None
        self.volume += added
        self.collapses += len(collapses)
        return sorted(set(kept).union(*(self.neighbours(a) for a in kept)))

    def _mirrored(self, point):
        image = point.copy()
        image[self.axis] = -image[self.axis]
        return image


def _volume(corners, origin):
    """The signed volume triangles (k, 3, 3) enclose with ``origin`` (that of a closed surface, for any origin)."""
    a, b, c = corners[:, 0] - origin, corners[:, 1] - origin, corners[:, 2] - origin
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)


def _stacked(limits):
    """One Limits for a batch, from each edge's Limits of one row (or None)."""
    rows = [Limits.none(1) if item is None else item for item in limits]
    return Limits(np.concatenate([row.normals for row in rows]), np.concatenate([row.offsets for row in rows]),
                  np.concatenate([row.used for row in rows]))

