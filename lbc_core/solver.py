"""The LBC optimisation (the paper's Eq. 6 and Appendix B), solved by ADMM.

    minimise   Σ_i Σ_cells ω_ci |c| |∇w_i|           (weighted total variation)
    subject to Σ_i w_i = 1, Σ_i w_i c_i = x        (partition of unity, reproduction)  at every vertex
               w_i ≥ 0                              (non-negativity)
               w = fixed boundary values on the cage

Unknowns are the interior vertices' weights Z (N_in, n). The equality constraints are eliminated exactly as in the
paper: Z = Y M + H with M an orthonormal basis of the constraints' null space and H the least-norm solution, so every
iterate satisfies them to round-off. ADMM splits X = ∇Z (per-cell gradients) and W = Z (clamped to [0, 1]).

Where this differs from the authors' reference, and why:
- The splitting is weighted by the mesh's measures (cell measure for X, lumped vertex mass for W), on a cage scaled to
  unit diagonal. The penalty then means the same on every mesh and the Y-step matrix is the P1 stiffness plus β times
  the mass matrix; the reference's unweighted splitting needs more iterations as the mesh is refined.
- The penalty adapts (residual balancing); that needs no new factorisation because both blocks share it.
- The start is the harmonic coordinates (the reference computes them and throws them away).
- The stopping rule is relative (Boyd et al. 2011, §3.3.1), so it behaves the same across mesh sizes.
- The result is projected onto the non-negative set with the equality constraints kept, so the output satisfies all
  constraints (the reference returns Z, which dips below zero).
"""

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import fem
from .objective import tv_objective
from .errors import Cancelled, CageError
from .reduction import restore_constraints

BETA = 0.05
DEFAULT_PENALTY = 0.3
MEMORY = 5


@dataclass
class SolveResult:
    """Result of :func:`solve_on_mesh`.

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
    history : list of dict
        Residuals and penalty at each convergence check.
    seconds : dict
        Time per stage.
    """

    weights: np.ndarray
    iterations: int
    converged: bool
    objective: float
    tv_weights: np.ndarray
    history: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)


def solve_on_mesh(
    vertices,
    cells,
    boundary_vertices,
    boundary_weights,
    control_points,
    tv_weights=None,
    *,
    weighting="quadratic",
    epsilon=0.0,
    tolerance=1e-4,
    max_iterations=10000,
    penalty=None,
    relaxation=1.6,
    check_every=10,
    progress=None,
    cancel=None,
):
    """Local barycentric coordinates on a given mesh of the cage's interior.

    Parameters
    ----------
    vertices : (N, d) float array
    cells : (F, d+1) int array, triangles (d = 2) or tetrahedra (d = 3)
    boundary_vertices : (B,) int array
        Vertices whose weights are fixed (all vertices on the cage).
    boundary_weights : (B, n) float array
        Their weights; each row sums to 1 and reproduces the vertex's position.
    control_points : (n, d) float array
    tv_weights : (F, n) float array, optional
        ω per cell and coordinate; None computes them from heat-method geodesic distances from the control points,
        which must then be mesh vertices.
    weighting : str or callable
        ρ for computing ``tv_weights`` (see :func:`lbc_core.geodesics.tv_weights`).
    epsilon : float
        C¹ relaxation width: |∇w| is replaced by its Huber smoothing (quadratic below ε, in 1/length units of the
        unit-diagonal cage, linear above), which makes the coordinates smoother at the cost of some locality.
        0 is the paper's plain total variation.
    tolerance : float
        Relative primal and dual residual tolerance of the stopping rule.
    max_iterations : int
    penalty : float, optional
        Initial ADMM penalty ρ (adapted during the solve); None picks one from the problem's scale.
    relaxation : float
        Over-relaxation α in (0, 2).
    check_every : int
        Iterations between convergence checks, progress reports and cancel checks.
    progress : callable(fraction, message), optional
    cancel : callable() -> bool, optional
        When it returns True the solve raises :class:`lbc_core.Cancelled`.

    Returns
    -------
    SolveResult
    """
    timer = _Timer()
    vertices = np.asarray(vertices, dtype=float)
    cells = np.asarray(cells, dtype=np.int64)
    boundary_vertices = np.asarray(boundary_vertices, dtype=np.int64)
    boundary_weights = np.asarray(boundary_weights, dtype=float)
    control_points = np.asarray(control_points, dtype=float)
    n_vertices, d = vertices.shape
    n = len(control_points)
    _check_problem(vertices, cells, boundary_vertices, boundary_weights, control_points, tv_weights)

    if tv_weights is None:
        from .geodesics import geodesic_distances, tv_weights as make_tv_weights

        sources = _control_vertices(vertices, control_points)
        tv_weights = make_tv_weights(cells, geodesic_distances(vertices, cells, sources, cancel), weighting)
        timer.lap("geodesics")
    tv_weights = np.asarray(tv_weights, dtype=float)

    # Work on the cage scaled to unit diagonal, so that penalty and tolerances are scale-free.
    centre = vertices.mean(axis=0)
    scale = np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))
    unit_vertices = (vertices - centre) / scale
    unit_controls = (control_points - centre) / scale

    interior = np.setdiff1d(np.arange(n_vertices), boundary_vertices)
    problem = _Problem(unit_vertices, cells, boundary_vertices, boundary_weights, unit_controls, interior)
    problem.length_scale = scale
    timer.lap("setup")

    weights = np.empty((n_vertices, n))
    weights[boundary_vertices] = boundary_weights
    if len(interior):
        factor = _Factor(problem.system)
        timer.lap("factorisation")
        Z, iterations, converged, history = _admm(
            problem, factor, tv_weights, epsilon, tolerance, max_iterations, penalty, relaxation, check_every,
            progress, cancel,
        )
        timer.lap("solve")
        weights[interior] = restore_constraints(Z, unit_controls, unit_vertices[interior])
    else:
        iterations, converged, history = 0, True, []
    objective = tv_objective(vertices, cells, weights, tv_weights)
    return SolveResult(weights, iterations, converged, objective, tv_weights, history, timer.seconds)


def _check_problem(vertices, cells, boundary_vertices, boundary_weights, control_points, tv_weights):
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
    if tv_weights is not None and np.shape(tv_weights) != (len(cells), n):
        raise CageError(f"tv_weights must be (F, n) = ({len(cells)}, {n}), got {np.shape(tv_weights)}")


def _control_vertices(vertices, control_points):
    from scipy.spatial import cKDTree

    distance, index = cKDTree(vertices).query(control_points)
    diagonal = np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))
    if np.any(distance > 1e-9 * diagonal):
        raise CageError("to compute geodesic TV weights every control point must be a vertex of the mesh")
    return index


class _Problem:
    """The fixed data of one solve, on the unit-diagonal cage."""

    def __init__(self, vertices, cells, boundary_vertices, boundary_weights, controls, interior):
        n_vertices, d = vertices.shape
        G, measures = fem.gradient_operator(vertices, cells)
        G = G.tocsc()
        self.d = d
        self.measures = measures  # (F,)
        self.cell_weight = np.repeat(measures, d)[:, None]  # (d F, 1): the X block's weighting
        self.G = G[:, interior].tocsr()  # (d F, N_in)
        self.GT = self.G.T.tocsr()
        self.E = G[:, boundary_vertices] @ boundary_weights  # (d F, n): gradient of the fixed boundary part
        self.mass = fem.mass_matrix(vertices, cells, lumped=True).diagonal()[interior][:, None]  # (N_in, 1)
        # Equality constraints z K = [x, 1] per vertex, K = [C, 1] (n, d+1): Z = Y M + H.
        K = np.c_[controls, np.ones(len(controls))]
        _, singular, vt = np.linalg.svd(K.T)
        rank = int(np.sum(singular > 1e-12 * singular[0]))
        if rank < d + 1:
            raise CageError("the control points are affinely dependent (all on a line or plane): the cage is flat")
        self.M = vt[rank:]  # (n - d - 1, n), orthonormal rows
        self.H = np.c_[vertices[interior], np.ones(len(interior))] @ np.linalg.pinv(K)  # (N_in, n)
        # β balances the two blocks: |∇w|² is in 1/length², |w|² is not; on the unit cage β ~ 1 per unit length².
        self.beta = 1.0 / np.mean(measures) ** (2.0 / d) * BETA
        stiffness = self.GT @ sp.diags(self.cell_weight.ravel()) @ self.G
        self.system = (stiffness + sp.diags(self.beta * self.mass.ravel())).tocsc()
        self.n_interior = len(interior)


class _Factor:
    """A factorisation of the SPD Y-step matrix that solves for many right-hand sides in one call."""

    def __init__(self, matrix):
        try:
            from cholespy import CholeskySolverD, MatrixType

            coo = matrix.tocoo()
            self._solver = CholeskySolverD(matrix.shape[0], coo.row, coo.col, coo.data, MatrixType.COO)
            self._kind = "cholespy"
        except ImportError:
            self._solver = spla.splu(matrix, permc_spec="MMD_AT_PLUS_A")
            self._kind = "splu"

    def solve(self, rhs):
        if self._kind == "cholespy":
            out = np.empty_like(rhs)
            self._solver.solve(np.ascontiguousarray(rhs), out)
            return out
        return self._solver.solve(rhs)


class _AdmmMap:
    """One over-relaxed ADMM iteration as a map on the state (X, W, U, V), stored in one flat array.

    The Y-step depends only on that state, so the iteration is a fixed-point map that Anderson acceleration can
    extrapolate.
    """

    def __init__(self, problem, factor, tv_weights, epsilon, alpha):
        p = problem
        self.p, self.factor, self.epsilon, self.alpha = p, factor, epsilon, alpha
        self.tv_weights = tv_weights
        self.n_cells, self.d = len(p.measures), p.d
        n = tv_weights.shape[1]
        self.shape_x = (self.n_cells * self.d, n)
        self.shape_w = (p.n_interior, n)
        size_x, size_w = self.shape_x[0] * n, self.shape_w[0] * n
        self.bounds = np.cumsum([0, size_x, size_w, size_x, size_w])
        # The metric of the residuals: cell measures on X and U, β-weighted vertex masses on W and V.
        sqrt_x = np.broadcast_to(np.sqrt(p.cell_weight), self.shape_x).ravel()
        sqrt_w = np.broadcast_to(np.sqrt(p.beta * p.mass), self.shape_w).ravel()
        self.metric = np.concatenate([sqrt_x, sqrt_w, sqrt_x, sqrt_w])
        self.cell_weight = p.cell_weight
        self.mass_weight = p.beta * p.mass
        self.rho = 1.0

    def views(self, state):
        """(X, W, U, V) as 2D views into a flat state."""
        b = self.bounds
        return (state[b[0]:b[1]].reshape(self.shape_x), state[b[1]:b[2]].reshape(self.shape_w),
                state[b[2]:b[3]].reshape(self.shape_x), state[b[3]:b[4]].reshape(self.shape_w))

    def initial_state(self):
        """The harmonic coordinates (the Y-step with zero fields and duals), with X, W taken from them."""
        p = self.p
        Z = self.factor.solve(-(p.GT @ (self.cell_weight * p.E)) @ p.M.T) @ p.M + p.H
        state = np.zeros(self.bounds[-1])
        X, W, _, _ = self.views(state)
        X[:] = p.G @ Z + p.E
        W[:] = np.clip(Z, 0.0, 1.0)
        return state

    def __call__(self, state, out):
        """Write the next state into ``out``; return Z and its gradient (for residuals and the objective)."""
        p, alpha = self.p, self.alpha
        X, W, U, V = self.views(state)
        rhs = p.GT @ (self.cell_weight * (X - p.E - U)) + self.mass_weight * (W - V)
        Z = self.factor.solve(rhs @ p.M.T) @ p.M + p.H
        gradient = p.G @ Z + p.E
        relaxed_gradient = alpha * gradient + (1.0 - alpha) * X
        relaxed_Z = alpha * Z + (1.0 - alpha) * W
        X_new, W_new, U_new, V_new = self.views(out)
        np.add(relaxed_gradient, U, out=U_new)
        X_new[:] = _shrink(U_new, self.tv_weights / self.rho, self.epsilon, self.n_cells, self.d)
        U_new -= X_new
        np.add(relaxed_Z, V, out=V_new)
        np.clip(V_new, 0.0, 1.0, out=W_new)
        V_new -= W_new
        return Z, gradient

    def objective(self, gradient):
        """Σ ω |c| |∇w| on the unit-diagonal cage."""
        return float(np.sum(self.tv_weights * self.p.measures[:, None] * _group_norms(gradient, self.n_cells, self.d)))


class _Anderson:
    """Anderson acceleration (type II) of a fixed-point map, with the residual safeguard of Zhang et al. 2019."""

    def __init__(self, size, memory, metric):
        self.memory = memory
        self.metric = metric
        self.dF = np.zeros((memory, size))  # weighted residual differences
        self.dG = np.zeros((memory, size))  # map-value differences
        self.count = 0

    def reset(self):
        self.count = 0

    def extrapolate(self, value, residual, previous_value, previous_residual):
        """Record the newest step and return the extrapolated next state (or None without history)."""
        if previous_value is not None:
            slot = self.count % self.memory
            self.dF[slot] = self.metric * (residual - previous_residual)
            self.dG[slot] = value - previous_value
            self.count += 1
        used = min(self.count, self.memory)
        if used == 0:
            return None
        dF, dG = self.dF[:used], self.dG[:used]
        gram = dF @ dF.T
        gram += 1e-10 * np.trace(gram) / used * np.eye(used)
        theta = np.linalg.solve(gram, dF @ (self.metric * residual))
        return value - theta @ dG


def _admm(problem, factor, tv_weights, epsilon, tolerance, max_iterations, penalty, alpha, check_every, progress,
          cancel, memory=None):
    memory = MEMORY if memory is None else memory
    step = _AdmmMap(problem, factor, tv_weights, epsilon, alpha)
    step.rho = penalty if penalty is not None else DEFAULT_PENALTY
    metric = step.metric
    anderson = _Anderson(step.bounds[-1], memory, metric) if memory else None

    state = step.initial_state()
    value = np.empty_like(state)
    Z, gradient = step(state, value)
    residual = value - state
    residual_norm = np.linalg.norm(metric * residual)
    previous_value = previous_residual = None
    history = []
    converged = False
    iteration = 1
    while iteration < max_iterations:
        candidate = anderson.extrapolate(value, residual, previous_value, previous_residual) if anderson else None
        accelerated = candidate is not None
        if not accelerated:
            candidate = value
        next_value = np.empty_like(state)
        Z_next, gradient_next = step(candidate, next_value)
        iteration += 1
        next_residual = next_value - candidate
        next_norm = np.linalg.norm(metric * next_residual)
        if accelerated and next_norm > residual_norm:
            # Safeguard: the extrapolation did not reduce the combined residual; take the plain step instead.
            anderson.reset()
            candidate = value
            Z_next, gradient_next = step(candidate, next_value)
            iteration += 1
            next_residual = next_value - candidate
            next_norm = np.linalg.norm(metric * next_residual)
            previous_value = previous_residual = None
        else:
            previous_value, previous_residual = value, residual
        state, value, residual, residual_norm = candidate, next_value, next_residual, next_norm
        Z, gradient = Z_next, gradient_next
        if iteration % check_every and iteration < max_iterations:
            continue
        X, W, U, V = step.views(value)
        X_old, W_old, _, _ = step.views(state)
        sqrt_cell, sqrt_mass = np.sqrt(step.cell_weight), np.sqrt(step.mass_weight)
        primal = _weighted_norm(sqrt_cell, gradient - X, sqrt_mass, Z - W)
        # Dual residual and its scale in the (X, W) space: the Y-block has no objective term, so Aᵀy is itself the
        # dual residual and cannot be its scale; the scaled duals U, V can.
        dual = _weighted_norm(sqrt_cell, X - X_old, sqrt_mass, W - W_old)
        scale_dual = _weighted_norm(sqrt_cell, U, sqrt_mass, V)
        scale_primal = max(
            _weighted_norm(sqrt_cell, gradient, sqrt_mass, Z), _weighted_norm(sqrt_cell, X, sqrt_mass, W)
        )
        history.append({
            "iteration": iteration,
            "objective": step.objective(gradient) * problem.length_scale ** (problem.d - 1),
            "primal": primal / scale_primal,
            "dual": dual / max(scale_dual, 1e-300),
        })
        if primal <= tolerance * scale_primal and dual <= tolerance * scale_dual:
            converged = True
            break
        if progress is not None:
            progress(iteration / max_iterations, f"ADMM iteration {iteration}")
        if cancel is not None and cancel():
            raise Cancelled("cancelled during the LBC solve")
    return Z, iteration, converged, history


def _shrink(values, thresholds, epsilon, n_cells, d):
    """Group soft-thresholding of each cell's gradient vector (prox of ω|g|, or of its Huber smoothing)."""
    grouped = values.reshape(n_cells, d, -1)
    norms = _group_norms(values, n_cells, d)
    if epsilon > 0:
        # prox of τ·huber_ε: shrink by τ beyond ε + τ, scale by ε / (ε + τ) inside.
        scale = np.where(
            norms > epsilon + thresholds,
            1.0 - thresholds / np.maximum(norms, 1e-300),
            epsilon / (epsilon + thresholds),
        )
    else:
        scale = np.maximum(1.0 - thresholds / np.maximum(norms, 1e-300), 0.0)
    return (grouped * scale[:, None, :]).reshape(values.shape)


def _weighted_norm(weight_x, x, weight_w, w):
    """sqrt(Σ weight_x² x² + Σ weight_w² w²): the measure-weighted norm of an (X, W) pair."""
    return float(np.sqrt(np.sum((weight_x * x) ** 2) + np.sum((weight_w * w) ** 2)))


def _group_norms(values, n_cells, d):
    """|g| of each cell's d-vector in a cell-major (d F, n) array; returns (F, n)."""
    grouped = values.reshape(n_cells, d, -1)
    squared = grouped[:, 0] * grouped[:, 0]
    for k in range(1, d):
        squared += grouped[:, k] * grouped[:, k]
    return np.sqrt(squared)


class _Timer:
    def __init__(self):
        self.seconds = {}
        self._last = time.perf_counter()

    def lap(self, stage):
        now = time.perf_counter()
        self.seconds[stage] = self.seconds.get(stage, 0.0) + now - self._last
        self._last = now
