"""Sparse, reduced coordinates that keep partition of unity, reproduction and non-negativity exactly.

Dropping small weights (the paper's reduction) breaks Σ w = 1 and Σ w c = x. Here each point's remaining weights get
the least-norm correction that restores both on its support; weights the correction pushes below zero are removed
and the correction repeated. Where a support is too small to reproduce the point, the point keeps its full support;
where even that cannot (a smooth fit that overshoots, below), the point is reduced from its piecewise-linear row.
"""

import numpy as np
import scipy.sparse as sp

from ..kernel.constraints import (alike_lengths, csr_from_padded, grow_support, padded_rows, restore_and_check,
                                  scatter_rows)
from ..kernel.parallel import map_row_chunks, one_blas_thread
from ..kernel.progress import Progress

# Rows reduced by one thread at a time: the padded (rows, K, d+1) work arrays of a million points would take
# gigabytes, so at most this many rows per thread are in flight (the smooth evaluation's own chunk).
ROWS_PER_CHUNK = 16_384
# How far from 1 an extrapolated row's sum may end, else the point follows its closest point inside instead; and
# the most its extrapolation's weights may sum to in magnitude, so that no cage vertex moves an outside point much
# more than itself (bench/RESULTS.md, "Points outside the cage extrapolate in every bind").
UNITY_TOLERANCE, EXTRAPOLATION_GAIN = 1e-12, 2.0
# Rows of alike lengths restored together at the fewest (bench/RESULTS.md, "The bind outside the solve, cheaper").
FEWEST_ALIKE = 512


def interpolate_and_reduce(located, domain_weights, controls, domain_vertices, threshold, tolerance, progress=None,
                           cancel=None):
    """Weights at points interpolated from a domain's vertices, reduced (weights below a threshold dropped, the
    constraints restored on what remains), one chunk of points at a time.

    Parameters
    ----------
    located : (m, N) scipy.sparse.csr_matrix, or any object with ``shape`` whose row slices are one
        Interpolation from the domain's N vertices to the points (barycentric, or
        :class:`lbc_core.evaluate.smoothing.SmoothInterpolation`, whose ``linear`` barycentric rows are the fallback of
        a point its fit leaves with no non-negative weights that meet the constraints, and whose ``outside`` rows, if
        any, extrapolate to points outside the cage: those are reduced without the sign constraint, which no
        weights reproducing such a point can meet).
    domain_weights : (N, n) float array
        Coordinates at the domain's vertices.
    controls : (n, d) float array
    domain_vertices : (N, d) float array
    threshold : float
        Weights below it are dropped (the paper uses 1e-3 / n); a point whose reduced support cannot meet the
        constraints (outside the hull of its remaining control points, e.g. just off a cage face) gets its largest
        dropped weights back, one, two, four, ... at a time, until it can.
    tolerance : float
        Largest reproduction error accepted after the correction, in the units of ``domain_vertices``.
    progress : callable(fraction, message) or Progress, optional
    cancel : callable() -> bool, optional
        Polled between chunks of rows; when it returns True, :class:`~lbc_core.errors.Cancelled` is raised.

    Returns
    -------
    (m, n) scipy.sparse.csr_matrix; memory stays bounded by the chunk size, not by m.
    """
    # A weight below threshold / 10 at every corner of a cell cannot reach the threshold inside it; drop those
    # entries (the solver's faint tails) before the product, keeping what a support may need to grow into.
    sparse_domain = sp.csr_matrix(np.where(domain_weights >= threshold / 10, domain_weights, 0.0))
    full_domain = sp.csr_matrix(domain_weights)
    linear = getattr(located, "linear", located)
    outside = getattr(located, "outside", None)
    # An interpolation that computes its rows by blocks of nearby points offers an order keeping them together, and
    # its rows' products without the rows (lbc_core.evaluate.smoothing.SmoothInterpolation).
    order = getattr(located, "order", None)
    progress = Progress.of(progress, cancel)

    def products(rows):
        if hasattr(located, "products"):
            return located.products(rows, sparse_domain, domain_vertices)
        block = located[rows]
        return block @ sparse_domain, block @ domain_vertices

    def reduce_chunk(rows):
        rows = np.arange(located.shape[0])[rows] if order is None else order[rows]
        extrapolated = np.zeros(len(rows), dtype=bool) if outside is None else outside[rows]
        inner, outer = np.flatnonzero(~extrapolated), np.flatnonzero(extrapolated)
        full, positions = products(rows[inner])
        reduced = _reduce_inside(full, linear[rows[inner]], positions)
        if not len(outer):
            return reduced
        block = located[rows[outer]]
        full, targets = _bounded_lever(block, linear[rows[outer]], block @ domain_vertices, full_domain,
                                       domain_vertices)
        signed, met = _reduce_signed(full, controls, targets, threshold, tolerance)
        if not met.all():
            # An extrapolation from too few or one-sided vertices (far outside a thin cage): the point follows its
            # closest point inside, reduced as a point inside.
            closest = linear[rows[outer[~met]]]
            signed = scatter_rows(sp.diags(met.astype(float)) @ signed, np.flatnonzero(~met),
                                  _reduce_inside(closest @ sparse_domain, closest, closest @ domain_vertices))
        return scatter_rows(scatter_rows(sp.csr_matrix((len(rows), controls.shape[0])), inner, reduced), outer,
                            signed)

    def _reduce_inside(full, fallback, positions):
        reduced, met = _reduce_rows(full, controls, positions, threshold, tolerance, progress.check)
        if met.all():
            return reduced
        # A smooth fit from few, one-sided vertices (coarse cells beside a fine cage) can overshoot so far that no
        # non-negative weights on its support meet the constraints; the barycentric row, a convex combination of the
        # vertices' coordinates, always does.
        failed = np.flatnonzero(~met)
        again, _ = _reduce_rows(fallback[failed] @ full_domain, controls, positions[failed],
                                threshold, tolerance, progress.check)
        kept = sp.diags(met.astype(float)) @ reduced
        kept.eliminate_zeros()
        return scatter_rows(kept, failed, again)

    with one_blas_thread():
        weights = _by_chunks(located.shape[0], controls.shape[0], reduce_chunk, progress)
    return weights if order is None else weights[np.argsort(order)]


def _bounded_lever(extrapolating, closest, positions, domain_weights, domain_vertices):
    """Outside points' coordinates (control space) and the points they reproduce: the closest point's row plus the
    extrapolation (to ``positions``, ``extrapolating``'s own), whose weights sum in magnitude to at most
    EXTRAPOLATION_GAIN, shortened toward the closest point where they would not (far outside a thin cage the
    extrapolation is a long lever on a short base)."""
    base = closest @ domain_weights
    lever = extrapolating @ domain_weights - base
    gain = np.asarray(abs(lever).sum(axis=1)).ravel()
    share = np.minimum(1.0, EXTRAPOLATION_GAIN / np.maximum(gain, 1e-300))
    at = closest @ domain_vertices
    targets = at + share[:, None] * (positions - at)
    return sp.csr_matrix(base + sp.diags(share) @ lever), targets


def _reduce_signed(full, controls, positions, threshold, tolerance):
    """Rows of points outside the cage, whose weights extrapolate (some negative): weights of magnitude below
    ``threshold`` dropped, then the least-norm change on the rest that makes them sum to 1 and reproduce the point
    (where those left span too few directions, the row is kept whole). Returns the (m, n) CSR rows and which of them
    meet the constraints to ``tolerance`` ((m,) bool array)."""
    n, d = controls.shape
    kept = full.copy()
    kept.data[np.abs(kept.data) < threshold] = 0.0
    kept.eliminate_zeros()
    values, columns = padded_rows(kept)
    present = np.arange(values.shape[1])[None, :] < np.diff(kept.indptr)[:, None]
    centre = positions[:, None, :]
    # Constraints A w = b with A = [1; c - x] per row (about the point, for conditioning).
    matrix = np.concatenate([present[:, None, :].astype(float),
                             np.swapaxes((controls[columns] - centre) * present[:, :, None], 1, 2)], axis=1)
    residual = -(matrix @ values[:, :, None])[:, :, 0]
    residual[:, 0] += 1.0
    gram = matrix @ np.swapaxes(matrix, 1, 2)
    spectrum = np.linalg.eigvalsh(gram)
    usable = spectrum[:, 0] > 1e-12 * spectrum[:, -1]
    solved = np.linalg.solve(np.where(usable[:, None, None], gram, np.eye(d + 1)), residual[:, :, None])
    corrected = values + (np.swapaxes(matrix, 1, 2) @ solved)[:, :, 0] * present
    reduced = csr_from_padded(np.where(present, corrected, 0.0), columns, n)
    if not usable.all():
        whole = np.flatnonzero(~usable)
        kept_rows = sp.diags(usable.astype(float)) @ reduced
        kept_rows.eliminate_zeros()
        reduced = scatter_rows(kept_rows, whole, sp.csr_matrix(full)[whole])
    unity = np.abs(np.asarray(reduced.sum(axis=1)).ravel() - 1.0)
    reproduction = np.abs(reduced @ controls - positions).max(axis=1, initial=0.0)
    return reduced, (unity <= UNITY_TOLERANCE) & (reproduction <= tolerance)


def _by_chunks(m, n, reduce_chunk, progress):
    """``reduce_chunk(rows)`` over consecutive equal row slices of at most ROWS_PER_CHUNK, one per thread at a time
    (:func:`~lbc_core.kernel.parallel.map_row_chunks`), stacked into an (m, n) CSR; ``progress`` is told before each
    round."""
    chunks = map_row_chunks(reduce_chunk, m, ROWS_PER_CHUNK,
                            lambda start: progress(start / m, f"reducing the weights: {start} of {m} points done"))
    progress(1.0, "reducing the weights: done")
    return sp.vstack(chunks, format="csr") if chunks else sp.csr_matrix((0, n))


def _reduce_rows(full, controls, positions, threshold, tolerance, check):
    """The reduction of :func:`interpolate_and_reduce` on one chunk of rows; ``check`` is called between rounds of
    corrections. Returns the (m, n) CSR rows and which of them meet the constraints ((m,) bool array)."""
    n = controls.shape[0]
    kept = full.copy()
    kept.data[kept.data < threshold] = 0.0
    kept.eliminate_zeros()
    # Most rows reproduce on their kept support: correct them all at once on short padded rows, rows of alike lengths
    # together (padded to a chunk's longest, a third of the entries were zeros).
    done = np.zeros(full.shape[0], dtype=bool)
    parts, order = [], []
    for alike in alike_lengths(np.diff(kept.indptr), FEWEST_ALIKE):
        values, columns = padded_rows(kept[alike])
        corrected, done[alike] = restore_and_check(values, columns, controls, positions[alike], tolerance, check)
        parts.append(csr_from_padded(np.where(done[alike][:, None], corrected, 0.0), columns, n))
        order.append(alike)
    reduced = (sp.vstack(parts, format="csr")[np.argsort(np.concatenate(order))] if parts
               else sp.csr_matrix(full.shape))
    if done.all():
        return reduced, done
    pending = np.flatnonzero(~done)
    grown, done[pending] = grow_support(full[pending], controls, positions[pending], np.diff(kept.indptr)[pending],
                                        tolerance, check)
    return scatter_rows(reduced, pending, grown), done
