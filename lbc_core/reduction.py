"""Sparse, reduced coordinates that keep partition of unity, reproduction and non-negativity exactly.

Dropping small weights (the paper's reduction) breaks Σ w = 1 and Σ w c = x. Here each point's remaining weights get
the least-norm correction that restores both on its support; weights the correction pushes below zero are removed
and the correction repeated. Where a support is too small to reproduce the point, the point keeps its full support.
"""

import numpy as np
import scipy.sparse as sp


def restore_constraints(weights, controls, positions, columns=None, rounds=20):
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

    Returns
    -------
    (m, K) float array; entries that were 0 stay 0. Rows that cannot be corrected on their support are returned
    as given with negatives clamped and renormalised (reported by :func:`constraint_residuals`).
    """
    weights = np.array(weights, dtype=float)
    m, K = weights.shape
    d = controls.shape[1]
    if columns is None:
        columns = np.broadcast_to(np.arange(K), (m, K))
    # Affine rows a_j = [c_j, 1]; targets t = [x, 1].
    affine = np.c_[controls, np.ones(len(controls))][columns]  # (m, K, d+1)
    target = np.c_[positions, np.ones(m)]
    support = weights > 0
    weights = np.where(support, weights, 0.0)
    for _ in range(rounds):
        residual = target - np.einsum("mk,mkj->mj", weights, affine)
        active = support[:, :, None] * affine
        gram = np.einsum("mki,mkj->mij", active, affine)
        # A tiny ridge keeps supports that cannot span the affine constraints from blowing up.
        ridge = 1e-14 * np.trace(gram, axis1=1, axis2=2)[:, None, None] * np.eye(d + 1)
        correction = np.linalg.solve(gram + ridge, residual[:, :, None])[:, :, 0]
        weights += np.einsum("mkj,mj->mk", active, correction)
        negative = weights < 0
        if not negative.any():
            break
        support &= ~negative
        weights[negative] = 0.0
    return weights


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
    m, K = weights.shape
    if columns is None:
        columns = np.broadcast_to(np.arange(K), (m, K))
    unity = np.abs(weights.sum(axis=1) - 1.0)
    reproduction = np.linalg.norm(np.einsum("mk,mkd->md", weights, controls[columns]) - positions, axis=1)
    return unity, reproduction


def reduce_weights(weights, controls, positions, threshold, tolerance):
    """Drop weights below ``threshold`` and restore the constraints on what remains.

    A point whose reduced support cannot meet the constraints (it lies outside the hull of its remaining control
    points, e.g. just off a cage face) gets its largest dropped weights back, one, two, four, ... at a time, until it
    can.

    Parameters
    ----------
    weights : (m, n) scipy.sparse matrix
        Full coordinates of m points (non-negative, satisfying the constraints).
    controls : (n, d) float array
    positions : (m, d) float array
        The positions the weights reproduce.
    threshold : float
        Weights below it are dropped (the paper uses 1e-3 / n).
    tolerance : float
        Largest reproduction error accepted after the correction, in the units of ``positions``.

    Returns
    -------
    (m, n) scipy.sparse.csr_matrix
    """
    full = sp.csr_matrix(weights)
    full.sum_duplicates()
    n = controls.shape[0]
    values, columns = _padded(full)
    order = np.argsort(-values, axis=1)  # each row's weights, largest first
    values = np.take_along_axis(values, order, axis=1)
    columns = np.take_along_axis(columns, order, axis=1)
    keep = np.count_nonzero(values >= threshold, axis=1)
    reduced = sp.csr_matrix(full.shape)
    pending = np.arange(full.shape[0])
    extra = 0
    while len(pending):
        size = np.minimum(keep[pending] + extra, values.shape[1])
        slots = np.where(np.arange(values.shape[1]) < size[:, None], values[pending], 0.0)
        corrected = restore_constraints(slots, controls, positions[pending], columns[pending])
        unity, reproduction = constraint_residuals(corrected, controls, positions[pending], columns[pending])
        done = (unity <= 1e-9) & (reproduction <= tolerance) & (corrected >= 0).all(axis=1)
        done |= size >= values.shape[1]  # the full support: nothing more to add
        reduced = _scatter_rows(reduced, pending[done], _from_padded(corrected[done], columns[pending][done], n))
        pending = pending[~done]
        extra = 2 * extra or 1
    return reduced


def _scatter_rows(matrix, rows, values):
    """``matrix``, whose given rows are empty, with those rows filled from ``values`` (CSR, same column count)."""
    placement = sp.csr_matrix((np.ones(len(rows)), (rows, np.arange(len(rows)))), shape=(matrix.shape[0], len(rows)))
    return (matrix + placement @ values).tocsr()


def _padded(matrix):
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


def _from_padded(values, columns, n):
    m, K = values.shape
    rows = np.repeat(np.arange(m), K)
    matrix = sp.csr_matrix((values.ravel(), (rows, columns.ravel())), shape=(m, n))
    matrix.eliminate_zeros()
    return matrix
