"""The prox of the weighted total variation, per (cell, coordinate) pair: group soft-thresholding of each gradient
vector, its Huber-relaxed form, and its form with the norm weighted per axis (a stretched frame)."""

import numpy as np

# Newton steps of the weighted prox (a stretched frame) at most per entry; from the previous step's root most need few.
NEWTON_STEPS = 30


def shrink_factor(values, thresholds, epsilon):
    """Group soft-thresholding of each cell's gradient vector (prox of ω|g|, or of its Huber smoothing) as a factor.

    Parameters
    ----------
    values : (d, F, n) float array
        Gradient vectors, component-major.
    thresholds : (F, n) float array
    epsilon : float or (F, n) float array
        Huber width in the units of ``values`` (0: plain total variation).

    Returns
    -------
    (F, n) float array s, with prox(values) = values · s.
    """
    norms = group_norms(values)
    np.maximum(norms, np.finfo(norms.dtype).tiny, out=norms)
    with np.errstate(over="ignore"):  # a zero gradient: its factor is 1 - ∞, clamped below
        factor = np.divide(thresholds, norms, out=norms)
    np.subtract(1.0, factor, out=factor)
    if np.any(epsilon):
        # prox of τ·huber_ε: shrink by τ beyond ε + τ, scale by ε / (ε + τ) inside.
        inside = factor <= epsilon / (epsilon + thresholds)  # |g| <= ε + τ
        factor[inside] = (epsilon / (epsilon + thresholds))[inside]
    else:
        np.maximum(factor, 0.0, out=factor)
    return factor


def weighted_shrink_factors(values, thresholds, axis_scale, guess=None, steps=NEWTON_STEPS):
    """The prox of τ|a ∘ g| (a norm weighted per axis) of each cell's gradient vector, as factors per component.

    prox(v)_k = v_k s / (s + a_k²), where s > 0 solves |q(s)|² = Σ_k a_k² v_k² / (s + a_k²)² = τ², the trust-region
    secular equation; no root (|v / a| ≤ τ) means the prox is 0, and τ = 0 leaves v as it is. 1 / |q(s)| is concave
    in s, so Newton steps from the left rise monotonically to the root, and a step from the right lands left of it;
    only the entries with a root are solved, each until its own root is found.

    Parameters
    ----------
    values : (d, F, n) float array
        Gradient vectors, component-major.
    thresholds : (F, n) float array
    axis_scale : (d,) float array
        a, the weight of each component in the norm.
    guess : (F, n) float array, optional
        Roots s near these (the previous step's): the steps start there, or at the lower bound if it is larger.
    steps : int
        Newton steps at most per entry (each stops once its factors move by less than 1e-5).

    Returns
    -------
    factors : (d, F, n) float array f, with prox(values) = values · f
    roots : (F, n) float array s (0 where the prox is 0)
    """
    d = values.shape[0]
    squared_threshold = np.square(thresholds).ravel()
    dual_norm = np.square(values[0] / axis_scale[0])
    for component, scale in zip(values[1:], axis_scale[1:]):
        dual_norm += np.square(component / scale)
    active = np.flatnonzero((dual_norm.ravel() > squared_threshold) & (squared_threshold > 0))
    # In float64: near the root 1 / |q| - 1 / τ cancels to float32's resolution, and the steps would wander there.
    # The components with the same a make one term of |q|².
    squared_scale = np.square(np.asarray(axis_scale, dtype=np.float64))
    poles, term_of = np.unique(squared_scale, return_inverse=True)
    poles = poles[:, None]
    numerators = np.zeros((len(poles), len(active)))
    flat_values = values.reshape(d, -1)
    for component in range(d):
        numerators[term_of[component]] += squared_scale[component] * np.square(
            flat_values[component, active].astype(np.float64))
    squared_threshold = squared_threshold[active].astype(np.float64)
    # |q(s)|² ≥ each term, so s ≥ a |v| / τ − a² for each: the largest of these bounds lies left of the root.
    lower = np.max(np.sqrt(numerators / squared_threshold) - poles, axis=0)
    np.maximum(lower, 0.0, out=lower)
    roots = lower.copy() if guess is None else np.maximum(lower, guess.ravel()[active])
    # The entries still moving, with their own copies of what the steps read (shrunk as entries settle).
    pending, s, inverse_threshold = np.arange(len(roots)), roots.copy(), 1.0 / np.sqrt(squared_threshold)
    for _ in range(steps):
        denominators = s + poles
        q_squared = numerators / np.square(denominators)
        norm = np.sqrt(q_squared.sum(axis=0))
        slope = np.sum(q_squared / denominators, axis=0) / norm ** 3
        moved = np.maximum(s - (1.0 / norm - inverse_threshold) / slope, lower)
        roots[pending] = moved
        # The factors s / (s + a_k²) move by at most |Δs| / (s + 1) (min a = 1).
        moving = np.abs(moved - s) > 1e-5 * (moved + 1.0)
        if not moving.any():
            break
        pending, s, numerators = pending[moving], moved[moving], numerators[:, moving]
        inverse_threshold, lower = inverse_threshold[moving], lower[moving]
    factors = np.zeros_like(values)
    factors.reshape(d, -1)[:, thresholds.ravel() == 0] = 1.0
    factors.reshape(d, -1)[:, active] = roots / (roots + squared_scale[:, None])
    all_roots = np.zeros_like(thresholds)
    all_roots.ravel()[active] = roots
    return factors, all_roots


def scaled_tv(gradient, tv_weights, sqrt_cell, axis_scale=None):
    """Σ ω |c| |∇w| from gradients scaled by √|c| (d, F, n), TV weights (F, n) and √|c| (F, 1); ``axis_scale`` (d,)
    weights the norm's components (a stretched frame)."""
    if axis_scale is not None:
        gradient = gradient * np.asarray(axis_scale)[:, None, None]
    return float(np.sum(tv_weights * sqrt_cell * group_norms(gradient)))


def group_norms(values):
    """|g| of each cell's d-vector in a component-major (d, F, n) array; returns (F, n)."""
    squared = np.square(values[0])
    for component in values[1:]:
        squared += np.square(component)
    return np.sqrt(squared, out=squared)

