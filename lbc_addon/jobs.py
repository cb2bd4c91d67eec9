"""The part of a bind that runs without Blender: the request, the solve (on a worker thread) and its result.

1. :func:`lbc_addon.geometry.snapshot` (main thread) copies the mesh and the evaluated cage into a
   :class:`BindRequest`.
2. :func:`solve` (any thread; this module never imports ``bpy``) calls ``lbc_core.bind``, thins its
   weights and turns them into K slots, a :class:`BindResult`.
3. :func:`lbc_addon.writing.apply` (main thread) checks the objects did not change meanwhile, then writes.

Nothing in the scene changes before step 3, so a failed or cancelled bind leaves the scene exactly as it was.
:class:`Worker` runs step 2 for several meshes in a thread, with progress and cancellation, for the modal operator.

Binding a mesh again to the same cage with the same options (Rebind, Rebind All, or Bind on a bound mesh) starts from
its previous binding when this session still has it (``lbc_core.rebind``: a small cage edit at rest re-binds several
times faster; only the weights it changed are thinned again). A mesh bound to a cage another mesh was bound to with the
same options starts from that mesh's binding likewise: the solve depends on the cage alone, so several meshes in one
cage solve it once and each is only evaluated at its vertices. The previous bindings live in memory only, the last
:data:`KEPT_BINDINGS` of them and the one the latest bind replaced (an undo brings it back into the scene): their
solver state is 8-30 MB a binding (their thinned weights about 8 MB for 64k vertices), too large for the .blend, so a
reopened file, or a mesh bound long ago, binds from scratch.
"""

import re
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field, replace

import numpy as np

from . import storage
from .core import (FEW_CELLS_PER_CONTROL_POINT, CageError, CageVertexError, PointsOutside, bind, make_cage, rebind,
                   rebind_report, reframed, solved_again, thin_changed_rows, thin_weights, too_small_warning)
from .options import AddonOptions


# How many meshes' last bindings (with their solver state) this session keeps for a warm re-bind.
KEPT_BINDINGS = 4
# The share of a bind's progress bar for the thinning after lbc_core's bind: 0.4 of the demo's 4.1 s.
THINNING_SHARE = 0.1


@dataclass
class _Previous:
    """A mesh's last binding in this session, and what it was a binding of."""

    mesh_uid: int
    mesh_name: str
    cage_uid: int
    options: AddonOptions
    loop: np.ndarray  # the flat cage's outline of a 2D bind, else None
    binding: object  # lbc_core.Binding
    thinned: object  # the binding's weights thinned as the options say (scipy.sparse, one column per control point)
    plane: tuple = None  # a 2D bind's (origin, axes): the frame of its flat cage's plane

    @property
    def dimension(self):
        return 2 if self.loop is not None else 3


_previous = OrderedDict()  # mesh session_uid -> _Previous, the most recent last
_replaced = {}  # the binding the latest bind replaced: mesh session_uid -> _Previous, one entry at most


@dataclass
class BindRequest:
    """Everything the solve needs, copied out of Blender; identifies the objects by ``session_uid``."""

    mesh_uid: int
    cage_uid: int
    mesh_name: str
    points: np.ndarray  # (m, 3) mesh vertices, mesh space
    cage_points: np.ndarray  # (c, 3) evaluated cage vertices, mesh space
    cage_faces: list  # faces of the evaluated cage (3D)
    flat: object  # lbc_core.cage.planar.FlatCage of a 2D bind (the outline and the points in the plane), else None
    options: AddonOptions  # the bind options, as Object.lbc stores them
    cage_topology: str
    mesh_topology: str
    cage_shape: str = ""  # geometry.shape_fingerprint of the cage's own data: an edit at rest since changes it
    warnings: list = field(default_factory=list)  # what the snapshot noticed (a cage with other vertices in renders)
    cage_modifiers: str = ""  # the cage's modifiers that can change its vertices, e.g. "modifier 'Mirror'"
    cage_modifiers_off: str = ""  # those of them off in viewports (the bind, as the deformer, sees the cage without)
    cage_name: str = ""
    bound_to_cage: bool = False  # the mesh holds a binding to this cage already (a Rebind, or Bind again)
    # Mesh and solve anew rather than start from a binding this session kept (From Scratch): the result then does not
    # depend on the edits and re-binds before it. Other meshes of the same call still share its solve.
    from_scratch: bool = False
    # The 3D solve's geometry in world space: (cage vertices, cage faces pointing outward, mesh vertices); None: the
    # mesh-space arrays above.
    world: tuple = None

    @property
    def dimension(self):
        return 2 if self.flat is not None else 3

    @property
    def loop(self):
        """The flat cage's outline (its Blender vertex indices in order) of a 2D bind, else None."""
        return None if self.flat is None else self.flat.loop

    def solve_geometry(self):
        """(cage vertices, cage faces, points, column base): what lbc_core binds.

        3D: the cage and the mesh in world space, the faces still pointing outward, so that every mesh bound to one
        cage sees the same cage, and the solve made for one serves the others exactly (:func:`warm_start`); the
        weights reproduce the points in any affine frame, the mesh's own included. 2D: the flat outline and the
        points in its plane. The column base maps lbc_core's cage vertices to the Blender cage's.
        """
        if self.flat is not None:
            return self.flat.polygon, None, self.flat.points, self.flat.loop
        cage_points, faces, points = self.world or (self.cage_points, self.cage_faces, self.points)
        return cage_points, faces, points, np.arange(len(cage_points))


@dataclass
class BindResult:
    """What :func:`lbc_addon.writing.apply` writes, and the figures the panel shows."""

    index: np.ndarray  # (m, K) int32 cage vertex indices
    weight: np.ndarray  # (m, K) float32
    rest: np.ndarray  # (m, 3) Σ w c at rest
    control_points: int
    outside: int
    core_fingerprint: str
    cells: int = 0  # the domain mesh's triangles or tetrahedra
    warnings: list = field(default_factory=list)
    seconds: float = 0.0
    welded: str = ""  # "copy:kept,..." cage vertices welded into one control point (the deformer reads the kept one)
    binding: object = None  # the lbc_core.Binding, kept for a later warm re-bind once applied
    thinned: object = None  # the thinned weights (scipy.sparse, one column per control point), kept likewise
    plane: tuple = None  # a 2D bind's (origin, axes): the frame of its flat cage's plane, for a re-bind to keep
    rebind: str = ""  # for a bind that had a previous binding to start from: how it went (lbc_core.rebind)
    stages: dict = field(default_factory=dict)  # seconds: lbc_core's stages, then "thinning" and "slots"


def welded_pairs(copies, kept):
    """The cage vertices welded into another one's control point, as "copy:kept" pairs joined by commas.

    Parameters
    ----------
    copies : (n_input,) int array
        Each input cage vertex's index in the Blender cage.
    kept : (n_input,) int array
        The Blender cage vertex the deformer reads for that vertex's control point.
    """
    apart = copies != kept
    return ",".join(f"{copy}:{keep}" for copy, keep in zip(copies[apart].tolist(), kept[apart].tolist()))


def read_welded(welded):
    """The (copy, kept) pairs of :func:`welded_pairs`' text, as a (k, 2) int64 array."""
    return np.array([pair.split(":") for pair in welded.split(",") if pair], dtype=np.int64).reshape(-1, 2)


def printed_progress(interval=1.0, label="LBC bind"):
    """A progress callback printing "LBC bind: 42% message" lines (``label`` first; background mode has no status
    bar): a line when
    the message says something new, else at most one per ``interval`` seconds. A message that differs from the last
    only in its numbers says nothing new: a stage's own counts can change dozens of times a second (a new user's
    5 s bind printed 65 lines, 21 of them geodesic counts within 0.08 s)."""
    last = {"words": None, "line": None, "time": -float("inf")}

    def progress(fraction, message):
        line = f"{label}: {100 * fraction:3.0f}% {message}"
        words = re.sub(r"[\d.]+", "#", message)
        now = time.perf_counter()
        if line != last["line"] and (words != last["words"] or now - last["time"] >= interval):
            print(line, flush=True)
            last.update(words=words, line=line, time=now)

    return progress


def _outside_warning(outside):
    """A warning about the mesh's points outside the cage (``outside``: (m,) bool; lbc_core refuses them all), since
    they follow the cage by extrapolation from the closest points inside, not exactly as the points inside do."""
    count = int(np.count_nonzero(outside))
    too_small = too_small_warning(count, len(outside), "Rebind")
    if too_small:
        return [too_small]
    if count == 1:
        return ["1 vertex lies outside the cage; it follows the cage around the closest point inside it"]
    if not count:
        return []
    return [f"{count} vertices lie outside the cage; they follow the cage around the closest points inside it"]


def cage_too_small(settings, vertex_count):
    """The too-small warning of a bound mesh (its ``obj.lbc`` settings and its vertex count now), as the panel and
    ``api.status`` show it for a mesh that follows; "" when little of it lies outside."""
    total = settings.mesh_vertex_count or vertex_count  # 0: bound before the count was recorded
    return too_small_warning(settings.outside, total, "Rebind")


def few_cells_warning(dimension, control_points, cells):
    """What to say of a 3D binding whose ``cells`` tetrahedra are few for its ``control_points``: fewer than lbc_core's
    FEW_CELLS_PER_CONTROL_POINT each, where the weights are coarse (bench/RESULTS.md, "Few cells per control point");
    with the cells to ask for. "" otherwise (0 cells: bound before they were recorded)."""
    if dimension != 3 or not cells or cells >= FEW_CELLS_PER_CONTROL_POINT * control_points:
        return ""
    enough = -(-FEW_CELLS_PER_CONTROL_POINT * control_points // 1000) * 1000
    return (f"the cage's {control_points} vertices have {cells / control_points:.0f} cells each ({cells} in all), "
            f"few for so fine a cage: the weights are coarse. Bind again with Cells {enough} or more (a slower bind)")


def _cap_warning(weights, cap):
    """A warning when Max Influences ``cap`` could not be kept everywhere: a vertex its ``cap`` largest weights cannot
    hold in place keeps the fewest that can (lbc_core.evaluate.thinning), and the panel would show more than the cap."""
    counts = weights.getnnz(axis=1)
    over = int(np.count_nonzero(counts > cap)) if cap else 0
    if not over:
        return []
    return [f"Max Influences {cap}: {over} of {len(counts)} vertices keep more cage vertices (up to {counts.max()}, "
            f"mean {counts.mean():.1f}), the fewest that can hold them in place"]


def solve(request, progress=None, cancel=None, earlier=()):
    """Compute the weights (no ``bpy`` here: safe in a worker thread). Raises CageError or lbc_core.Cancelled.

    ``earlier``: (request, result) pairs solved before this one and not yet written (the other meshes of one Bind),
    which it may start from as from a binding of this session (:func:`warm_start`).
    """
    start = time.perf_counter()
    previous = warm_start(request, earlier)
    request = _in_plane_of(request, previous)
    cage_vertices, faces, points, column_base = request.solve_geometry()
    core_progress, thinning_progress = _progress_parts(progress)
    try:
        if previous is not None:
            binding = rebind(previous.binding, cage_vertices, faces, points, progress=core_progress, cancel=cancel)
        else:
            binding = bind(cage_vertices, faces, points, options=request.options.core_options(request.dimension),
                           progress=core_progress, cancel=cancel)
    except PointsOutside as error:
        raise CageError(_all_outside(request)) from error
    except CageError as error:
        cause, note = _cage_modifiers_notes(request, error)
        hint = _swapped_hint(request)
        if hint or cause or note:
            raise CageError(f"{hint}{cause}{error}{f' ({note})' if note else ''}") from error
        raise
    column_vertex = column_base[binding.cage.first_inputs]
    cells = len(binding.domain.cells)
    # The deformer's cost per frame grows with the influences per vertex: fewer, continuously (lbc_core.evaluate.thinning).
    rest = binding.rest_cage_vertices
    thinning = request.options.floor_and_cap
    clock = time.perf_counter()
    if previous is not None and previous.options.floor_and_cap == thinning:
        # A warm re-bind keeps the rows its edit cannot reach: only the others are thinned again.
        weights, _ = thin_changed_rows(previous.thinned, previous.binding.weights, binding.weights,
                                       previous.binding.rest_cage_vertices, rest, *thinning,
                                       progress=thinning_progress, cancel=cancel)
    else:
        weights = thin_weights(binding.weights, rest, binding.weights @ rest, *thinning, progress=thinning_progress,
                               cancel=cancel)
    if thinning_progress is not None:
        thinning_progress(1.0, "")
    stages = dict(binding.timings, thinning=time.perf_counter() - clock)
    clock = time.perf_counter()
    index, weight = storage.slot_arrays(weights, column_vertex)
    rest_offsets = storage.rest_offsets(index, weight, request.cage_points)
    stages["slots"] = time.perf_counter() - clock
    return BindResult(
        index=index,
        weight=weight,
        rest=rest_offsets,
        control_points=len(column_vertex),
        outside=int(np.count_nonzero(binding.outside)),
        core_fingerprint=binding.cage.fingerprint(),
        warnings=request.warnings + _outside_warning(binding.outside) + list(binding.cage.warnings)
        + ([] if binding.converged else [_not_converged(binding.iterations)]) + _cap_warning(weights, thinning[1])
        + [warning for warning in [few_cells_warning(request.dimension, len(column_vertex), cells)] if warning],
        cells=cells,
        welded=welded_pairs(column_base, column_vertex[binding.cage.vertex_map]),
        seconds=time.perf_counter() - start,
        binding=binding,
        thinned=weights,
        plane=None if request.flat is None else (request.flat.origin, request.flat.axes),
        rebind=_rebind_report(request, previous, binding),
        stages=stages,
    )


def _all_outside(request):
    """The refusal of a mesh wholly outside its cage. Bound to it already (a Rebind), the mesh was moved away as an
    object (a Shift+D copy moved off, which its cage still places): nothing was selected the wrong way round."""
    mesh, cage = request.mesh_name, request.cage_name
    if request.bound_to_cage:
        return (f"every vertex of '{mesh}' lies outside its cage '{cage}' where '{mesh}' is now: it was moved as an "
                f"object out of the cage, which still places it. Move it back into '{cage}' (or undo the move); or, to "
                f"deform it where it is now, give it a cage there (duplicate '{cage}' and move the copy around it) "
                "and bind it to that cage")
    return (f"every vertex of '{mesh}' lies outside the cage '{cage}': the cage must enclose the mesh. Is it the right "
            "cage? (Select the mesh, then the cage last so it is active.)")


def _progress_parts(progress):
    """``progress`` split into lbc_core's bind and the thinning after it, which takes THINNING_SHARE of the bar (a
    new user saw the bar at 100 % while the demo's 64k vertices were thinned): the core's last message ("bound")
    is told when the thinning ends. (None, None) for None."""
    if progress is None:
        return None, None
    last = ["bound"]

    def core(fraction, message):
        if fraction >= 1.0:
            last[0], message = message, "thinning the weights"
        progress((1 - THINNING_SHARE) * fraction, message)

    def thinning(fraction, message):
        progress(1 - THINNING_SHARE * (1 - fraction), last[0] if fraction >= 1.0 else message)

    return core, thinning


def _in_plane_of(request, previous):
    """A 2D request in the plane coordinates of the binding it starts from, so that only the cage vertices that moved
    move in 2D; the request itself for a 3D one, or when the cage left that plane."""
    if previous is None or previous.plane is None or request.flat is None:
        return request
    flat = reframed(request.flat, request.cage_points, request.points, *previous.plane)
    return request if flat is None else replace(request, flat=flat)


def verb_for(modifiers, singular, plural):
    """The verb agreeing with ``modifiers``, "modifier 'Mirror'" or "modifiers 'Mirror', 'Subdivision'"."""
    return plural if modifiers.startswith("modifiers") else singular


def _swapped_hint(request):
    """What to say before a refusal when the mesh and the cage look swapped ("" otherwise): a refused cage with more
    vertices than its mesh is most often the mesh, made active by selecting it last. Only on the error path: it checks
    the cage alone again, to tell its refusal from others (e.g. the memory a resolution needs)."""
    cage_count, mesh_count = len(request.cage_points), len(request.points)
    if cage_count <= mesh_count:
        return ""
    cage_vertices, faces = request.solve_geometry()[:2]
    try:
        make_cage(cage_vertices, faces)
        return ""
    except CageError:
        pass
    return (f"'{request.cage_name}' is the cage here but has more vertices than '{request.mesh_name}' ({cage_count} "
            f"against {mesh_count}): were they swapped? The cage is the object selected last (active); in a script, "
            f"api.bind(mesh, cage). As a cage, '{request.cage_name}' is refused: ")


def _cage_modifiers_notes(request, error):
    """What to say, before and after lbc_core's ``error``, about a cage whose modifiers make it another cage than
    the artist's mesh data (each "" for none). A modifier off in viewports is the likely cause (a Mirror off leaves a
    hole), so it leads; the others may be (Solidify makes two parts), and vertex numbers count the evaluated cage's
    vertices, which Edit Mode does not show, so they follow."""
    cause = ""
    if request.cage_modifiers_off:
        verb = verb_for(request.cage_modifiers_off, "is", "are")
        cause = (f"the cage's {request.cage_modifiers_off} {verb} off in viewports, and the cage is bound as viewports "
                 "show it (turn it on, or apply it); so ")
    note = ""
    if request.cage_modifiers:
        verb = verb_for(request.cage_modifiers, "makes", "make")
        note = (f"vertex numbers of the cage with its {request.cage_modifiers} applied"
                if isinstance(error, CageVertexError)
                else f"this is the cage as its {request.cage_modifiers} {verb} it")
    return cause, note


def _not_converged(iterations):
    """The warning of a solve stopped at the iteration limit: the weights are valid, only less local."""
    return (f"the solver stopped at its limit of {iterations} iterations before its tolerance: the weights still sum "
            "to 1 and reproduce the mesh, but reach further than they would (very thin cages are the usual cause; a "
            "larger Tolerance stops sooner)")


def warm_start(request, earlier=()):
    """The binding (:class:`_Previous`) to start the request from, or None: a binding of this session to the same cage
    with the same options (a 2D bind: the same outline), among ``earlier`` (see :func:`solve`) and the kept ones.

    First one of the cage exactly as it is now (nothing to solve again: e.g. the second mesh of a Rebind after a cage
    edit starts from the first's new binding, and a Rebind after undoing a Rebind finds the binding the undo brought
    back), the mesh's own first; else the mesh's own; else the latest other's. A request ``from_scratch`` starts only
    from one of ``earlier`` (solved in the same call, from scratch too) of the cage exactly as it is now.
    """
    own = [] if request.from_scratch else [_previous.get(request.mesh_uid), _replaced.get(request.mesh_uid)]
    others = [_as_previous(*pair) for pair in reversed(earlier)]
    if not request.from_scratch:
        others += list(reversed(_previous.values()))
    candidates = [previous for previous in own + others if previous is not None and _same_solve(previous, request)]
    vertices = np.asarray(request.solve_geometry()[0], dtype=float)
    unmoved = [previous for previous in candidates if _bound_at(previous.binding, vertices)]
    return (unmoved + ([] if request.from_scratch else candidates) + [None])[0]


def _bound_at(binding, cage_vertices):
    """Whether ``binding``'s rest cage is exactly ``cage_vertices`` (n_input, d)."""
    if len(cage_vertices) != len(binding.cage.vertex_map):
        return False
    try:
        return np.array_equal(binding.cage.control_points_from_input(cage_vertices), binding.rest_cage_vertices)
    except CageError:  # welded copies posed apart
        return False


def _same_solve(previous, request):
    """Whether ``previous`` bound to the request's cage with its solve options and, in 2D, outline."""
    if previous.cage_uid != request.cage_uid:
        return False
    if previous.options.solve_changes(request.options, request.dimension):
        return False
    loop = request.loop
    return (previous.loop is None) == (loop is None) and (loop is None or np.array_equal(previous.loop, loop))


def _as_previous(request, result):
    """The :class:`_Previous` record of a solved request."""
    return _Previous(request.mesh_uid, request.mesh_name, request.cage_uid, request.options, request.loop,
                     result.binding, result.thinned, result.plane)


def _rebind_report(request, previous, binding):
    """How a bind that started from a binding of this session went, for the user; "" for any other bind.

    From the mesh's own binding, lbc_core's account (cells solved again, or why it bound from scratch); from another
    mesh's, what it reused, and when it bound from scratch, why for a mesh bound to this cage before (its own binding
    no longer in memory: more meshes than KEPT_BINDINGS rebound), nothing for a first bind.
    """
    report = rebind_report(binding)
    own = _previous.get(request.mesh_uid)
    if previous is None and request.from_scratch:
        return "bound from scratch, as asked (From Scratch)"
    if previous is None and own is not None and own.cage_uid == request.cage_uid:
        changed = own.options.solve_changes(request.options, request.dimension)
        return f"bound from scratch: its {', '.join(changed)} changed since its last bind" if changed else report
    if previous is None and own is None and request.bound_to_cage:
        return (f"bound from scratch: no earlier binding of it is in memory (kept for this session's last "
                f"{KEPT_BINDINGS} meshes, not in the .blend: a reopened file or an Unbind forgets it)")
    if previous is None or previous.mesh_uid == request.mesh_uid:
        return report
    reused = solved_again(binding)
    if not reused:
        return report if request.bound_to_cage else ""  # why a mesh bound before bound from scratch
    made = ", bound from scratch just before (From Scratch)" if request.from_scratch else ""
    return f"started from the binding of '{previous.mesh_name}' to the same cage{made}: {reused}"


def remember(request, result):
    """Keep ``result``'s binding as the mesh's previous one (the last KEPT_BINDINGS meshes' only); called once the
    binding is written."""
    kept = _as_previous(request, result)
    replaced = _previous.pop(request.mesh_uid, None)
    if replaced is not None and not _same_binding(replaced, kept):  # a Rebind that solved nothing replaces nothing
        _replaced.clear()
        _replaced[request.mesh_uid] = replaced
    _previous[request.mesh_uid] = kept
    while len(_previous) > KEPT_BINDINGS:
        _previous.popitem(last=False)


def _same_binding(first, second):
    """Whether two :class:`_Previous` records bound the same rest cage with the same solve."""
    a, b = first.binding.rest_cage_vertices, second.binding.rest_cage_vertices
    return _same_solve(first, second) and a.shape == b.shape and np.array_equal(a, b)


def forget(mesh_uid):
    """Drop a mesh's previous bindings (it was unbound)."""
    _previous.pop(mesh_uid, None)
    _replaced.pop(mesh_uid, None)


class Worker:
    """Solves bind requests one after the other in a thread, reporting progress and obeying a cancel flag.

    Read ``fraction``, ``message``, ``done`` from the main thread; results and errors are collected in ``results``
    (pairs of request and result) and ``error`` (the first exception, after which the worker stops). ``work`` is what
    runs for each request, as :func:`solve` (its default) takes it: Make Cage runs ``cage_job.make`` so. ``activity``
    says what runs, for the message of a button that waits for it ("a bind is already running").
    """

    def __init__(self, requests, work=None, activity="a bind"):
        self.requests = list(requests)
        self.work = solve if work is None else work
        self.activity = activity
        self.results = []
        self.error = None
        self.fraction = 0.0
        self.message = "starting"
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"lbc {activity}", daemon=True)

    def start(self):
        self._thread.start()

    def cancel(self):
        """Ask the solve to stop at its next check; ``done`` turns true soon after."""
        self._cancel.set()

    @property
    def cancelled(self):
        return self._cancel.is_set()

    @property
    def done(self):
        return not self._thread.is_alive()

    def join(self):
        self._thread.join()

    def _run(self):
        count = len(self.requests)
        try:
            for number, request in enumerate(self.requests):
                def progress(fraction, message, number=number, request=request):
                    self.fraction = (number + fraction) / count
                    self.message = f"{request.mesh_name}: {message}"

                self.results.append((request, self.work(request, progress, self._cancel.is_set, self.results)))
        except Exception as error:  # handed to the main thread, which reports it
            self.error = error
