"""Partition of unity and reproduction: the affine constraints every set of coordinates meets, and the projections
that restore them.

Per point, the weights w on a support S are corrected by the least-norm change that makes Σ w = 1 and Σ w c = x;
weights the correction pushes below zero are removed from S and the correction repeated. The solver projects its
output this way (:func:`project_onto_constraints`), the reduction its thresholded weights, the add-on its capped
slots. Rows travel as padded (m, K) arrays of values and column indices (:func:`padded_rows`).
"""

import numpy as np
import scipy.sparse as sp


def project_onto_constraints(clamped, unclamped, controls, positions, check=None):
    """The solver's output: ``clamped``'s exact zeros kept, partition of unity and reproduction restored on its
    support.

    A vertex whose support is too small to reproduce it (three control points for a point off their plane) gets
    ``unclamped``'s next largest weights added, largest first, until it is; where even all of ``unclamped``'s positive
    weights cannot, it gets the non-negative weights nearest to ``clamped`` that do (:func:`nearest_feasible`).

    Parameters
    ----------
    clamped : (m, n) float array
        Weights clamped to [0, 1] (the solver's split variable W).
    unclamped : (m, n) float array
        The iterate the constraints hold on (the solver's Z), where a support must grow.
    controls : (n, d) float array
    positions : (m, d) float array
    check : callable, optional
        Called between rounds of corrections (it raises to cancel).

    Returns
    -------
    (m, n) float array
    """
    on_support = restore_constraints(clamped, controls, positions, check=check)
    unity, reproduction = constraint_residuals(on_support, controls, positions)
    failed = (unity > 1e-12) | (reproduction > 1e-12) | (on_support < 0).any(axis=1)
    if failed.any():
        candidates = np.maximum(unclamped[failed], 0.0)
        keep = np.count_nonzero(clamped[failed] > 0, axis=1)
        grown, met = grow_support(sp.csr_matrix(candidates), controls, positions[failed], keep, tolerance=1e-12,
                                  check=check)
        grown = grown.toarray()
        if not met.all():
            grown[~met] = nearest_feasible(clamped[failed][~met], controls, positions[failed][~met], check)
        on_support[failed] = grown
    return on_support


def nearest_feasible(weights, controls, positions, check=None):
    """Non-negative weights that meet partition of unity and reproduction, nearest to ``weights`` in the L1 norm.

    Growing a support from the largest candidates first can end on a support that cannot reproduce the point, when
    the weights it needs are where the candidates are zero: a vertex 1e-4 of the diagonal off the plane of its three
    control points needs a little weight off that plane (measured on the gargoyle's cage L10 at 3000 cells).
    A small linear program per row finds it, changing as few weights as it can; the constraints are then restored
    on its support to round-off.

    Parameters
    ----------
    weights : (m, n) float array, non-negative
    controls : (n, d) float array
    positions : (m, d) float array, inside the controls' convex hull
    check : callable, optional
        Called before each row (it raises to cancel).

    Returns
    -------
    (m, n) float array; a row whose point lies outside the controls' hull is returned as given.
    """
    from scipy.optimize import linprog  # here: importing it costs the extension's start 60 ms, for a rare path

    n = len(controls)
    affine = np.c_[controls, np.ones(n)].T  # (d+1, n)
    # Variables [w, s], both non-negative: minimise Σ s with |w - weights| ≤ s and affine @ w = [x, 1].
    bound_rows = sp.bmat([[sp.eye(n), -sp.eye(n)], [-sp.eye(n), -sp.eye(n)]], format="csr")
    equality = sp.hstack([sp.csr_matrix(affine), sp.csr_matrix((len(affine), n))], format="csr")
    cost = np.r_[np.zeros(n), np.ones(n)]
    result = np.array(weights, dtype=float)
    for row, (given, x) in enumerate(zip(weights, positions)):
        if check is not None:
            check()
        solution = linprog(cost, A_ub=bound_rows, b_ub=np.r_[given, -given], A_eq=equality, b_eq=np.r_[x, 1.0],
                           bounds=(0, None), method="highs")
        if solution.status == 0:
            result[row] = restore_constraints(np.maximum(solution.x[None, :n], 0.0), controls, x[None])[0]
    return result


def restore_constraints(weights, controls, positions, columns=None, rounds=20, check=None):
    """Correct weights on their support so that they sum to 1, reproduce ``positions`` and are non-negative.

    Parameters
    ----------
    weights : (m, K) float array
        Each point's weights on its support (K slots; unused slots hold 0 and column index 0 with ``valid`` false).
    controls : (n, d) float array
        Control points.
    positions : (m, d) float array
        Positions the weights must reproduce.
    columns : (m, K) int array, optional
        The control point of each slot; None means K = n and slot j is control point j.
    rounds : int
        Correct-and-clamp rounds; corrections are small, so one or two usually suffice.
    check : callable, optional
        Called before each round (it raises to cancel).

    Returns
    -------
    (m, K) float array; entries that were 0 stay 0. Rows that cannot be corrected on their support are returned
    as given with negatives clamped and renormalised (reported by :func:`constraint_residuals`).
    """
    weights = np.array(weights, dtype=float)
    m, K = weights.shape
    d = controls.shape[1]
    # Affine rows a_j = [c_j, 1]; targets t = [x, 1]. Per point: A (K, d+1) its slots' rows; the correction of
    # w on its support S is A_S (A_Sᵀ A_S)⁻¹ (t - Aᵀw).
    affine_rows = np.c_[controls, np.ones(len(controls))]  # (n, d+1)
    if columns is None:
        # Every point has the same slots: the batched products become plain matrix products.
        outer_products = (affine_rows[:, :, None] * affine_rows[:, None, :]).reshape(K, -1)

        def reproduced(w):
            return w @ affine_rows

        def gram_on(support):
            return (support.astype(float) @ outer_products).reshape(m, d + 1, d + 1)

        def spread(correction, support):
            return support * (correction @ affine_rows.T)

        solve = _solve_each
    else:
        reproduced, gram_on, spread = _slot_products(controls, columns)
        solve = solve_symmetric
    target = np.c_[positions, np.ones(m)]
    support = weights > 0
    weights = np.where(support, weights, 0.0)
    for _ in range(rounds):
        if check is not None:
            check()
        residual = target - reproduced(weights)
        gram = gram_on(support)
        # A tiny ridge keeps supports that cannot span the affine constraints from blowing up.
        ridge = 1e-14 * np.trace(gram, axis1=1, axis2=2)[:, None, None] * np.eye(d + 1)
        weights += spread(solve(gram + ridge, residual), support)
        negative = weights < 0
        if not negative.any():
            break
        support &= ~negative
        weights[negative] = 0.0
    return weights


def _solve_each(matrices, vectors):
    return np.linalg.solve(matrices, vectors[:, :, None])[:, :, 0]


def _slot_products(controls, columns):
    """:func:`restore_constraints`' products for points whose K slots hold the controls ``columns`` (m, K): sums of
    products of one (m, K) array per axis, not batched products of (m, K, d+1) arrays (several times as fast;
    bench/RESULTS.md, "The bind outside the solve, cheaper"). Returns (reproduced, gram_on, spread)."""
    d = controls.shape[1]
    axes = [np.ascontiguousarray(controls[:, a])[columns] for a in range(d)]  # each (m, K)

    def reproduced(w):
        return np.column_stack([np.einsum("mk,mk->m", w, axis) for axis in axes] + [w.sum(axis=1)])

    def gram_on(support):
        inside = support.astype(float)
        gram = np.empty((len(inside), d + 1, d + 1))
        gram[:, d, d] = inside.sum(axis=1)
        for a in range(d):
            weighted = inside * axes[a]
            gram[:, a, d] = gram[:, d, a] = weighted.sum(axis=1)
            for b in range(a, d):
                gram[:, a, b] = gram[:, b, a] = np.einsum("mk,mk->m", weighted, axes[b])
        return gram

    def spread(correction, support):
        change = np.repeat(correction[:, d:], support.shape[1], axis=1)
        for a in range(d):
            change += axes[a] * correction[:, a, None]
        return support * change

    return reproduced, gram_on, spread


def constraint_residuals(weights, controls, positions, columns=None):
    """Largest violation of partition of unity and of reproduction per point.

    Parameters
    ----------
    weights : (m, K) float array
    controls : (n, d) float array
    positions : (m, d) float array
    columns : (m, K) int array, optional (None: K = n)

    Returns
    -------
    unity : (m,) float array, |Σ w - 1|
    reproduction : (m,) float array, |Σ w c - x| in the units of ``positions``
    """
    unity = np.abs(weights.sum(axis=1) - 1.0)
    reproduced = weights @ controls if columns is None else (weights[:, None, :] @ controls[columns])[:, 0]
    reproduction = np.linalg.norm(reproduced - positions, axis=1)
    return unity, reproduction


def restore_and_check(values, columns, controls, positions, tolerance, check=None):
    """Padded rows corrected by :func:`restore_constraints`, and which of them meet the constraints: (m, K) float
    array, (m,) bool array (unity within 1e-9, reproduction within ``tolerance``, non-negative)."""
    corrected = restore_constraints(values, controls, positions, columns, check=check)
    unity, reproduction = constraint_residuals(corrected, controls, positions, columns)
    return corrected, (unity <= 1e-9) & (reproduction <= tolerance) & (corrected >= 0).all(axis=1)


def grow_support(full, controls, positions, keep, tolerance, check=None):
    """Weights on each row's ``keep`` largest entries, plus the next largest, 1, 2, 4, ... at a time, until the
    constraints can be restored on them exactly.

    Parameters
    ----------
    full : (m, n) scipy.sparse matrix
        Non-negative candidate weights.
    controls : (n, d) float array
    positions : (m, d) float array
    keep : (m,) int array
        How many of each row's largest entries to start from.
    tolerance : float
        Largest reproduction error accepted, in the units of ``positions``.
    check : callable, optional
        Called between rounds of corrections (it raises to cancel).

    Returns
    -------
    reduced : (m, n) scipy.sparse.csr_matrix
    met : (m,) bool array
        Rows that meet the constraints; the others got as close as their whole support allows.
    """
    n = controls.shape[0]
    values, columns = padded_rows(full)
    order = np.argsort(-values, axis=1)
    values = np.take_along_axis(values, order, axis=1)
    columns = np.take_along_axis(columns, order, axis=1)
    reduced = sp.csr_matrix(full.shape)
    met = np.zeros(full.shape[0], dtype=bool)
    pending = np.arange(full.shape[0])
    extra = 1
    while len(pending):
        size = np.minimum(keep[pending] + extra, values.shape[1])
        slots = np.where(np.arange(values.shape[1]) < size[:, None], values[pending], 0.0)
        corrected, done = restore_and_check(slots, columns[pending], controls, positions[pending], tolerance, check)
        met[pending[done]] = True
        done |= size >= values.shape[1]  # the full support: nothing more to add
        reduced = scatter_rows(reduced, pending[done], csr_from_padded(corrected[done], columns[pending][done], n))
        pending = pending[~done]
        extra *= 2
    return reduced, met


def scatter_rows(matrix, rows, values):
    """``matrix``, whose given rows are empty, with those rows filled from ``values`` (CSR, same column count)."""
    placement = sp.csr_matrix((np.ones(len(rows)), (rows, np.arange(len(rows)))), shape=(matrix.shape[0], len(rows)))
    return (matrix + placement @ values).tocsr()


def padded_rows(matrix):
    """CSR rows as (m, K) arrays of values and column indices, K = the largest row length."""
    matrix = sp.csr_matrix(matrix)
    lengths = np.diff(matrix.indptr)
    K = max(int(lengths.max(initial=0)), 1)
    m = matrix.shape[0]
    slot = np.arange(matrix.nnz) - np.repeat(matrix.indptr[:-1], lengths)
    row = np.repeat(np.arange(m), lengths)
    values = np.zeros((m, K))
    columns = np.zeros((m, K), dtype=np.int64)
    values[row, slot] = matrix.data
    columns[row, slot] = matrix.indices
    return values, columns


def csr_from_padded(values, columns, n):
    """The (m, n) CSR matrix of padded rows (:func:`padded_rows`); zeros are dropped. A row's columns are distinct
    where its values are not 0, so the rows are read off directly (no sum of duplicates), then sorted."""
    m, K = values.shape
    present = values != 0
    indptr = np.zeros(m + 1, dtype=np.int64)
    np.cumsum(np.count_nonzero(present, axis=1), out=indptr[1:])
    matrix = sp.csr_matrix((values[present], columns[present], indptr), shape=(m, n))
    matrix.sort_indices()
    return matrix


def alike_lengths(counts, fewest):
    """Rows (indices into ``counts``, their lengths) in groups of alike lengths, to pad each group to its own
    longest row, not every row to the longest: up to 8, then up to a third more than the group before (12, 16, 21,
    28, ...); a group of fewer than ``fewest`` rows joins the next longer one.

    >>> [rows.tolist() for rows in alike_lengths(np.array([3, 20, 5, 9]), 1)]
    [[0, 2], [3], [1]]
    """
    bounds = [8]
    while bounds[-1] < counts.max(initial=0):
        bounds.append(bounds[-1] + max(bounds[-1] // 3, 4))
    group = np.searchsorted(bounds, counts)
    groups, pending = [], np.zeros(0, dtype=np.int64)
    for number in range(len(bounds)):
        pending = np.concatenate([pending, np.flatnonzero(group == number)])
        if len(pending) >= fewest or number == len(bounds) - 1:
            groups.append(pending)
            pending = np.zeros(0, dtype=np.int64)
    return [rows for rows in groups if len(rows)]


def solve_symmetric(matrices, vectors):
    """x with A x = b for each small symmetric positive definite A: an LDLᵀ factorisation without pivoting,
    vectorised over the batch (a few dozen array operations, not one LAPACK call per matrix: several times as fast
    for 4 × 4 matrices); a matrix with a pivot that is not positive is solved by ``np.linalg.solve`` instead.

    Parameters
    ----------
    matrices : (m, D, D) float array
    vectors : (m, D) float array

    Returns
    -------
    (m, D) float array
    """
    m, size, _ = matrices.shape
    entries = np.moveaxis(matrices, 0, -1)  # (D, D, m): each entry one contiguous-enough vector over the batch
    lower = np.zeros((size, size, m))
    pivots = np.empty((size, m))
    for j in range(size):
        pivots[j] = entries[j, j] - sum(lower[j, k] ** 2 * pivots[k] for k in range(j))
        for i in range(j + 1, size):
            lower[i, j] = (entries[i, j] - sum(lower[i, k] * lower[j, k] * pivots[k] for k in range(j))) / pivots[j]
    solution = np.empty((size, m))
    for i in range(size):
        solution[i] = vectors[:, i] - sum(lower[i, k] * solution[k] for k in range(i))
    solution /= pivots
    for i in reversed(range(size)):
        solution[i] -= sum(lower[k, i] * solution[k] for k in range(i + 1, size))
    solution = solution.T.copy()
    failed = np.flatnonzero(~(pivots > 0).all(axis=0) | ~np.isfinite(solution).all(axis=1))
    if len(failed):
        solution[failed] = np.linalg.solve(matrices[failed], vectors[failed][:, :, None])[:, :, 0]
    return solution
