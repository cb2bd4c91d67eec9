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
  unit diagonal. The penalty then means the same on every mesh (it is a discretisation of one continuous splitting)
  and the Y-step matrix is the P1 stiffness plus β times the mass matrix.
- ADMM runs as a Douglas-Rachford map on one state, in float32 (half the memory traffic of the loop); Anderson
  extrapolation with the safeguard of Zhang, Peng, Deng et al. (ACM TOG 2019) accelerates the map of three steps.
- The penalty is picked from the number of control points; the start is the harmonic coordinates (the reference
  computes them and throws them away).
- A 3D cage 1/200 as thick as wide or thinner (STRETCHED_SOLVE_FROM) with few control points is solved in the
  stretched frame it was meshed in, where its cells are round: the total variation's norm is then weighted per axis
  (its prox a per-entry root), and thousands of iterations become a few hundred.
- The stopping rule is relative (Boyd et al. 2011, §3.3.1), so it behaves the same across mesh sizes, and tested
  after every Anderson period: a Douglas-Rachford step's residual is α times its primal residual.
- The output is the clamped split variable W, with its exact zeros, projected back onto the equality constraints on
  its own support. It meets every constraint (the reference returns Z, which dips below zero), is exactly sparse,
  and is closer to optimal than Z at the same iteration: on the paper's cages it passes the reference's objective
  after 50-400 iterations.
"""

import time
from dataclasses import dataclass

import numpy as np

from ..kernel.constraints import project_onto_constraints
from ..kernel.frame import UnitFrame, principal_aspect
from ..kernel.progress import Laps, Progress
from .anderson import Anderson
from .forecast import default_tolerance, forecast_iterations, format_remaining, seconds_left
from .nullspace import NORM_SLICE, DenseProblem, DenseSplitting
from .objective import tv_objective
# The options record, checks, residuals and penalty are the working sets' solver's own (settings.py).
from .settings import SolveResult, balancing_factor, relative_residuals, residual_scale
from .stretch import Stretch

# Tuned on the unit-diagonal cage, per dimension (see bench/RESULTS.md): β weighs the W = Z block against the
# gradient block; the best initial penalty falls with the number of control points n as c_d / n^(1/(d-1)).
BETA = {2: 20.0, 3: 20.0}
PENALTY_SCALE = {2: 1.3, 3: 1.3}
# The dual residual is allowed this many times the primal tolerance: it lags, and the objective settles first.
DUAL_TOLERANCE_FACTOR = 10.0
# Anderson extrapolates the map of several steps: about as many steps in all as extrapolating every step (±10 %), at a
# fraction of the history work per step; in 3D five steps take 5-20 % less time than three (see bench/RESULTS.md).
ANDERSON_PERIOD = {2: 3, 3: 5}
# Over-relaxation α of each step: in 3D 1.9 takes 8-12 % fewer iterations than 1.6 on cages of 18 control points and
# more, as many on smaller ones, at the same objectives (2D keeps the α its packs were tuned with; bench/RESULTS.md).
RELAXATION = {2: 1.6, 3: 1.9}
# Penalty balancing up to iteration BALANCE_UNTIL, every BALANCE_SPACING iterations: doubled where the primal / dual
# residual ratio passes BALANCE_HIGH[d], halved below BALANCE_LOW (bench/RESULTS.md, "The penalty balanced against the
# residuals in the first iterations"; 3D's 0.6: "The penalty's band in 3D").
BALANCE_UNTIL = 300
BALANCE_HIGH, BALANCE_LOW = {2: 2.0, 3: 0.6}, 0.05
BALANCE_SPACING = 30


@dataclass
class SolverState:
    """A dense solve's final Douglas-Rachford state and what gives its parts their meaning, which the solver carries
    onto working sets for a warm re-bind (:meth:`lbc_core.solve.state.SolverState.from_dense`).

    The state is in measure-scaled variables (see :class:`DenseProblem`): v_X = X̃ + Ũ per cell, v_W = W̃ + Ṽ per
    interior vertex. A solve on the same cells and interior vertices, moved, rescales each part by its own measure: the
    split gradient X̃ = shrink(v_X) by √|c|, the dual Ũ = v_X - X̃ by the cell's shrink threshold, v_W by √(β m_v).

    Attributes
    ----------
    state : (d F n + N_in n,) float array
    thresholds : (F, n) float array
        Shrink thresholds √|c| ω / ρ the state was computed with.
    sqrt_cell : (F, 1) float array
        √|c| of each cell.
    sqrt_mass : (N_in, 1) float array
        √(β m_v) of each interior vertex.
    interior : (N_in,) int array
        The interior vertices, in the state's order.
    penalty : float or None
        The ADMM penalty the solve ended with (balanced against its residuals), for a warm start to go on with.
    """

    state: np.ndarray
    thresholds: np.ndarray
    sqrt_cell: np.ndarray
    sqrt_mass: np.ndarray
    interior: np.ndarray
    penalty: float = None

    def parts(self):
        """Views of the state as v_X (d, F, n) and v_W (N_in, n)."""
        F, n = self.thresholds.shape
        size_w = len(self.interior) * n
        v_x = self.state[:len(self.state) - size_w]
        return v_x.reshape(-1, F, n), self.state[len(self.state) - size_w:].reshape(-1, n)

    @property
    def nbytes(self):
        return sum(part.nbytes for part in (self.state, self.thresholds, self.sqrt_cell, self.sqrt_mass,
                                            self.interior))


def solve(problem, settings, penalty=None, progress=None):
    """The LBC problem solved by the dense splitting, as :func:`lbc_core.solve.solver.solve_on_mesh` takes it where
    its cost model says this splitting's iterations cost less (a cold 3D solve of a small or convex cage), or where
    ``splitting="dense"`` asks for it (the reference a tight solve gives the tests and benchmarks).

    Parameters
    ----------
    problem : tuple
        ``solve_on_mesh``'s six arrays, checked: vertices, cells, boundary vertices and weights, control points,
        TV weights.
    settings : SolveSettings
        The options ``solve_on_mesh`` resolved (tolerance, relaxation, Anderson's memory and period, precision).
    penalty : float, optional
        The starting ADMM penalty on the unit-diagonal cage; None: c_d / n^(1/(d-1)).
    progress : Progress, optional

    Returns
    -------
    SolveResult
        Its ``state`` (:class:`SolverState`) is the dense splitting's own, which the solver carries onto working sets.
    """
    timer = Laps()
    progress = Progress.of(progress)
    vertices, cells, boundary_vertices, boundary_weights, control_points, tv_weights = problem
    n_vertices, d = vertices.shape
    n = len(control_points)
    # Work on the mesh scaled to unit diagonal, so that penalty and tolerances are scale-free.
    frame = UnitFrame.exact(vertices)
    scale = frame.scale
    unit_vertices, unit_controls = frame.to_unit(vertices), frame.to_unit(control_points)
    # A very thin 3D cage is solved in its stretched frame, where its cells are round (lbc_core.solve.stretch).
    stretch = Stretch.of(unit_controls, settings.epsilon)
    solve_vertices, solve_controls = (unit_vertices, unit_controls) if stretch is None else (
        stretch.apply(unit_vertices), stretch.apply(unit_controls))
    interior = np.setdiff1d(np.arange(n_vertices), boundary_vertices)
    weights = np.empty((n_vertices, n))
    weights[boundary_vertices] = boundary_weights
    if not len(interior):
        objective = tv_objective(vertices, cells, weights, tv_weights)
        progress(1.0, "solved")
        return SolveResult(weights, 0, True, objective, tv_weights, [], timer.seconds, None)
    progress(0.0, "factorising the solver's matrix")
    problem = DenseProblem(solve_vertices, cells, boundary_vertices, boundary_weights, solve_controls, interior, BETA[d],
                           settings.dtype, progress, stretch)
    timer.lap("factorisation")
    Z, W, iterations, converged, history, state = _iterate(problem, tv_weights, settings, penalty, stretch,
                                                           unit_controls, progress)
    for record in history:  # objectives in the input's units
        if "objective" in record:
            record["objective"] *= scale ** (d - 1)
    timer.lap("solve")
    progress(_ADMM_END, "projecting onto the constraints")
    weights[interior] = project_onto_constraints(W, Z, unit_controls, unit_vertices[interior], progress.check)
    progress.check()
    # From the operators at hand, in float64: TV scales with length^(d-1).
    objective = problem.objective(weights[interior], tv_weights, progress.check) * scale ** (d - 1)
    progress(1.0, "solved")
    return SolveResult(weights, iterations, converged, objective, tv_weights, history, timer.seconds, state,
                       splitting="dense")


def _iterate(problem, tv_weights, settings, penalty, stretch, unit_controls, progress):
    """Z and W at the interior vertices (float64, unscaled), the iterations, whether converged, the history and the
    final SolverState: ADMM (:class:`_Admm`), except on a simplex cage."""
    d, n = problem.d, len(unit_controls)
    if problem.M.shape[0] == 0:
        # n = d + 1: a simplex cage. The constraints leave no freedom; Z = H are its barycentric coordinates.
        Z = W = problem.H.astype(np.float64)
        return Z, W, 0, True, [], None
    # A cold solve at the default tolerance knows about how many iterations to expect, which bounds the time left it
    # tells early on, while its residual still falls slowly.
    expected = (forecast_iterations(n, d, stretch is not None, principal_aspect(unit_controls))
                if settings.tolerance == default_tolerance(d, n) else None)
    admm = _Admm(problem, tv_weights, settings, _default_penalty(d, n) if penalty is None else penalty,
                 progress.part(_FACTORISATION_END, _ADMM_END), expected)
    return admm.solve()


# Where each part of the solve ends on its progress range (the ADMM iterations take most of the time).
_FACTORISATION_END, _ADMM_END = 0.06, 0.98


def _default_penalty(d, n):
    return PENALTY_SCALE[d] / n ** (1.0 / (d - 1))


class _Admm:
    """One solve's iterations: Douglas-Rachford steps by Anderson periods, the stopping test, the progress and time
    left it reports, and the penalty's balancing."""

    def __init__(self, problem, tv_weights, settings, penalty, progress, expected=None):
        self.problem, self.progress, self.expected = problem, progress, expected
        self.tolerance, self.max_iterations = settings.tolerance, settings.max_iterations
        self.alpha, self.check_every, self.period = settings.relaxation, settings.check_every, settings.anderson_period
        self.step = DenseSplitting(problem, tv_weights, settings.epsilon, self.alpha, penalty, progress.check)
        memory = settings.anderson_memory
        self.anderson = (Anderson(self.step.size_x + self.step.shape_w[0] * self.step.shape_w[1], memory,
                                  problem.G.dtype, progress.check) if memory else None)
        self.iteration, self.converged, self.history = 0, False, []
        # The state after the last period, its residual (None: start afresh) and its norm, and the last step.
        self.value = self.residual = self.residual_norm = self.out = None
        # What the progress reports read: the share shown, the first check's distance, the checks since the
        # penalty last changed, and when the iterations started.
        self.fraction, self.first_distance, self.checks, self.started = 0.0, None, [], None
        self.next_check = self.next_balance = settings.check_every  # the first check balances the penalty

    def solve(self):
        """Iterate from the harmonic coordinates until the residuals pass the tolerance or the iterations run out. Returns Z and W (float64, unscaled), the iterations, whether converged,
        the history and the final SolverState."""
        self.started = time.perf_counter()
        self.progress(0.0, "ADMM: starting from the harmonic coordinates")
        initial = self.step.initial_state()
        self.iteration = min(self.period, self.max_iterations)
        self.value, self.out, _, self.residual, self.residual_norm, _ = self._advance(initial, None, self.iteration)
        primal_scale, early_check_done = None, False  # the last scheduled check's scale; one early check per window
        while self.iteration < self.max_iterations:
            previous, last_norm = self._period()
            scheduled = self.iteration >= self.next_check or self.iteration >= self.max_iterations
            if scheduled:
                self.next_check += self.check_every * ((self.iteration - self.next_check) // self.check_every + 1)
            if not scheduled and early_check_done:
                continue
            # A step's residual is α times its primal residual: the primal test costs one norm. The full check (dual
            # residual, objective) runs only once it passes, at most once between two scheduled checks.
            if scheduled:
                primal_scale = residual_scale(self.out, self.step.p.sqrt_mass * self.out.Z)
            if primal_scale is None:
                continue
            passed, distance = self._check(previous, last_norm / (self.alpha * primal_scale), primal_scale, scheduled)
            if self.converged:
                break
            early_check_done = passed and not scheduled
            if scheduled:
                self._report(distance)
                self._balance(previous, primal_scale)
        # W, the clamped split variable, has exact zeros where the solver decided a coordinate vanishes; Z carries
        # faint tails there until full convergence. Both go back unscaled.
        problem, out = self.problem, self.out
        W_unscaled = out.W.astype(np.float64) / problem.sqrt_mass.astype(np.float64)
        final = SolverState(self.value, self.step.thresholds, problem.sqrt_cell, problem.sqrt_mass, problem.interior,
                            self.step.penalty)
        return out.Z.astype(np.float64), W_unscaled, self.iteration, self.converged, self.history, final

    def _advance(self, start, last, count):
        """``count`` steps from ``start``. Returns the final state, the last two steps' :class:`Step`, the residual
        final - start and its norm, and the norm of the last step's own residual (α times its primal residual).
        ``last`` is the step before, needed if count is 1. Only what the final step's checks need is kept alive
        (each state is as large as the whole problem)."""
        state = start
        for k in range(count):
            previous, previous_state = (last, state) if k == count - 1 else (None, None)
            last = None
            state, last = self.step(state)
            self.progress.check()
        residual, residual_norm = _difference(state, start, self.progress.check)
        last_norm = (residual_norm if count == 1 else
                     _difference(state, previous_state, self.progress.check, keep=False)[1])
        return state, last, previous, residual, residual_norm, float(last_norm)

    def _period(self):
        """One Anderson period from the current state: the steps from its extrapolation, or from the state itself
        where the extrapolation did not reduce the residual. Returns the step before the last and the last step's
        residual norm."""
        anderson, value, residual = self.anderson, self.value, self.residual
        candidate = anderson.extrapolate(value, residual) if anderson and residual is not None else None
        self.progress.check()  # the extrapolation and the push below each read the whole history
        if candidate is None:
            candidate = value
        count = min(self.period, self.max_iterations - self.iteration)
        before, self.out = self.out, None  # the step that made ``value``: a count of 1 needs it for its residuals
        next_value, self.out, previous, next_residual, next_norm, last_norm = self._advance(
            candidate, before if count == 1 else None, count)
        self.iteration += count
        retry = min(count, self.max_iterations - self.iteration)
        if candidate is not value and next_norm > self.residual_norm and retry:
            # Safeguard: the extrapolation did not reduce the residual; take the plain steps instead (within the
            # iteration limit; without steps left, the extrapolated ones stand).
            anderson.reset()
            candidate = value
            next_value, self.out, previous, next_residual, next_norm, last_norm = self._advance(
                candidate, before if retry == 1 else None, retry)
            self.iteration += retry
        elif anderson and residual is not None:
            anderson.push(next_value, next_residual, value, residual)
            self.progress.check()
        self.value, self.residual, self.residual_norm = next_value, next_residual, next_norm
        return previous, last_norm

    def _check(self, previous, primal, primal_scale, scheduled):
        """The stopping test on a relative primal residual: the full check once it passes (converged when both
        residuals do), recorded in the history, as a failing one is at a scheduled check. Returns whether it passed
        and the distance to the tolerance (the residuals over their tolerances, the larger)."""
        tolerance = self.tolerance
        if primal <= tolerance:
            record = dict(iteration=self.iteration, **relative_residuals(
                self.out, previous, self.step.p.sqrt_mass * self.out.Z, primal_scale, self.step.objective))
            self.history.append(record)
            if record["primal"] <= tolerance and record["dual"] <= DUAL_TOLERANCE_FACTOR * tolerance:
                self.converged = True
            return True, max(record["primal"] / tolerance, record["dual"] / (DUAL_TOLERANCE_FACTOR * tolerance))
        if scheduled:
            self.history.append(dict(iteration=self.iteration, primal=float(primal)))
        return False, primal / tolerance

    def _report(self, distance):
        """The progress at a scheduled check: the share of the way to the tolerance, and the time left."""
        self.first_distance = self.first_distance or max(distance, 1.0 + 1e-9)
        # Residuals fall roughly geometrically: show the share of the way, in log scale, to the tolerance.
        by_residual = min(0.99, np.log(self.first_distance / distance) / np.log(self.first_distance))
        self.fraction = max(self.fraction, self.iteration / self.max_iterations, by_residual)
        # The time left; none until the residual has fallen since the first check (the share of the iteration limit
        # alone said "10 min" for 2 s).
        elapsed = time.perf_counter() - self.started
        self.checks.append((self.iteration, distance))
        time_left = seconds_left(elapsed, self.fraction, self.checks, self.max_iterations)
        if self.expected is not None and self.iteration < self.expected:
            # The residual's fall early on says up to 20 times the time left (a 314-vertex UV sphere: "2 min" with
            # 8 s to go); the iterations the forecast expects say about it (bench/RESULTS.md).
            time_left = min(time_left, (self.expected - self.iteration) * elapsed / self.iteration)
        left = f", {format_remaining(time_left)}" if by_residual > 0 else ""
        self.progress(self.fraction, f"ADMM iteration {self.iteration}, residual {distance:.1f}× the tolerance{left}")

    def _balance(self, previous, primal_scale):
        """Up to BALANCE_UNTIL, every BALANCE_SPACING iterations: the penalty doubled or halved where the residuals'
        ratio leaves its band, and the next steps started afresh from the rescaled state."""
        if self.iteration < self.next_balance or self.iteration > BALANCE_UNTIL:
            return
        self.next_balance = self.iteration + BALANCE_SPACING
        massed = self.step.p.sqrt_mass * self.out.Z
        factor = balancing_factor(relative_residuals(self.out, previous, massed, primal_scale),
                                  BALANCE_HIGH[self.problem.d])
        if factor == 1.0:
            return
        self.step.rescale_penalty(self.value, factor)
        self.history.append(dict(iteration=self.iteration, penalty=self.step.penalty))
        self.checks = self.checks[-1:]  # the residual falls at another rate from here: the time left reads it anew
        if self.anderson:
            self.anderson.reset()
        self.residual, self.residual_norm = None, np.inf


def _difference(a, b, check, keep=True):
    """a - b of two flat arrays (None unless ``keep``) and its norm, slice by slice with cancel checked between: a
    state of 64k tetrahedra and 168 control points has 34M entries."""
    difference = np.empty_like(a) if keep else None
    squares = 0.0
    for start in range(0, len(a), NORM_SLICE):
        check()
        piece = np.subtract(a[start:start + NORM_SLICE], b[start:start + NORM_SLICE],
                            out=difference[start:start + NORM_SLICE] if keep else None)
        squares += float(np.linalg.norm(piece)) ** 2
    return difference, np.sqrt(squares)


