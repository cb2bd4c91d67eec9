"""A bind in three steps, so that the long one runs off Blender's main thread.

1. :func:`snapshot` (main thread) copies the mesh and the evaluated cage out of Blender into numpy arrays.
2. :func:`solve` (any thread, no ``bpy``) calls ``lbc_core.bind`` and turns its sparse weights into K slots.
3. :func:`apply` (main thread) checks the objects did not change meanwhile, then writes the cache and the modifier.

Nothing in the scene changes before step 3, so a failed or cancelled bind leaves the scene exactly as it was.
:class:`Worker` runs step 2 for several meshes in a thread, with progress and cancellation, for the modal operator.
"""

import threading
import time
from dataclasses import dataclass, field

import numpy as np

from . import deformer, geometry, influence, storage
from .core import CageError, lbc_core
from .properties import DEFAULT_INFLUENCES, is_bound


@dataclass
class BindRequest:
    """Everything the solve needs, copied out of Blender; identifies the objects by ``session_uid``."""

    mesh_uid: int
    cage_uid: int
    mesh_name: str
    points: np.ndarray  # (m, 3) mesh vertices, mesh space
    cage_points: np.ndarray  # (c, 3) evaluated cage vertices, mesh space
    cage_faces: list  # faces of the evaluated cage (3D)
    frame: tuple  # (origin, axes) of the plane for a 2D bind, else None
    loop: np.ndarray  # 2D: the cage vertices of the outline in order, else None
    options: dict
    cage_topology: str
    mesh_topology: str

    @property
    def dimension(self):
        return 2 if self.frame is not None else 3


@dataclass
class BindResult:
    """What :func:`apply` writes, and the figures the panel shows."""

    index: np.ndarray  # (m, K) int32 cage vertex indices
    weight: np.ndarray  # (m, K) float32
    rest: np.ndarray  # (m, 3) Σ w c at rest
    control_points: int
    outside: int
    core_fingerprint: str
    warnings: list = field(default_factory=list)
    seconds: float = 0.0


def find_object(uid):
    """The object with this ``session_uid``, or None once it was deleted."""
    import bpy

    for obj in bpy.data.objects:
        if obj.session_uid == uid:
            return obj
    return None


def snapshot(mesh_obj, cage_obj, depsgraph, resolution=0, weighting="quadratic", epsilon=0.0, tolerance=0.0,
             threshold=0.0, influences=DEFAULT_INFLUENCES, mode="AUTO"):
    """Copy what binding ``mesh_obj`` to ``cage_obj`` needs; raises CageError for what can be seen already."""
    if mesh_obj.type != "MESH":
        raise CageError(f"'{mesh_obj.name}' is not a mesh: only meshes can be bound")
    if cage_obj.type != "MESH":
        raise CageError(f"the cage '{cage_obj.name}' is not a mesh object: use a mesh as the cage")
    if mesh_obj == cage_obj:
        raise CageError("a mesh cannot be its own cage: select the mesh, then the cage last (active)")
    if mesh_obj.data.users > 1:
        raise CageError(
            f"the mesh data of '{mesh_obj.name}' is shared by {mesh_obj.data.users} objects and the weights are "
            "stored in it: make it single user first (Object > Relations > Make Single User)"
        )
    points = geometry.vertex_positions(mesh_obj.data)
    cage_eval = cage_obj.evaluated_get(depsgraph)
    cage_mesh = cage_eval.to_mesh()
    try:
        matrix = geometry.cage_to_mesh_matrix(cage_eval, mesh_obj.evaluated_get(depsgraph))
        cage_points = geometry.to_local(matrix, geometry.vertex_positions(cage_mesh))
        cage_faces = geometry.polygon_faces(cage_mesh)
        cage_topology = geometry.topology_fingerprint(cage_mesh)
        frame = None if mode == "3D" else geometry.flat_frame(cage_points, points)
        if mode == "2D" and frame is None:
            raise CageError(
                "2D binding needs a flat cage with the mesh lying in its plane: flatten them, or bind in 3D"
            )
        loop = geometry.boundary_loop(cage_mesh) if frame is not None else None
    finally:
        cage_eval.to_mesh_clear()
    return BindRequest(
        mesh_uid=mesh_obj.session_uid,
        cage_uid=cage_obj.session_uid,
        mesh_name=mesh_obj.name,
        points=points,
        cage_points=cage_points,
        cage_faces=cage_faces,
        frame=frame,
        loop=loop,
        options={"resolution": resolution, "weighting": weighting, "epsilon": epsilon, "tolerance": tolerance,
                 "threshold": threshold, "influences": influences, "mode": mode},
        cage_topology=cage_topology,
        mesh_topology=geometry.topology_fingerprint(mesh_obj.data),
    )


def solve(request, progress=None, cancel=None):
    """Compute the weights (no ``bpy`` here: safe in a worker thread). Raises CageError or lbc_core.Cancelled."""
    start = time.perf_counter()
    options = request.options
    if request.frame is not None:
        origin, axes = request.frame
        cage_vertices = (request.cage_points[request.loop] - origin) @ axes.T
        faces = None
        points = (request.points - origin) @ axes.T
        column_base = request.loop
    else:
        cage_vertices, faces, points = request.cage_points, request.cage_faces, request.points
        column_base = np.arange(len(request.cage_points))
    binding = lbc_core.bind(
        cage_vertices,
        faces,
        points,
        cells=options["resolution"] or None,
        weighting=options["weighting"],
        epsilon=options["epsilon"],
        threshold=options["threshold"] or None,
        tolerance=options["tolerance"] or None,
        # Shewchuk's Triangle is not bundled (its licence is not GPL-compatible): use lbc_core's own mesher.
        method="delaunay",
        progress=progress,
        cancel=cancel,
    )
    column_vertex = column_base[binding.control_input_index]
    index, weight = storage.slot_arrays(binding.weights, column_vertex)
    if options["influences"]:
        reproduced = storage.rest_offsets(index, weight, request.cage_points)
        index, weight = storage.cap_slots(index, weight, request.cage_points, reproduced, options["influences"])
    return BindResult(
        index=index,
        weight=weight,
        rest=storage.rest_offsets(index, weight, request.cage_points),
        control_points=len(column_vertex),
        outside=int(np.count_nonzero(binding.outside)),
        core_fingerprint=binding.cage.fingerprint(),
        warnings=list(binding.cage.warnings),
        seconds=time.perf_counter() - start,
    )


def apply(request, result):
    """Write the binding into the scene (main thread), replacing the mesh's binding if it has one.

    A transaction: when any write fails, everything written is taken back (:class:`_SavedBinding`) and the error is
    raised again, so the scene is as it was, the previous binding included. Raises CageError if the objects changed
    during the solve. Returns the bound mesh object.
    """
    mesh_obj, cage_obj = find_object(request.mesh_uid), find_object(request.cage_uid)
    if mesh_obj is None or cage_obj is None:
        raise CageError(f"'{request.mesh_name}' or its cage was deleted during the bind: nothing was bound")
    if geometry.topology_fingerprint(mesh_obj.data) != request.mesh_topology:
        raise CageError(f"'{mesh_obj.name}' was edited during the bind: bind again")
    saved = _SavedBinding(mesh_obj)
    try:
        replaced_group = _write(mesh_obj, cage_obj, request, result)
    except Exception:
        saved.restore(mesh_obj)
        raise
    deformer.release_group(replaced_group, mesh_obj.lbc.node_group)
    return mesh_obj


def _write(mesh_obj, cage_obj, request, result):
    """The writes of :func:`apply`, in order; returns the node group of the replaced binding (or None)."""
    replacing = is_bound(mesh_obj)
    settings = mesh_obj.lbc
    if not replacing:
        active = mesh_obj.modifiers.active
        settings.active_modifier = active.name if active is not None else ""
    storage.remove(mesh_obj.data)
    storage.write(mesh_obj.data, result.index, result.weight, result.rest)
    modifier, replaced_group = deformer.attach(mesh_obj, cage_obj, result.index.shape[1], len(request.cage_points),
                                              len(request.points))
    _store_settings(settings, request, result, cage_obj, modifier.node_group)
    if settings.show_influence:  # repainted with the new weights
        influence.show(mesh_obj, settings.influence_vertex)
    return replaced_group


def _store_settings(settings, request, result, cage_obj, group):
    settings.is_bound = True
    settings.cage = cage_obj
    settings.node_group = group
    for key, value in request.options.items():
        setattr(settings, key, value)
    settings.dimension = request.dimension
    settings.cage_vertex_count = len(request.cage_points)
    settings.mesh_vertex_count = len(request.points)
    settings.cage_topology = request.cage_topology
    settings.core_fingerprint = result.core_fingerprint
    settings.control_points = result.control_points
    settings.slots = result.index.shape[1]
    settings.mean_influences = float(np.count_nonzero(result.weight, axis=1).mean()) if len(result.weight) else 0.0
    settings.outside = result.outside
    settings.bind_seconds = result.seconds
    settings.warnings = "; ".join(result.warnings)
    settings.status = f"Following '{cage_obj.name}'"


class _SavedBinding:
    """What :func:`apply` may change on a mesh object, saved before it writes, to put back if a write fails.

    Saved: the add-on's attributes (and the influence colors) of the mesh data, the modifier stack's names and
    active modifier, the LBC modifier's node group and inputs, the file's node groups, and ``Object.lbc``.
    """

    def __init__(self, mesh_obj):
        import bpy

        mesh = mesh_obj.data
        self.attributes = storage.copy_attributes(mesh, storage.binding_names(mesh) + [influence.ATTRIBUTE_NAME])
        self.active_color = mesh.color_attributes.active_color_name
        self.modifiers = [modifier.name for modifier in mesh_obj.modifiers]
        self.active_modifier = mesh_obj.modifiers.active.name if mesh_obj.modifiers.active else None
        modifier = deformer.find_modifier(mesh_obj) if is_bound(mesh_obj) else None
        self.deformer = None if modifier is None else (modifier.name, modifier.node_group,
                                                       deformer.raw_inputs(modifier))
        self.node_groups = {group.session_uid for group in bpy.data.node_groups}
        self.settings = _settings_values(mesh_obj.lbc) if mesh_obj.is_property_set("lbc") else None

    def restore(self, mesh_obj):
        import bpy

        for modifier in list(mesh_obj.modifiers):
            if modifier.name not in self.modifiers:
                deformer.remove_modifier(mesh_obj, modifier)
        if self.deformer is not None:
            name, group, values = self.deformer
            modifier = mesh_obj.modifiers[name]
            modifier.node_group = group
            deformer.set_raw_inputs(modifier, values)
        for group in list(bpy.data.node_groups):
            if group.session_uid not in self.node_groups:
                bpy.data.node_groups.remove(group)
        mesh = mesh_obj.data
        storage.restore_attributes(mesh, self.attributes, storage.binding_names(mesh) + [influence.ATTRIBUTE_NAME])
        active = self.active_color
        mesh.color_attributes.active_color_name = active if active in mesh.color_attributes else ""
        if self.settings is None:
            mesh_obj.property_unset("lbc")
        else:
            for key, value in self.settings.items():
                setattr(mesh_obj.lbc, key, value)
        if self.active_modifier is not None:
            mesh_obj.modifiers.active = mesh_obj.modifiers[self.active_modifier]
        mesh.update()


def _settings_values(settings):
    """Every registered property of an ``Object.lbc`` group: {name: value}."""
    return {prop.identifier: getattr(settings, prop.identifier) for prop in settings.bl_rna.properties
            if prop.identifier != "rna_type"}


def remove(mesh_obj):
    """Undo :func:`apply`: the modifier, its node group and ``Object.lbc`` go, and the attributes too unless another
    bound object shares the mesh data (an Alt+D linked duplicate still uses them); the active modifier is the one
    active before binding.

    Returns the names of the bound objects that keep the shared weights (empty when they were removed).
    """
    influence.hide(mesh_obj)
    active = mesh_obj.lbc.active_modifier
    deformer.detach(mesh_obj)
    mesh_obj.property_unset("lbc")
    sharing = shared_with(mesh_obj)
    if not sharing:
        storage.remove(mesh_obj.data)
    if active in mesh_obj.modifiers:
        mesh_obj.modifiers.active = mesh_obj.modifiers[active]
    return [obj.name for obj in sharing]


def shared_with(mesh_obj):
    """The other bound objects using ``mesh_obj``'s mesh data (linked duplicates)."""
    import bpy

    if mesh_obj.data.users < 2:
        return []
    return [obj for obj in bpy.data.objects if obj != mesh_obj and obj.data == mesh_obj.data and is_bound(obj)]


class Worker:
    """Solves bind requests one after the other in a thread, reporting progress and obeying a cancel flag.

    Read ``fraction``, ``message``, ``done`` from the main thread; results and errors are collected in ``results``
    (pairs of request and result) and ``error`` (the first exception, after which the worker stops).
    """

    def __init__(self, requests):
        self.requests = list(requests)
        self.results = []
        self.error = None
        self.fraction = 0.0
        self.message = "starting"
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lbc-bind", daemon=True)

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

                self.results.append((request, solve(request, progress, self._cancel.is_set)))
        except Exception as error:  # handed to the main thread, which reports it
            self.error = error
