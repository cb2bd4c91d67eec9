"""How finely the 3D mesher samples and fills a cage, chosen by counting before any tetrahedralisation, and how much
work it may do: budgets of counts, never of seconds, so the same cage always takes the same path.

A conforming Delaunay tetrahedralisation of the surface samples and the lattice has about
:data:`CELLS_PER_LATTICE_POINT` tetrahedra per lattice point and :data:`CELLS_PER_SAMPLE` per surface sample. Both
counts are known once the samples and the lattice are made, before the tetrahedralisation: the mesher makes them at
a candidate lattice side, predicts the cells and, when the prediction misses the target, makes them again at a
corrected side (:meth:`Sizing.next_side`), a few times at most. A thin part (a finger one or two cube sides across,
whose band along the surface leaves little lattice inside) or a narrow gap (sampled finer from the start) makes
surface samples the larger share: the side from the volume alone gave 44 % too many cells on a hand, 2.5 times too
many at 2000 cells, and then a whole second tetrahedralisation to correct it.
"""

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..kernel.geometry import triangle_normals, unit

# Tetrahedra per lattice point and per surface sample (the samples before refinement): fitted on the first and
# second tries of the corpus, gargoyle, hand and arm cages at 2000 and 8000 cells (bench/RESULTS.md, "Meshing cages
# whose parts nearly touch: sized by counting, bounded by counts").
CELLS_PER_LATTICE_POINT = 5.86
CELLS_PER_SAMPLE = 3.0
# A predicted count this close (relative) to the target is kept; at most SIZING_ROUNDS candidate sides are counted.
SIZING_TOLERANCE = 0.08
SIZING_ROUNDS = 4
# The side counted stays within this factor of the side the volume alone gives, either way: the samples along a narrow
# gap make a floor on the count that no coarser lattice goes below, and fingers a cube side across lose their inside.
MOST_SIDE_CHANGE = 1.25
# The points meshing may hand to the tetrahedraliser, summed over every refinement round, try and attempt: per
# target cell and a constant. The valid cages measured took at most 13.3 per cell (bench/RESULTS.md, same section).
WORK_PER_CELL, WORK_BASE = 60, 100_000
# Facets sharing a vertex and facing each other at below WEDGE_ANGLE (radians) make a narrow wedge; each pair adds
# WEDGE_WORK × (WEDGE_ANGLE / angle − 1) to the meshing's work (bench/RESULTS.md, "Faces meeting at small angles").
WEDGE_ANGLE = np.radians(5.0)
WEDGE_WORK = 0.55


@dataclass(frozen=True)
class Candidate:
    """The counts made at one lattice side: the side, the lattice points and surface samples, the cells predicted."""

    side: float
    lattice_points: int
    samples: int
    predicted: float


@dataclass(frozen=True)
class Sizing:
    """The cell count asked for, the lattice side the volume alone gives for it, the model's correction measured on
    a first try (cells made / predicted), and how many sides may be counted (1: the side given, as it is)."""

    target: int
    volume_side: float
    scale: float = 1.0
    rounds: int = SIZING_ROUNDS

    def candidate(self, side, lattice_points, samples):
        """The Candidate at ``side`` with these counts."""
        predicted = self.scale * (CELLS_PER_LATTICE_POINT * lattice_points + CELLS_PER_SAMPLE * samples)
        return Candidate(side, lattice_points, samples, predicted)

    def miss(self, candidate):
        """How far a candidate's prediction is from the target, as |log(predicted / target)|."""
        return abs(np.log(max(candidate.predicted, 1.0) / self.target))

    def near(self, candidate):
        """Whether a candidate's prediction is within SIZING_TOLERANCE of the target."""
        return self.miss(candidate) <= np.log1p(SIZING_TOLERANCE)

    def next_side(self, tried):
        """The side to count next, from the candidates counted so far (list of Candidate, in order).

        The count falls as a power of the side: about the third power where the lattice makes it, the second where
        the surface does. After one candidate that power is the shares' mean; after two, the secant's slope through
        the last two (log count against log side), kept within [1/2, 3]. None when the side would pass its bounds
        (MOST_SIDE_CHANGE) from a candidate already at them.
        """
        last = tried[-1]
        if len(tried) == 1:
            lattice = CELLS_PER_LATTICE_POINT * last.lattice_points
            surface = CELLS_PER_SAMPLE * last.samples
            power = (3.0 * lattice + 2.0 * surface) / max(lattice + surface, 1e-300)
        else:
            before = tried[-2]
            power = -np.log(max(last.predicted, 1.0) / max(before.predicted, 1.0)) / np.log(last.side / before.side)
            power = float(np.clip(power if np.isfinite(power) else 0.5, 0.5, 3.0))
        factor = (max(last.predicted, 1.0) / self.target) ** (1.0 / power)
        low, high = self.volume_side / MOST_SIDE_CHANGE, self.volume_side * MOST_SIDE_CHANGE
        side = float(np.clip(last.side * factor, low, high))
        return None if np.isclose(side, last.side, rtol=1e-9) else side


class WorkBudget:
    """The points the tetrahedraliser may still be handed in one meshing (WORK_PER_CELL per target cell and
    WORK_BASE): the last guard on refinement that neither converges nor runs away, counted, so that it stops at the
    same round on any machine under any load."""

    def __init__(self, cells):
        self.left = WORK_PER_CELL * int(cells) + WORK_BASE
        self.exhausted = False

    def spend(self, points):
        """Take ``points`` from the budget; False, and exhausted from then on, when they are more than is left."""
        if self.exhausted or points > self.left:
            self.exhausted = True
            return False
        self.left -= points
        return True


def wedge_work(vertices, facets):
    """How many times an ordinary cage's meshing work (for as many cells) a 3D cage's takes, from its narrow wedges
    (:data:`WEDGE_ANGLE`, :data:`WEDGE_WORK`): 1 for a cage without any; counted before meshing, for the forecast.

    Where two faces meet at a small angle θ and face each other (the web between two fingers), the gap between them
    shrinks to nothing: the tetrahedra follow them only once their samples are about as fine as the gap, some 1 / θ
    of them per octave of distance from where they meet, which refinement adds round after round.

    Parameters
    ----------
    vertices : (V, 3) float array
    facets : (F, 3) int array, outward triangles

    Returns
    -------
    float, at least 1
    """
    facets = np.asarray(facets)
    incidence = sp.csr_matrix((np.ones(facets.size), (np.repeat(np.arange(len(facets)), 3), facets.ravel())),
                              shape=(len(facets), len(vertices)))
    sharing = sp.triu(incidence @ incidence.T, k=1).tocoo()  # facet pairs with a vertex in common
    normals = unit(triangle_normals(np.asarray(vertices, float)[facets]))
    facing = -np.einsum("ij,ij->i", normals[sharing.row], normals[sharing.col])
    angle = np.arccos(np.clip(facing, -1.0, 1.0))  # between the two planes, where the normals are opposite
    narrow = np.maximum(angle[angle < WEDGE_ANGLE], 1e-3 * WEDGE_ANGLE)
    return 1.0 + WEDGE_WORK * float(np.sum(WEDGE_ANGLE / narrow - 1.0))
