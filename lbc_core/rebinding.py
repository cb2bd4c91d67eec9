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

The stages are :mod:`lbc_core.pipeline`'s, with its one table of progress shares and timings: this module carries
the previous mesh (in place of meshing), chooses the vertices to solve again and the points to evaluate again, and
merges the rows it kept; the geodesics, the solve, the interpolation, the evaluation and the binding record are the
pipeline's stage functions.
"""

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from .binding import SOLVED_AGAIN, WARM, BindOutcome
from .boundary import boundary_weights
from .cage import ZERO_LENGTH, edge_pairing, make_cage
from .constraints import padded_rows
from .errors import CageError
from .fem import boundary_facets
from .frame import UnitFrame
from .geometry import (bary_positions, closest_on_facets, orient_positive, radius_ratios, row_keys, signed_measures,
                       triangle_normals, unit)
from .meshing import COPLANAR_ANGLE
from .meshing.common import cell_edges
from .meshing.tetrahedra import polish
from .objective import tv_objective
from .parallel import counted_in_load
from .pipeline import (REBIND_STAGES, REPRODUCTION_TOLERANCE, StageClock, bind, check_points, evaluate,
                       geodesic_weights, lbc_binding, locate, request_of, solve)
from .progress import Progress
from .smoothing import DEEP_RADIUS_EDGES, median_edge, radius_for
from .solver import SolveResult

# Share of its radius ratio a carried cell with a corner off the cage must keep (bench/RESULTS.md, "The warm re-bind
# keeps a carried mesh whose squashed cells lie wholly on the cage").
QUALITY_KEPT = 0.25
# A carried boundary face may cross a cage face that the edit bent (a quad's diagonal, an n-gon's split) as a chord:
# its corners stay on the cage, its inside leaves it. Up to this share of the median cell edge, the carried mesh is
# kept: binds were measured as close to a bind from scratch as two binds from scratch are to each other.
CHORD_KEPT = 0.5
# A cage edge the edit bends is followed by splitting the mesh edges it crosses (following_bent_edges), except within
# this share of a mesh edge's length from its ends: a split so near a corner would make a sliver, and the mesh
# follows the cage edge there within that share already.
CROSSING_END = 0.05
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
        Its ``outcome`` (:class:`~lbc_core.binding.BindOutcome`): ``start`` is "previous solution" (:data:`WARM`)
        for a warm re-bind, "harmonic" (:data:`lbc_core.binding.COLD`) for a cold one; ``report`` says, for the user, how many cells
        were solved again, or why the bind started from scratch; a warm one's ``solved_again`` holds those counts as
        numbers (see :func:`solved_again_text`), its ``travel`` how far the cage moved since its last bind from
        scratch.

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
                             request.threshold_for(cage.n_control_points), reach, unit_points[again], outside_again,
                             request.smoothness)
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
    cage, reason = _split_as_before(previous.cage, cage)
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
    counts = dict(zip(SOLVED_AGAIN, (int(solved), len(carry.mesh.cells), evaluated, points)))
    done = (solved_again_text(counts) if carry.moved.any() or evaluated
            else "it was made for the cage as it is now, so nothing was solved or evaluated again")
    return BindOutcome(start=WARM, solved_again=counts, report=f"bound again from the previous binding: {done}",
                       travel=carry.travel)


def solved_again_text(counts):
    """What a warm re-bind solved again, for the user: "s of c cells solved, e of p points evaluated".

    ``counts`` is its ``Binding.outcome.solved_again``: {"cells solved", "cells", "points evaluated", "points"}.
    """
    return (f"{counts['cells solved']} of {counts['cells']} cells solved, "
            f"{counts['points evaluated']} of {counts['points']} points evaluated")


def _to_solve_again(carry):
    """The vertices to solve again, (N,) bool: where the moved control points' coordinates reach (their support,
    grown by FREE_RINGS rings of vertices), around the vertices the split touched and the cells a flip made, and
    where the carry polished a vertex; none on the cage. And the previous solver state on the carried cells."""
    previous, carried = carry.previous, carry.mesh
    free = np.any(previous.domain_weights[:, carry.moved] > 0, axis=1)
    # Vertices the carry polished away from where the previous weights put them (see _polished), and those of cells
    # a flip made (see _flipped_slivers), must be solved again.
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


def following_bent_edges(previous, cage):
    """``previous`` with its mesh's surface split along the cage edges the edit bends, where its faces cross them.

    Where coplanar facets meet (a quad's diagonal, an n-gon's split lines, a loop cut across a flat side), the mesher
    needs no mesh edge along the cage edge, and mesh faces cross it. The edit bends such an edge into a crease of the
    boundary values; carried, those faces would cut across it as chords, and a mesh that does not follow the crease
    holds on to the flat cage's coordinates: the loop-cut Cylinder's side vertex moved out by 0.25-2 % came out 2.3-3.2
    times as far from a fine bind as a bind from scratch under a pose of that vertex (bench/RESULTS.md). Each mesh
    edge on the cage that the bent edge crosses is split where it crosses, the cells around it in two, in the previous
    (flat) geometry; the segment between two crossings then is a mesh edge, so the carried surface follows the crease.
    A new vertex lies on the cage, with the exact boundary values there; the previous solution and state are kept
    elsewhere (a split cell's state is its parent's), and the cells around the new vertices are solved again.

    Parameters
    ----------
    previous : Binding (3D: else returned as it is)
    cage : Cage
        The edited cage, split into the previous cage's facets (:func:`_split_as_before`).

    Returns
    -------
    previous : Binding
        On the split mesh (the same object when nothing was split).
    touched : (N,) bool array or None
        The vertices of the cells around the new vertices; None when nothing was split.
    """
    if cage.dim != 3:
        return previous, None
    old_cage, mesh = previous.cage, previous.domain
    bent = _bent_edges(old_cage, cage)
    if not len(bent):
        return previous, None
    vertices, cells = mesh.vertices, mesh.cells
    weights, stale = previous.domain_weights, previous.stale
    boundary = [mesh.boundary_vertices, mesh.boundary_facet, mesh.boundary_bary]
    source = np.arange(len(cells))
    first_new = len(vertices)
    carried = weights @ cage.vertices  # where the carry will put each vertex
    zero = ZERO_LENGTH * old_cage.bbox_diagonal
    values = cage.surface_values.toarray()
    for a, b, facet in bent:
        ends = old_cage.surface_vertices[[a, b]]
        for p, q, at in _crossings(ends, vertices, cells, zero):
            x = len(vertices)
            row = (1.0 - at) * values[[a]] + at * values[[b]]  # the boundary values on the cage edge
            around = np.flatnonzero(np.any(cells == p, axis=1) & np.any(cells == q, axis=1))
            towards_p, towards_q = cells[around].copy(), cells[around].copy()
            towards_p[towards_p == q] = x
            towards_q[towards_q == p] = x
            halves = np.concatenate([towards_p, towards_q])
            # Where the edit bends the edge inwards, halves thin across it fold once carried: left as a chord.
            after = np.vstack([carried, row @ cage.vertices])
            before = np.vstack([vertices, (1.0 - at) * ends[0] + at * ends[1]])
            if np.any(signed_measures(after, halves) <= 0) or np.any(
                    radius_ratios(after, halves) < QUALITY_KEPT * radius_ratios(before, halves)):
                continue
            vertices, carried = before, after
            weights = np.vstack([weights, row])
            if stale is not None:
                stale = np.append(stale, max(stale[p], stale[q]))
            corners = list(old_cage.facets[facet])
            bary = np.zeros((1, 3))
            bary[0, corners.index(a)], bary[0, corners.index(b)] = 1.0 - at, at
            boundary = [np.append(boundary[0], x), np.append(boundary[1], facet), np.vstack([boundary[2], bary])]
            cells = np.vstack([cells, towards_q])
            cells[around] = towards_p
            source = np.append(source, source[around])
    if len(vertices) == first_new:
        return previous, None
    touched = np.zeros(len(vertices), dtype=bool)
    touched[cells[np.any(cells >= first_new, axis=1)].ravel()] = True
    domain = replace(mesh, vertices=vertices, cells=cells, boundary_vertices=boundary[0], boundary_facet=boundary[1],
                     boundary_bary=boundary[2])
    state = None if previous.solver_state is None else previous.solver_state.for_cells(source)
    return replace(previous, domain=domain, domain_weights=weights, stale=stale, solver_state=state), touched


def _bent_edges(old_cage, cage):
    """(K, 3) int array: the cage edges (a, b) whose two facets were coplanar in ``old_cage`` and are not in ``cage``
    (same facets), with one of those facets."""
    facets = old_cage.facets
    directed, order, _ = edge_pairing(facets)  # a closed manifold cage: each edge twice, its two facets side by side
    edges = np.sort(directed[order[::2]], axis=1)
    first, second = order[::2] % len(facets), order[1::2] % len(facets)
    old_normals, normals = (unit(triangle_normals(c.surface_vertices[facets])) for c in (old_cage, cage))
    bent = _coplanar(old_normals, first, second) & ~_coplanar(normals, first, second)
    return np.column_stack([edges[bent], first[bent]])


def _crossings(ends, vertices, cells, zero):
    """The mesh edges on the cage that the segment ``ends`` (2, 3) crosses, in the flat geometry where both lie in
    one plane (within COPLANAR_ANGLE): a list of (p, q, t), the crossing at (1 - t) ends[0] + t ends[1]. Crossings
    within CROSSING_END of an edge's length from its ends are left out: the mesh there follows the cage edge within
    that share already, and splitting so near a corner would make slivers."""
    edges = cell_edges(boundary_facets(cells))
    start, direction = ends[0], ends[1] - ends[0]
    p, along = vertices[edges[:, 0]], vertices[edges[:, 1]] - vertices[edges[:, 0]]
    normal = np.cross(direction, along)
    area = np.einsum("ij,ij->i", normal, normal)
    apart = p - start
    with np.errstate(divide="ignore", invalid="ignore"):  # parallel edges: nan, never a crossing
        on_segment = np.einsum("ij,ij->i", np.cross(apart, along), normal) / area
        on_edge = np.einsum("ij,ij->i", np.cross(apart, direction), normal) / area
        lengths = np.linalg.norm(along, axis=1)
        gap = np.linalg.norm(start + on_segment[:, None] * direction - (p + on_edge[:, None] * along), axis=1)
        end = CROSSING_END * lengths / np.linalg.norm(direction)
        hit = np.flatnonzero((gap <= zero + np.sin(COPLANAR_ANGLE) * lengths)
                            & (CROSSING_END < on_edge) & (on_edge < 1 - CROSSING_END)
                            & (end < on_segment) & (on_segment < 1 - end))
    return [(int(edges[k, 0]), int(edges[k, 1]), float(on_segment[k])) for k in hit]


def carry_domain(previous, unit_cage):
    """The previous binding's domain mesh carried onto an edited cage by its own coordinates, if still valid.

    Parameters
    ----------
    previous : Binding
    unit_cage : Cage
        The edited cage (same topology as ``previous.cage``), in its unit frame.

    Returns
    -------
    mesh : DomainMesh or None
        In the unit frame of ``unit_cage``; None when the carried mesh is not a valid domain.
    reason : str or None
        Why not, for the user.
    """
    old = previous.domain
    vertices = previous.domain_weights @ unit_cage.vertices
    vertices[old.boundary_vertices] = bary_positions(unit_cage, old.boundary_facet, old.boundary_bary)
    vertices[old.control_vertices] = unit_cage.vertices
    folded = signed_measures(vertices, old.cells) <= 0
    cells = old.cells
    if folded.any() and vertices.shape[1] == 3:
        cells = _flipped_slivers(vertices, old.cells, old.boundary_vertices, folded)
        folded = signed_measures(vertices, cells) <= 0
    if folded.any():
        return None, _near(previous, cells[folded],
                           "the edit would turn inside out some of the cells the last bind filled the cage with")
    # Each flip trades three cells for two, put last: the cells before them are old ones, with an old shape to keep.
    kept = np.arange(len(cells)) < len(cells) - 2 * (len(old.cells) - len(cells))
    kept_mesh = replace(old, cells=cells[kept])
    squashed = np.zeros(len(cells), dtype=bool)
    squashed[kept] = _squashed(kept_mesh, vertices)
    if squashed.any() and vertices.shape[1] == 3:
        vertices = _polished(replace(old, cells=cells), vertices, squashed)  # every cell kept positive
        squashed[kept] = _squashed(kept_mesh, vertices)
    if squashed.any():
        return None, _near(previous, cells[squashed],
                           "the edit would squash some of the cells the last bind filled the cage with, to less "
                           f"than {QUALITY_KEPT:.0%} of their shape")
    bent = _faces_off_cage(old, vertices, previous.cage, unit_cage)
    if len(bent):
        one = len(bent) == 1
        return None, (f"{_named_faces(bent)} bent too far: the cells the last bind filled the cage with cross "
                      f"{'it' if one else 'them'} and would leave the cage by more than {CHORD_KEPT:.0%} of a cell's "
                      "size")
    return replace(old, vertices=vertices, cells=cells), None


def _flipped_slivers(vertices, cells, boundary_vertices, folded):
    """The cells with folded slivers on the cage mended by a 3-2 flip where one applies.

    A sliver with every corner on the cage, two of its faces on the cage either side of a cage edge (e1, e2), is
    turned inside out when an edit turns that edge past flat. When its two other faces (sharing the edge a-b) lead to
    two cells with one apex p, and these three cells are all that surround a-b, the three are replaced by the two
    cells (e1, e2, p, a) and (e1, e2, p, b): the same faces bound the same region, and the cage faces stay faces.
    Applied only where both new cells are positively oriented at ``vertices``.

    Parameters
    ----------
    vertices : (N, 3) float array, the carried positions
    cells : (F, 4) int array
    boundary_vertices : (B,) int array
    folded : (F,) bool array

    Returns
    -------
    (F', 4) int array, F' <= F: cells whose rows a flip replaced come last
    """
    on_cage = np.zeros(len(vertices), dtype=bool)
    on_cage[boundary_vertices] = True
    cells = cells.copy()
    removed, added = [], []
    for sliver in np.flatnonzero(folded & np.all(on_cage[cells], axis=1)):
        corners = cells[sliver]
        # Cells sharing a face with the sliver: three of its corners each.
        sharing = np.count_nonzero(np.isin(cells, corners), axis=1) == 3
        sharing[sliver] = False
        neighbours = np.flatnonzero(sharing)
        if len(neighbours) != 2 or np.isin(neighbours, removed).any():
            continue
        apexes = [np.setdiff1d(cells[n], corners) for n in neighbours]
        inner = np.intersect1d(*[np.intersect1d(cells[n], corners) for n in neighbours])  # the edge a-b
        if apexes[0][0] != apexes[1][0] or len(inner) != 2:
            continue
        around = np.flatnonzero(np.count_nonzero(np.isin(cells, inner), axis=1) == 2)
        if len(around) != 3:  # a-b has more cells around it than the sliver and its two neighbours
            continue
        apex, (e1, e2) = apexes[0][0], np.setdiff1d(corners, inner)
        flipped = orient_positive(vertices, np.array([[e1, e2, apex, inner[0]], [e1, e2, apex, inner[1]]]))
        if np.any(signed_measures(vertices, flipped) <= 0):
            continue
        removed += [sliver, *neighbours]
        added.append(flipped)
    if not removed:
        return cells
    return np.concatenate([np.delete(cells, removed, axis=0), *added])


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


def _split_as_before(old, new):
    """The edited cage split into the previous cage's facets, and why a carried mesh cannot serve it (or None).

    How a quad or an n-gon is split into triangles follows the positions (a quad's shorter diagonal), so a small edit
    can change the split alone; the carried mesh lies on the previous facets, which stay a valid surface of the same
    faces as long as none of them folds against its face or flattens, and as long as the faces split otherwise stay
    flat: a bent face's surface is its split, and a cold bind would bind the other one.
    """
    if old.fingerprint() == new.fingerprint():
        return new, None
    if not np.array_equal(old.vertex_map, new.vertex_map) or old.face_corners() != new.face_corners():
        return new, "the cage's vertices, faces or welding changed"
    # The same faces (so the same face numbers), triangles per face differing: an n-gon split otherwise, its middle
    # now too near a side (or no longer) to split it from there.
    old_counts, new_counts = np.bincount(old.facet_face), np.bincount(new.facet_face)
    if not np.array_equal(old_counts, new_counts):
        faces = np.flatnonzero(old_counts != new_counts)
        its = "its" if len(faces) == 1 else "their"
        return new, (f"{_named_faces(faces)} changed shape so far that {its} split into triangles changed (from the "
                     "middle to one of the vertices, or back), which the cells the last bind filled the cage with do "
                     "not follow")
    if new.dim == 3:
        normals = triangle_normals(new.surface_vertices[old.facets])
        face_normals = np.zeros((int(new.facet_face.max()) + 1, 3))
        np.add.at(face_normals, new.facet_face, triangle_normals(new.surface_vertices[new.facets]))
        facing = np.einsum("ij,ij->i", normals, face_normals[old.facet_face])
        face_sizes = np.linalg.norm(face_normals[old.facet_face], axis=1)
        if np.any(facing <= ZERO_LENGTH * new.bbox_diagonal ** 2 * face_sizes):
            return new, "a cage face bent so far that its previous split into triangles folds"
        # A bent face's surface is its split: keeping the previous one would bind another cage than a cold bind.
        size = len(new.surface_vertices)
        resplit = np.unique(old.facet_face[~np.isin(row_keys(np.sort(old.facets, axis=1), size),
                                                    row_keys(np.sort(new.facets, axis=1), size))])
        bent = _bent(normals, old.facet_face, resplit)
        if len(bent):
            return new, (f"{_named_faces(bent)} bent and now split into other triangles (the edit changed which "
                         "diagonal a bind splits it along), which the cells the last bind filled the cage with do "
                         "not follow")
    return replace(new, facets=old.facets, facet_face=old.facet_face), None


def _named_faces(faces):
    """ "cage face 3", "cage faces 1, 4" or "cage faces 0, 1, 2, 3, 4 and 2 more": the first five of ``faces``."""
    listed = ", ".join(map(str, faces[:5])) + (f" and {len(faces) - 5} more" if len(faces) > 5 else "")
    return f"cage face{'s' if len(faces) > 1 else ''} {listed}"


def _bent(normals, facet_face, faces):
    """The faces among ``faces`` whose facets (normals (E, 3), any length) are not all coplanar within
    COPLANAR_ANGLE."""
    directions = unit(normals)
    mean = np.zeros((int(facet_face.max()) + 1, 3))
    np.add.at(mean, facet_face, normals)
    off = np.einsum("ij,ij->i", directions, unit(mean)[facet_face]) < np.cos(COPLANAR_ANGLE)
    return faces[np.isin(faces, facet_face[off])]


def _polished(mesh, vertices, squashed):
    """The carried ``vertices`` (N, 3) with the free corners of the ``squashed`` cells (F,) moved, as the mesher
    polishes its own, where that raises the least quality around them; :func:`_solve_near` solves them again."""
    movable = np.zeros(len(vertices), dtype=bool)
    movable[mesh.cells[squashed].ravel()] = True
    movable[mesh.boundary_vertices] = False
    poor_below = np.where(squashed, QUALITY_KEPT * radius_ratios(mesh.vertices, mesh.cells), -np.inf)
    return polish(vertices, mesh.cells, movable, median_edge(vertices, mesh.cells), np.random.default_rng(0),
                  Progress.of(None, None), poor_below)


def _squashed(mesh, vertices):
    """(F,) bool array: the cells of ``mesh`` that, at the carried ``vertices`` (N, d), keep less than QUALITY_KEPT
    of their shape quality and have a corner off the cage."""
    on_cage = np.zeros(len(vertices), dtype=bool)
    on_cage[mesh.boundary_vertices] = True
    kept = radius_ratios(vertices, mesh.cells) >= QUALITY_KEPT * radius_ratios(mesh.vertices, mesh.cells)
    return ~kept & ~np.all(on_cage[mesh.cells], axis=1)


def _faces_off_cage(mesh, vertices, old_cage, cage):
    """Input faces (3D) that some carried mesh boundary face crosses as a chord leaving the cage by more than
    CHORD_KEPT of the median cell edge.

    A mesh boundary face may straddle the split lines of a planar cage face (a quad's diagonal, the edge between two
    coplanar faces); carried, its corners stay on their facets but its inside stays on the cage only if those facets
    stay coplanar. (A face vertex on a sharp cage edge may be recorded on the facet beyond it; such pairs were not
    coplanar before either, and the vertex stays on the edge.)

    Parameters
    ----------
    mesh : DomainMesh, before the edit (in the frame of ``old_cage``)
    vertices : (N, 3) float array, the mesh's vertices carried onto ``cage`` (in its unit frame)
    old_cage, cage : Cage, before and after the edit, with the same facets
    """
    if cage.dim == 2:
        return np.zeros(0, dtype=np.int64)
    facet_of = np.full(len(mesh.vertices), -1)
    facet_of[mesh.boundary_vertices] = mesh.boundary_facet
    triangles = boundary_facets(mesh.cells)
    facets = facet_of[triangles]  # (K, 3): the cage facet of each corner
    mixed = np.any(facets != facets[:, :1], axis=1)
    triangles, facets = triangles[mixed], facets[mixed]
    # A corner on an edge or at a corner of a facet is recorded on any facet there: a face lying within one facet
    # is no face across a split line, whatever its corners' records say. That facet holds the first corner, so it
    # shares a vertex with the facet the first corner is recorded on.
    within = np.zeros(len(triangles), dtype=bool)
    tolerance = (1e-9 * old_cage.bbox_diagonal) ** 2
    old_surface = old_cage.surface_vertices
    for candidates in _facets_around(old_cage.facets, facets[:, 0]).T:
        corners = old_surface[old_cage.facets[np.maximum(candidates, 0)]]
        inside = candidates >= 0
        for k in range(3):
            inside &= closest_on_facets(mesh.vertices[triangles[:, k]], corners)[0] <= tolerance
        within |= inside
    triangles, facets = triangles[~within], facets[~within]
    old_normals, normals = (unit(triangle_normals(c.surface_vertices[c.facets])) for c in (old_cage, cage))
    off = np.zeros(len(facets), dtype=bool)
    for k in (1, 2):
        off |= _coplanar(old_normals, facets[:, 0], facets[:, k]) & ~_coplanar(normals, facets[:, 0], facets[:, k])
    triangles, facets = triangles[off], facets[off]
    far = _chord_distances(vertices[triangles], facets, cage) > CHORD_KEPT * median_edge(vertices, mesh.cells)
    faces = np.unique(cage.facet_face[facets[far]])
    bent = _bent(triangle_normals(cage.surface_vertices[cage.facets]), cage.facet_face, faces)
    return bent if len(bent) else faces  # the faces that bent, not their flat neighbours the mesh spans with them


def _chord_distances(corners, facets, cage):
    """(K,) float array: how far each triangle (corners (K, 3, 3), on the cage) leaves the surface of ``cage``, taken
    at its centroid and edge midpoints, against the facets around its corners' facets ``facets`` (K, 3)."""
    samples = np.stack([corners.mean(axis=1), *((corners[:, k] + corners[:, k - 1]) / 2 for k in range(3))], axis=1)
    nearest = np.full(samples.shape[:2], np.inf)
    surface = cage.surface_vertices
    for k in range(3):
        for candidates in _facets_around(cage.facets, facets[:, k]).T:
            facet_corners = surface[cage.facets[np.maximum(candidates, 0)]]
            for s in range(samples.shape[1]):
                squared = closest_on_facets(samples[:, s], facet_corners)[0]
                nearest[:, s] = np.minimum(nearest[:, s], np.where(candidates >= 0, squared, np.inf))
    return np.sqrt(nearest.max(axis=1))


def _facets_around(facets, which):
    """(len(which), D) int array: for each facet of ``which``, the facets sharing a vertex with it (itself included),
    padded with -1."""
    count = len(facets)
    incidence = sp.csr_matrix((np.ones(facets.size), (np.repeat(np.arange(count), facets.shape[1]), facets.ravel())))
    shared, around = padded_rows(incidence[which] @ incidence.T)  # shared vertices, 0 in the padding
    return np.where(shared > 0, around, -1)


def _coplanar(normals, first, second):
    """Whether facets ``first`` and ``second`` (arrays of indices) have unit normals within COPLANAR_ANGLE."""
    return np.einsum("kd,kd->k", normals[first], normals[second]) >= np.cos(COPLANAR_ANGLE)


def _near(previous, cells, what):
    """``what``, and the cage vertices nearest the offending cells, for the user."""
    centroid = previous.domain.vertices[np.unique(cells)].mean(axis=0)
    nearest = np.argsort(np.linalg.norm(previous.cage.vertices - centroid, axis=1))[:3]
    inputs = previous.cage.first_inputs[nearest]
    count = f"{len(cells)} cell" if len(cells) == 1 else f"{len(cells)} cells"
    return f"{what} ({count}, near cage vertices {', '.join(map(str, inputs))})"
