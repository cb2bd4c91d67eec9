"""Sparse, reduced coordinates that keep partition of unity, reproduction and non-negativity exactly.

Dropping small weights (the paper's reduction) breaks Σ w = 1 and Σ w c = x. Here each point's remaining weights get
the least-norm correction that restores both on its support; weights the correction pushes below zero are removed
and the correction repeated. Where a support is too small to reproduce the point, the point keeps its full support.
"""

import numpy as np
import scipy.sparse as sp

from .progress import Progress


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
    else:
        affine = affine_rows[columns]  # (m, K, d+1)

        def reproduced(w):
            return (w[:, None, :] @ affine)[:, 0]

        def gram_on(support):
            return np.swapaxes(support[:, :, None] * affine, 1, 2) @ affine

        def spread(correction, support):
            return support * (affine @ correction[:, :, None])[:, :, 0]
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
        weights += spread(np.linalg.solve(gram + ridge, residual[:, :, None])[:, :, 0], support)
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
    unity = np.abs(weights.sum(axis=1) - 1.0)
    reproduced = weights @ controls if columns is None else (weights[:, None, :] @ controls[columns])[:, 0]
    reproduction = np.linalg.norm(reproduced - positions, axis=1)
    return unity, reproduction


# Rows reduced at a time: the padded (rows, K, d+1) work arrays of a million points would take gigabytes.
ROWS_PER_CHUNK = 65_536


def reduce_weights(weights, controls, positions, threshold, tolerance, progress=None, cancel=None):
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
    progress : callable(fraction, message) or Progress, optional
    cancel : callable() -> bool, optional
        Polled between chunks of rows; when it returns True, :class:`~lbc_core.errors.Cancelled` is raised.

    Returns
    -------
    (m, n) scipy.sparse.csr_matrix
    """
    full = sp.csr_matrix(weights)
    full.sum_duplicates()
    progress = Progress.of(progress, cancel)
    return _by_chunks(full.shape[0], controls.shape[0], lambda rows: _reduce_rows(
        full[rows], controls, positions[rows], threshold, tolerance, progress.check), progress)


def interpolate_and_reduce(located, domain_weights, controls, domain_vertices, threshold, tolerance, progress=None,
                           cancel=None):
    """Weights at points interpolated from a domain's vertices, reduced, one chunk of points at a time.

    Parameters
    ----------
    located : (m, N) scipy.sparse.csr_matrix, or any object with ``shape`` whose row slices are one
        Interpolation from the domain's N vertices to the points (barycentric, or
        :class:`lbc_core.smoothing.SmoothInterpolation`).
    domain_weights : (N, n) float array
        Coordinates at the domain's vertices.
    controls : (n, d) float array
    domain_vertices : (N, d) float array
    threshold, tolerance, progress, cancel
        As in :func:`reduce_weights`.

    Returns
    -------
    (m, n) scipy.sparse.csr_matrix; memory stays bounded by the chunk size, not by m.
    """
    # A weight below threshold / 10 at every corner of a cell cannot reach the threshold inside it; drop those
    # entries (the solver's faint tails) before the product, keeping what a support may need to grow into.
    sparse_domain = sp.csr_matrix(np.where(domain_weights >= threshold / 10, domain_weights, 0.0))
    progress = Progress.of(progress, cancel)

    def reduce_chunk(rows):
        block = located[rows]  # once: a smooth interpolation computes its rows on demand
        return _reduce_rows(block @ sparse_domain, controls, block @ domain_vertices, threshold, tolerance,
                            progress.check)

    return _by_chunks(located.shape[0], controls.shape[0], reduce_chunk, progress)


def _by_chunks(m, n, reduce_chunk, progress):
    """``reduce_chunk(rows)`` over consecutive row slices of at most ROWS_PER_CHUNK, stacked into an (m, n) CSR;
    ``progress`` is told before each chunk."""
    chunks = []
    for start in range(0, m, ROWS_PER_CHUNK):
        progress(start / m, "reducing the weights")
        chunks.append(reduce_chunk(slice(start, start + ROWS_PER_CHUNK)))
    progress(1.0, "reducing the weights: done")
    return sp.vstack(chunks, format="csr") if chunks else sp.csr_matrix((0, n))


def _reduce_rows(full, controls, positions, threshold, tolerance, check):
    """:func:`reduce_weights` on one chunk of rows; ``check`` is called between rounds of corrections."""
    n = controls.shape[0]
    kept = full.copy()
    kept.data[kept.data < threshold] = 0.0
    kept.eliminate_zeros()
    # Most rows reproduce on their kept support: correct them all at once on short padded rows.
    values, columns = _padded(kept)
    corrected, done = _restore_and_check(values, columns, controls, positions, tolerance, check)
    reduced = _scatter_rows(sp.csr_matrix(full.shape), np.flatnonzero(done),
                            _from_padded(corrected[done], columns[done], n))
    pending = np.flatnonzero(~done)
    if len(pending):
        kept_counts = np.diff(kept.indptr)[pending]
        reduced = _scatter_rows(reduced, pending, grow_support(full[pending], controls, positions[pending],
                                                               kept_counts, tolerance, check))
    return reduced


def _restore_and_check(values, columns, controls, positions, tolerance, check=None):
    """Corrected rows, and which of them meet the constraints."""
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
    (m, n) scipy.sparse.csr_matrix
    """
    n = controls.shape[0]
    values, columns = _padded(full)
    order = np.argsort(-values, axis=1)
    values = np.take_along_axis(values, order, axis=1)
    columns = np.take_along_axis(columns, order, axis=1)
    reduced = sp.csr_matrix(full.shape)
    pending = np.arange(full.shape[0])
    extra = 1
    while len(pending):
        size = np.minimum(keep[pending] + extra, values.shape[1])
        slots = np.where(np.arange(values.shape[1]) < size[:, None], values[pending], 0.0)
        corrected, done = _restore_and_check(slots, columns[pending], controls, positions[pending], tolerance, check)
        done |= size >= values.shape[1]  # the full support: nothing more to add
        reduced = _scatter_rows(reduced, pending[done], _from_padded(corrected[done], columns[pending][done], n))
        pending = pending[~done]
        extra *= 2
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
