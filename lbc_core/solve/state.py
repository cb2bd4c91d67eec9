"""The solver's state kept between solves: :class:`SolverState`, the split variables and working sets of a finished
solve, which a warm re-bind restricts to the cells it solves again, updates with what it solved and carries onto
the edited cage's mesh; a dense splitting's state is carried onto working sets (:meth:`SolverState.from_dense`).
"""

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .pairs import cell_pairs
from .working_sets import WorkingSets


@dataclass
class SolverState:
    """A solve's final state on its working sets, for a warm start on the same mesh carried onto an edited cage.

    Measure-scaled as in :mod:`lbc_core.solve.splitting`: per slot v_W = W̃ + Ṽ, per (cell, control point) pair
    v_X = X̃ + Ũ; a solve on the same cells and vertices, moved, rescales each by its own measure.

    Attributes
    ----------
    sets : WorkingSets
        Over ``interior``.
    slot_state : (S,) float array
    duals : (N_in, d+1) float array
        The projection's duals.
    pair_indptr : (F + 1,) int array
        The pairs of cell c: ``pair_indptr[c]:pair_indptr[c + 1]``.
    pair_control : (P,) int array
    pair_state : (P, d) float array
    pair_threshold : (P,) float array
        The shrink thresholds √|c| ω / ρ the state was computed with.
    sqrt_cell : (F,) float array
    sqrt_mass : (N_in,) float array
    interior : (N_in,) int array
    penalty : float
    """

    sets: WorkingSets
    slot_state: np.ndarray
    duals: np.ndarray
    pair_indptr: np.ndarray
    pair_control: np.ndarray
    pair_state: np.ndarray
    pair_threshold: np.ndarray
    sqrt_cell: np.ndarray
    sqrt_mass: np.ndarray
    interior: np.ndarray
    penalty: float = None

    @classmethod
    def of(cls, step, state, mesh):
        ops = step.ops
        v_x, v_w = step.split(state)
        indptr = np.searchsorted(ops.pair_cell, np.arange(len(mesh.cells) + 1))
        return cls(ops.sets, v_w.copy(), step.duals.copy(), indptr, ops.pair_control.copy(), v_x.T.copy(),
                   step.thresholds.copy(), mesh.sqrt_cell.copy(), mesh.sqrt_mass.copy(), mesh.interior.copy(),
                   step.penalty)

    @classmethod
    def from_dense(cls, dense, weights, mesh, penalty):
        """The state of a dense solve (:class:`lbc_core.solve.dense.SolverState`) on working sets: one ring around
        the support of its output ``weights`` (N_in, n), as a solve on working sets ends. The split weights are the
        output with zero duals (the projection's duals 0: the output is feasible), the split gradients and their duals
        the dense state's on the pairs (its thresholds kept, so that a warm start rescales those duals to its own
        ``penalty``)."""
        support = WorkingSets.from_matrix(sp.csr_matrix(weights > 0))
        sets = WorkingSets.from_matrix(mesh.margins(support, np.ones(support.n_slots))[0]).widened()
        pair_cell, pair_control = cell_pairs(mesh, sets)
        v_x, _ = dense.parts()
        slot_vertex = sets.vertex_of_slot
        slot_state = mesh.sqrt_mass[slot_vertex] * weights[slot_vertex, sets.controls]
        indptr = np.searchsorted(pair_cell, np.arange(len(mesh.cells) + 1))
        return cls(sets, slot_state, np.zeros((len(mesh.interior), mesh.vertices.shape[1] + 1)), indptr, pair_control,
                   np.ascontiguousarray(v_x[:, pair_cell, pair_control].T, dtype=float),
                   dense.thresholds[pair_cell, pair_control].astype(float), mesh.sqrt_cell.copy(),
                   mesh.sqrt_mass.copy(), mesh.interior.copy(), penalty)

    @property
    def n_cells(self):
        return len(self.pair_indptr) - 1

    @property
    def nbytes(self):
        return sum(part.nbytes for part in (self.sets.indptr, self.sets.controls, self.slot_state, self.duals,
                                            self.pair_indptr, self.pair_control, self.pair_state,
                                            self.pair_threshold, self.sqrt_cell, self.sqrt_mass, self.interior))

    def state_for(self, step, sets):
        """The flat state of ``step`` (on ``sets``, grown from this state's) from this one, rescaled to the step's
        measures: X̃ by the ratio of √|c|, Ũ by the ratio of the thresholds, v_W by the ratio of √(β m_v)."""
        ops = step.ops
        n = sets.n_controls
        cells = np.repeat(np.arange(self.n_cells), np.diff(self.pair_indptr))
        positions = np.searchsorted(ops.pair_cell * n + ops.pair_control, cells * n + self.pair_control)
        found = positions < ops.n_pairs
        found[found] = (ops.pair_cell[positions[found]] == cells[found]) & \
            (ops.pair_control[positions[found]] == self.pair_control[found])
        state = np.zeros(step.size_x + sets.n_slots, dtype=step.dtype)
        v_x, v_w = step.split(state)
        old = self.pair_state[found].T
        thresholds = self.pair_threshold[found]
        kept = step.shrink_factors(old, thresholds)
        new_positions = positions[found]
        cell_ratio = ops.pair_sqrt_cell[new_positions] / self.sqrt_cell[cells[found]]
        threshold_ratio = np.divide(step.thresholds[new_positions], thresholds, out=np.ones_like(thresholds),
                                    where=thresholds > 0)
        v_x[:, new_positions] = old * (kept * cell_ratio + (1.0 - kept) * threshold_ratio)
        mass_ratio = ops.slot_mass / self.sqrt_mass[sets.vertex_of_slot]
        v_w[self.sets.slot_positions(sets)] = self.slot_state  # ``sets`` holds every slot of this state's
        v_w *= mass_ratio
        return state

    def restricted(self, cells, interior):
        """The state of a sub-problem: the cells where ``cells`` (F,) is true and the interior vertices
        ``interior`` (a subset of this state's, sorted), the others held fixed."""
        rows = np.searchsorted(self.interior, interior)
        sets, slots = _take_rows(self.sets, rows)
        pair_rows = np.flatnonzero(cells)
        pair_indptr, pairs = _row_ranges(self.pair_indptr, pair_rows)
        return SolverState(sets, self.slot_state[slots], self.duals[rows], pair_indptr, self.pair_control[pairs],
                           self.pair_state[pairs], self.pair_threshold[pairs], self.sqrt_cell[pair_rows],
                           self.sqrt_mass[rows], np.asarray(interior), self.penalty)

    def updated(self, sub, cells):
        """This state with a sub-problem's final state (:meth:`restricted` with the same ``cells``) written in."""
        rows = np.searchsorted(self.interior, sub.interior)
        vertex_parts = _replace_rows(self.sets.indptr, [self.sets.controls, self.slot_state], rows, sub.sets.indptr,
                                     [sub.sets.controls, sub.slot_state])
        sets = WorkingSets(vertex_parts[0], vertex_parts[1], self.sets.n_controls)
        duals, sqrt_mass = self.duals.copy(), self.sqrt_mass.copy()
        duals[rows], sqrt_mass[rows] = sub.duals, sub.sqrt_mass
        cell_rows = np.flatnonzero(cells)
        pair_parts = _replace_rows(self.pair_indptr, [self.pair_control, self.pair_state, self.pair_threshold],
                                   cell_rows, sub.pair_indptr, [sub.pair_control, sub.pair_state,
                                                                sub.pair_threshold])
        sqrt_cell = self.sqrt_cell.copy()
        sqrt_cell[cell_rows] = sub.sqrt_cell
        return SolverState(sets, vertex_parts[2], duals, pair_parts[0], pair_parts[1], pair_parts[2],
                           pair_parts[3], sqrt_cell, sqrt_mass, self.interior, sub.penalty)

    def for_cells(self, source):
        """This state on another list of cells, cell i taking cell ``source[i]``'s part (a warm start's guess where
        a re-bind replaced cells)."""
        pair_indptr, pairs = _row_ranges(self.pair_indptr, np.asarray(source))
        return SolverState(self.sets, self.slot_state, self.duals, pair_indptr, self.pair_control[pairs],
                           self.pair_state[pairs], self.pair_threshold[pairs], self.sqrt_cell[source],
                           self.sqrt_mass, self.interior, self.penalty)


def _row_ranges(indptr, rows):
    """The CSR rows ``rows`` of a layout: their new indptr and the entries they take, in order."""
    counts = indptr[rows + 1] - indptr[rows]
    new_indptr = np.r_[0, np.cumsum(counts)]
    entries = np.repeat(indptr[rows] - new_indptr[:-1], counts) + np.arange(new_indptr[-1])
    return new_indptr, entries


def _take_rows(sets, rows):
    """The working sets of the vertices ``rows``, and which slots they take."""
    indptr, slots = _row_ranges(sets.indptr, rows)
    return WorkingSets(indptr, sets.controls[slots], sets.n_controls), slots


def _replace_rows(indptr, arrays, rows, sub_indptr, sub_arrays):
    """A CSR layout with the rows ``rows`` replaced by those of a sub-layout: [indptr, *arrays]."""
    counts = np.diff(indptr)
    counts[rows] = np.diff(sub_indptr)
    new_indptr = np.r_[0, np.cumsum(counts)]
    replaced = np.zeros(len(counts), dtype=bool)
    replaced[rows] = True
    kept_rows = np.flatnonzero(~replaced)
    _, old_entries = _row_ranges(indptr, kept_rows)
    _, new_kept = _row_ranges(new_indptr, kept_rows)
    _, new_sub = _row_ranges(new_indptr, rows)
    results = [new_indptr]
    for array, sub_array in zip(arrays, sub_arrays):
        out = np.empty((new_indptr[-1],) + array.shape[1:], dtype=array.dtype)
        out[new_kept] = array[old_entries]
        out[new_sub] = sub_array
        results.append(out)
    return results
