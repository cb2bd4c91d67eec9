"""Warm re-bind: bind again after a few cage vertices moved at rest, reusing the previous domain mesh and solution.

The previous binding's coordinates at its domain vertices, w(x), carry its mesh onto the edited cage:
x' = Σ_i w_i(x) c'_i. Boundary vertices stay on their (moved) facets exactly, since boundary values are linear on
facets, and control vertices land on the moved control points. Where no cell inverts or loses its shape, the carried
mesh is a valid domain of the edited cage, and at its vertices the old coordinates meet every constraint exactly
(they sum to 1, reproduce the carried positions by construction, and are non-negative).

Where no moved control point's coordinate reaches, nothing moved and the old coordinates stay optimal but for the
geodesic weights of the moved coordinates, which only matter where those coordinates are non-zero. So only the
cells around the moved coordinates' supports (grown by FREE_RINGS rings) are solved again, the other vertices held
at their previous weights as fixed values, starting from the previous solve's final state (``Binding.solver_state``,
kept in memory) rather than from the harmonic coordinates; the geodesic weights and the evaluation at the points are
computed afresh, as in :func:`lbc_core.bind`.

Where the edit bends a cage edge between coplanar facets (a quad's diagonal, an n-gon's split line, a loop cut across
a flat side), which the previous mesh's faces may cross (the mesher follows only well-shaped quads' diagonals), the
mesh edges it crosses are split there first (:func:`following_bent_edges`), so that the carried surface follows the
new crease of the boundary values.

Where the carried mesh is not valid (a cell folds or loses too much of its shape, typically where a cage vertex
moved by more than about a cell's size; a mesh face left across a bent edge, unsplit within CROSSING_END of a mesh
vertex, would leave the cage by more than CHORD_KEPT of a cell), a bent face now splits into other triangles than
before, the cage's topology or welding
changed, or the previous binding has no solver state (one loaded from a file), the re-bind is a cold bind with the
previous options, and ``Binding.outcome.report`` says why.

The stages are :mod:`lbc_core.binding.pipeline`'s, with its one table of progress shares and timings: this module
carries the previous mesh (in place of meshing), chooses the vertices to solve again and the points to evaluate again,
and merges the rows it kept; the geodesics, the solve, the interpolation, the evaluation and the binding record are the
pipeline's stage functions.
"""

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..cage import make_cage
from ..errors import CageError
from ..evaluate.smoothing import DEEP_RADIUS_EDGES, median_edge, radius_for
from ..kernel.frame import UnitFrame
from ..kernel.geometry import (
    row_keys,
)
from ..kernel.parallel import counted_in_load
from ..kernel.progress import Progress
from ..solve.boundary import boundary_weights
from ..solve.objective import tv_objective
from ..solve.solver import SolveResult
from .carry import carry_domain, following_bent_edges, split_as_before
from .pipeline import (
    REBIND_STAGES,
    REPRODUCTION_TOLERANCE,
    StageClock,
    bind,
    check_points,
    evaluate,
    geodesic_weights,
    lbc_binding,
    locate,
    request_of,
    solve,
)
from .record import WARM, BindOutcome, SolvedAgain

# Rings of mesh vertices around the moved control points' supports solved again, room for a support to grow
# (bench/RESULTS.md, "A Rebind's fixed costs, and one ring around the supports").
FREE_RINGS = 1
# Change (largest coordinate change plus move in median cell edges, Binding.stale) under which the points near a domain
# vertex keep their rows (bench/RESULTS.md, "Points near small changes keep their rows").
STALE = 1e-2
# Largest moves over the diagonal, summed over warm re-binds since the last bind from scratch, past which a re-bind
# binds from scratch (bench/RESULTS.md, "Warm re-binds that add up").
CARRY_LIMIT = 0.08


@counted_in_load
def rebind(previous, cage_vertices, cage_faces=None, points=None, *, progress=None, cancel=None):
    """Bind again to an edited cage, starting from a previous binding's mesh and solution.

    Parameters
    ----------
    previous : Binding
        An LBC binding of the same cage (same vertices, faces and welding), before the edit.
    cage_vertices : (n_input, d) float array
        The edited cage's vertices, in the order and number given to :func:`lbc_core.bind`.
    cage_faces : None or sequence of index sequences
        The cage's faces, as given to :func:`lbc_core.bind` (None for a 2D polygon).
    points : (m, d) float array, optional
        The points to bind; None binds the previous binding's points again.
    progress : callable(fraction, message), optional
    cancel : callable() -> bool, optional
        Returning True stops the re-bind with :class:`lbc_core.Cancelled`.

    Returns
    -------
    Binding
        Its ``outcome`` (:class:`~lbc_core.binding.record.BindOutcome`): ``start`` is
        :attr:`~lbc_core.binding.record.Start.WARM` for a warm re-bind, :attr:`~lbc_core.binding.record.Start.COLD`
        for a cold one; ``report`` says, for the user, how many cells were solved again, or why the bind started from
        scratch; a warm one's ``solved_again`` holds those counts (a
        :class:`~lbc_core.binding.record.SolvedAgain`), its ``travel`` how far the cage moved since its last bind
        from scratch.

    Raises
    ------
    CageError
        For a bad cage or points (as :func:`lbc_core.bind`), or a previous binding that is not an LBC one.
    """
    clock = StageClock(Progress.of(progress, cancel), REBIND_STAGES)
    request, cage, points = _checked(previous, cage_vertices, cage_faces, points)
    clock.done("checks")
    carry, reason = _carried(previous, cage)
    if carry is None:
        clock.progress(0.0, f"binding from scratch: {reason}")
        binding = bind(cage_vertices, cage_faces, points, options=request, progress=clock.progress)
        binding.outcome = replace(binding.outcome, report=f"bound from scratch: {reason}")
        return binding
    clock.part("carry")(1.0, "the previous mesh carried onto the edited cage" if carry.moved.any()
                        else "the previous mesh and solution reused: the cage has not moved")
    clock.done("carry")
    omega = geodesic_weights(clock, carry.mesh, request.weighting)
    result, solved = _solve_near(clock, carry, omega, request)
    unit_points = carry.frame.to_unit(points)
    again, stale, reach = _to_evaluate(carry, points, unit_points, result.weights, radius_for(request.smoothness))
    # New points (e.g. another mesh in this cage) are refused as bind refuses them.
    located, outside_again = locate(clock, carry.mesh, unit_points[again], refuse_outside=len(again) == len(points))
    weights_again = evaluate(clock, carry.mesh, located, result.weights, carry.unit_cage,
                             request.threshold_for(cage.n_control_points), request, reach, unit_points[again],
                             outside_again)
    if len(again) == len(points):
        weights, outside = weights_again, outside_again
    else:
        weights, outside = _merged_rows(carry.previous, again, weights_again, outside_again)
    clock.done("reduction")
    clock.progress(1.0, "bound again from the previous solution")
    return lbc_binding(carry.frame, carry.cage, carry.mesh, result, weights, outside, points, request, clock,
                       _warm_outcome(carry, solved, len(again), len(points)), stale)


@dataclass
class _Carry:
    """What a warm re-bind starts from.

    Attributes
    ----------
    previous : Binding
        The previous binding, its mesh split along the cage edges the edit bends (:func:`following_bent_edges`).
    cage, unit_cage : Cage
        The edited cage (split into the previous cage's facets), and the same in its unit ``frame``.
    frame : UnitFrame
    mesh : DomainMesh
        The previous mesh carried onto ``unit_cage`` (:func:`carry_domain`), in the unit frame.
    moved : (n,) bool array
        The control points the edit moved.
    touched : (N,) bool array or None
        The vertices around those the split added.
    travel : float
        :attr:`BindOutcome.travel` with this edit.
    """

    previous: object
    cage: object
    unit_cage: object
    frame: UnitFrame
    mesh: object
    moved: np.ndarray
    touched: np.ndarray
    travel: float


def _checked(previous, cage_vertices, cage_faces, points):
    """The options ``previous`` was made with, the edited cage and the points: the checks stage of a re-bind."""
    if previous.scheme != "lbc":
        raise CageError(f"a warm re-bind needs an LBC binding to start from, not a {previous.scheme!r} one: bind "
                        "with lbc_core.bind")
    request = request_of(previous)
    if cage_faces is None and previous.cage.dim == 3:
        raise CageError("the previous binding is 3D: pass the edited cage's faces too, rebind(previous, vertices, "
                        "faces), as given to lbc_core.bind")
    cage = make_cage(cage_vertices, cage_faces)
    points = previous.points if points is None else check_points(cage, points)
    return request, cage, points


def _carried(previous, cage):
    """The carry stage: a :class:`_Carry` of ``previous`` onto the edited ``cage``, or None and why not (for the
    user)."""
    cage, reason = split_as_before(previous.cage, cage)
    if previous.cage.is_simplex:
        reason = "a simplex cage has nothing to solve"
    elif previous.solver_state is None:
        reason = "the previous binding's solver state is not at hand (it is kept in memory only, not in files)"
    travel = previous.outcome.travel + _largest_move(previous, cage)
    if reason is not None:
        return None, reason
    frame = UnitFrame.of(cage)
    unit_cage = frame.cage_to_unit(cage)
    previous, touched = following_bent_edges(previous, cage)
    mesh, reason = carry_domain(previous, unit_cage)
    if mesh is not None and travel > CARRY_LIMIT:
        mesh, reason = None, (f"its vertices moved {travel:.0%} of the cage's diagonal in all since it was last "
                              "bound from scratch, and a mesh carried that far drifts from a fresh one")
    if mesh is None:
        return None, reason
    moved = np.any(cage.vertices != previous.rest_cage_vertices, axis=1)
    return _Carry(previous, cage, unit_cage, frame, mesh, moved, touched, travel), None


def _largest_move(previous, cage):
    """The largest distance a control point moved from ``previous``'s rest cage to ``cage``, over its diagonal (0
    where the control points differ in number: that re-bind binds from scratch anyway)."""
    rest = previous.rest_cage_vertices
    if rest.shape != cage.vertices.shape:
        return 0.0
    return float(np.linalg.norm(cage.vertices - rest, axis=1).max() / previous.cage.bbox_diagonal)


def _warm_outcome(carry, solved, evaluated, points):
    """The :class:`BindOutcome` of a warm re-bind that solved ``solved`` cells again and evaluated ``evaluated`` of
    ``points`` points (its iterations and convergence are filled in with the binding)."""
    counts = SolvedAgain(int(solved), len(carry.mesh.cells), evaluated, points)
    done = (str(counts) if carry.moved.any() or evaluated
            else "it was made for the cage as it is now, so nothing was solved or evaluated again")
    return BindOutcome(start=WARM, solved_again=counts, report=f"bound again from the previous binding: {done}",
                       travel=carry.travel)


def _to_solve_again(carry):
    """The vertices to solve again, (N,) bool: where the moved control points' coordinates reach (their support,
    grown by FREE_RINGS rings of vertices), around the vertices the split touched and the cells a flip made, and
    where the carry polished a vertex; none on the cage. And the previous solver state on the carried cells."""
    previous, carried = carry.previous, carry.mesh
    free = np.any(previous.domain_weights[:, carry.moved] > 0, axis=1)
    # Vertices the carry polished away from where the previous weights put them (see polished), and those of cells
    # a flip made (see flipped_slivers), must be solved again.
    carried_to = previous.domain_weights @ carry.unit_cage.vertices
    free |= np.linalg.norm(carried.vertices - carried_to, axis=1) > REPRODUCTION_TOLERANCE
    if carry.touched is not None:
        free |= carry.touched
    state = previous.solver_state
    if len(carried.cells) != len(previous.domain.cells):  # flips replaced cells: the state follows the cells
        source, new = _cell_sources(previous.domain.cells, carried.cells)
        free[carried.cells[new].ravel()] = True
        state = state.for_cells(source)
    free = _grown(free, carried.cells, FREE_RINGS)
    free[carried.boundary_vertices] = False
    return free, state


def _solve_near(clock, carry, omega, request):
    """The solve stage of a warm re-bind: the vertices of :func:`_to_solve_again` solved again from the previous
    solver state, the rest of the carried mesh held at the previous solution.

    Returns
    -------
    result : SolveResult
        Its weights, objective (unit frame) and state cover the whole mesh, the state for the next warm re-bind.
    solved : int
        How many cells were solved again.
    """
    free, state = _to_solve_again(carry)
    carried = carry.mesh
    cells = np.any(free[carried.cells], axis=1)
    fixed = np.flatnonzero(~free)
    # The boundary values of the edited cage: a convex poked n-gon's follow its outline's shape (boundary.py), so
    # those of an n-gon the edit moved differ from the previous ones; they have weight on a moved control point, and
    # so does the interior around them, which is solved again.
    held = carry.previous.domain_weights.copy()
    held[carried.boundary_vertices] = boundary_weights(carried, carry.unit_cage)
    if not free.any():  # nothing moved, or only where no coordinate reaches the interior
        result = SolveResult(held, 0, True, float("nan"), omega)
        return replace(result, objective=tv_objective(carried.vertices, carried.cells, held, omega), state=state), 0
    result = solve(clock, carried.vertices, carried.cells[cells], fixed, held[fixed], carry.unit_cage.vertices,
                   omega[cells], request, start=state.restricted(cells, np.flatnonzero(free)))
    objective = tv_objective(carried.vertices, carried.cells, result.weights, omega)
    state = state if result.state is None else state.updated(result.state, cells)
    return replace(result, objective=objective, state=state), int(cells.sum())


def _to_evaluate(carry, points, unit_points, domain_weights, radius_edges):
    """The points a warm re-bind evaluates again: those whose evaluation can see a vertex that changed by STALE
    since they were last evaluated (the carried mesh's coordinates ``domain_weights``; the fit's radius
    ``radius_edges``, in median cell edges).

    Returns
    -------
    again : (k,) int array
        Their indices.
    stale : (N,) float array
        :attr:`Binding.stale` of the new binding.
    reach : float
        The previous evaluation's radius and fade, in this mesh's median edges: kept and new rows fit alike.
    """
    previous, carried = carry.previous, carry.mesh
    old_vertices = carry.frame.to_unit(previous.domain.vertices)
    # The median cell edge before and after the carry: the unit of a vertex's move, and of the evaluation's reach.
    old_edge, edge = (median_edge(at, carried.cells) for at in (old_vertices, carried.vertices))
    stale = _staleness(previous, carried, old_vertices, domain_weights, edge)
    changed = stale > STALE
    again = _points_to_evaluate(previous, points, unit_points, carried, old_vertices, old_edge, changed, carry.moved,
                                radius_edges)
    stale[changed] = 0.0  # every point within reach of these is evaluated again
    if len(again) == len(points):
        stale[:] = 0.0
    return again, stale, old_edge / edge


def _staleness(previous, carried, old_vertices, domain_weights, edge):
    """(N,) float array: :attr:`Binding.stale` of ``previous`` (0 where None) plus each domain vertex's change from
    ``previous`` to the ``carried`` mesh (unit frame; ``old_vertices`` the previous vertices in it) with
    ``domain_weights``: its largest coordinate change plus its move in median cell edges (``edge``, the carried
    mesh's).

    A sum of changes bounds the change since the points near a vertex were last evaluated, however many re-binds
    kept their rows.
    """
    change = np.abs(domain_weights - previous.domain_weights).max(axis=1)
    change += np.linalg.norm(carried.vertices - old_vertices, axis=1) / edge
    return change if previous.stale is None else previous.stale + change


def _points_to_evaluate(previous, points, unit_points, carried, old_vertices, old_edge, changed, moved,
                        radius_edges):
    """Indices of the points to evaluate again: all of them if the points changed, else those outside the cage (their
    closest domain point may have moved), with weight on a moved control point, or within reach of a changed vertex
    (the fit's widest radius, in the previous median edges ``old_edge``, or a cell's longest edge for the
    piecewise-linear part and the fade near the cage, both read at the corners of the point's cell)."""
    if len(points) != len(previous.points) or not np.array_equal(points, previous.points):
        return np.arange(len(points))
    on_moved = np.asarray(previous.weights[:, np.flatnonzero(moved)].sum(axis=1)).ravel() > 0
    on_moved |= previous.outside
    changed = _grown(changed, carried.cells, 1)
    if not changed.any():
        return np.flatnonzero(on_moved)
    corners = old_vertices[carried.cells]
    longest = max(float(np.linalg.norm(corners[:, a] - corners[:, b], axis=1).max())
                  for a in range(corners.shape[1]) for b in range(a))
    reach = max(max(radius_edges, DEEP_RADIUS_EDGES) * old_edge, longest)
    distance, _ = cKDTree(old_vertices[changed]).query(unit_points, distance_upper_bound=reach)
    return np.flatnonzero(on_moved | np.isfinite(distance))


def _merged_rows(previous, again, weights_again, outside_again):
    """The previous weights and outside flags with the rows ``again`` replaced."""
    m = previous.weights.shape[0]
    kept = np.ones(m)
    kept[again] = 0.0
    placement = sp.csr_matrix((np.ones(len(again)), (again, np.arange(len(again)))), shape=(m, len(again)))
    weights = (sp.diags(kept) @ previous.weights + placement @ weights_again).tocsr()
    weights.eliminate_zeros()
    outside = previous.outside.copy()
    outside[again] = outside_again
    return weights, outside


def _cell_sources(old_cells, new_cells):
    """Where each of ``new_cells`` (F_new, k) takes its warm state from among ``old_cells`` (F, k).

    Returns
    -------
    source : (F_new,) int array
        The old cell with the same corners, or for a cell no old one matches, an old cell with the most corners in
        common.
    new : (F_new,) bool array
        The cells no old one matches.
    """
    base = int(max(old_cells.max(), new_cells.max())) + 1
    old_keys, new_keys = (row_keys(np.sort(c, axis=1), base) for c in (old_cells, new_cells))
    order = np.argsort(old_keys)
    at = order[np.minimum(np.searchsorted(old_keys, new_keys, sorter=order), len(order) - 1)]
    new = old_keys[at] != new_keys
    at[new] = [np.argmax(np.count_nonzero(np.isin(old_cells, cell), axis=1)) for cell in new_cells[new]]
    return at, new


def _grown(mask, cells, rings):
    """(N,) bool array: ``mask`` grown by ``rings`` rings of vertices through the cells."""
    mask = mask.copy()
    for _ in range(rings):
        mask[cells[np.any(mask[cells], axis=1)].ravel()] = True
    return mask
