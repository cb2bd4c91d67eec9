"""The LBC optimisation (the paper's Eq. 6), solved by ADMM on working sets whose cost follows the supports.

    minimise   Σ_i Σ_cells ω_ci |c| |∇w_i|           (weighted total variation)
    subject to Σ_i w_i = 1, Σ_i w_i c_i = x        (partition of unity, reproduction)  at every vertex
               w_i ≥ 0                              (non-negativity)
               w = fixed boundary values on the cage

The constraints are a per-vertex block: the split variable W = Z is projected, vertex by vertex, onto them
(:mod:`lbc_core.solve.projection`), so every iterate W is exactly feasible and no basis couples the coordinates. Each
vertex holds only the coordinates of its working set (:mod:`lbc_core.solve.working_sets`): they start from the harmonic
coordinates' largest and grow where a coordinate turns positive next to a vertex that cannot hold it, so a
step's cost follows the (cell, coordinate) pairs near the supports, not the number of control points. The step
itself is :mod:`lbc_core.solve.splitting`; Anderson extrapolation (:mod:`lbc_core.solve.anderson`) with the safeguard of
Zhang, Peng, Deng et al. (ACM TOG 2019) accelerates it; the penalty is balanced against the residuals early on (Boyd et
al. 2011, §3.4.1); the stopping rule is relative (§3.3.1). A very thin 3D cage with few control points iterates in the
stretched frame it was meshed in (:mod:`lbc_core.solve.stretch`). Measurements: bench/RESULTS.md, "The locality solver".
"""

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import CageError
from ..kernel import fem
from ..kernel.factor import Factor
from ..kernel.frame import UnitFrame, principal_aspect
from ..kernel.geometry import hull_share, signed_measures
from ..kernel.progress import Laps, Progress
from . import dense
from .anderson import Anderson
from .forecast import (SMALL_CAGE, default_tolerance, dense_tolerance_share, forecast_iterations, format_remaining,
                       seconds_left, takes_dense_splitting)
from .objective import tv_objective
from .settings import (SolveResult, SolveSettings, balancing_factor, check_affine, check_problem, relative_residuals,
                       residual_scale, starting_penalty)
from .splitting import DouglasRachford
from .state import SolverState
from .stretch import Stretch
from .pairs import PairOperators
from .working_sets import MeshData, WorkingSets, feasible_working_sets, first_working_sets

# β: the weight of the W = Z block against the gradient block, on the unit-diagonal cage.
BETA = {2: 1280.0, 3: 1280.0}
# The starting penalty c_d / n^(1/(d-1)) for n control points: c_d.
PENALTY_SCALE = {2: 1.3, 3: 0.3}
# The dual residual's tolerance as a multiple of the primal one (it lags; the objective settles first).
DUAL_TOLERANCE_FACTOR = 10.0
# Steps per Anderson extrapolation, and the over-relaxation α of each step.
ANDERSON_PERIOD = {2: 3, 3: 5}
RELAXATION = {2: 1.6, 3: 1.9}
# Penalty balancing: up to BALANCE_UNTIL iterations, every BALANCE_SPACING, double the penalty when the primal
# residual exceeds BALANCE_HIGH times the dual, halve it below BALANCE_LOW times (bench/RESULTS.md, "The penalty
# balanced against the residuals in the first iterations").
BALANCE_UNTIL, BALANCE_SPACING = 300, 30
BALANCE_HIGH = {2: 2.0, 3: 0.6}  # BALANCE_LOW: settings.py
# The working sets are reshaped to one ring of vertices around the weights above GROWTH_FLOOR at iterations
# GROWTH_FIRST_CHECK, then each time GROWTH_SPACING times as many (bench/RESULTS.md, "Working sets: start, growth,
# pruning").
GROWTH_FIRST_CHECK, GROWTH_SPACING, GROWTH_FLOOR = 20, 3, 1e-3
# A solve that meets its tolerance stops unless growing would add more than END_GROWTH_SHARE of its slots; it then
# grows around the weights above END_GROWTH_FLOOR, a margin for the next check (same section).
END_GROWTH_SHARE, END_GROWTH_FLOOR = 0.005, 1e-4
# Whole working sets of cages above SMALL_CAGE control points (supports spread wide: a slow tail) stop at this
# share of the tolerance (bench/RESULTS.md, "Whole working sets stop at a fifth of the tolerance").
WHOLE_TOLERANCE_SHARE = 0.2
# Where each part of the solve ends on its progress range.
_SETUP_END, _ADMM_END = 0.06, 0.98
# The iterations' progress until the tolerance is first met stops at this share: where the forecast's iterations
# are too few, the rest and the end game's growth still move it (bench/RESULTS.md, "The time left in the end game").
BEFORE_END_GAME_SHARE = 0.9


def solve_on_mesh(
    vertices,
    cells,
    boundary_vertices,
    boundary_weights,
    control_points,
    tv_weights,
    *,
    epsilon=0.0,
    tolerance=None,
    max_iterations=10000,
    penalty=None,
    relaxation=None,
    check_every=10,
    anderson_memory=5,
    anderson_period=None,
    single_precision=True,
    start=None,
    splitting=None,
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
    tv_weights : (F, n) float array
        ω per cell and coordinate (:func:`lbc_core.solve.geodesics.tv_weights` of the geodesic distances).
    epsilon : float
        C¹ relaxation width: |∇w| is replaced by its Huber smoothing (quadratic below ε, in 1/length units of the
        unit-diagonal cage, linear above), smoother coordinates at the cost of some locality. 0 is the paper's plain
        total variation.
    tolerance : float, optional
        Relative primal residual tolerance of the stopping rule (the dual one is DUAL_TOLERANCE_FACTOR times larger);
        None: :func:`lbc_core.solve.forecast.default_tolerance`.
    max_iterations : int
    penalty : float, optional
        The starting ADMM penalty ρ on the unit-diagonal cage; None picks the one ``start`` ended with, else
        c_d / n^(1/(d-1)). It is balanced against the residuals in the first BALANCE_UNTIL iterations.
    relaxation : float, optional
        Over-relaxation α in (0, 2); None picks RELAXATION[d].
    check_every : int
        Iterations between progress reports and checks of the working sets (cancel is checked within every
        iteration).
    anderson_memory : int
        Extrapolations remembered by Anderson acceleration (0: plain ADMM).
    anderson_period : int, optional
        Steps per Anderson extrapolation (None: ANDERSON_PERIOD of the dimension).
    single_precision : bool
        Iterate in float32 (half the memory and its traffic); the output is projected onto the constraints in
        float64 either way.
    start : SolverState, optional
        A previous solve's final state (``SolveResult.state``) on the same cells and interior vertices, whose
        vertices may have moved (a mesh carried onto an edited cage, see :mod:`lbc_core.binding.rebinding`).
    splitting : {None, "working sets", "dense"}
        None: a cold 3D solve without a ``penalty`` takes the dense splitting where the cost model says its iterations
        cost less (:func:`~lbc_core.solve.forecast.takes_dense_splitting`: few control points, or a convex cage), the
        splitting on working sets otherwise; the others force one (a warm start always takes the working sets').
    progress : callable(fraction, message) or Progress, optional
    cancel : callable() -> bool, optional
        Polled between the steps of every stage; when it returns True the solve raises :class:`lbc_core.Cancelled`.

    Returns
    -------
    SolveResult
    """
    if splitting not in (None, "working sets", "dense"):
        raise CageError(f"splitting must be None, 'working sets' or 'dense', not {splitting!r}")
    clock = Laps()
    progress = Progress.of(progress, cancel)
    vertices = np.asarray(vertices, dtype=float)
    cells = np.asarray(cells, dtype=np.int64)
    boundary_vertices = np.asarray(boundary_vertices, dtype=np.int64)
    boundary_weights = np.asarray(boundary_weights, dtype=float)
    control_points = np.asarray(control_points, dtype=float)
    tv_weights = np.asarray(tv_weights, dtype=float)
    n_vertices, d = vertices.shape
    n = len(control_points)
    check_problem(vertices, cells, boundary_vertices, boundary_weights, control_points, tv_weights)
    if start is not None:
        _check_start(start, cells, n, n_vertices - len(boundary_vertices))
    tolerance = default_tolerance(d, n) if tolerance is None else tolerance
    settings = SolveSettings(epsilon, tolerance, max_iterations, relaxation or RELAXATION[d], check_every,
                         anderson_memory, anderson_period or ANDERSON_PERIOD[d],
                         np.float32 if single_precision else np.float64)

    # Work on the mesh scaled to unit diagonal, so that penalty and tolerances are scale-free.
    frame = UnitFrame.exact(vertices)
    unit_vertices, unit_controls = frame.to_unit(vertices), frame.to_unit(control_points)
    check_affine(unit_controls)
    stretch = Stretch.of(unit_controls, epsilon)
    solve_vertices = unit_vertices if stretch is None else stretch.apply(unit_vertices)

    weights = np.zeros((n_vertices, n))
    weights[boundary_vertices] = boundary_weights
    iterations, converged, history, state = 0, True, [], None
    progress.check()
    mesh = MeshData.of(solve_vertices, cells, boundary_vertices, boundary_weights, BETA[d], unit_controls,
                       unit_vertices)
    convexity = _convexity(unit_vertices, cells)
    dense = splitting == "dense" or (splitting is None and penalty is None and
                                      takes_dense_splitting(n, len(cells), d, convexity))
    if len(mesh.interior) and start is None and dense:
        if tolerance == default_tolerance(d, n):
            settings.tolerance *= dense_tolerance_share(n, d, convexity)
        return _dense_solve(mesh, (vertices, cells, boundary_vertices, boundary_weights, control_points, tv_weights),
                            settings, penalty, progress)
    if len(mesh.interior):
        progress(0.0, "finding where each control point may act (preparing the solver)")
        sets, first, duals, carried = _starting_point(mesh, start, progress)
        clock.lap("factorisation")
        expected = (forecast_iterations(n, d, stretch is not None, principal_aspect(unit_controls), len(cells),
                                        convexity)
                    if start is None and tolerance == default_tolerance(d, n) else None)
        run = _Run(mesh, tv_weights, settings, stretch, starting_penalty(penalty, start, _default_penalty(d, n)),
                   progress, expected)
        solution = run.solve(sets, first, duals, carried)
        iterations, converged, history, state = run.iteration, run.converged, run.history, solution.state
        for record in history:  # objectives in the input's units
            if "objective" in record:
                record["objective"] *= frame.scale ** (d - 1)
        weights[mesh.interior] = solution.sets.matrix(solution.weights).toarray()
        clock.lap("solve")
    objective = tv_objective(vertices, cells, weights, tv_weights)
    progress(1.0, "solved")
    return SolveResult(weights, iterations, converged, objective, tv_weights, history, clock.seconds, state)


def _dense_solve(mesh, problem, settings, penalty, progress):
    """The solve by the dense splitting (:mod:`lbc_core.solve.dense`), taken where its cost model says its iterations
    cost less (:func:`~lbc_core.solve.forecast.takes_dense_splitting`): the same problem, options and guarantees, its
    final state carried onto working sets for a warm re-bind. ``problem``: solve_on_mesh's six arrays."""
    vertices, control_points, tv_weights = problem[0], problem[4], problem[5]
    result = dense.solve(problem, settings, penalty, progress)
    state = None
    if result.state is not None:
        d, n = vertices.shape[1], len(control_points)
        state = SolverState.from_dense(result.state, result.weights[mesh.interior], mesh,
                                       _default_penalty(d, n))
    return SolveResult(result.weights, result.iterations, result.converged, result.objective, tv_weights,
                       result.history, result.seconds, state, splitting="dense")


@dataclass
class _Solution:
    sets: WorkingSets
    weights: np.ndarray
    state: "SolverState"


def _starting_point(mesh, start, progress):
    """The first working sets, weights on them, projection duals, and the carried split state (or None)."""
    if start is None:
        harmonic = _harmonic(mesh, progress.check)
        sets, weights, duals = first_working_sets(mesh, harmonic, progress.check)
        return sets, weights, duals, None
    values = start.slot_state / start.sqrt_mass[start.sets.vertex_of_slot]
    sets, weights, duals = feasible_working_sets(mesh, start.sets, values, start.duals, progress.check)
    return sets, weights, duals, start


def _harmonic(mesh, check):
    """The harmonic coordinates at the interior vertices: the P1 Laplacian's solve with the boundary values."""
    stiffness = fem.stiffness_matrix(mesh.vertices, mesh.cells)
    interior = mesh.interior
    check()
    lower = sp.tril(stiffness[interior][:, interior]).tocoo()
    rhs = -(stiffness[interior] @ mesh.fixed).toarray()
    check()
    return Factor(lower, np.float64).solve(rhs)


class _Run:
    """One solve's iterations: steps, Anderson, checks, penalty balancing and growth of the working sets."""

    def __init__(self, mesh, tv_weights, settings, stretch, penalty, progress, expected):
        self.mesh, self.tv_weights, self.settings, self.stretch = mesh, tv_weights, settings, stretch
        self.penalty, self.expected = penalty, expected
        self.outer_progress, self.progress = progress, progress.part(_SETUP_END, _ADMM_END)
        self.iteration, self.converged, self.history = 0, False, []
        self.next_growth_check = GROWTH_FIRST_CHECK
        self.reshapes = self.reshapes_told = 0
        self.wide = self.wide_told = False
        # The end game's clock: seconds spent in reshapes, the last one's iteration, and how many iterations the
        # residual took to meet the tolerance after it (None until it first did).
        self.reshape_seconds, self.last_reshape, self.settle = 0.0, 0, None

    def _step_map(self, ops, duals):
        axis_scale = None if self.stretch is None else self.stretch.axis_scale
        tv_scale = 1.0 if self.stretch is None else self.stretch.tv_scale
        return DouglasRachford(ops, self.tv_weights, self.settings.epsilon, self.settings.relaxation, self.penalty,
                               axis_scale, tv_scale, duals)

    def solve(self, sets, weights, duals, carried):
        check = self.progress.check
        grown = sets.grown(self.mesh.margins(sets, weights)[0])
        if grown is not None:
            weights = _moved(weights, sets.slot_positions(grown), grown.n_slots)
            sets = grown
        check()
        step = self._step_map(PairOperators(self.mesh, sets, self.settings.dtype, check), duals)
        check()
        start = [step, step.state_of(weights) if carried is None else carried.state_for(step, sets)]
        if carried is not None:  # a warm start's sets fit already: its first reshape comes later
            self.next_growth_check = GROWTH_SPACING ** 2 * GROWTH_FIRST_CHECK
        self.started = time.perf_counter()
        self.checks, self.fraction, self.way, self.first_distance = [], 0.0, 0.0, None
        del step, weights, sets  # _iterate empties ``start``: no frame here keeps the first layout once reshaped
        state, out, step = self._iterate(start)
        final = SolverState.of(step, state, self.mesh)
        self.outer_progress(_ADMM_END, "projecting onto the constraints")
        return _Solution(step.ops.sets, step.final_weights(state), final)

    def _iterate(self, start):
        """Steps from ``start`` ([step map, state], emptied here) until convergence or the iteration limit, through
        growths of the working sets: the final state, the last step's record and the step map it ended on."""
        step, value = start
        start.clear()
        settings, check = self.settings, self.progress.check
        anderson = Anderson(len(value), settings.anderson_memory, np.float32, check) \
            if settings.anderson_memory else None
        alpha, period = settings.relaxation, settings.anderson_period
        residual, norm, out, previous = None, np.inf, None, None
        next_check = self.iteration + settings.check_every
        primal_scale = None
        while self.iteration < settings.max_iterations:
            candidate = anderson.extrapolate(value, residual) if anderson and residual is not None else None
            check()
            start_value = value if candidate is None else candidate
            count = min(period, settings.max_iterations - self.iteration)
            new_value, new_out, new_previous, last_norm = self._advance(step, start_value, count, out)
            self.iteration += count
            new_residual = new_value - start_value
            new_norm = float(np.linalg.norm(new_residual))
            if candidate is not None and new_norm > norm:
                # Safeguard: the extrapolation did not reduce the residual; take the plain steps instead.
                anderson.reset()
                retry = min(count, settings.max_iterations - self.iteration)
                if retry:
                    new_value, new_out, new_previous, last_norm = self._advance(step, value, retry, out)
                    self.iteration += retry
                    new_residual = new_value - value
                    new_norm = float(np.linalg.norm(new_residual))
            elif anderson and residual is not None:
                anderson.push(new_value, new_residual, value, residual)
            value, residual, norm, out, previous = new_value, new_residual, new_norm, new_out, new_previous
            if self.iteration < next_check and self.iteration < settings.max_iterations:
                continue
            next_check = self.iteration + settings.check_every
            primal_scale = residual_scale(out, step.ops.slot_mass * out.z)
            verdict = self._check(step, value, out, previous, last_norm / (alpha * primal_scale), primal_scale)
            if verdict == "converged":
                self.converged = True
                return value, out, step
            if verdict == "reshaped":
                # The old layout's records and candidates are not kept through the reshape (its memory peak).
                out = previous = None
                del candidate, start_value, new_value, new_out, new_previous, new_residual
                began = time.perf_counter()
                step, positions = self._reshape(step)
                value = _moved(value, positions, step.size_x + step.ops.sets.n_slots)
                check()
                residual = None if residual is None else _moved(residual, positions, len(value))
                check()
                if anderson:
                    anderson.embed(positions, len(value), residual)
                next_check = self.iteration + settings.check_every
                self.reshape_seconds += time.perf_counter() - began
                self.last_reshape = self.iteration
            if verdict == "rescaled":
                if anderson:
                    anderson.reset()
                residual, norm = None, np.inf
        return value, out, step

    def _advance(self, step, state, count, last):
        """``count`` steps from ``state``: the final state, the last two steps' records and the norm of the last
        step's own residual (α times its primal residual)."""
        previous = last
        for k in range(count):
            before = state
            state, record = step(state)
            previous, last = last, record
            self.progress.check()
        return state, last, previous, float(np.linalg.norm(state - before))

    def _check(self, step, value, out, previous, primal, primal_scale):
        """A scheduled check: progress, convergence, growth of the working sets, penalty balancing."""
        settings = self.settings
        if step.ops.sets.whole and step.ops.sets.n_controls > SMALL_CAGE and not self.wide:
            self.wide, self.expected = True, None  # the forecast's iterations know nothing of the tighter stop
            if self.first_distance:  # the way left is measured against the tighter stop from here on
                self.first_distance /= WHOLE_TOLERANCE_SHARE
        tolerance = settings.tolerance * (WHOLE_TOLERANCE_SHARE if self.wide else 1.0)
        self.pending_growth = None
        if primal <= tolerance and previous is not None:
            massed = step.ops.slot_mass * out.z
            record = dict(iteration=self.iteration,
                          **relative_residuals(out, previous, massed, primal_scale, step.objective))
            self.history.append(record)
            distance = max(record["primal"] / tolerance, record["dual"] / (DUAL_TOLERANCE_FACTOR * tolerance))
            if distance <= 1:
                self.settle = self.iteration - self.last_reshape
                self.pending_growth = self._growth(step, out, GROWTH_FLOOR, prune=False)
                if self.pending_growth is None or \
                        self.pending_growth.n_slots <= (1 + END_GROWTH_SHARE) * step.ops.sets.n_slots:
                    self.pending_growth = None
                    return "converged"
                self.pending_growth = self._growth(step, out, END_GROWTH_FLOOR, prune=False)
        else:
            self.history.append(dict(iteration=self.iteration, primal=float(primal)))
            distance = primal / tolerance
        if self.pending_growth is None and self.iteration >= self.next_growth_check:
            self.next_growth_check = GROWTH_SPACING * self.iteration
            self.pending_growth = self._growth(step, out, GROWTH_FLOOR)
        self._report(distance)
        if self.pending_growth is not None:
            return "reshaped"
        if self.iteration <= BALANCE_UNTIL and previous is not None and \
                self.iteration % BALANCE_SPACING < settings.check_every:
            factor = balancing_factor(relative_residuals(out, previous, step.ops.slot_mass * out.z, primal_scale),
                                       BALANCE_HIGH[step.ops.d])
            if factor != 1.0:
                step.rescale_penalty(value, factor)
                self.penalty = step.penalty
                self.history.append(dict(iteration=self.iteration, penalty=step.penalty))
                self.checks = self.checks[-1:]
                return "rescaled"
        return None

    def _growth(self, step, out, floor, prune=True):
        """The working sets reshaped to the weights above ``floor``: grown to one ring around them, and (with
        ``prune``) rid of the slots beyond two rings; None where they already hold that."""
        weights = step.weights(out)
        one_ring, two_rings = self.mesh.margins(step.ops.sets, np.where(weights > floor, weights, 0.0))
        self.progress.check()
        sets = step.ops.sets
        return sets.reshaped(one_ring, one_ring) if prune else sets.grown(one_ring)

    def _reshape(self, step):
        """The step map on the reshaped working sets, and where each entry of the flat state goes there (-1:
        dropped)."""
        sets = self.pending_growth
        # A reshape takes as long as 10-60 steps (seconds on large cages): said, so that progress does not fall silent.
        self.progress(self.fraction, f"ADMM iteration {self.iteration}: updating where each control point may act "
                                     "(factorising)")
        step.ops.release()  # only its pairs and sets are read from here on: its matrices go before the new ones come
        ops = PairOperators(self.mesh, sets, self.settings.dtype, self.progress.check)
        new_step = self._step_map(ops, step.duals)
        self.progress.check()
        pair_positions = step.ops.pair_positions(ops)
        self.progress.check()
        x_positions = np.arange(ops.d)[:, None] * ops.n_pairs + pair_positions[None, :]
        x_positions[:, pair_positions < 0] = -1
        slot_positions = step.ops.sets.slot_positions(sets)
        self.progress.check()
        positions = np.concatenate([x_positions.ravel(),
                                    np.where(slot_positions >= 0, new_step.size_x + slot_positions, -1)])
        self.history.append(dict(iteration=self.iteration, slots=sets.n_slots, pairs=ops.n_pairs))
        self.reshapes += 1
        return new_step, positions

    def _report(self, distance):
        """Progress: the time elapsed over the time elapsed and left, and the time left in words."""
        self.first_distance = self.first_distance or max(distance, 1.0 + 1e-9)
        by_residual = min(0.99, np.log(self.first_distance / max(distance, 1e-300)) / np.log(self.first_distance))
        self.way = max(self.way, self.iteration / self.settings.max_iterations, by_residual)
        elapsed = time.perf_counter() - self.started
        self.checks.append((self.iteration, distance))
        left = self._seconds_left(elapsed)
        most = BEFORE_END_GAME_SHARE if self.settle is None else 0.99
        self.fraction = max(self.fraction, min(most, elapsed / (elapsed + left)))
        told = f", {format_remaining(left)}" if by_residual > 0 or self.expected or self.settle is not None else ""
        self.progress(self.fraction, f"ADMM iteration {self.iteration}, residual {distance:.1f}× the tolerance"
                                     f"{self._why_on()}{told}")

    def _seconds_left(self, elapsed):
        """The time left: the forecast's iterations at this solve's pace while they last (the residual's way says
        little across reshapes), then the residual's way; once the tolerance was met, at least the end game's
        (bench/RESULTS.md, "The time left in the end game")."""
        expected_left = None
        if self.expected is not None and self.iteration < self.expected:
            expected_left = (self.expected - self.iteration) * elapsed / self.iteration
        if self.settle is not None:
            return max(self._end_game_left(elapsed), expected_left or 0.0)
        if expected_left is not None:
            return expected_left
        return seconds_left(elapsed, max(self.way, 1e-9), self.checks, self.settings.max_iterations)

    def _end_game_left(self, elapsed):
        """Seconds left once the tolerance was met: the iterations it took to meet it after the last reshape, from
        that reshape or the one pending, at this solve's seconds a step, and the reshape pending."""
        steps_done = max(self.iteration, 1)
        step_seconds = max(elapsed - self.reshape_seconds, 0.0) / steps_done
        pending = self.pending_growth is not None
        reshape_seconds = self.reshape_seconds / max(self.reshapes, 1) if pending else 0.0
        since = self.iteration if pending else self.last_reshape
        steps = max(since + self.settle - self.iteration, self.settings.check_every)
        return steps * step_seconds + reshape_seconds

    def _why_on(self):
        """Why a solve goes on though its residual rose, or met the tolerance, for the progress message."""
        if self.wide and not self.wide_told:
            why = " (every control point may act everywhere now: a tighter stop)"
        elif self.reshapes > self.reshapes_told:
            # A reshape adds unknowns the step has not settled yet: the residual rises.
            why = " after updating where control points act (a rise, then a fall)"
        elif self.pending_growth is not None and self.checks[-1][1] <= 1:
            why = ": met, but weights reach the edge of where their control points may act: widening it"
        else:
            why = ""
        self.reshapes_told, self.wide_told = self.reshapes, self.wide
        return why


def _moved(values, positions, size):
    """``values`` placed at ``positions`` of a zero array of ``size`` (those at -1 dropped)."""
    out = np.zeros(size, dtype=values.dtype)
    kept = positions >= 0
    out[positions[kept]] = values[kept]
    return out


def _convexity(vertices, cells):
    """The domain's area or volume over its convex hull's: the cage's :attr:`~lbc_core.cage.make.Cage.convexity`."""
    return hull_share(vertices, np.abs(signed_measures(vertices, cells)).sum())


def _default_penalty(d, n):
    """The starting penalty c_d / n^(1/(d-1)) (bench/RESULTS.md, "The starting penalty c_d / √n (3D)")."""
    return PENALTY_SCALE[d] / n ** (1.0 / (d - 1))


def _check_start(start, cells, n, n_interior):
    if start.n_cells != len(cells) or start.sets.n_controls != n or len(start.interior) != n_interior:
        raise CageError(f"the start state is for {start.n_cells} cells, {start.sets.n_controls} control points and "
                        f"{len(start.interior)} interior vertices, not {len(cells)}, {n} and {n_interior}: start "
                        "from a solve on this mesh")
