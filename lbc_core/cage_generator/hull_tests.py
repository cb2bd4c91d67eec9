"""What the progressive hull (:mod:`lbc_core.cage_generator.hull`) does to its surface and checks after each move:
collapsing an edge and undoing it, and the tests a move must pass (no triangle turned over or a sliver, none meeting
the rest of the surface, no witness point left outside); and the mirror plane's bookkeeping."""

import numpy as np

from ..kernel.geometry import winding_numbers
from ..kernel.intersections import FLOAT32_ROUNDING, triangles_meet
from .clearance import facing_gaps
from .placement import Limits, cross, shapes_fine


def mirror_map(points, axis):
    """(n,) int array: each vertex's mirror image about the plane through 0 normal to ``axis`` (itself on the plane);
    raises ValueError when the points are not exactly symmetric."""
    image = points.copy()
    image[:, axis] = -image[:, axis]
    order = np.lexsort(points.T[::-1])
    image_order = np.lexsort(image.T[::-1])
    if not np.array_equal(points[order], image[image_order]):
        raise ValueError("the surface is not exactly mirror-symmetric")
    mirror = np.empty(len(points), dtype=np.int64)
    mirror[image_order] = order
    return mirror


def pinned_limits(axis):
    """Limits keeping a new vertex on the plane through 0 normal to ``axis`` (both its sides)."""
    normals = np.zeros((1, 2, 3))
    normals[0, 0, axis], normals[0, 1, axis] = 1.0, -1.0
    return Limits(normals, np.zeros((1, 2)), np.ones((1, 2), dtype=bool))


def side_limits(axis, side, zero):
    """Limits keeping a new vertex on its ``side`` (±1) of the plane, farther than ``zero``."""
    normals = np.zeros((1, 2, 3))
    normals[0, 0, axis] = side
    return Limits(normals, np.array([[zero, 0.0]]), np.array([[True, False]]))


class HullTests:
    """The surface edits and tests of :class:`~lbc_core.cage_generator.hull.ProgressiveHull` (a mixin: it holds the
    arrays)."""

    def _update_faces(self, faces):
        corners = self.points[self.faces[faces]]
        self.low[faces] = corners.min(axis=1)
        self.high[faces] = corners.max(axis=1)
        normal = cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        self.normals[faces] = normal / np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]

    def _collapse(self, a, b, position):
        """Collapse edge (a, b) into vertex a at ``position``; returns what undoes it."""
        shared = sorted(self.vertex_faces[a] & self.vertex_faces[b])
        touched = sorted(self.vertex_faces[a] | self.vertex_faces[b])
        corners = set(self.faces[shared].ravel().tolist()) | {a, b}
        undo = (a, b, touched, self.faces[touched].copy(), {v: set(self.vertex_faces[v]) for v in corners},
                self.points[a].copy(), shared)
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
        return undo

    def _undo(self, undone):
        for a, b, touched, faces, vertex_faces, point, shared in reversed(undone):
            self.faces[touched] = faces
            for vertex, around in vertex_faces.items():
                self.vertex_faces[vertex] = around
            self.alive_faces[shared] = True
            self.alive_vertices[b] = True
            self.points[a] = point
            self._update_faces(np.array(touched, dtype=np.int64))
            self.vertex_count += 1

    def passes(self, changed, before, old_corners, old_normals, relaxed=False):
        """Whether the changed faces are well shaped, meet no other face, and the witnesses stay inside (and, for a
        ``relaxed`` move, which may cut into the surface before it, meet no mesh edge or triangle); ``before`` are
        the faces around the move before it, with their ``old_corners`` and ``old_normals``."""
        where = np.searchsorted(before, changed)
        if not shapes_fine(self.points[self.faces[changed]][None], old_normals[where][None],
                           np.ones((1, len(changed)), dtype=bool))[0]:
            return False
        if self._meets_rest(changed) or self._too_close(changed):
            return False
        if relaxed and self.guard is not None and self.guard.meets(self.points[self.faces[changed]]):
            return False
        return not self._leaves_witness(before, old_corners)

    def _near_pairs(self, changed, reach):
        """(first, second): the pairs of triangles (vertex indices) of a changed face and another face (changed or
        not, each pair once) whose boxes, grown by ``reach``, overlap."""
        low, high = self.low[changed] - reach, self.high[changed] + reach
        near = self.alive_faces & np.all(self.low <= high.max(axis=0), axis=1) & np.all(self.high >= low.min(axis=0),
                                                                                          axis=1)
        near[changed] = False
        others = np.concatenate([np.flatnonzero(near), changed])
        i, j = np.nonzero(np.all(low[:, None] <= self.high[others][None], axis=2)
                          & np.all(high[:, None] >= self.low[others][None], axis=2))
        # Each changed face against the unchanged ones and the changed ones after it.
        keep = (j < len(others) - len(changed)) | (j > len(others) - len(changed) + i)
        return self.faces[changed[i[keep]]], self.faces[others[j[keep]]]

    def _meets_rest(self, changed):
        """Whether a changed face meets another face (changed or not) anywhere but where they share corners."""
        first, second = self._near_pairs(changed, self.zero)
        maybe = ~self._apart(first, second)
        return bool(np.any(triangles_meet(self.points, first[maybe], second[maybe], self.zero)))

    def _too_close(self, changed):
        """Whether a changed face and another face face each other across the outside closer than the cage's
        clearance (:mod:`lbc_core.cage_generator.clearance`: lbc's mesher needs the parts apart)."""
        if not self.clearance:
            return False
        first, second = self._near_pairs(changed, self.clearance)
        return bool(np.any(facing_gaps(self.points, first, second) < self.clearance))

    def _apart(self, first, second):
        """(P,) bool: pairs of triangles that cannot meet (beyond what the exact test counts as touching): one has
        every corner it does not share with the other strictly on one side of the other's plane, or, sharing none,
        an axis separates them (the two normals, the nine cross products of their edges, the six normals of their
        edges within their planes: the separating axes of two triangles)."""
        limit = max(self.zero, FLOAT32_ROUNDING * float(np.abs(self.points).max()))
        apart = np.zeros(len(first), dtype=bool)
        for one, other in ((first, second), (second, first)):
            corners = self.points[one]
            normal = self.normals_of(other)
            height = np.einsum("pkj,pj->pk", corners - self.points[other[:, 0]][:, None], normal)
            free = ~np.any(one[:, :, None] == other[:, None, :], axis=2)
            apart |= np.all((height > limit) | ~free, axis=1) | np.all((height < -limit) | ~free, axis=1)
        disjoint = np.flatnonzero(~apart & ~np.any(first[:, :, None] == second[:, None, :], axis=(1, 2)))
        if len(disjoint):
            apart[disjoint] = separated(self.points[first[disjoint]], self.points[second[disjoint]], limit)
        return apart

    def normals_of(self, triangles):
        corners = self.points[triangles]
        normal = cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        return normal / np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]

    def _leaves_witness(self, before, old_corners):
        """Whether a witness point inside the old faces lies outside the new ones: its winding number about the
        shell between them (the old faces and the new ones turned inward) is 1."""
        if self.witnesses is None:
            return False
        alive = np.asarray(before)[self.alive_faces[before]]
        corners = np.concatenate([old_corners, self.points[self.faces[alive]][:, ::-1]])
        low, high = corners.min(axis=(0, 1)), corners.max(axis=(0, 1))
        slab = self.witnesses[np.searchsorted(self.witnesses[:, 0], low[0], side="left"):
                              np.searchsorted(self.witnesses[:, 0], high[0], side="right")]
        near = slab[np.all((slab >= low) & (slab <= high), axis=1)]
        if not len(near):
            return False
        shell = corners.reshape(-1, 3)
        winding = winding_numbers(shell, np.arange(len(shell)).reshape(-1, 3), near)
        return bool(np.any(winding > 0.5))


def separated(first, second, limit):
    """(P,) bool: triangles (P, 3, 3) whose projections on one of their separating axes lie more than ``limit``
    apart."""
    edges_1 = np.roll(first, -1, axis=1) - first
    edges_2 = np.roll(second, -1, axis=1) - second
    normal_1, normal_2 = cross(edges_1[:, 0], edges_1[:, 1]), cross(edges_2[:, 0], edges_2[:, 1])
    axes = np.concatenate([normal_1[:, None], normal_2[:, None],
                           cross(edges_1[:, :, None], edges_2[:, None, :]).reshape(-1, 9, 3),
                           cross(normal_1[:, None], edges_1), cross(normal_2[:, None], edges_2)], axis=1)
    length = np.linalg.norm(axes, axis=2)
    axes = axes / np.maximum(length, 1e-300)[..., None]
    usable = length > 1e-12 * np.maximum(length.max(axis=1, keepdims=True), 1e-300)
    project_1, project_2 = first @ axes.transpose(0, 2, 1), second @ axes.transpose(0, 2, 1)  # (P, 3, A)
    gap = np.maximum(project_2.min(axis=1) - project_1.max(axis=1), project_1.min(axis=1) - project_2.max(axis=1))
    return np.any(usable & (gap > limit), axis=1)
