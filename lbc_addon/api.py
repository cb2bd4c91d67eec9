"""Python API for scripts, e.g. ``blender -b scene.blend --python-expr "..."``; runs synchronously.

Example::

    import bpy
    from lbc_addon import api   # inside Blender with the extension enabled: from bl_ext.user_default.lbc import api
    summary = api.bind(bpy.data.objects["Body"], bpy.data.objects["Cage"], cells=20000)
    # or, without a cage yet: made = api.make_cage([bpy.data.objects["Body"]]); api.bind(body, made.cage)
    print(summary.warnings)
    assert api.status(bpy.data.objects["Body"]).ok
    bpy.ops.wm.save_mainfile()
"""

import logging
import warnings
from dataclasses import dataclass, replace

import bpy

from . import cage_job, cage_scene, deformer, diagnosis, geometry, jobs, node_group, writing
from .core import DEFAULT_SMOOTHNESS, CageError, Cancelled  # noqa: F401  (Cancelled: for scripts, except api.Cancelled)
from .diagnosis import Note, NoteKind  # noqa: F401  (for scripts: what Status.notes holds)
from .options import DEFAULT_INFLUENCES, MESHER_NAMES, AddonOptions
from .properties import bound_to, is_bound

# A bind's warnings go to this logger for pipelines; the NullHandler keeps Python's last-resort handler from printing
# them a second time in background mode, where they are printed anyway.
logger = logging.getLogger(__name__)
logger.addHandler(logging.NullHandler())


@dataclass(frozen=True)
class BindSummary:
    """What one bind did: :func:`bind` returns it, :func:`rebind_all` one per mesh.

    Attributes
    ----------
    mesh : str
        The bound mesh object's name.
    dimension : int
        2 or 3: how the weights were computed.
    control_points : int
        The cage's vertices after welding duplicates.
    cells : int
        The triangles (2D) or tetrahedra (3D) the weights were computed on.
    slots : int
        K, the most cage vertices moving one mesh vertex (the deformer's attribute pairs).
    mean_influences : float
        Cage vertices moving a mesh vertex, on average (3 decimals: stored as float32, its noise says nothing).
    outside : int
        Mesh vertices outside the cage, which follow it by extrapolation.
    warnings : tuple of str
        The bind's warnings, and why the deformer is held off if the modifier stack holds it off.
    seconds : float
        The bind's time, writing included.
    rebind : str
        For a mesh bound before in this session, how it went (from its previous binding, or from scratch and why);
        "" for a first bind (unless ``from_scratch``).

    Examples
    --------
    >>> summary = api.bind(bpy.data.objects["Sphere"], bpy.data.objects["Box"], cells=1000)
    >>> summary.dimension, summary.control_points, summary.outside
    (3, 8, 0)
    >>> summary.warnings
    ()
    """

    mesh: str
    dimension: int
    control_points: int
    cells: int
    slots: int
    mean_influences: float
    outside: int
    warnings: tuple
    seconds: float
    rebind: str


@dataclass(frozen=True)
class Status:
    """What :func:`status` says of an object: whether its deformer works, and what else the panels say of it.

    Attributes
    ----------
    following : bool
        The deformer works: the mesh follows its cage.
    message : str
        The panel's status line: "Following 'Cage'", or why the mesh stays at rest and what to do.
    notes : tuple of :class:`Note`
        What the panels add of a mesh that follows, each with its ``kind`` (a :class:`NoteKind`) and ``text``:
        lasting problems of the binding (much of the mesh outside a cage too small, the mesh moved out of its cage)
        and advice (few cells for the cage; the cage edited since the bind, the mesh moved as an object).

    Examples
    --------
    >>> state = api.status(bpy.data.objects["Sphere"])
    >>> state.ok, state.message
    (True, "Following 'Box'")
    >>> [note.kind for note in state.notes]
    []
    """

    following: bool
    message: str
    notes: tuple = ()

    @property
    def ok(self):
        """Following, and no note is a problem (:attr:`Note.problem`): what a pipeline checks before a render."""
        return self.following and not any(note.problem for note in self.notes)

    @property
    def text(self):
        """The message and the notes' texts, joined by "; ", as one line to print."""
        return "; ".join([self.message] + [note.text for note in self.notes])


def bind(mesh_obj, cage_obj, *, cells=0, weighting="quadratic", epsilon=0.0, tolerance=0.0, thinning=0.0,
         influences=DEFAULT_INFLUENCES, mode="AUTO", mesher=MESHER_NAMES[0], smoothness=DEFAULT_SMOOTHNESS,
         from_scratch=False, progress=None,
         cancel=None):
    """Bind ``mesh_obj`` to ``cage_obj`` (replacing an existing binding) and add the deformer.

    Parameters are those of the Bind operator (``mode`` its Dimension, ``mesher`` its Mesher: "auto" or
    "delaunay"); ``progress(fraction, message)`` and ``cancel() -> bool`` are passed to lbc_core. Nothing in the
    scene changes unless the bind succeeds. A mesh bound before in this session starts from its previous binding
    (``lbc_core.rebind``) unless ``from_scratch``: a pipeline that wants the same result whatever the session bound
    before asks for that.

    Returns
    -------
    BindSummary
        With no ``progress`` in background mode, progress lines are printed, and the warnings after them ("LBC bind:
        warning: Body: ..."). The warnings are also logged, at level WARNING, to the ``logging`` logger named after
        this module (e.g. "bl_ext.user_default.lbc.api"), for pipelines.

    Raises
    ------
    CageError
        With lbc_core's message, for a cage or mesh that cannot be bound (``api.CageError``, a ValueError); at once,
        in the Bind button's words, for a would-be cage that is most likely the mesh (mesh and cage swapped).
    Cancelled
        When ``cancel()`` turned true.
    RuntimeError
        When the extension is installed but not enabled (before any work).

    Examples
    --------
    >>> api.bind(bpy.data.objects["Sphere"], bpy.data.objects["Box"], cells=1000, thinning=0.01).slots
    8
    >>> api.bind(bpy.data.objects["Box"], bpy.data.objects["Sphere"])  # swapped: refused before any work
    Traceback (most recent call last):
    lbc_core.errors.CageError: 'Sphere' is active and would be the cage; ...
    """
    _require_enabled()
    options = AddonOptions(cells=cells, weighting=weighting, epsilon=epsilon, tolerance=tolerance, thinning=thinning,
                           influences=influences, mode=mode, mesher=mesher, smoothness=smoothness)
    request = geometry.snapshot(mesh_obj, cage_obj, bpy.context.evaluated_depsgraph_get(), options)
    return _bind_request(replace(request, from_scratch=from_scratch), progress, cancel)


def _bind_request(request, progress, cancel, solved=None):
    """Solve and write one :class:`jobs.BindRequest`; returns its :class:`BindSummary`. ``solved``: a list of the
    (request, result) pairs of the same call, which the solve may start from (:func:`jobs.solve`) and this one joins."""
    printing = progress is None and bpy.app.background
    if printing:
        progress = jobs.printed_progress()
    result = jobs.solve(request, progress, cancel, earlier=() if solved is None else solved)
    if solved is not None:
        solved.append((request, result))
    bound = writing.apply(request, result)
    settings = bound.lbc
    held_off = diagnosis.held_off_warning(bound)
    found = list(result.warnings) + ([held_off] if held_off else [])
    _tell(bound.name, found, printing)
    return BindSummary(
        mesh=bound.name,
        dimension=settings.dimension,
        control_points=settings.control_points,
        cells=settings.domain_cells,
        slots=settings.slots,
        mean_influences=round(settings.mean_influences, 3),  # stored as float32: its noise says nothing
        outside=settings.outside,
        warnings=tuple(found),
        seconds=settings.bind_seconds,
        rebind=result.rebind,
    )


def _tell(mesh_name, found, printing, label="LBC bind"):
    """Log a bind's (or Make Cage's) warnings (a background script returns its summary, and nobody may read it), and
    print them when ``printing``, among the progress lines that begin with ``label``."""
    for warning in found:
        logger.warning("%s: %s", mesh_name, warning)
        if printing:
            print(f"{label}: warning: {mesh_name}: {warning}", flush=True)


@dataclass(frozen=True)
class CageSummary:
    """What :func:`make_cage` made.

    Lengths and the volume are in the cage object's own units, which are the first mesh's (the cage takes its world
    transform: with a scale of 1, world units).

    Attributes
    ----------
    cage : bpy.types.Object
        The new cage object (a reference, valid as any until an undo or another file is loaded).
    name : str
        Its name, "<first mesh>Cage" (".001" added by Blender when that is taken).
    meshes : tuple of str
        The meshes it was made around, the first giving its frame, name and collections.
    vertices : int
        The cage's vertex count.
    faces : int
        Its faces.
    asked_vertices : int
        The vertex count asked, or the one chosen for the meshes (``vertices=0``).
    volume : float
        What it encloses.
    clearance : float
        About the least distance from a mesh vertex to the cage.
    mean_distance : float
        About the mean distance from a cage vertex to the meshes.
    margin : float
        The margin it was made with (wider than asked when the first attempts failed: see ``warnings``).
    attempts : int
        How many attempts it took (1: the first).
    warnings : tuple of str
        What the artist should know (e.g. why the first attempts failed).
    seconds : float
        The time to make it.

    Examples
    --------
    >>> made = api.make_cage([bpy.data.objects["Suzanne"]], vertices=40)
    >>> made.name, made.cage.display_type, abs(made.vertices - 40) <= 6
    ('SuzanneCage', 'WIRE', True)
    >>> api.bind(bpy.data.objects["Suzanne"], made.cage).outside
    0
    """

    cage: object
    name: str
    meshes: tuple
    vertices: int
    faces: int
    asked_vertices: int
    volume: float
    clearance: float
    mean_distance: float
    margin: float
    attempts: int
    warnings: tuple
    seconds: float


def make_cage(mesh_objs, *, vertices=0, margin=0.0, symmetry=None, vertex_group="", progress=None, cancel=None):
    """Make a closed cage around ``mesh_objs`` (one mesh object or several: one cage around them all) and add it to
    the scene, as the Make Cage button does: a new object "<first mesh>Cage" drawn as a wire, hidden in renders,
    with the first mesh's world transform, in its collections; the meshes selected and the cage active.

    Parameters are those of the Make Cage operator: ``vertices`` (0: chosen for the meshes' shape), ``margin`` (a
    share of their bounding-box diagonal; 0: lbc's default), ``symmetry`` (None, "x", "y" or "z": mirror-symmetric
    across that axis of the first mesh), ``vertex_group`` (a partial cage around the faces of this group of each
    mesh; "": the whole meshes). ``progress(fraction, message)`` and ``cancel() -> bool`` are passed to lbc_core.
    Nothing in the scene changes unless the cage is made. Bind the meshes to it with :func:`bind`.

    Returns
    -------
    CageSummary
        With no ``progress`` in background mode, progress lines are printed ("LBC cage: 42% shaping the cage"), and
        the warnings after them; the warnings are also logged, as :func:`bind`'s are.

    Raises
    ------
    CageError
        For what cannot be caged (not a mesh, in Edit Mode, a vertex group missing or empty, flat, bad options), at
        once; or when lbc_core could make no valid cage (``CageGenerationFailed``), saying what to try.
    Cancelled
        When ``cancel()`` turned true.
    RuntimeError
        When the extension is installed but not enabled (before any work).
    """
    _require_enabled()
    options = cage_job.CageOptions(vertices=vertices, margin=margin, symmetry=symmetry, vertex_group=vertex_group)
    request = cage_scene.snapshot(mesh_objs, options)
    printing = progress is None and bpy.app.background
    if printing:
        progress = jobs.printed_progress(label="LBC cage")
    result = cage_job.make(request, progress, cancel)
    cage = cage_scene.write(request, result)
    made = result.cage
    _tell(cage.name, made.warnings, printing, "LBC cage")
    return CageSummary(cage=cage, name=cage.name, meshes=request.mesh_names, vertices=made.vertex_count,
                       faces=len(made.faces), asked_vertices=made.asked_vertices, volume=made.volume,
                       clearance=made.clearance, mean_distance=made.mean_distance, margin=made.margin,
                       attempts=made.attempts, warnings=tuple(made.warnings), seconds=result.seconds)


def unbind(mesh_obj):
    """Remove the binding; the mesh is exactly as before it was bound. For an unbound mesh, removes the LBC weights
    it carries for no binding (a bound mesh joined into it), if any; raises CageError for a mesh linked from a library
    (its binding lives in that file).

    Returns
    -------
    list of str
        The bound objects sharing the mesh data (linked duplicates), for which the weights stay in it; empty when
        they were removed with the binding.
    """
    _require_enabled()
    leftovers = geometry.leftover_weights(mesh_obj)
    if not is_bound(mesh_obj) and not leftovers:
        return []
    linked = geometry.not_editable_here(mesh_obj)
    if linked:
        raise CageError(linked)
    if leftovers:
        writing.remove_leftovers(mesh_obj)
        return []
    return writing.remove(mesh_obj)


def rebind_all(cage_obj, *, from_scratch=False, progress=None, cancel=None):
    """Bind every mesh of the scene bound to ``cage_obj`` again, to the cage as it is now, each with its own options;
    ``from_scratch`` as in :func:`bind` (the meshes with the same options still share one solve).

    A mesh that cannot be bound before any work (e.g. its data shared by a linked duplicate, Alt+D) or whose LBC
    modifier was removed or applied is left as it was with a ``UserWarning`` saying why, as the Rebind All operator
    does (and logs it, as :func:`bind` logs its warnings). Returns a :class:`BindSummary` per mesh bound; raises as :func:`bind` does when every mesh is refused or a solve fails, the meshes bound before
    the error keeping their new binding.
    """
    _require_enabled()
    targets, left_out = deformer.rebind_all_targets(cage_obj, bpy.context.scene.objects)
    requests, refused = geometry.snapshots(targets, bpy.context.evaluated_depsgraph_get(), skip_refused=True,
                                           left_out=left_out)
    for message in refused:
        logger.warning("%s", message)
        warnings.warn(message, stacklevel=2)
    solved = []
    return [_bind_request(replace(request, from_scratch=from_scratch), progress, cancel, solved)
            for request in requests]


def set_deformer(mesh_obj, **inputs):
    """Set the inputs of a bound mesh's LBC modifier: ``strength`` (float), ``vertex_group`` (str, "" for none),
    ``invert_vertex_group`` (bool); the same as the panel's fields.

    Raises
    ------
    lbc_core.CageError
        When the mesh is not bound, its modifier was removed, or the object is linked from a library (not an
        override: the change would be lost on saving).
    TypeError, ValueError
        For an unknown input, a value of the wrong type, or a strength outside -10 to 10 (the panel's range).
    """
    _require_enabled()
    if isinstance(mesh_obj, bpy.types.Object) and mesh_obj.library is not None:
        raise CageError(geometry.not_editable_here(mesh_obj))
    modifier = deformer.find_modifier(mesh_obj) if is_bound(mesh_obj) else None
    if modifier is None:
        raise CageError(f"'{mesh_obj.name}' has no LBC modifier: bind it first")
    names = {"strength": "Strength", "vertex_group": "Vertex Group", "invert_vertex_group": "Invert Vertex Group"}
    unknown = set(inputs) - set(names)
    if unknown:
        raise TypeError(f"set_deformer() got unknown inputs {sorted(unknown)}; it takes {sorted(names)}")
    types = {"strength": (float, int), "vertex_group": (str,), "invert_vertex_group": (bool,)}
    for key, value in inputs.items():
        if not isinstance(value, types[key]) or (key == "strength" and isinstance(value, bool)):
            expected = " or ".join(kind.__name__ for kind in types[key])
            raise TypeError(f"set_deformer({key}=...) takes a {expected}, not {type(value).__name__} {value!r}")
    low, high = node_group.STRENGTH_RANGE
    if "strength" in inputs and not low <= inputs["strength"] <= high:
        raise ValueError(f"set_deformer(strength={inputs['strength']!r}) is out of the Strength range {low:g} to {high:g}"
                         " (1 follows the cage fully, 0 stays at rest)")
    deformer.set_inputs(modifier, {names[key]: value for key, value in inputs.items()})
    mesh_obj.update_tag()


def save_shape_key(mesh_obj, name=""):
    """Save the deformation the cage gives ``mesh_obj`` now as a new shape key at value 0 (e.g. to sculpt a corrective
    shape on it), named ``name`` (default "LBC <cage>"); the binding stays. Returns the shape key's name.

    Raises
    ------
    lbc_core.CageError
        When the mesh is not bound, its deformer does not work now (the message says why), or it is linked from a
        library; nothing is changed then.
    """
    _require_enabled()
    return writing.save_shape_key(mesh_obj, bpy.context.evaluated_depsgraph_get(), name).name


def status(mesh_obj):
    """Whether the deformer of a bound mesh works and, if not, why; for an unbound object, that it is not bound.

    Returns
    -------
    Status
        A mesh that follows gets the panels' notes (:attr:`Status.notes`); ``ok`` is false when one of them is a
        lasting problem, as much of the mesh outside a cage too small.

    Examples
    --------
    >>> api.status(bpy.data.objects["Sphere"]).text
    "Following 'Box'"
    >>> api.status(bpy.data.objects["Box"]).text
    "'Box' is the cage of 1 bound mesh(es) ('Sphere'): ask api.status of each of them"
    """
    _require_enabled()
    if not isinstance(mesh_obj, bpy.types.Object):
        return Status(False, f"{mesh_obj!r} is not an object: pass it as e.g. bpy.data.objects['Name']")
    if mesh_obj.type != "MESH":
        return Status(False, geometry.not_a_mesh(mesh_obj, "only meshes can be bound", "bind a mesh"))
    if not is_bound(mesh_obj):
        meshes = bound_to(mesh_obj, bpy.data.objects)
        if meshes:
            names = ", ".join(f"'{obj.name}'" for obj in meshes[:3]) + (", …" if len(meshes) > 3 else "")
            return Status(False, f"'{mesh_obj.name}' is the cage of {len(meshes)} bound mesh(es) ({names}): ask "
                                 f"api.status of each of them")
        leftover = ("; it carries LBC weights for no binding (from a bound mesh joined into it), which api.unbind "
                    "removes" if geometry.leftover_weights(mesh_obj) else "")
        return Status(False, f"'{mesh_obj.name}' is not bound to a cage: bind it first (api.bind){leftover}")
    ok, message = diagnosis.status(mesh_obj, bpy.context.evaluated_depsgraph_get())
    if not ok:
        return Status(False, message)
    # Following, with the panel's notes: a pipeline checks here what an artist reads there.
    return Status(True, message, diagnosis.notes(mesh_obj, diagnosis.SCRIPT_WORDS))


def _require_enabled():
    """Refuse at once when the extension is installed but not enabled (its properties are then not registered), as on
    a render farm machine whose preferences were never saved; every call would otherwise fail after the work."""
    if not hasattr(bpy.types.Object, "lbc"):
        raise RuntimeError(
            f"the LBC extension is installed but not enabled: call bpy.ops.preferences.addon_enable(module="
            f"{__package__!r}) first (or enable it in Edit > Preferences > Add-ons and save the preferences)"
        )
