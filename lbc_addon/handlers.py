"""Blender's handlers for bound meshes: after every depsgraph update, file load, undo and redo, each binding is
checked (:func:`diagnosis.diagnose`) and its deformer stopped or resumed; a cage the user deleted is let go; a file's
node groups that do not suit this Blender are built again once it is opened.
"""

import functools

import bpy
from bpy.app.handlers import persistent

from . import deformer, diagnosis, node_group, storage
from .properties import is_bound

_last_messages = {}  # object session_uid -> the last status printed, so a problem is reported once, not per redraw
# The session_uids of cages seen in a collection. A cage in none was deleted (X) only if it was in one before: a cage
# that came in with an appended or linked mesh, indirectly, was never in one, and Mesh Deform follows such a cage.
_cages_in_scene = set()


def note_cage_in_scene(cage):
    """Remember that ``cage`` was in a collection: from now on, leaving every collection means it was deleted."""
    _cages_in_scene.add(cage.session_uid)


def check_bindings(depsgraph, changed=None):
    """Check every bound object of the depsgraph's scene; stop or resume its deformation; print changes of state.

    ``changed``: when given, the names of the objects whose geometry changed; only bindings involving one of them
    (or whose cage is gone) are checked. Cages deleted by the user (no longer in any collection, having been in one)
    are let go first (:func:`forget_cage`).
    """
    bound = [obj for obj in depsgraph.scene.objects if is_bound(obj)]
    deleted = []
    for obj in bound:
        cage = obj.lbc.cage
        if cage is None or cage in deleted:
            continue
        if cage.users_collection:
            note_cage_in_scene(cage)
        elif cage.session_uid in _cages_in_scene:
            deleted.append(cage)
    for cage in deleted:
        forget_cage(cage)
    cages = {}
    for obj in bound:
        cage = obj.lbc.cage
        if changed is not None and cage is not None and not {obj.name_full, cage.name_full} & changed:
            continue
        cause, message = diagnosis.diagnose(obj, depsgraph, cages)
        deformer.set_enabled(obj, cause not in diagnosis.STOPPED_HERE)
        if obj.lbc.status != message:  # writing the same value would trigger another depsgraph update
            obj.lbc.state = "FOLLOWING" if cause is None else "STOPPED"
            obj.lbc.status = message
        if _last_messages.get(obj.session_uid) != message:
            _last_messages[obj.session_uid] = message
            if cause is not None and cause not in diagnosis.ARTISTS_CHOICE:
                print(f"LBC: {obj.name}: {message}")


def forget_cage(cage, defer=None):
    """Let go of a cage the user deleted, as Blender's Mesh Deform does.

    Deleting an object (X) only unlinks it from its scene while something else counts as its user, and the
    binding's pointer and the modifier's Cage input both do: the cage would live on off-scene with the meshes
    following it. Every binding to ``cage`` drops it (the node group then leaves the mesh at rest), and the cage is
    removed once nothing else uses it (:func:`remove_if_orphan`). This runs in a depsgraph handler: in a session with
    an event loop the removal waits for a timer, outside the handler; ``defer`` None means "when there is one".
    """
    _cages_in_scene.discard(cage.session_uid)
    for obj in bpy.data.objects:
        if is_bound(obj) and obj.lbc.cage == cage:
            obj.lbc.cage = None
            modifier = deformer.find_modifier(obj)
            if modifier is not None:
                deformer.set_inputs(modifier, {"Cage": None})
                obj.update_tag()
    if defer is None:
        defer = not bpy.app.background
    if defer:
        bpy.app.timers.register(functools.partial(remove_if_orphan, cage.name_full), first_interval=0.0)
    else:
        remove_if_orphan(cage.name_full)


def remove_if_orphan(name):
    """Remove the object called ``name`` if it is in no collection and nothing uses it any more."""
    obj = bpy.data.objects.get(name)
    if obj is not None and obj.users == 0 and not obj.users_collection:
        bpy.data.objects.remove(obj)


@persistent
def _on_depsgraph_update(scene, depsgraph):
    # Hashing a cage's topology is only needed when its geometry changed; bindings whose cage is gone are cheap to
    # check and are checked on every update (deleting an object reports no geometry update).
    changed = {
        update.id.original.name_full
        for update in depsgraph.updates
        if isinstance(update.id, bpy.types.Object) and update.is_updated_geometry
    }
    check_bindings(depsgraph, changed)


@persistent
def _on_load_or_undo(*_args):
    check_bindings(bpy.context.evaluated_depsgraph_get())


@persistent
def _on_load(*_args):
    refresh_outdated_groups()
    _on_load_or_undo()


def refresh_outdated_groups():
    """Rebuild, once a file is opened, the node groups of bound meshes that do not suit this Blender
    (:func:`node_group.outdated`: a file moved between 4.2 and a newer line), for the same counts, the modifier's inputs
    kept. Linked data is left to its own file. Returns the refreshed objects."""
    refreshed = []
    for obj in bpy.data.objects:
        modifier = deformer.find_modifier(obj) if is_bound(obj) else None
        group = None if modifier is None else modifier.node_group
        if group is None or not node_group.outdated(group) or obj.library or group.library or obj.lbc.cage is None:
            continue
        _, weight = storage.read(obj.data)
        kept = deformer.inputs(modifier)
        modifier, replaced = deformer.attach(obj, obj.lbc.cage, weight.shape[1], obj.lbc.cage_vertex_count,
                                             kept.get("Mesh Vertices", len(obj.data.vertices)),
                                             node_group.shared_slot_count(weight))
        # The add-on's stop for a changed topology stays as it was (attach enables the new group).
        deformer.set_inputs(modifier, {"Enabled": kept.get("Enabled", True)})
        obj.lbc.node_group = modifier.node_group
        obj.lbc.node_group_bytes = node_group.saved_bytes(modifier.node_group)
        deformer.release_group(replaced, modifier.node_group)
        refreshed.append(obj)
    return refreshed


_HANDLERS = (
    (bpy.app.handlers.depsgraph_update_post, _on_depsgraph_update),
    (bpy.app.handlers.load_post, _on_load),
    (bpy.app.handlers.undo_post, _on_load_or_undo),
    (bpy.app.handlers.redo_post, _on_load_or_undo),
)


def register():
    for handlers, handler in _HANDLERS:
        if handler not in handlers:
            handlers.append(handler)


def unregister():
    for handlers, handler in _HANDLERS:
        if handler in handlers:
            handlers.remove(handler)
