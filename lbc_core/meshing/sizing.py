"""How much work the 3D mesher may do: budgets of counts, never of seconds, so the same cage always takes the same
path, on any machine under any load."""

# The points meshing may hand to the tetrahedraliser, summed over every refinement round, try and attempt: per
# target cell and a constant. The valid cages measured took at most 13.3 per cell (bench/RESULTS.md, "Meshing cages
# whose parts nearly touch: sized by counting, bounded by counts").
WORK_PER_CELL, WORK_BASE = 60, 100_000


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
