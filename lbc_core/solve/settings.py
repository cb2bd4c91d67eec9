"""What both splittings of the solve share: their options record, the problem's checks, the penalty's balancing.

:mod:`lbc_core.solve.solver` takes the dense splitting (:mod:`lbc_core.solve.dense`) where its cost model says it is the
cheaper one, and the dense splitting takes these from here, so that neither imports the other both ways.
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import CageError

# Penalty balancing halves the penalty where the primal residual is below BALANCE_LOW times the dual (bench/RESULTS.md,
# "The penalty balanced against the residuals in the first iterations").
BALANCE_LOW = 0.05


@dataclass
class SolveSettings:
    """solve_on_mesh's options, the defaults of the dimension filled in (both splittings take them)."""

    epsilon: float
    tolerance: float
    max_iterations: int
    relaxation: float
    check_every: int
    anderson_memory: int
    anderson_period: int
    dtype: type


@dataclass
class SolveResult:
    """Result of :func:`lbc_core.solve.solver.solve_on_mesh`, by either splitting.

    Attributes
    ----------
    weights : (N, n) float array
        Coordinates at every mesh vertex.
    iterations : int
    converged : bool
        Whether the stopping rule was met before ``max_iterations``.
    objective : float
        Σ_cells Σ_i ω A |∇w_i| of ``weights``, in the input's units (length^(d-1)).
    tv_weights : (F, n) float array
        The ω the solve was given.
    history : list of dict
        At each scheduled check the iteration and the relative primal residual; where the primal test passed, the
        relative dual residual and the objective of the iterate (input's units). Where the penalty was balanced,
        the iteration and the new penalty; where the working sets grew, the iteration and the slots.
    seconds : dict
        Time per stage.
    state : SolverState or None
        The solver's final state (:class:`lbc_core.solve.state.SolverState`; the dense splitting's own, which the
        solver carries onto working sets), to warm-start a solve on the same mesh carried onto an edited cage (None
        when there was nothing to iterate).
    splitting : str
        "working sets", or "dense" where the cost model took the dense splitting.
    """

    weights: np.ndarray
    iterations: int
    converged: bool
    objective: float
    tv_weights: np.ndarray
    history: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)
    state: object = None
    splitting: str = "working sets"


def balancing_factor(residuals, high):
    """2 when the primal residual lags (beyond ``high`` times the dual), 1/2 when the dual one does (below
    BALANCE_LOW times), else 1."""
    ratio = residuals["primal"] / max(residuals["dual"], 1e-300)
    return 2.0 if ratio > high else 0.5 if ratio < BALANCE_LOW else 1.0


def check_problem(vertices, cells, boundary_vertices, boundary_weights, control_points, tv_weights):
    """Refuse arrays whose shapes or indices do not make one solve's problem (:class:`CageError`)."""
    n_vertices, d = vertices.shape
    if d not in (2, 3) or cells.ndim != 2 or cells.shape[1] != d + 1:
        raise CageError(f"cells must be (F, {d + 1}) for {d}D vertices, got shape {cells.shape}")
    if cells.min() < 0 or cells.max() >= n_vertices:
        raise CageError("cells refer to vertices that do not exist")
    n = len(control_points)
    if boundary_weights.shape != (len(boundary_vertices), n):
        raise CageError(
            f"boundary_weights must be (B, n) = ({len(boundary_vertices)}, {n}), got {boundary_weights.shape}"
        )
    if n < d + 1:
        raise CageError(f"a {d}D cage needs at least {d + 1} control points, got {n}")
    if np.shape(tv_weights) != (len(cells), n):
        raise CageError(f"tv_weights must be (F, n) = ({len(cells)}, {n}), got {np.shape(tv_weights)}")


def starting_penalty(penalty, start, default):
    """The penalty asked for, else the one a warm start's solve ended with, else ``default``."""
    if penalty is not None:
        return penalty
    if start is not None and start.penalty is not None:
        return start.penalty
    return default


def residual_scale(out, massed):
    """The primal residual's scale (Boyd et al. 2011, §3.3.1): max(|(g̃, √(βm) z)|, |(X̃, W̃)|) of one step ``out``;
    ``massed`` is its z times √(βm) (the splitting's own layout of it)."""
    return float(max(np.hypot(np.linalg.norm(out.gradient), np.linalg.norm(massed)),
                     np.hypot(np.linalg.norm(out.X), np.linalg.norm(out.W)), 1e-300))


def relative_residuals(out, previous, massed, scale, objective=None):
    """Relative primal and dual residuals (Boyd et al. 2011, §3.3.1) of the step ``out`` after ``previous``, and the
    ``objective`` of its gradient (a function; None: not computed). The dual residual is measured in the (X, W) space
    against the scaled duals: the Y-block has no objective term, so Aᵀy is itself the dual residual and cannot serve
    as its scale."""
    X, W = out.X, out.W
    primal = np.hypot(np.linalg.norm(out.gradient - X), np.linalg.norm(massed - W))
    dual = np.hypot(np.linalg.norm(X - previous.X), np.linalg.norm(W - previous.W))
    scale_dual = np.hypot(np.linalg.norm(out.v_x - X), np.linalg.norm(out.v_w - W))
    record = {"primal": float(primal / scale), "dual": float(dual / max(scale_dual, 1e-300))}
    if objective is not None:
        record["objective"] = objective(out.gradient)
    return record


def check_affine(controls):
    """Refuse control points that are affinely dependent (all on a line or plane): no weights reproduce there."""
    K = np.c_[controls, np.ones(len(controls))]
    singular = np.linalg.svd(K, compute_uv=False)
    if np.sum(singular > 1e-12 * singular[0]) < controls.shape[1] + 1:
        raise CageError("the control points are affinely dependent (all on a line or plane): the cage is flat")
