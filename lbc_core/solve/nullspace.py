"""The dense splitting's problem and step: the equality constraints (partition of unity, reproduction) eliminated by a
dense orthonormal basis M of their null space, Z = Y M + H, and one Douglas-Rachford step of ADMM on X = ∇Z and
W = Z (:class:`DenseSplitting`), with the gradient products done in chunks of cells, one per thread. The loop around
it is :mod:`lbc_core.solve.dense`.
"""

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import CageError
from ..kernel import fem
from ..kernel.factor import Factor
from ..kernel.parallel import CHUNKS_PER_ROUND, thread_map, worker_count
from .shrink import scaled_tv, shrink_factor, weighted_shrink_factors


class DenseProblem:
    """The fixed data of one solve, on the unit-diagonal cage, in measure-scaled variables.

    X̃ = √|c| ∇w per cell and W̃ = √(β m_v) w per vertex, so the penalty's weighted norms become Euclidean. Gradient
    rows are component-major (row k F + c is component k on cell c): a (d F, n) array reshapes to (d, F, n), whose
    (F, n) slabs the per-cell work reads contiguously.
    """

    def __init__(self, vertices, cells, boundary_vertices, boundary_weights, controls, interior, beta, dtype,
                 progress, stretch=None):
        d = vertices.shape[1]
        # In a stretched frame (:class:`_Stretch`) the total variation's norm is weighted per axis.
        self.axis_scale = None if stretch is None else stretch.axis_scale.astype(dtype)
        self.tv_scale = 1.0 if stretch is None else stretch.tv_scale
        gradients, measures = fem.cell_gradients(vertices, cells)
        self.d = d
        self.n_cells = len(measures)
        self.n_interior = len(interior)
        self.interior = interior
        self.measures = measures
        self.beta = beta
        # Rows component-major, scaled by √|c|; columns split into the unknowns and the fixed boundary.
        values = np.transpose(gradients * np.sqrt(measures)[:, None, None], (2, 0, 1))  # (d, F, d+1)
        interior_index = _renumber(interior, len(vertices))[cells]  # (F, d+1), -1 on the boundary
        boundary_index = _renumber(boundary_vertices, len(vertices))[cells]
        self.G64 = _rows_on_columns(values, interior_index, len(interior))  # (d F, N_in)
        progress.check()
        self.E64 = _rows_on_columns(values, boundary_index, len(boundary_vertices)) @ boundary_weights  # (d F, n)
        progress.check()
        self.G = self.G64.astype(dtype)
        self.GT = self.G.T.tocsr()
        self.E = self.E64.astype(dtype)
        progress.check()
        mass = fem.lumped_mass(cells, measures, len(vertices))[interior]
        self.sqrt_mass = np.sqrt(beta * mass)[:, None].astype(dtype)  # (N_in, 1)
        # Equality constraints z K = [x, 1] per vertex, K = [C, 1] (n, d+1): Z = Y M + H.
        K = np.c_[controls, np.ones(len(controls))]
        _, singular, vt = np.linalg.svd(K.T)
        rank = int(np.sum(singular > 1e-12 * singular[0]))
        if rank < d + 1:
            raise CageError("the control points are affinely dependent (all on a line or plane): the cage is flat")
        self.M = vt[rank:].astype(dtype)  # (n - d - 1, n), orthonormal rows
        self.MT = np.ascontiguousarray(self.M.T)
        self.H = (np.c_[vertices[interior], np.ones(len(interior))] @ np.linalg.pinv(K)).astype(dtype)  # (N_in, n)
        progress.check()
        # The Y-step matrix, stiffness + β mass, as lower-triangle triplets from each cell's Gᵀ G block, corner pair
        # by corner pair on contiguous (F,) arrays.
        by_corner = np.ascontiguousarray(np.transpose(values, (2, 0, 1)))  # (d+1, d, F)
        corner_index = np.ascontiguousarray(interior_index.T)  # (d+1, F)
        entries, rows, cols = [beta * mass], [np.arange(len(interior))], [np.arange(len(interior))]
        for i in range(d + 1):
            for j in range(i + 1):
                kept = (corner_index[j] >= 0) & (corner_index[i] >= 0)
                entries.append(np.einsum("kf,kf->f", by_corner[i], by_corner[j])[kept])
                row, col = corner_index[i][kept], corner_index[j][kept]  # lower triangle: the larger is the row
                rows.append(np.maximum(row, col))
                cols.append(np.minimum(row, col))
        system_lower = sp.coo_matrix((np.concatenate(entries), (np.concatenate(rows), np.concatenate(cols))),
                                     shape=(len(interior), len(interior)))
        progress.check()
        self.factor = Factor(system_lower, dtype)  # one uninterruptible call: 0.3-0.6 s at 64k tetrahedra
        progress.check()
        # √|c| of each cell, to turn scaled gradients back into ω |c| |∇w|.
        self.sqrt_cell = np.sqrt(measures)[:, None]

    def objective(self, interior_weights, tv_weights, check):
        """Σ ω |c| |∇w| (float64, unit-diagonal cage) of interior weights (N_in, n) with the boundary values, over
        slices of NORM_SLICE gradient entries with ``check`` called between."""
        n = interior_weights.shape[1]
        per_slice = max(1, NORM_SLICE // (self.d * n))
        total = 0.0
        for start in range(0, self.n_cells, per_slice):
            check()
            cells = np.arange(start, min(start + per_slice, self.n_cells))
            rows = (np.arange(self.d)[:, None] * self.n_cells + cells).ravel()  # component-major
            gradient = (self.G64[rows] @ interior_weights + self.E64[rows]).reshape(self.d, len(cells), n)
            total += scaled_tv(gradient, tv_weights[cells], self.sqrt_cell[cells], self.axis_scale)
        return total * self.tv_scale


def _renumber(subset, n):
    """(n,) int array: position of each index in ``subset``, -1 for those not in it."""
    positions = np.full(n, -1)
    positions[subset] = np.arange(len(subset))
    return positions


def _rows_on_columns(values, columns, n_columns):
    """A CSR matrix from per-cell row entries, keeping the entries whose column is not -1.

    Parameters
    ----------
    values : (d, F, k) float array
        Entries of row (component c, cell f): ``values[c, f]``.
    columns : (F, k) int array
        Their columns, shared by the d rows of a cell; -1 drops an entry.
    n_columns : int

    Returns
    -------
    (d F, n_columns) scipy.sparse.csr_matrix, rows component-major
    """
    columns = np.broadcast_to(columns, values.shape).reshape(-1, values.shape[-1])
    kept = columns >= 0
    counts = sum(kept[:, corner].astype(np.int64) for corner in range(kept.shape[1]))  # a row sum over 3-4 entries
    indptr = np.r_[0, np.cumsum(counts)]
    return sp.csr_matrix((values.reshape(columns.shape)[kept], columns[kept], indptr),
                         shape=(len(columns), n_columns))


class DenseSplitting:
    """One over-relaxed ADMM iteration as a Douglas-Rachford map on the state v = (X̃ + Ũ, W̃ + Ṽ).

    X̃ = shrink(v_X) and W̃ = clip(v_W) are the split variables and v minus them the scaled duals, so one array of
    the size of (X, W) carries the whole iteration. Its fixed-point residual is the primal residual and never grows
    for plain steps, which is what the Anderson safeguard relies on.
    """

    def __init__(self, problem, tv_weights, epsilon, alpha, rho, check):
        p = problem
        self.p, self.epsilon, self.alpha = p, epsilon, alpha
        # Called between the parts of a step: one step of a large problem can take a second.
        self.check = check
        n = tv_weights.shape[1]
        self.size_x = p.n_cells * p.d * n
        self.shape_x, self.shape_w = (p.d, p.n_cells, n), (p.n_interior, n)
        self.tv_weights = tv_weights * p.tv_scale
        # In scaled variables the shrink threshold of cell c is √|c| ω / ρ; the clip bound of vertex v is √(β m_v).
        self.thresholds = (p.sqrt_cell * self.tv_weights / rho).astype(p.G.dtype)
        self.penalty = rho
        # X̃ = v_X · shrink: one factor per cell and coordinate (1, F, n), or per component in a stretched frame.
        self.shape_shrink = (1 if p.axis_scale is None else p.d,) + self.shape_x[1:]
        self.secular_roots = None if p.axis_scale is None else np.zeros(self.shape_x[1:], dtype=p.G.dtype)
        self.boundary_part = p.E.reshape(self.shape_x)
        self.boundary_load = p.GT @ p.E  # (N_in, n): Gᵀ E, so that the reflection need not subtract E each step
        check()
        self.chunks = _cell_chunks(p, self.size_x)
        self.threads = worker_count()

    def split(self, state):
        """Views of a state as v_X (d, F, n) and v_W (N_in, n)."""
        return state[:self.size_x].reshape(self.shape_x), state[self.size_x:].reshape(self.shape_w)

    def initial_state(self):
        """The harmonic coordinates (the Y-step with X̃ = W̃ = 0) with zero duals."""
        p = self.p
        Z = self.solve(-(p.GT @ p.E) @ p.MT) @ p.M + p.H
        state = np.empty(self.size_x + Z.size, dtype=Z.dtype)
        v_x, v_w = self.split(state)

        def gradient(chunk):
            np.add((chunk.G @ Z).reshape(v_x[:, chunk.cells].shape), self.boundary_part[:, chunk.cells],
                   out=v_x[:, chunk.cells])

        self.in_rounds(gradient)
        v_w[:] = p.sqrt_mass * np.clip(Z, 0.0, 1.0)
        return state

    def rescale_penalty(self, state, factor):
        """Change the penalty to ``factor`` times itself, in place on ``state``: the split variables stay, the
        scaled duals (v minus them) shrink by ``factor``, and so do the shrink thresholds. The Y-step's matrix does
        not depend on the penalty (both blocks are scaled alike), so nothing is factorised again."""
        v_x, v_w = self.split(state)
        old_thresholds = self.thresholds
        self.thresholds = (old_thresholds / factor).astype(old_thresholds.dtype)
        self.penalty *= factor

        def rescale(chunk):
            cells = chunk.cells
            kept = self.shrink_factors(v_x[:, cells], old_thresholds[cells])  # X̃ = v_X · kept
            v_x[:, cells] *= kept + (1.0 - kept) / factor

        self.in_rounds(rescale)
        W = self.clipped(v_w)
        v_w -= W
        v_w /= factor
        v_w += W

    def clipped(self, v_w):
        """W̃ = v_W clipped to [0, √(β m_v)] per interior vertex (np.clip with a broadcast bound is several times
        slower)."""
        W = np.maximum(v_w, 0.0)
        return np.minimum(W, self.p.sqrt_mass, out=W)

    def shrink_factors(self, values, thresholds, cells=None):
        """The prox of the cells' total variation as factors of ``values`` (d, F', n): (1, F', n), or (d, F', n) with
        the norm weighted per axis. With ``cells`` (the steps' own calls) the weighted prox starts its Newton steps
        from the roots they found on those cells the step before."""
        if self.p.axis_scale is None:
            return shrink_factor(values, thresholds, self.epsilon)[None]
        guess = None if cells is None else self.secular_roots[cells]
        factors, roots = weighted_shrink_factors(values, thresholds, self.p.axis_scale, guess)
        if cells is not None:
            self.secular_roots[cells] = roots
        return factors

    def solve(self, rhs):
        """The Y-step's factorised solve, SOLVE_COLUMNS right-hand sides at a time with cancel checks between (as
        fast as all at once: 0.11-0.16 s for 162 columns on 64k tetrahedra)."""
        out = np.empty_like(rhs)
        for start in range(0, rhs.shape[1], SOLVE_COLUMNS):
            self.check()
            out[:, start:start + SOLVE_COLUMNS] = self.p.factor.solve(rhs[:, start:start + SOLVE_COLUMNS])
        return out

    def in_rounds(self, function):
        """``function`` over the chunks of cells, one chunk per thread at a time, checking for cancel between."""
        results = []
        for start in range(0, len(self.chunks), self.threads):
            self.check()
            results += thread_map(function, self.chunks[start:start + self.threads])
        return results

    def __call__(self, state):
        """Return the next state and this step's :class:`Step` (for residuals).

        X̃ is never formed: it is v_X times the per-cell shrink factor, which the reflection and the update fold into
        their products. The per-cell work runs on chunks of cells in threads (numpy and scipy release the GIL)
        around the one factorised solve.
        """
        p, alpha, E = self.p, self.alpha, self.boundary_part
        v_x, v_w = self.split(state)
        new_state = np.empty_like(state)
        new_x, new_w = self.split(new_state)
        shrink = np.empty(self.shape_shrink, dtype=state.dtype)  # X̃ = v_X · shrink
        gradient = np.empty_like(v_x)

        def shrink_and_reflect(chunk):
            cells = chunk.cells
            shrink[:, cells] = self.shrink_factors(v_x[:, cells], self.thresholds[cells], cells)
            reflected = v_x[:, cells] * (2.0 * shrink[:, cells] - 1.0)  # 2 X̃ - v_X (E is subtracted after Gᵀ)
            return chunk.GT @ reflected.reshape(-1, reflected.shape[2])

        def update(chunk):
            cells = chunk.cells
            g = gradient[:, cells]
            np.add((chunk.G @ Z).reshape(g.shape), E[:, cells], out=g)
            # v_X + α (g - X̃), with X̃ = v_X · shrink
            np.multiply(v_x[:, cells], 1.0 - alpha * shrink[:, cells], out=new_x[:, cells])
            new_x[:, cells] += alpha * g

        W = self.clipped(v_w)
        reflected_w = 2.0 * W
        reflected_w -= v_w
        rhs = sum(self.in_rounds(shrink_and_reflect))
        rhs -= self.boundary_load
        rhs += p.sqrt_mass * reflected_w
        Z = self.solve(rhs @ p.MT) @ p.M
        Z += p.H
        self.in_rounds(update)
        np.multiply(p.sqrt_mass, Z, out=new_w)
        new_w -= W
        new_w *= alpha
        new_w += v_w
        return new_state, Step(v_x, v_w, shrink, W, Z, gradient)

    def objective(self, gradient):
        """Σ ω |c| |∇w| on the unit-diagonal cage, from a scaled gradient (d, F, n)."""
        return scaled_tv(gradient, self.tv_weights, self.p.sqrt_cell, self.p.axis_scale)


@dataclass
class Step:
    """One Douglas-Rachford step: its input state (v_X, v_W), the split variables X̃ = v_X · shrink and W̃, the
    iterate Z and its scaled gradient (d, F, n), boundary part included."""

    v_x: np.ndarray
    v_w: np.ndarray
    shrink: np.ndarray
    W: np.ndarray
    Z: np.ndarray
    gradient: np.ndarray

    @property
    def X(self):
        return self.v_x * self.shrink


@dataclass
class _Chunk:
    """A range of cells, with its rows of the gradient operator (component-major), processed by one thread."""

    cells: slice
    G: sp.csr_matrix
    GT: sp.csr_matrix


# Below this many entries in the X block, threads cost more than they save (2D problems of the paper's size).
PARALLEL_MIN_ENTRIES = 500_000
# At most this many entries of the X block per chunk: a chunk's share of a step then takes about 20-50 ms, and cancel
# is checked between rounds of chunks (one step of 64k tetrahedra and 168 control points takes 0.6 s or more).
ENTRIES_PER_CHUNK = 4_000_000
# Right-hand sides per call of the Y-step's solve, and entries per slice of a state's norm: cancel is checked between.
SOLVE_COLUMNS = 32
NORM_SLICE = 4_000_000


def _cell_chunks(problem, size_x):
    """Split the cells into CHUNKS_PER_ROUND chunks when the problem is large enough to gain from threads, and into
    more (a multiple of it) when a chunk would exceed ENTRIES_PER_CHUNK: by the problem's size alone, never the
    cores, since the step sums one partial product per chunk and a sum's rounding follows its terms."""
    if size_x < PARALLEL_MIN_ENTRIES:
        count = 1
    else:
        count = CHUNKS_PER_ROUND * -(-size_x // (ENTRIES_PER_CHUNK * CHUNKS_PER_ROUND))
    if count == 1:
        return [_Chunk(slice(0, problem.n_cells), problem.G, problem.GT)]
    bounds = np.linspace(0, problem.n_cells, count + 1).astype(int)
    chunks = []
    for start, stop in zip(bounds[:-1], bounds[1:]):
        rows = (np.arange(problem.d)[:, None] * problem.n_cells + np.arange(start, stop)[None, :]).ravel()
        G = problem.G[rows]
        chunks.append(_Chunk(slice(start, stop), G, G.T.tocsr()))
    return chunks
