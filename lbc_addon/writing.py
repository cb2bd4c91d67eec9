"""Writing a bind into Blender (main thread): the cached weights, the deformer and ``Object.lbc``, as one
transaction; and taking a binding out again (Unbind).
"""

import time

import bpy
import numpy as np

from . import deformer, diagnosis, geometry, handlers, influence, jobs, node_group, storage
from .core import CageError
from .properties import is_bound


def apply(request, result):
    """Write the binding into the scene (main thread), replacing the mesh's binding if it has one.

    A transaction: when any write fails, everything written is taken back (:class:`_SavedBinding`) and the error is
    raised again, so the scene is as it was, the previous binding included. Raises CageError if the objects changed
    during the solve. Returns the bound mesh object, whose Bind Time counts these writes too.
    """
    start = time.perf_counter()
    mesh_obj, cage_obj = geometry.find_object(request.mesh_uid), geometry.find_object(request.cage_uid)
    if mesh_obj is None or cage_obj is None:
        raise CageError(f"'{request.mesh_name}' or its cage was deleted during the bind: nothing was bound")
    if mesh_obj.data.is_editmode:
        raise CageError(f"'{mesh_obj.name}' is in Edit Mode, which would write over the weights on leaving it: switch "
                        "to Object Mode and bind again")
    changed = geometry.changed_since(request, mesh_obj, cage_obj, bpy.context.evaluated_depsgraph_get())
    if changed:
        raise CageError(f"{changed}: nothing was bound; bind again")
    saved = _SavedBinding(mesh_obj)
    try:
        replaced_group = _write(mesh_obj, cage_obj, request, result)
    except Exception:
        saved.restore(mesh_obj)
        raise
    deformer.release_group(replaced_group, mesh_obj.lbc.node_group)
    # Building the deformer's node group takes seconds for hundreds of cage vertices: part of the artist's wait.
    mesh_obj.lbc.bind_seconds = result.seconds + time.perf_counter() - start
    jobs.remember(request, result)
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
                                              len(request.points), node_group.shared_slot_count(result.weight))
    _store_settings(settings, request, result, cage_obj, modifier.node_group)
    settings.status = diagnosis.following_message(mesh_obj)  # with the share outside, from the start
    settings.mesh_transform = _flat(mesh_obj.matrix_basis)
    settings.mesh_in_cage = _flat(diagnosis.mesh_in_cage(mesh_obj, cage_obj))
    if replaced_group is not None or not settings.node_group_bytes:  # a new group (a kept one keeps its size)
        settings.node_group_bytes = node_group.saved_bytes(modifier.node_group)
    if cage_obj.users_collection:  # from now on, leaving every collection means X deleted it
        handlers.note_cage_in_scene(cage_obj)
    if settings.show_influence:  # repainted with the new weights
        influence.show(mesh_obj, settings.influence_vertex)
    return replaced_group


def _store_settings(settings, request, result, cage_obj, group):
    settings.is_bound = True
    settings.cage = cage_obj
    settings.node_group = group
    request.options.write(settings)
    settings.dimension = request.dimension
    settings.cage_vertex_count = len(request.cage_points)
    settings.mesh_vertex_count = len(request.points)
    settings.cage_topology = request.cage_topology
    settings.cage_shape = request.cage_shape
    settings.core_fingerprint = result.core_fingerprint
    settings.welded = result.welded
    settings.control_points = result.control_points
    settings.domain_cells = result.cells
    settings.slots = result.index.shape[1]
    settings.mean_influences = float(np.count_nonzero(result.weight, axis=1).mean()) if len(result.weight) else 0.0
    settings.outside = result.outside
    settings.bind_report = result.rebind
    settings.warnings = "; ".join(result.warnings)
    settings.state = "FOLLOWING"
    settings.status = f"Following '{cage_obj.name}'"


def _flat(matrix):
    """A 4×4 matrix as 16 numbers, row by row (a FloatVectorProperty's value)."""
    return [value for row in matrix for value in row]


class _SavedBinding:
    """What :func:`apply` may change on a mesh object, saved before it writes, to put back if a write fails.

    Saved: the add-on's attributes (and the influence colors) of the mesh data, the modifier stack's names and
    active modifier, the LBC modifier's node group and inputs, the file's node groups, and ``Object.lbc``.
    """

    def __init__(self, mesh_obj):
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
    """Every registered property of an ``Object.lbc`` group: {name: value}, an array's values copied (Blender gives
    a view of the stored array, which the writes would change)."""
    values = {}
    for prop in settings.bl_rna.properties:
        if prop.identifier != "rna_type":
            value = getattr(settings, prop.identifier)
            values[prop.identifier] = tuple(value) if getattr(prop, "is_array", False) else value
    return values


def remove(mesh_obj):
    """Undo :func:`apply`: the modifier, its node group and ``Object.lbc`` go, and the attributes too unless another
    bound object shares the mesh data (an Alt+D linked duplicate still uses them); the active modifier is the one
    active before binding.

    Returns the names of the bound objects that keep the shared weights (empty when they were removed).
    """
    influence.hide(mesh_obj)
    jobs.forget(mesh_obj.session_uid)
    active = mesh_obj.lbc.active_modifier
    deformer.detach(mesh_obj)
    mesh_obj.property_unset("lbc")
    sharing = geometry.shared_with(mesh_obj)
    if not sharing:
        storage.remove(mesh_obj.data)
    if active in mesh_obj.modifiers:
        mesh_obj.modifiers.active = mesh_obj.modifiers[active]
    return [obj.name for obj in sharing]


def save_shape_key(mesh_obj, depsgraph, name=""):
    """Add a shape key holding the mesh's basis moved as the deformer moves it now (as Mesh Deform's Save as Shape
    Key), at value 0, named ``name`` (default "LBC <cage>"); a Basis first where the mesh has no shape keys.

    Raises CageError, before any change, for a mesh whose deformer does not work now (its status says why) or that
    cannot be changed here. Returns the shape key.
    """
    if not is_bound(mesh_obj):
        raise CageError(f"'{mesh_obj.name}' is not bound to a cage: bind it first")
    linked = geometry.not_editable_here(mesh_obj)
    if linked:
        raise CageError(linked)
    if mesh_obj.data.is_editmode:
        raise CageError(f"'{mesh_obj.name}' is in Edit Mode: switch to Object Mode first")
    cages = {}  # the cage evaluated once, for the check and the displacement
    cause, message = diagnosis.diagnose(mesh_obj, depsgraph, cages)
    if cause is not None and cause not in diagnosis.ARTISTS_CHOICE:
        raise CageError(f"the deformer does not work now: {message}")
    offsets = deformer.displacement(mesh_obj, depsgraph, cages)
    if mesh_obj.data.shape_keys is None:
        mesh_obj.shape_key_add(name="Basis", from_mix=False)
    basis = geometry.shape_key_positions(mesh_obj.data.shape_keys.reference_key)
    key = mesh_obj.shape_key_add(name=name or f"LBC {mesh_obj.lbc.cage.name}", from_mix=False)
    key.data.foreach_set("co", (basis + offsets).astype(np.float32).ravel())
    key.value = 0.0
    mesh_obj.data.update()
    return key


def remove_leftovers(obj):
    """Delete the attributes :func:`geometry.leftover_weights` names, leaving the mesh's own as they were."""
    storage.remove(obj.data)
