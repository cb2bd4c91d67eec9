"""Fewer influences per point without creases: a continuous threshold and a multiplicative restoration.

A deformer's cost per frame grows with the influences per point; the smooth evaluation (:mod:`smoothing`) gives
many small ones. Keeping each point's K largest weights is discontinuous where two weights swap rank, and keeping
the survivors' constraints by an additive correction moves every kept weight when the support changes: a bent
smooth mesh creases (bench/RESULTS.md, "Blender deformer"). Here every weight is lowered by a threshold τ and clamped
at 0, so a weight enters and leaves at exactly 0; then partition of unity and reproduction are restored by the
closest weights in the Kullback–Leibler sense, w''_j = w'_j exp(λ · (c_j − x, 1)) (d + 1 unknowns per point, a few
Newton steps), which keeps zeros at zero, stays positive and is smooth in w'. τ is a constant (the floor), smooth in
the point; a cap on the count raises τ to the (K+1)-th largest weight, continuous but only piecewise smooth.

A floor that rose with the weights' spread was tried and withdrawn: on few-vertex cages it left many points weights
that cannot reproduce them, whose relaxed threshold then differed from their neighbours' (spikes on a flat mesh in a
box cage, bench/RESULTS.md, "The floor's rise withdrawn").
"""

import numpy as np
import scipy.sparse as sp

from ..kernel.constraints import alike_lengths, csr_from_padded, padded_rows, scatter_rows, solve_symmetric
from ..kernel.parallel import map_row_chunks, one_blas_thread
from ..kernel.progress import Progress
from .smoothing import DEFAULT_SMOOTHNESS

# The floor at smoothness 0 (BindOptions.smoothness): keeps the bent capsule (bench/capsule.py) less creased than
# Mesh Deform with a margin (0.005 did once, and on today's meshes reached 3.48° against its 3.33°; 0.004 gives 2.53°,
# at 4 % more influences; bench/RESULTS.md).
LOCAL_FLOOR = 0.004
# The floor at smoothness 1: the twisted capsule's creases are the floor's past a wide fit, and 0.001 meets Mesh
# Deform's there (bench/RESULTS.md, "Joints as smooth as Mesh Deform's").
SMOOTH_FLOOR = 0.001

# The tilt's tolerance: rows sum to 1 within it and reproduce their point within it times the controls' extent.
TOLERANCE = 1e-9

# Rows thinned by one thread at a time (about 0.05 s each); cancel is polled between rounds of one chunk per thread.
ROWS_PER_CHUNK = 8192

# The most of a point's weight the floor may take away, Σ_j min(w_j, τ); beyond it τ is lowered
# (bench/RESULTS.md, "The floor never takes more than a tenth of a point's weight").
MOST_REMOVED = 0.1

# Rows of alike lengths tilted together at the fewest (bench/RESULTS.md, "The bind outside the solve, cheaper").
FEWEST_ALIKE = 512

# Times a point's threshold is relaxed (floor / 4; a cap raised by 1, 2, 4, ...) before it keeps its whole row
# (bench/RESULTS.md, "Constants' notes").
RELAXATIONS = 12


def floor_for(smoothness):
    """The thinning's floor for a smoothness in [0, 1] (:class:`lbc_core.binding.options.BindOptions`): :data:`LOCAL_FLOOR`
    at 0 to :data:`SMOOTH_FLOOR` at 1, geometrically (each step keeps about as many more influences)."""
    return LOCAL_FLOOR * (SMOOTH_FLOOR / LOCAL_FLOOR) ** float(smoothness)


# The floor at the default smoothness.
DEFAULT_FLOOR = floor_for(DEFAULT_SMOOTHNESS)


def thin_weights(weights, controls, positions, floor=DEFAULT_FLOOR, max_influences=0, progress=None, cancel=None):
    """Each point's weights lowered by a threshold and clamped at 0, then made to sum to 1 and reproduce it again.

    Parameters
    ----------
    weights : (m, n) scipy.sparse matrix
        Weights that sum to 1 and reproduce ``positions``, non-negative (rows with a negative weight are kept).
    controls : (n, d) float array
        Control points.
    positions : (m, d) float array
        What each row reproduces (Σ_j w_j c_j).
    floor : float
        τ, subtracted from every weight (weights are fractions of 1; 0 keeps every weight).
    max_influences : int
        K > 0: τ is at least each point's (K+1)-th largest weight, so at most K weights stay; 0: no cap.
    progress : callable(fraction, message) or Progress, optional
    cancel : callable() -> bool, optional
        Polled between rounds of :data:`ROWS_PER_CHUNK` rows per thread; True stops with :class:`lbc_core.Cancelled`.

    Returns
    -------
    (m, n) scipy.sparse.csr_matrix
        Non-negative rows that sum to 1 and reproduce ``positions`` (to 1e-9 of the controls' extent), each a
        subset of its input row's support; an input row with a negative weight (a point outside the cage, whose
        weights extrapolate) is kept as it is. Where a point's kept weights cannot reproduce it (it lies on the hull of
        their control points), its threshold is relaxed (floor / 4, K raised by 1, 2, 4, ..., then the least cap
        between the last that failed and the one that did) until they can, and after :data:`RELAXATIONS` times it
        keeps its input row. A cap too low for a point thus ends at the least that reproduces it.
    """
    weights = sp.csr_matrix(weights, dtype=float)
    controls = np.asarray(controls, dtype=float)
    positions = np.asarray(positions, dtype=float)
    progress = Progress.of(progress, cancel)
    m = weights.shape[0]

    def thin(rows):
        return _thin_rows(weights[rows], controls, positions[rows], floor, max_influences)

    with one_blas_thread():
        chunks = map_row_chunks(thin, m, ROWS_PER_CHUNK, lambda start: progress(start / m, "thinning the weights"))
    return sp.vstack(chunks, format="csr") if chunks else sp.csr_matrix(weights.shape)


def thin_changed_rows(thinned, before, weights, controls_before, controls, floor=DEFAULT_FLOOR, max_influences=0,
                      progress=None, cancel=None):
    """:func:`thin_weights` of ``weights`` when ``thinned`` is that of ``before``: only the rows that can differ are
    thinned again (a warm re-bind keeps the rows its edit cannot reach).

    A row is thinned again when its weights differ from ``before``'s or it has weight on a control point that moved,
    or, when the controls' extent changed (it scales the tilt's tolerance, not the floor), when its thinned row no
    longer reproduces its point within :data:`TOLERANCE` of the new extent. Each row's thinning depends on that row
    alone, so the result is :func:`thin_weights`'s (to rounding: a chunk pads its rows to its longest; where the
    extent changed, to the tilt's convergence in the rows kept).

    Parameters
    ----------
    thinned : (m, n) scipy.sparse matrix
        ``thin_weights(before, controls_before, before @ controls_before, floor, max_influences)``.
    before, weights : (m, n) scipy.sparse matrix
        The previous and the new weights (non-negative, summing to 1).
    controls_before, controls : (n, d) float array
        The control points ``before`` and ``weights`` reproduce with.
    floor, max_influences, progress, cancel
        As for :func:`thin_weights`, and the same as ``thinned`` was made with.

    Returns
    -------
    thinned : (m, n) scipy.sparse.csr_matrix
    again : int
        How many rows were thinned again.
    """
    weights, before = sp.csr_matrix(weights, dtype=float), sp.csr_matrix(before, dtype=float)
    controls, controls_before = np.asarray(controls, dtype=float), np.asarray(controls_before, dtype=float)
    if before.shape != weights.shape or controls_before.shape != controls.shape:
        return (thin_weights(weights, controls, weights @ controls, floor, max_influences, progress, cancel),
                weights.shape[0])
    difference = weights - before
    difference.eliminate_zeros()
    moved = np.flatnonzero(np.any(controls != controls_before, axis=1))
    changed = (np.diff(difference.indptr) > 0) | (weights[:, moved].getnnz(axis=1) > 0)
    extent = controls_extent(controls)
    if extent != controls_extent(controls_before):
        off = np.linalg.norm(sp.csr_matrix(thinned) @ controls - weights @ controls, axis=1)
        changed |= off > TOLERANCE * extent
    again = np.flatnonzero(changed)
    if not len(again):
        return sp.csr_matrix(thinned), 0
    rows = weights[again]
    thinned_again = thin_weights(rows, controls, rows @ controls, floor, max_influences, progress, cancel)
    kept = sp.diags((~changed).astype(float)) @ sp.csr_matrix(thinned)
    kept.eliminate_zeros()
    return scatter_rows(kept, again, thinned_again), len(again)


def controls_extent(controls):
    """The length scale of the thinning: the controls' bounding box diagonal (1 for no controls)."""
    return float(np.linalg.norm(np.ptp(controls, axis=0))) if len(controls) else 1.0


def _thin_rows(weights, controls, positions, floor, max_influences):
    """:func:`thin_weights` on one chunk of rows."""
    values, columns = padded_rows(weights)
    order = np.argsort(-values, axis=1, kind="stable")
    values = np.take_along_axis(values, order, axis=1)
    columns = np.take_along_axis(columns, order, axis=1)
    extent = controls_extent(controls)
    thinned = values.copy()  # rows that never reproduce keep their input
    slot_controls = controls[columns]  # (m, L, d)
    floors = np.full(len(values), float(floor))
    caps = np.full(len(values), int(max_influences))

    def thin(rows):
        """Thin ``rows`` at their floors and caps into ``thinned`` where they then reproduce; which did."""
        prior = np.maximum(values[rows] - thresholds(values[rows], floors[rows], caps[rows])[:, None], 0.0)
        # Rows are sorted, so the weights left are a prefix: the tilt (which keeps zeros at zero) skips the rest,
        # rows of alike lengths together (padded to the longest of a chunk, the rows were half zeros).
        counts = np.count_nonzero(prior, axis=1)
        done = np.zeros(len(rows), dtype=bool)
        for alike in alike_lengths(counts, FEWEST_ALIKE):
            width = max(int(counts[alike].max(initial=0)), 1)
            tilted, done[alike] = tilt(prior[alike, :width], slot_controls[rows[alike], :width], positions[rows[alike]],
                                       extent)
            settled = rows[alike[done[alike]]]
            thinned[settled] = 0.0
            thinned[settled, :width] = tilted[done[alike]]
        return done

    # A capped row that cannot reproduce its point raises its cap by 1, 2, 4, ... (one by one, a cap of 4 in Blender's
    # Cylinder, whose points need about 20 of its 64 vertices, ran out of relaxations and kept all 64), then takes
    # the least cap between the last that failed and the one that did.
    raises = np.ones(len(values), dtype=int)
    failed = np.zeros(len(values), dtype=int)  # the largest cap a row failed at
    # A row with negative weights reproduces a point outside the hull of its control points (a point outside the
    # cage, extrapolated: lbc_core.evaluate.smoothing): no non-negative weights can, so it keeps its input.
    pending = np.flatnonzero(~(values < 0).any(axis=1))
    for _ in range(RELAXATIONS + 1):
        if not len(pending):
            break
        pending = pending[~thin(pending)]
        failed[pending] = caps[pending]
        floors[pending] /= 4
        caps[pending] += raises[pending] * (caps[pending] > 0)
        raises[pending] *= 2
    reproduces = np.ones(len(values), dtype=bool)
    reproduces[pending] = False
    search = np.flatnonzero(reproduces & (failed > 0) & (caps > failed + 1))
    while len(search):
        reproduced = caps[search].copy()
        caps[search] = (failed[search] + reproduced) // 2
        done = thin(search)
        failed[search[~done]] = caps[search[~done]]
        caps[search[~done]] = reproduced[~done]
        search = search[caps[search] > failed[search] + 1]
    return csr_from_padded(thinned, columns, weights.shape[1])


def thresholds(values, floors, caps):
    """Each row's τ: its floor, lowered where it would take more than :data:`MOST_REMOVED` of the row's weight, then
    raised to its (K+1)-th largest value where it has a cap K > 0.

    Parameters
    ----------
    values : (m, L) float array, each row sorted in decreasing order
    floors : (m,) float array
    caps : (m,) int array (0: no cap)

    Returns
    -------
    (m,) float array
    """
    capped = (caps > 0) & (caps < values.shape[1])
    ranked = values[np.arange(len(values)), np.minimum(caps, values.shape[1] - 1)]
    floors = np.minimum(floors, removing(values, MOST_REMOVED))
    return np.where(capped, np.maximum(floors, ranked), floors)


def removing(values, mass):
    """Each row's τ with Σ_j min(w_j, τ) = ``mass`` (continuous and increasing in the weights: thresholds stay smooth
    in the point).

    Parameters
    ----------
    values : (m, L) float array, each row sorted in decreasing order, summing to 1 or more than ``mass``
    mass : float

    Returns
    -------
    (m,) float array
    """
    ascending = values[:, ::-1]
    count = ascending.shape[1]
    below = np.cumsum(ascending, axis=1) - ascending  # Σ of the weights before each
    # Σ min(w, τ) at τ = each weight in turn: increasing along the row; τ lies below the first that reaches ``mass``.
    taken = below + ascending * (count - np.arange(count))
    first = np.argmax(taken >= mass, axis=1)
    rows = np.arange(len(values))
    return (mass - below[rows, first]) / (count - first)


def tilt(prior, controls, positions, extent, iterations=40):
    """The weights closest to ``prior`` (Kullback–Leibler) that sum to 1 and reproduce ``positions``.

    w_j = prior_j exp(λ · a_j), a_j = ((c_j − x) / extent, 1), with λ minimising the convex dual
    Σ_j prior_j exp(λ · a_j) − λ_d (damped Newton steps).

    Parameters
    ----------
    prior : (m, K) float array, non-negative
    controls : (m, K, d) float array
        The control point of each slot.
    positions : (m, d) float array
    extent : float
        Length scale of the controls (their bounding box diagonal).

    Returns
    -------
    weights : (m, K) float array
        Zero where ``prior`` is zero.
    done : (m,) bool array
        Rows that sum to 1 within 1e-9 and reproduce their position within 1e-9 × ``extent``; the others (a
        point on or outside the hull of its prior's support, or a zero prior) are to be taken with more weights.
    """
    m, K, d = controls.shape
    total = prior.sum(axis=1, keepdims=True)
    prior = np.divide(prior, total, out=np.zeros_like(prior), where=total > 0)
    # a_j's first d entries, one contiguous (m, K) array per axis (its last entry is the constant 1).
    offsets = np.ascontiguousarray(np.moveaxis((controls - positions[:, None, :]) / extent, 2, 0))
    target = np.zeros(d + 1)
    target[d] = 1.0
    multipliers = np.zeros((m, d + 1))
    # The rows still iterating, gathered once and compacted as rows settle (not gathered again at every evaluation).
    active = np.flatnonzero(total[:, 0] > 0)
    axes, kept, lam = offsets[:, active], prior[active], multipliers[active]
    weights = kept.copy()  # tilted by λ = 0
    final = np.zeros_like(prior)  # each row's weights where it settled
    for _ in range(iterations):
        if not len(active):
            break
        first = _first_moments(weights, axes)
        gradient = first - target
        # A point outside the hull of its prior's support has no solution: λ runs off (weights grown e^50-fold).
        settled = (np.abs(gradient).max(axis=1) <= 1e-12) | ~(np.abs(lam).max(axis=1) < 50)
        if settled.any():
            multipliers[active[settled]] = lam[settled]
            final[active[settled]] = weights[settled]
            going = ~settled
            active, axes, kept, lam = active[going], axes[:, going], kept[going], lam[going]
            weights, gradient, first = weights[going], gradient[going], first[going]
            if not len(active):
                break
        dual = first[:, d] - lam[:, d]
        hessian = _moments(weights, axes, first)
        hessian += 1e-14 * np.eye(d + 1)
        step = solve_symmetric(hessian, gradient)
        lam, weights = _damped_step(kept, axes, lam, step, dual)
    multipliers[active] = lam
    final[active] = weights
    weights = final
    unity = np.abs(weights.sum(axis=1) - 1.0)
    reproduction = np.linalg.norm(np.einsum("mk,mkd->md", weights, controls) - positions, axis=1)
    done = (total[:, 0] > 0) & (unity <= TOLERANCE) & (reproduction <= TOLERANCE * extent)
    return weights, done


def _tilted(kept, axes, lam):
    """The prior ``kept`` (m, K) tilted by the multipliers ``lam`` (m, d+1): kept_j exp(λ · a_j), a_j's first d entries
    ``axes`` (d, m, K) and its last 1."""
    d = len(axes)
    exponent = np.repeat(lam[:, d:], kept.shape[1], axis=1)
    for axis in range(d):
        exponent += axes[axis] * lam[:, axis, None]
    return kept * np.exp(np.clip(exponent, -200.0, 200.0, out=exponent), out=exponent)


def _first_moments(weights, axes):
    """Σ_j w_j a_j per row, (m, d+1), a_j's first d entries ``axes`` (d, m, K) and its last 1: the dual's gradient
    plus the target."""
    d = len(axes)
    first = np.empty((len(weights), d + 1))
    for a in range(d):
        first[:, a] = np.einsum("mk,mk->m", weights, axes[a])
    first[:, d] = weights.sum(axis=1)
    return first


def _moments(weights, axes, first):
    """Σ_j w_j a_j a_jᵀ per row, (m, d+1, d+1), from its last row ``first`` (:func:`_first_moments`): the dual's
    Hessian (six sums of products in 3D, not a batched product of (m, K, d+1) arrays: twice as fast)."""
    d = len(axes)
    moments = np.empty((len(weights), d + 1, d + 1))
    moments[:, d] = moments[:, :, d] = first
    for a in range(d):
        weighted = weights * axes[a]
        for b in range(a, d):
            moments[:, a, b] = moments[:, b, a] = np.einsum("mk,mk->m", weighted, axes[b])
    return moments


def _damped_step(kept, axes, lam, step, dual):
    """Each row's λ − s step for the first s of 1, 1/2, 1/4, ... (30 at most) where the dual ``dual`` does not grow
    (rounding is no growth), and the weights there: the last weights a row tried are its next iteration's, so each
    Newton step evaluates the exponentials once, not twice (bench/RESULTS.md, "The bind outside the solve, cheaper").

    Returns
    -------
    lam : (m, d+1) float array
    weights : (m, K) float array
    """
    d = lam.shape[1] - 1
    scale = np.ones(len(lam))
    trial = lam - step  # the full step for every row first, without gathering them
    weights = _tilted(kept, axes, trial)
    growing = np.flatnonzero(weights.sum(axis=1) - trial[:, d] > dual + 1e-14)
    for _ in range(29):
        if not len(growing):
            break
        scale[growing] /= 2
        trial = lam[growing] - scale[growing, None] * step[growing]
        tried = _tilted(kept[growing], axes[:, growing], trial)
        weights[growing] = tried
        growing = growing[tried.sum(axis=1) - trial[:, d] > dual[growing] + 1e-14]
    if len(growing):  # halved once more than tried
        scale[growing] /= 2
        weights[growing] = _tilted(kept[growing], axes[:, growing],
                                   lam[growing] - scale[growing, None] * step[growing])
    return lam - scale[:, None] * step, weights
