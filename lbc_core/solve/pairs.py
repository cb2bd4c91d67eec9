"""The solver's operators on one layout of working sets (:mod:`lbc_core.solve.working_sets`): on the (cell, control
point) pairs where a coordinate's gradient may be non-zero, the gradient operator and the boundary values' part of it;
the least-squares step's matrix (P1 stiffness + β mass, block-diagonal over the control points) factorised in groups;
and the slots as rows padded per vertex for the per-vertex projection. Their sizes follow the slots and pairs, not
the number of control points.
"""

import numpy as np
import scipy.sparse as sp

from ..kernel.constraints import constraint_residuals, nearest_feasible, restore_constraints
from ..kernel.factor import Factor
from ..kernel.parallel import thread_map, worker_count
from .projection import PADDING_VALUE, STEP_TOLERANCE, corner_products, project_rows

# Newton steps of the projection within an iteration (bench/RESULTS.md, "The locality solver").
STEP_NEWTON_STEPS = 3
# Slots per factorisation at most: the least-squares matrix is factorised in groups of whole control points, so that
# cancel is heard between them (bench/RESULTS.md, "The step").
FACTOR_GROUP_SLOTS = 20000
# Pairs per chunk of the gradient matrix's assembly, cancel checked between chunks (bench/RESULTS.md, "The locality
# solver, third round").
GRADIENT_CHUNK_PAIRS = 100_000
# The largest violation of partition of unity or reproduction the solve's output keeps (unit-frame coordinates).
EXACT = 1e-12
# Row blocks of the gradient matrix, whatever the threads: Gᵀ sums one partial product per block, and a sum's
# rounding follows its terms, so a count that followed the cores gave other weights on another machine.
PRODUCT_BLOCKS = 8


def key_positions(keys, sorted_keys):
    """The position of each of ``keys`` in ``sorted_keys``, -1 where it is not there."""
    if not len(sorted_keys):
        return np.full(len(keys), -1)
    found = np.minimum(np.searchsorted(sorted_keys, keys), len(sorted_keys) - 1)
    return np.where(sorted_keys[found] == keys, found, -1)


def _block_system(system, sets, table, slots, position):
    """The lower triangle (COO) of the least-squares matrix on ``slots``, whole control points' blocks, numbered in
    the order given: each control point's block is ``system``'s principal submatrix on the vertices holding it.
    ``table`` (N_in, n) gives the slot of each (vertex, control point), -1 where none; ``position`` (S,) is a work
    array of -1, left so."""
    vertex = sets.vertex_of_slot[slots]
    counts = np.diff(system.indptr)[vertex]
    rows = np.repeat(np.arange(len(slots)), counts)
    entry = np.repeat(system.indptr[vertex] - np.r_[0, np.cumsum(counts)[:-1]], counts) + np.arange(counts.sum())
    other = table[system.indices[entry], sets.controls[slots][rows]]
    position[slots] = np.arange(len(slots))
    columns = np.where(other >= 0, position[np.maximum(other, 0)], -1)
    position[slots] = -1
    lower = (other >= 0) & (rows >= columns)
    size = len(slots)
    return sp.coo_matrix((system.data[entry[lower]], (rows[lower], columns[lower])), shape=(size, size)).tocsr().tocoo()


def _group_factors(system, sets, order, dtype, check):
    """Factorisations of the least-squares matrix, block-diagonal over the control points, in control-major
    ``order``: [(positions (k, m), Factor)], each factor solving the blocks at ``positions`` of that order.

    Control points held by the same vertices have the same block: one factor solves all k of them as k right-hand
    sides (where the supports are wide, as in Blender's Cylinder, most are alike). The others are factorised in
    groups of about FACTOR_GROUP_SLOTS slots (k = 1), each group's block built just before its factorisation."""
    table = np.full((len(sets.indptr) - 1, sets.n_controls), -1, dtype=np.int64)
    table[sets.vertex_of_slot, sets.controls] = np.arange(sets.n_slots)
    position = np.full(sets.n_slots, -1, dtype=np.int64)
    counts = np.bincount(sets.controls, minlength=sets.n_controls)
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    ordered_vertices = sets.vertex_of_slot[order]
    alike = {}
    for control in np.flatnonzero(counts):
        key = ordered_vertices[starts[control]:starts[control] + counts[control]].tobytes()
        alike.setdefault(key, []).append(control)

    def factor(slots):  # ``slots``: positions in control-major order
        return Factor(_block_system(system, sets, table, order[slots], position), dtype)

    factors, singles = [], []
    for controls in sorted(alike.values()):
        if len(controls) == 1:
            singles.append(controls[0])
            continue
        block = np.arange(counts[controls[0]])
        check()
        factors.append((starts[controls][:, None] + block, factor(starts[controls[0]] + block)))
    for group in _groups(singles, counts, FACTOR_GROUP_SLOTS):
        slots = np.concatenate([starts[control] + np.arange(counts[control]) for control in group])
        check()
        factors.append((slots[None, :], factor(slots)))
    return factors


def _groups(controls, counts, size):
    """``controls`` in consecutive groups of at least ``size`` slots (``counts`` per control point), the last one
    smaller."""
    group, slots = [], 0
    for control in controls:
        group.append(control)
        slots += counts[control]
        if slots >= size:
            yield group
            group, slots = [], 0
    if group:
        yield group


def cell_pairs(mesh, sets):
    """The (cell, control point) pairs of ``sets`` on ``mesh``, sorted by cell: (P,) cells and (P,) control points,
    as :class:`PairOperators` holds them."""
    return PairOperators.pairs(mesh, sets, mesh.interior[sets.vertex_of_slot])


class PaddedRows:
    """The slots as rows padded to a common width, for the per-vertex projection."""

    def __init__(self, sets, mesh):
        counts = np.diff(sets.indptr)
        self.width = max(int(counts.max()), 1)
        self.vertex = sets.vertex_of_slot
        self.column = np.arange(sets.n_slots) - sets.indptr[self.vertex]
        d = mesh.unit_controls.shape[1]
        self.corners = np.zeros((len(counts), self.width, d + 1))
        self.corners[self.vertex, self.column, 0] = 1.0
        self.corners[self.vertex, self.column, 1:] = mesh.unit_controls[sets.controls]
        self.products = corner_products(self.corners)
        self.targets = np.c_[np.ones(len(counts)), mesh.unit_interior]
        self.full = sets.n_slots == len(counts) * self.width  # no padding (whole sets): rows are a reshape

    def gather(self, slot_values):
        """(S,) → (N_in, width) float64, a fresh array, padding slots PADDING_VALUE."""
        if self.full:
            return np.array(slot_values, dtype=float).reshape(self.corners.shape[:2])
        rows = np.full(self.corners.shape[:2], PADDING_VALUE)
        rows[self.vertex, self.column] = slot_values
        return rows

    def scatter(self, rows):
        """(N_in, width) → (S,)."""
        if self.full:
            return rows.ravel()
        return rows[self.vertex, self.column]


class PairOperators:
    """The solver's operators on one layout of working sets.

    Attributes
    ----------
    sets : WorkingSets
    pair_cell, pair_control : (P,) int arrays
        The (cell, control point) pairs where a coordinate's gradient may be non-zero, sorted.
    gradient : (d P, S) CSR matrix
        Slot values → √|c| ∇w on the pairs, component-major rows (row k P + p); None on whole sets.
    cells_gradient, cells_gradient_t : (d F, N_in) CSR matrix and its transpose
        On whole sets (None otherwise): the same products on the (N_in, n) block of the slots, 3–4 times faster
        than the pairs' matrix (bench/RESULTS.md, "Whole working sets' products on blocks").
    boundary_part : (d, P) float array
        The boundary values' part of √|c| ∇w on the pairs.
    slot_mass : (S,) float array
        √(β m_v) of each slot's vertex.
    factors : list of (int, int, Factor)
        Of gradientᵀ gradient + diag(slot_mass²), the least-squares step's matrix, in control-major order: each
        factor holds the rows ``start:stop`` of that order, whole control points' blocks.
    padded : PaddedRows
    """

    def __init__(self, mesh, sets, dtype=np.float64, check=None):
        check = check or (lambda: None)  # between the parts of a layout, each well under half a second
        self.sets = sets
        slot_vertex = mesh.interior[sets.vertex_of_slot]
        n = sets.n_controls
        self.pair_cell, self.pair_control = self.pairs(mesh, sets, slot_vertex)
        check()
        d = mesh.vertices.shape[1]
        corner_vertex = mesh.cells[self.pair_cell].astype(np.int32)  # (P, d+1)
        control = self.pair_control[:, None]
        touching = np.flatnonzero(mesh.cell_on_cage[self.pair_cell])  # pairs carrying boundary values: a few
        boundary_row = mesh.boundary_position[corner_vertex[touching]]
        corner_fixed = np.where(boundary_row >= 0,
                                mesh.boundary_weights[np.maximum(boundary_row, 0), control[touching]], 0.0)
        self.boundary_part = np.zeros((d, len(self.pair_cell)), dtype=dtype)
        self.boundary_part[:, touching] = np.einsum("pc,pck->kp", corner_fixed,
                                                    mesh.scaled_gradients[self.pair_cell[touching]])
        del boundary_row, corner_fixed
        check()
        if sets.whole:  # every pair of every cell: the products act on (N_in, n) blocks through the cells' operator
            del corner_vertex
            self.cells_gradient = _cells_gradient(mesh, dtype)
            self.cells_gradient_t = self.cells_gradient.T.tocsr()
            self.gradient = self.row_blocks = None
        else:
            self.cells_gradient = self.cells_gradient_t = None
            # Each pair's corners: a slot (its index), or a boundary value, or nothing; looked up in a dense (N, n)
            # table, built for this and dropped (a sorted search of the keys takes ten times as long).
            table = np.full((len(mesh.vertices), n), -1, dtype=np.int32)
            table[slot_vertex, sets.controls] = np.arange(sets.n_slots, dtype=np.int32)
            corner_slot = table[corner_vertex, control]
            del table, corner_vertex
            check()
            self.gradient = _gradient_matrix(mesh.scaled_gradients, self.pair_cell, corner_slot, sets.n_slots, dtype,
                                             check)
            del corner_slot
            self.row_blocks = _row_blocks(self.gradient, PRODUCT_BLOCKS)
        check()
        self.slot_mass = mesh.sqrt_mass[sets.vertex_of_slot].astype(dtype)
        # Control-major order: the matrix is block-diagonal over the control points, which the factorisation's
        # analysis then sees at once (a quarter faster on the gargoyle's cages).
        self.order = np.lexsort((sets.vertex_of_slot, sets.controls))
        self.factors = _group_factors(mesh.system, sets, self.order, dtype, check)
        check()
        self.pair_sqrt_cell = mesh.sqrt_cell[self.pair_cell].astype(dtype)
        self.dtype = dtype
        check()
        self.padded = PaddedRows(sets, mesh)
        bounds = np.linspace(0, len(self.padded.targets), worker_count() + 1).astype(int)
        self.vertex_blocks = [slice(start, stop) for start, stop in zip(bounds[:-1], bounds[1:])]
        self.d = d

    @staticmethod
    def pairs(mesh, sets, slot_vertex):
        """The (cell, control point) pairs touching a slot or a non-zero boundary value, sorted by cell; on whole
        sets every pair (the few more on cells wholly on the cage stay zero)."""
        n_cells, k = mesh.cells.shape
        if sets.whole:
            return (np.repeat(np.arange(n_cells, dtype=np.int64), sets.n_controls),
                    np.tile(np.arange(sets.n_controls, dtype=np.int64), n_cells))
        holds = sp.csr_matrix((np.ones(sets.n_slots), (slot_vertex, sets.controls)),
                              shape=(len(mesh.vertices), sets.n_controls))
        holds = (holds + mesh.fixed).astype(bool).astype(float)
        incidence = sp.csr_matrix((np.ones(n_cells * k), mesh.cells.ravel(), np.arange(0, n_cells * k + 1, k)),
                                  shape=(n_cells, len(mesh.vertices)))
        pairs = (incidence @ holds).tocoo()
        order = np.lexsort((pairs.col, pairs.row))
        return pairs.row[order].astype(np.int64), pairs.col[order].astype(np.int64)

    @property
    def n_pairs(self):
        return len(self.pair_cell)

    def gradients(self, slot_values):
        """√|c| ∇w (d, P) on the pairs, boundary values included, row blocks one per thread."""
        if self.cells_gradient is not None:
            out = (self.cells_gradient @ slot_values.reshape(-1, self.sets.n_controls)).reshape(self.d, -1)
            out += self.boundary_part
            return out
        out = np.empty((self.d * self.n_pairs,), dtype=np.result_type(self.dtype, slot_values.dtype))

        def rows(block):
            start, matrix = block
            out[start:start + matrix.shape[0]] = matrix @ slot_values

        thread_map(rows, self.row_blocks)
        out = out.reshape(self.d, -1)
        out += self.boundary_part
        return out

    def transposed(self, values):
        """Gᵀ ``values`` (d P,) → (S,), a partial sum per row block and thread."""
        if self.cells_gradient_t is not None:
            return (self.cells_gradient_t @ values.reshape(-1, self.sets.n_controls)).ravel()
        return sum(thread_map(lambda block: block[1].T @ values[block[0]:block[0] + block[1].shape[0]],
                              self.row_blocks))

    def solve(self, rhs):
        """The least-squares step's solve, in slot order."""
        ordered = rhs[self.order]
        for positions, factor in self.factors:
            ordered[positions.T] = factor.solve(ordered[positions.T])
        out = np.empty_like(rhs)
        out[self.order] = ordered
        return out

    def project(self, slot_values, duals, tolerance=STEP_TOLERANCE, steps=STEP_NEWTON_STEPS):
        """Each vertex's slot values projected onto its constraints: (S,) weights, (N_in, d+1) duals, feasible.
        Within the iterations a few Newton steps each time suffice: the next projection starts where they ended."""
        values = self.padded.gather(slot_values)  # float64 rows, a fresh array
        padded = self.padded
        duals = np.zeros(padded.targets.shape) if duals is None else duals

        def block(rows):
            return project_rows(values[rows], padded.corners[rows], padded.targets[rows], duals[rows],
                                products=padded.products[rows], tolerance=tolerance, steps=steps)

        parts = thread_map(block, self.vertex_blocks)
        weights = np.concatenate([part[0] for part in parts])
        return (padded.scatter(weights), np.concatenate([part[1] for part in parts]),
                np.concatenate([part[2] for part in parts]))

    def release(self):
        """Drop the matrices, factors and padded rows (a layout being replaced keeps only its pairs and sets)."""
        self.gradient = self.row_blocks = self.factors = self.padded = None
        self.cells_gradient = self.cells_gradient_t = None

    def restore_rows(self, weights, rows):
        """(S,) weights with the given vertices' rows, whose projection missed round-off (a badly conditioned hull,
        as in a very thin cage), restored on their slots: the least-norm correction, else the nearest feasible
        weights (a linear program; the slots' hull holds the vertex, so one exists)."""
        weights = np.array(weights, dtype=float)
        padded_rows = np.maximum(self.padded.gather(weights)[rows], 0.0)  # padding slots → 0
        residual = np.abs(np.einsum("nk,nkm->nm", padded_rows, self.padded.corners[rows]) - self.padded.targets[rows])
        for vertex in rows[residual.max(axis=1) > EXACT]:
            slots = slice(self.sets.indptr[vertex], self.sets.indptr[vertex + 1])
            controls = self.padded.corners[vertex, :slots.stop - slots.start, 1:]
            position = self.padded.targets[vertex, 1:][None]
            row = restore_constraints(np.maximum(weights[slots], 0.0)[None], controls, position)
            unity, reproduction = constraint_residuals(row, controls, position)
            if unity[0] > EXACT or reproduction[0] > EXACT or (row < 0).any():
                row = nearest_feasible(np.maximum(weights[slots], 0.0)[None], controls, position)
            weights[slots] = row[0]
        return weights

    def pair_positions(self, other):
        """Where each of this layout's pairs sits in ``other``, -1 where ``other`` has no such pair."""
        n = self.sets.n_controls
        return key_positions(self.pair_cell * n + self.pair_control, other.pair_cell * n + other.pair_control)


def _cells_gradient(mesh, dtype):
    """The (d F, N_in) CSR matrix of interior vertex values → √|c| ∇ on every cell, rows component-major (row
    k F + f): on whole working sets, applied to the (N_in, n) block of the slots at once."""
    n_cells, d = len(mesh.cells), mesh.vertices.shape[1]
    position = mesh.interior_position[mesh.cells]
    cell, corner = np.nonzero(position >= 0)
    rows = (np.arange(d)[:, None] * n_cells + cell[None, :]).ravel()
    columns = np.tile(position[cell, corner], d)
    values = mesh.scaled_gradients[cell, corner, :].T.ravel().astype(dtype)
    return sp.csr_matrix((values, (rows, columns)), shape=(d * n_cells, len(mesh.interior)))


def _row_blocks(matrix, count):
    """(first row, rows) of ``matrix`` in ``count`` blocks, for the products' threads."""
    bounds = np.linspace(0, matrix.shape[0], count + 1).astype(int)
    blocks = []
    for start, stop in zip(bounds[:-1], bounds[1:]):  # views of the matrix's arrays, not copies
        first, last = matrix.indptr[start], matrix.indptr[stop]
        blocks.append((start, sp.csr_matrix((matrix.data[first:last], matrix.indices[first:last],
                                             matrix.indptr[start:stop + 1] - first), shape=(stop - start, matrix.shape[1]))))
    return blocks


def _gradient_matrix(scaled, pair_cell, corner_slot, n_slots, dtype, check):
    """The (d P, S) CSR matrix of slot values → √|c| ∇w on the pairs, rows component-major, from each cell's corner
    gradients (F, d+1, d), each pair's cell (P,) and corner slots (P, d+1), -1 where a corner holds no slot. Filled
    GRADIENT_CHUNK_PAIRS pairs at a time, ``check`` called between them."""
    n_pairs, d = len(pair_cell), scaled.shape[2]
    row_starts = np.r_[0, np.cumsum(np.count_nonzero(corner_slot >= 0, axis=1))]
    entries = int(row_starts[-1])
    index_type = np.int32 if d * entries < 2**31 else np.int64
    indptr = np.concatenate([row_starts[:-1] + k * entries for k in range(d)] + [[d * entries]]).astype(index_type)
    indices, data = np.empty(d * entries, dtype=index_type), np.empty(d * entries, dtype=dtype)
    for first in range(0, n_pairs, GRADIENT_CHUNK_PAIRS):
        check()
        chunk = corner_slot[first:first + GRADIENT_CHUNK_PAIRS]
        pair, corner = np.nonzero(chunk >= 0)  # row-major: each pair's corners in order
        cell, slot = pair_cell[first + pair], chunk[pair, corner]
        start, stop = row_starts[first], row_starts[first] + len(pair)
        for k in range(d):
            indices[k * entries + start:k * entries + stop] = slot
            data[k * entries + start:k * entries + stop] = scaled[cell, corner, k]
    return sp.csr_matrix((data, indices, indptr), shape=(d * n_pairs, n_slots))
