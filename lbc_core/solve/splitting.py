"""One Douglas–Rachford step of the LBC splitting on working sets, and the state it maps.

Variables in measure-scaled form, so that the penalty's norms are Euclidean:
- per (cell, control point) pair p, the split gradient X̃_p = √|c| ∇w_i (d values), its state v_X = X̃ + Ũ;
- per slot s = (vertex, control point), the split weight W̃_s = √(β m_v) w_vi, its state v_W = W̃ + Ṽ;
- the free coordinates z per slot, found by the least-squares step each iteration.

One step: X̃ = shrink(v_X) (the weighted TV's prox per pair), W̃ = the projection of each vertex's row onto
{w ≥ 0, Σ w = 1, Σ w c = x} (:mod:`lbc_core.solve.projection`), z from (Gᵀ G + diag(√(βm))²) z = Gᵀ(2X̃ − v_X − E) +
√(βm)(2W̃ − v_W) (one factorised solve, block-diagonal over the control points), then v += α (the new split values'
targets − the split values). Nothing couples the coordinates but the per-vertex projection.
"""

from dataclasses import dataclass

import numpy as np

from .projection import NEWTON_STEPS, RESIDUAL_TOLERANCE
from .shrink import group_norms, shrink_factor, weighted_shrink_factors


@dataclass
class Step:
    """One step's input state (v_X (d, P), v_W (S,)), its split variables X̃ = v_X · shrink and W̃, the free
    coordinates z and their scaled gradients (d, P), boundary part included."""

    v_x: np.ndarray
    v_w: np.ndarray
    shrink: np.ndarray
    W: np.ndarray
    z: np.ndarray
    gradient: np.ndarray

    @property
    def X(self):
        return self.v_x * self.shrink


class DouglasRachford:
    """The step map on one layout of working sets (:class:`lbc_core.solve.working_sets.PairOperators`).

    Attributes
    ----------
    ops : PairOperators
    thresholds : (P,) float array
        √|c| ω / ρ of each pair: the shrink threshold.
    duals : (N_in, d+1) float array
        The projection's duals, warm-starting each step's projection.
    """

    def __init__(self, ops, tv_weights, epsilon, alpha, rho, axis_scale=None, tv_scale=1.0, duals=None):
        self.ops, self.alpha, self.penalty = ops, alpha, rho
        # In scaled variables g̃ = √|c| ∇w the Huber width ε of |∇w| is ε √|c| per pair.
        self.epsilon = (epsilon * ops.pair_sqrt_cell).astype(ops.dtype) if epsilon > 0 else 0.0
        self.axis_scale, self.tv_scale = axis_scale, tv_scale
        self.pair_weights = tv_weights[ops.pair_cell, ops.pair_control] * tv_scale
        self.thresholds = (ops.pair_sqrt_cell * self.pair_weights / rho).astype(ops.dtype)
        self.size_x = ops.d * ops.n_pairs
        self.duals = np.zeros((len(ops.padded.targets), ops.d + 1)) if duals is None else duals
        self.secular_roots = None if axis_scale is None else np.zeros(ops.n_pairs)
        self.dtype = ops.dtype
        self.buffers = None

    def split(self, state):
        """Views of a flat state as v_X (d, P) and v_W (S,)."""
        return state[:self.size_x].reshape(self.ops.d, -1), state[self.size_x:]

    def state_of(self, weights):
        """The state whose split variables are ``weights`` (S,) and their gradients, with zero duals."""
        weights = weights.astype(self.dtype)
        return np.concatenate([self.ops.gradients(weights).ravel(), self.ops.slot_mass * weights])

    def shrink_factors(self, v_x, thresholds, remember=False):
        """The prox of the pairs' total variation as factors of v_X: (P,), or (d, P) with the norm weighted per
        axis (whose Newton steps start from the roots of the step before when ``remember``)."""
        if self.axis_scale is None:
            return shrink_factor(v_x, thresholds, self.epsilon)
        guess = self.secular_roots if remember else None
        factors, roots = weighted_shrink_factors(v_x, thresholds, self.axis_scale, guess)
        if remember:
            self.secular_roots = roots
        return factors

    def projected(self, v_w, exact=False):
        """W̃: each vertex's row of v_W / √(βm) projected onto its constraints, scaled back; within a step to the
        iterations' tolerance, or ``exact`` to round-off."""
        mass = self.ops.slot_mass
        accuracy = (RESIDUAL_TOLERANCE, NEWTON_STEPS) if exact else ()
        weights, self.duals, _ = self.ops.project(v_w / mass, self.duals, *accuracy)
        return (weights * mass).astype(self.dtype)

    def __call__(self, state):
        """The next state and this step's :class:`Step`."""
        ops, alpha = self.ops, self.alpha
        v_x, v_w = self.split(state)
        shrink = self.shrink_factors(v_x, self.thresholds, remember=True)
        W = self.projected(v_w)
        # Temporaries of the pairs' size go to buffers kept from step to step: fresh ones cost page faults.
        pair_factor, pair_work = self._buffers(shrink.shape, v_x.shape)
        np.multiply(shrink, 2.0, out=pair_factor)
        pair_factor -= 1.0
        reflected_x = np.multiply(v_x, pair_factor, out=pair_work)
        reflected_x -= ops.boundary_part
        rhs = ops.transposed(reflected_x.ravel())
        rhs += ops.slot_mass * (2.0 * W - v_w)
        z = ops.solve(rhs)
        gradient = ops.gradients(z)
        new_state = np.empty_like(state)
        new_x, new_w = self.split(new_state)
        np.multiply(shrink, -alpha, out=pair_factor)
        pair_factor += 1.0
        np.multiply(v_x, pair_factor, out=new_x)
        new_x += np.multiply(gradient, alpha, out=pair_work)
        np.multiply(ops.slot_mass, z, out=new_w)
        new_w -= W
        new_w *= alpha
        new_w += v_w
        return new_state, Step(v_x, v_w, shrink, W, z, gradient)

    def _buffers(self, factor_shape, work_shape):
        """Two work arrays of the step's dtype, (P,) or (d, P) for the factor and (d, P), kept across steps; made at
        the first step, not while a reshape builds this map beside the old layout."""
        if self.buffers is None:
            self.buffers = np.empty(factor_shape, self.dtype), np.empty(work_shape, self.dtype)
        return self.buffers

    def rescale_penalty(self, state, factor):
        """Change the penalty to ``factor`` times itself, in place on ``state``: the split variables stay, the scaled
        duals (v minus them) shrink by ``factor``, and so do the thresholds. The least-squares step's matrix does not
        depend on the penalty, so nothing is factorised again."""
        v_x, v_w = self.split(state)
        kept = self.shrink_factors(v_x, self.thresholds)
        v_x *= (kept + (1.0 - kept) / factor).astype(self.dtype)
        self.thresholds = (self.thresholds / factor).astype(self.dtype)
        self.penalty *= factor
        W = self.projected(v_w, exact=True)
        v_w -= W
        v_w /= factor
        v_w += W

    def objective(self, gradient):
        """Σ ω |c| |∇w| on the solve's frame from scaled gradients (d, P)."""
        if self.axis_scale is not None:
            gradient = gradient * np.asarray(self.axis_scale)[:, None]
        return float(np.sum(self.pair_weights * self.ops.pair_sqrt_cell * group_norms(gradient)))

    def weights(self, step):
        """The weights (S,) of a step: W̃ unscaled, feasible to the iterations' tolerance."""
        return step.W / self.ops.slot_mass

    def final_weights(self, state):
        """The weights (S,) of a state, projected onto the constraints to round-off: the solve's output."""
        values = self.split(state)[1].astype(np.float64) / self.ops.slot_mass
        weights, self.duals, feasible = self.ops.project(values, self.duals, RESIDUAL_TOLERANCE, NEWTON_STEPS)
        return weights if feasible.all() else self.ops.restore_rows(weights, np.flatnonzero(~feasible))
