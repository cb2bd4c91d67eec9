"""The Euclidean projection of each vertex's row of weights onto its constraints.

    C_v = {w ≥ 0, Σ_i w_i = 1, Σ_i w_i c_i = x_v}   over the control points c_i in the vertex's working set

minimise ½|w − y|² over C_v has a (d+1)-dimensional dual: w(ν) = max(0, y + Aᵀν) with A = [1; c_1 … c_k], and ν
maximises φ(ν) = νᵀb − ½|w(ν)|², b = [1; x_v], whose gradient is b − A w(ν) and whose generalised Hessian is
−A D Aᵀ (D: the entries with w > 0). Semismooth Newton on ν, batched over the vertices as (N, d+1, d+1) systems,
with a Levenberg–Marquardt term (A D Aᵀ is singular where fewer than d+1 entries are positive) and a backtracking line
search on φ. Warm-started from the previous projection's ν it takes a few steps (bench/RESULTS.md, "The locality
solver"). The rows are padded to a common width: padding slots carry a far negative value and never enter.

Example
-------
>>> import numpy as np
>>> corners = np.array([[[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [1.0, 0.0, 1.0]]])  # [1, c_i]: a triangle in 2D
>>> w, nu, feasible = project_rows(np.array([[0.5, 0.5, 0.5]]), corners, np.array([[1.0, 0.25, 0.25]]))
>>> np.round(w, 12).tolist(), feasible.tolist()
([[0.5, 0.25, 0.25]], [True])
"""

import numpy as np

# Newton steps at most per projection; a converged vertex leaves the batch.
NEWTON_STEPS = 50
# A vertex is converged when |b − A w| is below this (its entries are weights and unit-frame coordinates), and
# below STEP_TOLERANCE within a solve's iterations (bench/RESULTS.md, "The locality solver").
RESIDUAL_TOLERANCE, STEP_TOLERANCE = 1e-15, 1e-10
# Halvings of a Newton step at most in the line search, and the residual below which it takes the full step.
LINE_SEARCH_STEPS, LINE_SEARCH_FROM = 30, 1e-6
# A batch is copied down to its unconverged rows once they are fewer than this share of it.
COMPACT_BELOW = 0.5
# What padding slots hold: far below any y + Aᵀν, so they stay 0.
PADDING_VALUE = -1e30


def project_rows(values, corners, targets, duals=None, steps=NEWTON_STEPS, products=None,
                 tolerance=RESIDUAL_TOLERANCE):
    """Project each row of ``values`` onto its vertex's constraint set.

    Parameters
    ----------
    values : (N, K) float array
        y, the rows to project (PADDING_VALUE in padding slots).
    corners : (N, K, m) float array
        [1, c_i] of each slot's control point, m = d + 1 (zeros in padding slots).
    targets : (N, m) float array
        b = [1, x_v].
    duals : (N, m) float array, optional
        A warm start for ν (the previous projection's); zeros otherwise.
    steps : int
    products : (N, K, m(m+1)/2) float array, optional
        :func:`corner_products` of ``corners``, when the caller keeps them from one projection to the next.
    tolerance : float
        |b − A w| at which a row is done (the iterations of a solve take a looser one than its output).

    Returns
    -------
    weights : (N, K) float array
        The projections, exactly 0 where inactive.
    duals : (N, m) float array
        ν at the end, to warm-start the next projection.
    feasible : (N,) bool array
        Whether the constraints were met to ``tolerance``; False where x_v lies outside the hull of the row's
        control points (the dual ascent then diverges) or the steps ran out.
    """
    nu = np.zeros(targets.shape) if duals is None else np.array(duals, dtype=float)
    if products is None:
        products = corner_products(corners)
    weights = np.empty_like(values)
    feasible = np.zeros(len(values), dtype=bool)
    pending = np.arange(len(values))
    batch = _Batch(values, corners, products, targets)  # the arrays themselves: copying costs a Newton step
    for step in range(steps + 1):
        shifted = batch.values + _apply(batch.corners, nu[pending])
        active = shifted > 0
        rows = np.where(active, shifted, 0.0)
        gradient = batch.targets - _apply_transposed(batch.corners, rows)
        size = np.sqrt(np.einsum("nj,nj->n", gradient, gradient))
        done = size <= tolerance
        weights[pending[done]] = rows[done]
        feasible[pending[done]] = True
        if step == steps:
            weights[pending[~done]] = rows[~done]
            break
        if done.all():
            break
        if np.count_nonzero(~done) < COMPACT_BELOW * len(pending):
            keep = ~done
            pending, active, rows, gradient, size = pending[keep], active[keep], rows[keep], gradient[keep], size[keep]
            batch = _Batch.of(values, corners, products, targets, pending)
            done = np.zeros(len(pending), dtype=bool)
        nu[pending] = _newton_step(batch, nu[pending], active, rows, gradient, size, done)
    return weights, nu, feasible


class _Batch:
    """The rows a Newton step works on: the whole arrays, or copies of some rows."""

    def __init__(self, values, corners, products, targets):
        self.values, self.corners, self.products, self.targets = values, corners, products, targets

    @classmethod
    def of(cls, values, corners, products, targets, rows):
        return cls(values[rows], corners[rows], products[rows], targets[rows])


def corner_products(corners):
    """(N, K, m(m+1)/2): the products a_i a_j (i ≥ j) of each slot's [1, c], whose masked sums make A D Aᵀ."""
    m = corners.shape[2]
    lower = [(i, j) for i in range(m) for j in range(i + 1)]
    return np.stack([corners[:, :, i] * corners[:, :, j] for i, j in lower], axis=2)


def _apply(corners, nu):
    """Aᵀν per slot: (N, K)."""
    return np.matmul(corners, nu[:, :, None])[:, :, 0]


def _apply_transposed(corners, rows):
    """A w per vertex: (N, m)."""
    return np.matmul(rows[:, None, :], corners)[:, 0, :]


def _newton_step(batch, nu, active, rows, gradient, size, done):
    """One guarded semismooth Newton step of the dual ascent on a batch; returns the new ν (the rows ``done`` keep
    theirs)."""
    values, corners, products, targets = batch.values, batch.corners, batch.products, batch.targets
    m = targets.shape[1]
    lower = np.matmul(active[:, None, :].astype(products.dtype), products)[:, 0, :]  # A D Aᵀ's lower triangle
    # Levenberg–Marquardt: a term that vanishes with the gradient keeps the step defined where A D Aᵀ is singular.
    regular = size + 1e-14 * (1.0 + lower[:, [i * (i + 1) // 2 + i for i in range(m)]].sum(axis=1))
    direction = _solve_spd(lower, regular, gradient)
    trial = nu + direction
    # Near the solution φ's changes fall below its round-off: there the full step is taken (Newton is exact once the
    # active set is right).
    searched = np.flatnonzero((size > LINE_SEARCH_FROM) & ~done)
    if len(searched):
        rows_of = batch if len(searched) == len(nu) else \
            _Batch(values[searched], corners[searched], None, targets[searched])
        _line_search(rows_of, searched, nu, trial, direction, rows[searched], gradient[searched])
    trial[done] = nu[done]
    return trial


def _line_search(batch, searched, nu, trial, direction, rows, gradient):
    """Backtracking (Armijo) on φ for the rows ``searched`` of ``trial`` (in place), ``batch`` holding just those
    rows; each halving recomputes only the rows still short."""
    value = _dual_value(nu[searched], rows, batch.targets)
    slope = np.einsum("nj,nj->n", gradient, direction[searched])
    step = np.ones(len(searched))
    short = np.arange(len(searched))
    for _ in range(LINE_SEARCH_STEPS):
        every = len(short) == len(searched)  # the first pass reads the batch without copying it
        values, corners, targets = (batch.values, batch.corners, batch.targets) if every else \
            (batch.values[short], batch.corners[short], batch.targets[short])
        moved = trial[searched[short]]
        trial_rows = np.maximum(values + _apply(corners, moved), 0.0)
        still = _dual_value(moved, trial_rows, targets) < value[short] + 1e-4 * step[short] * slope[short]
        if not still.any():
            break
        short = short[still]
        step[short] *= 0.5
        trial[searched[short]] = nu[searched[short]] + step[short, None] * direction[searched[short]]


def _solve_spd(lower, regular, rhs):
    """Solve (L + μ I) x = rhs per row, L given by its lower triangle (N, m(m+1)/2) row by row: a Cholesky
    factorisation written out over the batch (numpy's batched solve is several times slower for m = 3, 4)."""
    m = rhs.shape[1]
    entry = {}
    index = 0
    for i in range(m):
        for j in range(i + 1):
            entry[i, j] = lower[:, index] + (regular if i == j else 0.0)
            index += 1
    factor = {}
    for j in range(m):
        diagonal = entry[j, j] - sum(factor[j, k] ** 2 for k in range(j))
        factor[j, j] = np.sqrt(np.maximum(diagonal, 1e-300))
        for i in range(j + 1, m):
            factor[i, j] = (entry[i, j] - sum(factor[i, k] * factor[j, k] for k in range(j))) / factor[j, j]
    forward = []
    for i in range(m):
        forward.append((rhs[:, i] - sum(factor[i, k] * forward[k] for k in range(i))) / factor[i, i])
    solution = [None] * m
    for i in reversed(range(m)):
        solution[i] = (forward[i] - sum(factor[k, i] * solution[k] for k in range(i + 1, m))) / factor[i, i]
    return np.stack(solution, axis=1)


def _dual_value(nu, weights, targets):
    """φ(ν) = νᵀb − ½|w(ν)|² per row (the constant ½|y|² left out)."""
    return np.einsum("nj,nj->n", nu, targets) - 0.5 * np.einsum("nk,nk->n", weights, weights)
