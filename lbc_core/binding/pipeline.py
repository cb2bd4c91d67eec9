"""The bind pipeline: a cage and points in, a :class:`~lbc_core.binding.record.Binding` out, every stage called here
in order.

    check the request → unit frame → domain mesh → boundary values → interpolation to the points (refused when
    every point lies outside) → geodesic TV weights → solve (ADMM) → smooth evaluation and reduction → back to the
    user's frame

Each stage is a public function of its own module; this module orders them, gives each its share of the progress bar
(one table, :data:`STAGES`) and times it (:class:`StageClock`). The stage functions below (:func:`mesh_cage`,
:func:`locate`, :func:`geodesic_weights`, :func:`solve`, :func:`evaluate`, :func:`lbc_binding`) are what
:func:`bind` and the warm re-bind (:mod:`lbc_core.binding.rebinding`) both run: the re-bind carries the previous mesh in
place of meshing, solves again only part of it and evaluates again only some points, through the same functions.
The baselines (:mod:`lbc_core.compare.baselines`) run the same first stages through :func:`check_cage_and_points`.
"""

from dataclasses import replace

import numpy as np

from ..cage import make_cage, real_array, some_indices
from ..errors import CageError, PointsOutside
from ..evaluate.interpolation import interpolation_matrix
from ..evaluate.reduction import interpolate_and_reduce
from ..evaluate.evaluators import EVALUATORS, EvaluationRequest
from ..kernel.frame import UnitFrame, principal_aspect
from ..kernel.parallel import busy_factor, counted_in_load
from ..kernel.progress import Laps, Progress
from ..meshing import mesh_domain, simplex_domain
from ..meshing.sizing import wedge_work
from ..solve.boundary import boundary_weights
from ..solve.forecast import bind_seconds, check_memory, solve_forecast, solves_stretched
from ..solve.geodesics import geodesic_distances, tv_weights
from ..solve.solver import solve_on_mesh
from .options import DEFAULT_CELLS, BindOptions, SavedWeighting
from .record import COLD, Binding, BindOutcome

# Largest reproduction error |Σ w c - x| the reduction accepts, relative to the cage's diagonal.
REPRODUCTION_TOLERANCE = 1e-9
# Each stage's share of the progress bar (the solve dominates); a run of stages shares the bar among its own in
# proportion. Binding.timings names the stages alike (the solve by the solver's own parts).
STAGES = {"checks": 0.0, "meshing": 0.08, "carry": 0.05, "interpolation": 0.05, "geodesics": 0.084, "solve": 0.756,
          "reduction": 0.03}
# The stages of a bind, in order. A warm re-bind carries the previous mesh in place of meshing, and locates the
# points after the solve, which tells it which points to evaluate again.
BIND_STAGES = ("checks", "meshing", "interpolation", "geodesics", "solve", "reduction")
REBIND_STAGES = ("checks", "carry", "geodesics", "solve", "interpolation", "reduction")
# Beyond this share of a mesh's points outside its cage, the cage is too small rather than grazed by a few stray
# points (a tail's tip): a bind warns with the share and the fix.
OUTSIDE_SHARE_WARNED = 0.05


class StageClock:
    """One run of stages: each stage's part of the progress bar and the seconds it took (``timings``).

    Parameters
    ----------
    progress : Progress
    order : sequence of str
        The stages of the run, in order (names of :data:`STAGES`).
    """

    def __init__(self, progress, order):
        self.progress = progress
        self._laps = Laps()
        self.timings = self._laps.seconds
        total = sum(STAGES[name] for name in order)
        self._share({name: STAGES[name] / total for name in order})

    def _share(self, shares):
        """Each stage's part of the bar from its share ({stage: share}, in order, summing to 1); the last ends at 1
        exactly, whatever the sum's round-off (the bar never passes the final "bound")."""
        self._parts, start = {}, 0.0
        for name, share in shares.items():
            self._parts[name] = (start, min(start + share, 1.0))
            start += share
        self._parts[name] = (self._parts[name][0], 1.0)

    def weigh(self, told):
        """Share the bar by the time told before the bind (:class:`~lbc_core.solve.forecast.BindSeconds`, or None to
        keep the shares): the meshing, the solve and the reduction in proportion to their seconds, within what the
        other stages' shares leave (the reduction of 64k points is a quarter of the demo's bind)."""
        timed = {} if told is None else {"meshing": told.meshing, "solve": told.solve, "reduction": told.points}
        shares = {name: end - start for name, (start, end) in self._parts.items()}
        seconds = sum(timed.get(name, 0.0) for name in shares)
        if seconds <= 0:
            return
        left = sum(share for name, share in shares.items() if name in timed)
        self._share({name: left * timed[name] / seconds if name in timed else share
                     for name, share in shares.items()})

    def part(self, stage):
        """The Progress of ``stage``: its part of the bar."""
        return self.progress.part(*self._parts[stage])

    def done(self, stage):
        """``stage`` ends: the seconds since the previous one ended are its own."""
        self._laps.lap(stage)

    def add(self, seconds):
        """A stage that timed its own parts ends: ``seconds`` ({part: seconds}) are its timings."""
        self.timings.update(seconds)
        self._laps.restart()


@counted_in_load
def bind(
    cage_vertices,
    cage_faces,
    points,
    *,
    cells=None,
    weighting=None,
    epsilon=None,
    threshold=None,
    method=None,
    tolerance=None,
    max_iterations=None,
    smoothness=None,
    evaluation=None,
    options=None,
    progress=None,
    cancel=None,
):
    """Local barycentric coordinates of ``points`` with respect to a cage.

    Parameters
    ----------
    cage_vertices : (n_input, 2) or (n_input, 3) float array
    cage_faces : None or sequence of index sequences
        None: a 2D polygon, vertices in boundary order. Else the faces of a closed 3D cage.
    points : (m, d) float array
        The points to bind (a mesh's vertices). 2D points may be given with a constant z.
    cells, weighting, epsilon, threshold, method, tolerance, max_iterations, smoothness, evaluation : optional
        The fields of :class:`lbc_core.binding.options.BindOptions` (None: the default): about how many triangles /
        tetrahedra fill the cage (3000 in 2D, 8000 in 3D; more is finer and slower), ρ of the geodesic TV weights
        ("quadratic", the paper's default, "linear", "sqrt", "constant" or a function), the C¹ relaxation width
        (0: plain total variation), the reduction threshold (1e-3 / n), the domain mesher ("auto"), the ADMM
        stopping tolerance (the solver's), its iteration limit (10000), smooth ↔ local in [0, 1] (0.5; 1 folds
        bent joints least, 0 gives each point the fewest influences) and the evaluator at the points ("smooth"; or
        "linear", the paper's piecewise-linear interpolation).
    options : BindOptions, optional
        The same options as one object; keywords given besides it override its fields.
    progress : callable(fraction, message), optional
    cancel : callable() -> bool, optional
        Returning True stops the bind with :class:`lbc_core.Cancelled`; every stage polls it at least every few tenths
        of a second.

    Returns
    -------
    Binding

    Raises
    ------
    CageError
        For any bad option, cage or points, before any meshing or solving.
    """
    clock = StageClock(Progress.of(progress, cancel), BIND_STAGES)
    request = BindOptions.of(options, cells=cells, weighting=weighting, epsilon=epsilon, threshold=threshold,
                             method=method, tolerance=tolerance, max_iterations=max_iterations, smoothness=smoothness,
                             evaluation=evaluation)
    cage, points, told = check_request(cage_vertices, cage_faces, points, request, clock.progress)
    clock.weigh(told)
    clock.done("checks")
    # Every stage computes in the unit frame; the weights are the same in any frame.
    frame = UnitFrame.of(cage)
    unit_cage = frame.cage_to_unit(cage)
    domain, fixed = mesh_cage(clock, unit_cage, request)
    # Located before the solve: points that all lie outside are refused before the long work.
    located, outside = locate(clock, domain, frame.to_unit(points))
    omega = geodesic_weights(clock, domain, request.weighting)
    result = solve(clock, domain.vertices, domain.cells, domain.boundary_vertices, fixed, unit_cage.vertices, omega,
                   request)
    weights = evaluate(clock, domain, located, result.weights, unit_cage, request.threshold_for(cage.n_control_points),
                       request, points=frame.to_unit(points), outside=outside)
    clock.progress(1.0, "bound")
    return lbc_binding(frame, cage, domain, result, weights, outside, points, request, clock)


def mesh_cage(clock, unit_cage, request):
    """The meshing stage: the domain mesh of ``unit_cage`` (a simplex is its own one cell) and its boundary values.

    Returns
    -------
    domain : DomainMesh
    fixed : (B, n) float array
        The boundary values at ``domain.boundary_vertices``.
    """
    if unit_cage.is_simplex:
        domain = simplex_domain(unit_cage)
    else:
        domain = mesh_domain(unit_cage, request.cells, request.method, progress=clock.part("meshing"))
    fixed = boundary_weights(domain, unit_cage)
    clock.done("meshing")
    return domain, fixed


def locate(clock, domain, unit_points, refuse_outside=True):
    """The interpolation stage: each point in its cell of ``domain``, outside points bound to the closest domain point.

    Returns the (m, N) barycentric matrix and the (m,) outside flags; :class:`PointsOutside` when every point lies
    outside and ``refuse_outside``.
    """
    located, outside, _ = interpolation_matrix(domain.vertices, domain.cells, unit_points,
                                               progress=clock.part("interpolation"))
    if refuse_outside:
        check_inside(outside)
    clock.done("interpolation")
    return located, outside


def geodesic_weights(clock, domain, weighting):
    """The geodesics stage: ω (F, n) of ``domain``, from the heat-method distances to its control vertices."""
    distances = geodesic_distances(domain.vertices, domain.cells, domain.control_vertices, clock.part("geodesics"))
    clock.progress.check()
    omega = tv_weights(domain.cells, distances, weighting)
    clock.done("geodesics")
    return omega


def solve(clock, vertices, cells, fixed, values, control_points, omega, request, start=None):
    """The solve stage: :func:`~lbc_core.solve.solver.solve_on_mesh` on ``cells`` with the vertices ``fixed`` held at
    ``values``, as ``request`` (:class:`BindOptions`) asks, from ``start`` (a SolverState) if given; the solver's
    own stage times are the timings."""
    result = solve_on_mesh(vertices, cells, fixed, values, control_points, omega, epsilon=request.epsilon,
                           tolerance=request.tolerance, max_iterations=request.max_iterations, start=start,
                           progress=clock.part("solve"))
    clock.add(result.seconds)
    return result


def evaluate(clock, domain, located, domain_weights, unit_cage, threshold, request, reach=1.0, points=None,
             outside=None):
    """The reduction stage: the rows of the evaluator ``request.evaluation`` names at the located points
    (:data:`~lbc_core.evaluate.evaluators.EVALUATORS`), reduced (weights below ``threshold`` dropped, the constraints
    restored); ``reach`` scales the smooth fit's radii, depths and fade, in median edges. With the (unit frame)
    ``points`` and their ``outside`` flags, the rows of points outside the cage may extrapolate to them.

    Returns the (m, n) sparse weights.
    """
    part = clock.part("reduction")
    evaluator = EVALUATORS[request.evaluation]
    rows = evaluator(domain, located, EvaluationRequest(request.smoothness, reach, points, outside, part))
    weights = interpolate_and_reduce(rows, domain_weights, unit_cage.vertices, domain.vertices, threshold,
                                     tolerance=REPRODUCTION_TOLERANCE * unit_cage.bbox_diagonal, progress=part)
    clock.done("reduction")
    return weights


def lbc_binding(frame, cage, unit_domain, solution, weights, outside, points, request, clock, outcome=None,
                stale=None):
    """The :class:`Binding` of an LBC solve made in the unit ``frame``: the domain and objective in the cage's units.

    Parameters
    ----------
    frame : UnitFrame
    cage : Cage
        The cage in the caller's units.
    unit_domain : DomainMesh
        The domain mesh in the unit frame.
    solution : SolveResult
        The solve on ``unit_domain`` (its objective in the unit frame).
    weights : (m, n) scipy.sparse.csr_matrix
    outside : (m,) bool array
    points : (m, d) float array
    request : BindOptions
    clock : StageClock
        Its timings.
    outcome : BindOutcome, optional
        Where the solve started and what a re-bind did (None: a bind from scratch); its iterations and convergence
        are the ``solution``'s.
    stale : (N,) float array, optional
        :attr:`Binding.stale`.
    """
    outcome = replace(outcome or BindOutcome(start=COLD), iterations=solution.iterations,
                      converged=solution.converged, cells=len(unit_domain.cells),
                      threshold=request.threshold_for(cage.n_control_points))
    return Binding(
        cage=cage,
        rest_cage_vertices=cage.vertices.copy(),
        weights=weights,
        domain=frame.domain_from_unit(unit_domain, cage),
        domain_weights=solution.weights,
        outside=outside,
        points=points,
        scheme="lbc",
        options=request,
        outcome=outcome,
        timings=clock.timings,
        objective=solution.objective * frame.scale ** (cage.dim - 1),  # TV scales as length^(d-1)
        solver_state=solution.state,
        stale=stale,
    )


def request_of(binding):
    """The :class:`BindOptions` ``binding`` was made with, checked that it can be solved again.

    Raises
    ------
    CageError
        For a binding saved with a weighting function of its own, which its file names but does not keep.
    """
    if isinstance(binding.options.weighting, SavedWeighting):
        binding.options.weighting(None)  # raises, saying so
    return binding.options


def check_request(cage_vertices, cage_faces, points, options, progress=None):
    """Everything a bind is given, checked before any long work: options, cage, points and the memory it needs.

    The one memory check of a bind: a resolution the machine cannot hold is refused before meshing, not after the
    OS kills the process.

    Parameters
    ----------
    cage_vertices, cage_faces, points
        As for :func:`bind`.
    options : BindOptions
    progress : callable(fraction, message), optional
        Told, at 0, how much memory and (roughly) time the solve will take.

    Returns
    -------
    cage, points
        As :func:`check_cage_and_points`.
    told : BindSeconds or None
        The time told for the meshing, the solve and the points (None for a simplex cage: nothing to mesh or solve).

    Raises as :func:`check_cage_and_points`, and CageError for a bind the memory cannot hold.
    """
    cage, points = check_cage_and_points(cage_vertices, cage_faces, points, options)
    n_cells = options.cells or DEFAULT_CELLS[cage.dim]
    convexity = cage.convexity
    check_memory(cage.n_control_points, n_cells, cage.dim, convexity)
    if cage.is_simplex:
        if progress is not None:
            progress(0.0, "a simplex cage: its coordinates are the barycentric ones, nothing to mesh or solve")
        return cage, points, None
    busy = 1.0 if progress is None else busy_factor()  # the bar's shares are ratios: the load cancels
    shape = (cage.n_control_points, n_cells, cage.dim, solves_stretched(cage.vertices, options.epsilon),
             principal_aspect(cage.vertices), busy, len(points))
    work = wedge_work(cage.surface_vertices, cage.facets) if cage.dim == 3 else 1.0
    if progress is not None:
        progress(0.0, solve_forecast(*shape, meshing=True, convexity=convexity, meshing_work=work))
    return cage, points, bind_seconds(*shape, convexity=convexity, meshing_work=work)


def check_cage_and_points(cage_vertices, cage_faces, points, options=None):
    """The cage made and the points checked against it, as every bind (LBC or baseline) starts.

    Parameters
    ----------
    cage_vertices, cage_faces, points
        As for :func:`bind`.
    options : BindOptions, optional
        Checked against the cage (e.g. a threshold for its number of control points).

    Returns
    -------
    cage : Cage
    points : (m, d) float array

    Raises
    ------
    CageError
    """
    cage = make_cage(cage_vertices, cage_faces)
    if options is not None:
        options.check_for_cage(cage.n_control_points, cage.dim)
    plane_z = None
    if cage_faces is None and np.shape(cage_vertices)[1:] == (3,):
        plane_z = float(np.asarray(cage_vertices, dtype=float)[0, 2])
    return cage, check_points(cage, points, plane_z)


def too_small_warning(count, total, then="bind again"):
    """What to say when ``count`` of a mesh's ``total`` points lie outside its cage, more than
    :data:`OUTSIDE_SHARE_WARNED` of them: the share and the fix (``then`` is its last step); "" for fewer.

    Examples
    --------
    >>> too_small_warning(1, 100)
    ''
    >>> too_small_warning(7, 42)[:57]
    '7 of 42 vertices (17%) lie outside the cage, which is too'
    """
    if not total or count <= OUTSIDE_SHARE_WARNED * total:
        return ""
    return (f"{count} of {total} vertices ({count / total:.0%}) lie outside the cage, which is too small for the mesh: "
            "they follow the cage only by extrapolation from the closest points inside it. Scale the cage up so it "
            f"encloses the mesh, then {then}")


def check_inside(outside):
    """Refuse points that all lie outside the cage (``outside``: (m,) bool): each would extrapolate from the closest
    point of the cage's interior, which is meant for a few stray points, and a cage around none is most likely the
    wrong one."""
    if len(outside) and outside.all():
        subject = "the point lies" if len(outside) == 1 else f"all {len(outside)} points lie"
        raise PointsOutside(f"{subject} outside the cage: the cage must enclose the points it deforms. Is it the right "
                        "cage (or the mesh and cage swapped)?")


def check_points(cage, points, plane_z=None):
    """Points as an (m, d) float array for a d-dimensional cage.

    2D points may come as (m, 3) with a constant z (file data).

    Parameters
    ----------
    cage : Cage
    points : (m, 2) or (m, 3) array-like
    plane_z : float, optional
        The z of a 2D cage given with a constant z: 2D points given with a z must lie in that plane.

    Raises
    ------
    CageError
        Wrong shape, dimension mismatch, another plane than the cage's, or NaN/inf coordinates.
    """
    points = real_array(points, "points", "(m, 2) or (m, 3)")
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise CageError(f"points must be an (m, 2) or (m, 3) array, got shape {points.shape}")
    if cage.dim == 2 and points.shape[1] == 3:
        tolerance = 1e-9 * cage.bbox_diagonal
        if len(points) and np.ptp(points[:, 2]) > tolerance:
            raise CageError("the cage is 2D but the points' z varies: bind 2D points (or a z = constant plane)")
        if len(points) and plane_z is not None and abs(points[0, 2] - plane_z) > tolerance:
            raise CageError(
                f"the 2D cage lies in the plane z = {plane_z:g} but the points in z = {points[0, 2]:g}: move them "
                "into the cage's plane (or give both as 2D arrays)"
            )
        points = points[:, :2]
    if points.shape[1] != cage.dim:
        raise CageError(f"the cage is {cage.dim}D but the points are {points.shape[1]}D")
    finite = np.all(np.isfinite(points), axis=1)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise CageError(f"{len(bad)} of the points ({some_indices(bad)}, counted from 0) "
                        f"{'has' if len(bad) == 1 else 'have'} NaN or infinite coordinates: fix or delete them")
    return points
