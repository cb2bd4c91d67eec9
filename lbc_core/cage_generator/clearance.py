"""How far apart the cage's parts must stay for lbc to bind it, and the gaps that say whether they do.

lbc's tetrahedral mesher (:mod:`lbc_core.meshing.tetrahedra`) samples the cage's surface about one lattice side s
apart, s = (TETRAHEDRA_PER_CUBE × volume / cells)^(1/3); a part of the cage facing another across a gap g narrower
than s is sampled finer, at 2 √(0.7 g s), and a gap far below s makes that refinement run away: the bind is refused
(``GapTooNarrow``), or the tetrahedra cannot follow the surface there. Two triangles sharing corners count too: a
sharp fold between them is a gap closing to nothing (pgc_elephant's cage: 9 of the 10 faces the mesher named lay on
such folds, or on two triangles a quarter of s apart). Where the cage the hull makes has such a gap, the hull runs
again keeping every two triangles that face each other at least CLEARANCE_SHARE × s apart, s taken at the default
cells from the surface the hull starts from (the smallest volume it has, so the finished cage's own s is larger;
bench/RESULTS.md, "Cage generator", the third round)."""

import numpy as np

from ..kernel.geometry import closest_on_triangles, triangle_normals, unit
from ..kernel.intersections import overlapping_boxes
from ..meshing import DEFAULT_CELLS

# The mesher's tetrahedra per lattice cube (meshing/tetrahedra.py, its lattice side from the volume; the tests check
# that the two agree).
TETRAHEDRA_PER_CUBE = 9.5
# Two cage triangles facing each other stay at least this share of the mesher's lattice side apart: at s / 8
# pgc_elephant's cage binds with 1 % more volume; s / 4 added 8 %, s / 16 bound too (bench/RESULTS.md, "Cage
# generator", the third round).
CLEARANCE_SHARE = 0.125
# Two triangles face each other when their normals are opposite within this cosine, and a gap runs within it of
# the normal (the mesher's own test of a gap, meshing/surface.py).
FACING = 0.7

# Distances below this share of a triangle's longest edge are rounding's.
ROUNDING = 1e-9


def mesher_side(volume, cells=None):
    """The lattice side lbc's tetrahedral mesher takes for a cage enclosing ``volume`` at ``cells`` cells (the
    default when None), in the cage's units."""
    cells = DEFAULT_CELLS[3] if cells is None else cells
    return float((TETRAHEDRA_PER_CUBE * max(volume, 0.0) / cells) ** (1.0 / 3.0))


def cage_clearance(volume, share=CLEARANCE_SHARE):
    """The least gap two cage triangles facing each other keep, for a cage enclosing about ``volume``."""
    return share * mesher_side(volume)


# Points of each triangle (barycentric) at which its gap to another is measured: the mesher's own probes
# (meshing/surface.py).
PROBES = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0], [0, 0.5, 0.5], [0.5, 0, 0.5], [1 / 3, 1 / 3, 1 / 3],
                   [2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])


def facing_gaps(vertices, first, second):
    """(P,) the gap between triangles ``first[p]`` and ``second[p]`` (P, 3) of vertex indices (of a closed surface
    facing out) as lbc's mesher measures it: for two triangles whose normals are opposite within FACING, the least
    distance from a probe of one to the other straight ahead of it (within FACING of its normal), either way; inf
    where they do not face each other. Triangles sharing corners count too: a sharp fold between two of them is
    a gap closing to nothing at the fold (the mesher refines it and runs away the same)."""
    gaps = np.full(len(first), np.inf)
    corners_1, corners_2 = vertices[first], vertices[second]
    normals_1, normals_2 = unit(triangle_normals(corners_1)), unit(triangle_normals(corners_2))
    facing = np.flatnonzero(np.einsum("ij,ij->i", normals_1, normals_2) < -FACING)
    # A probe on a corner or an edge both triangles share is no gap: its distance, rounding's, is left out.
    rounding = ROUNDING * np.linalg.norm(corners_1[facing] - np.roll(corners_1[facing], 1, axis=1), axis=2).max(axis=1)
    for probed, target, normal in ((corners_1, corners_2, normals_1), (corners_2, corners_1, normals_2)):
        points = np.einsum("pk,fkd->fpd", PROBES, probed[facing]).reshape(-1, 3)
        aimed = np.repeat(target[facing], len(PROBES), axis=0)
        squared, bary = closest_on_triangles(points, aimed[:, 0], aimed[:, 1], aimed[:, 2])
        across = np.einsum("ik,ikd->id", bary, aimed) - points
        distance = np.sqrt(squared)
        ahead = np.einsum("ij,ij->i", across, np.repeat(normal[facing], len(PROBES), axis=0)) > FACING * distance
        ahead &= distance > np.repeat(rounding, len(PROBES))
        least = np.where(ahead, distance, np.inf).reshape(-1, len(PROBES)).min(axis=1, initial=np.inf)
        gaps[facing] = np.minimum(gaps[facing], least)
    return gaps


def narrow_gaps(vertices, triangles, clearance):
    """(P, 2) int array: the pairs of the surface's triangles (i < j) that face each other across a gap narrower than
    ``clearance`` (:func:`facing_gaps`)."""
    corners = vertices[triangles]
    pairs = overlapping_boxes(corners.min(axis=1) - clearance, corners.max(axis=1) + clearance)
    return pairs[facing_gaps(vertices, triangles[pairs[:, 0]], triangles[pairs[:, 1]]) < clearance]
