"""Operators: Bind, Rebind, Rebind All (every mesh bound to a cage), Unbind, Show / Hide Influence.

Bind runs modal in the UI: the solve goes to a worker thread, a timer polls it, the status bar shows its progress and
Esc cancels it; the scene is only written when the solve succeeded. In background mode (``blender -b``, the bpy
module) there is no event loop, so it runs synchronously and prints its progress.

Adjust Last Operation (the redo panel) runs ``execute()``, synchronously: Blender undoes the bind, then
``ED_undo_operator_repeat`` calls ``WM_operator_repeat``, which calls the operator's exec and never its invoke (read in
Blender's source, editors/undo/ed_undo.cc and windowmanager/intern/wm_event_system.cc). So a changed option there
binds again on the main thread: the UI waits for the solve, Esc does not cancel it, progress goes to the console.
"""

from dataclasses import replace

import bpy
from bpy.props import BoolProperty

from . import deformer, diagnosis, geometry, influence, jobs, writing
from .core import CageError, Cancelled
from .properties import OPTION_NAMES, BindOptionProperties, bound_to, is_bound

# The Worker of the bind (or of Make Cage) in progress: one at a time, so two binds never write the same mesh.
running = []


def _selection(context):
    """The selected objects, the active one included."""
    objects = list(context.selected_objects)
    if context.active_object is not None and context.active_object not in objects:
        objects.append(context.active_object)
    return objects


def _bound_selection(context):
    """Selected objects holding a binding (the active one included)."""
    return [obj for obj in _selection(context) if is_bound(obj)]


def _leftover_selection(context):
    """Selected unbound meshes carrying LBC weights of no binding (:func:`geometry.leftover_weights`)."""
    return [obj for obj in _selection(context) if geometry.leftover_weights(obj)]


def _report_result(operator, mesh_obj):
    """Warnings about a finished bind: vertices outside the cage, repairs lbc_core made (:func:`jobs.solve`), a
    deformer the stack holds off."""
    for warning in (mesh_obj.lbc.warnings, diagnosis.held_off_warning(mesh_obj)):
        if warning:
            operator.report({"WARNING"}, f"{mesh_obj.name}: {warning}")


def _bound_summary(bound, named=5):
    """ "Bound 'Body', 'Hat' to 'Cage'": which meshes went to which cage, so that a mesh selected by mistake shows."""
    by_cage = {}
    for mesh_obj in bound:
        by_cage.setdefault(mesh_obj.lbc.cage.name, []).append(mesh_obj.name)
    parts = []
    for cage, meshes in by_cage.items():
        names = ", ".join(f"'{name}'" for name in meshes[:named])
        more = f" and {len(meshes) - named} more" if len(meshes) > named else ""
        parts.append(f"{names}{more} to '{cage}'")
    return "Bound " + "; ".join(parts)


def apply_all(operator, pairs):
    """Write every solved binding; returns the bound objects. Reports what could not be written, what was bound, and
    the bindings' warnings last: Blender's status bar shows only the last report, and "Bound" over a warning hid it."""
    bound = []
    for request, result in pairs:
        try:
            bound.append(writing.apply(request, result))
        except CageError as error:
            operator.report({"ERROR"}, str(error))
        except Exception as error:  # a write Blender refused: apply took everything back
            operator.report({"ERROR"}, f"'{request.mesh_name}': writing the binding failed "
                                       f"({type(error).__name__}: {error}); the scene was left as it was")
    if bound:
        operator.report({"INFO"}, f"{_bound_summary(bound)} in {sum(o.lbc.bind_seconds for o in bound):.1f} s")
    for request, result in pairs:
        if result.rebind:
            operator.report({"INFO"}, f"{request.mesh_name}: {result.rebind}")
    for mesh_obj in bound:
        _report_result(operator, mesh_obj)
    return bound


def solve_printing(requests):
    """Solve in this thread, printing progress lines (background mode has no status bar): one percentage for all the
    meshes, each mesh's lines beginning with its name when there are several (a new user saw the percentage reach
    100 % "bound" and start again for the second mesh)."""
    printed = jobs.printed_progress()
    pairs, count = [], len(requests)
    for number, request in enumerate(requests):
        def progress(fraction, message, number=number, name=request.mesh_name):
            printed((number + fraction) / count, f"{name}: {message}" if count > 1 else message)

        pairs.append((request, jobs.solve(request, progress, earlier=pairs)))
    return pairs


def _in_edit_mode(pairs):
    """The name of the first mesh of the solved (request, result) pairs that is in Edit Mode now, or None."""
    for request, _ in pairs or ():
        mesh_obj = geometry.find_object(request.mesh_uid)
        if mesh_obj is not None and mesh_obj.type == "MESH" and mesh_obj.data.is_editmode:
            return mesh_obj.name
    return None


class _Binder:
    """What Bind and Rebind share: snapshot on the main thread, solve (modal or not), apply.

    Subclasses define ``targets(context)``: the (mesh, cage, options) triples to bind, and the messages of meshes
    left out already ("'Name' left as it was: …"); and ``skips_refused``: whether a mesh that cannot be bound (e.g.
    its data shared by a linked duplicate) is left out with a warning, the others bound, or stops them all.
    """

    skips_refused = False

    from_scratch: BoolProperty(
        name="From Scratch",
        description="Mesh the cage and solve anew instead of starting from this session's previous binding: slower, "
        "but the result no longer depends on the cage edits and binds before it",
        default=False,
        options={"SKIP_SAVE"},  # asked for one bind: the next Rebind button press starts warm again
    )

    def snapshot(self, context):
        targets, left_out = self.targets(context)
        requests, refused = geometry.snapshots(targets, context.evaluated_depsgraph_get(), self.skips_refused,
                                               left_out)
        for message in refused:
            self.report({"WARNING"}, message)
        return [replace(request, from_scratch=self.from_scratch) for request in requests]

    def execute(self, context):
        try:
            pairs = solve_printing(self.snapshot(context))
        except Cancelled:
            self.report({"WARNING"}, "Bind cancelled: nothing changed")
            return {"CANCELLED"}
        except CageError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        return {"FINISHED"} if apply_all(self, pairs) else {"CANCELLED"}

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        try:
            requests = self.snapshot(context)
        except CageError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        worker = jobs.Worker(requests)
        running.append(worker)
        worker.start()
        self._worker = worker
        self._timer = context.window_manager.event_timer_add(0.1, window=context.window)
        context.window_manager.modal_handler_add(self)
        context.workspace.status_text_set("LBC bind: starting (Esc to cancel)")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        worker = self._worker
        if event.type == "ESC":
            worker.cancel()
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            # The UI stays usable while the solve runs; apply() checks the objects did not change meanwhile.
            return {"PASS_THROUGH"}
        if not worker.done:
            state = "cancelling" if worker.cancelled else f"{100 * worker.fraction:.0f}% {worker.message}"
            context.workspace.status_text_set(f"LBC bind: {state} (Esc to cancel)")
            return {"RUNNING_MODAL"}
        editing = _in_edit_mode(worker.results)
        if editing and not worker.cancelled and worker.error is None:
            # Leaving Edit Mode writes the edit mesh back over the mesh data, weights included: wait for it.
            context.workspace.status_text_set(f"LBC bind: solved; switch '{editing}' to Object Mode to apply it "
                                              "(Esc to cancel)")
            return {"RUNNING_MODAL"}
        self._finish(context)
        if worker.cancelled:
            self.report({"WARNING"}, "Bind cancelled: nothing changed")
            return {"CANCELLED"}
        if worker.error is not None:
            self.report({"ERROR"}, str(worker.error))
            return {"CANCELLED"}
        return {"FINISHED"} if apply_all(self, worker.results) else {"CANCELLED"}

    def cancel(self, context):
        """Blender ends the modal operator itself (its window closed, another file opened): stop the solve and let
        later binds run (without this, every poll would say a bind is running, and Esc could no longer reach it)."""
        self._worker.cancel()
        self._finish(context)

    def _finish(self, context):
        context.window_manager.event_timer_remove(self._timer)
        context.workspace.status_text_set(None)
        running.remove(self._worker)


def busy_message(context, label):
    """Why no bind (or Make Cage) labelled ``label`` can start now (another runs, or not in Object Mode), or None."""
    if running:
        activity = running[0].activity
        return f"{activity[:1].upper()}{activity[1:]} is already running (Esc cancels it)"
    if context.mode != "OBJECT":
        return f"{label} works in Object Mode"
    return None


def allowed(operator_class, message):
    """A poll() result: True when ``message`` (why the operator cannot run) is None, else False with the message
    shown on the greyed-out button."""
    if message:
        operator_class.poll_message_set(message)
    return message is None


def _bind_poll_message(context):
    """Why Bind cannot run now, or None when it can."""
    busy = busy_message(context, "Bind")
    if busy:
        return busy
    cage = context.active_object
    if cage is None:
        return "Select the mesh(es) to bind, then the cage mesh last so it is active"
    if cage.type != "MESH":
        return f"The active object {geometry.not_a_mesh(cage, 'the cage must be one', 'make the cage mesh active')}"
    meshes = [obj for obj in context.selected_objects if obj.type == "MESH" and obj != cage]
    if not meshes:
        others = [obj for obj in context.selected_objects if obj != cage]
        if others:  # e.g. a Text to deform: say why it does not count
            return geometry.not_a_mesh(others[0], "only meshes can be bound", "select a mesh to bind")
        return "Select the mesh(es) to bind as well as the cage (active)"
    return geometry.swapped_selection(cage, meshes)


class OBJECT_OT_lbc_bind(_Binder, BindOptionProperties, bpy.types.Operator):
    """Bind the selected meshes to the active cage with Local Barycentric Coordinates"""

    bl_idname = "object.lbc_bind"
    bl_label = "Bind to Cage"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return allowed(cls, _bind_poll_message(context))

    def targets(self, context):
        cage = context.active_object
        options = self.bind_options()
        return [(obj, cage, options) for obj in context.selected_objects if obj.type == "MESH" and obj != cage], ()

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        for name in OPTION_NAMES:
            layout.prop(self, name)
        layout.prop(self, "from_scratch")


class OBJECT_OT_lbc_rebind(_Binder, bpy.types.Operator):
    """Bind the selected bound meshes again to their cage as it is now, with the same options"""

    bl_idname = "object.lbc_rebind"
    bl_label = "Rebind"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        message = busy_message(context, cls.bl_label)
        selection = _bound_selection(context)
        if message is None and not selection:
            message = "Select a bound mesh"
        elif message is None and all(obj.lbc.cage is None for obj in selection):
            message = "The cage was deleted: select the mesh, then a cage (active), and Bind"
        return allowed(cls, message)

    def targets(self, context):
        triples = []
        for obj in _bound_selection(context):
            if obj.lbc.cage is None:
                raise CageError(f"the cage of '{obj.name}' was deleted: select a cage and Bind instead")
            triples.append((obj, obj.lbc.cage, obj.lbc.bind_options()))
        return triples, ()


class OBJECT_OT_lbc_rebind_all(_Binder, bpy.types.Operator):
    """Bind every mesh bound to the active cage again, to the cage as it is now, each with its own options"""

    bl_idname = "object.lbc_rebind_all"
    bl_label = "Rebind All"
    bl_options = {"REGISTER", "UNDO"}
    skips_refused = True  # one linked duplicate among them does not hold the others back

    @classmethod
    def poll(cls, context):
        message = busy_message(context, cls.bl_label)
        if message is None and (context.active_object is None
                                or not bound_to(context.active_object, context.scene.objects)):
            message = "Make a cage with bound meshes active"
        return allowed(cls, message)

    def targets(self, context):
        return deformer.rebind_all_targets(context.active_object, context.scene.objects)


class OBJECT_OT_lbc_unbind(bpy.types.Operator):
    """Remove the binding: the mesh is exactly as before binding (data, modifiers, attributes). Also removes the LBC
    weights a mesh carries for no binding (a bound mesh joined into it)"""

    bl_idname = "object.lbc_unbind"
    bl_label = "Unbind"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        message = "Wait for the running bind, or cancel it with Esc" if running else None
        if message is None and not _bound_selection(context) and not _leftover_selection(context):
            message = "Select a bound mesh"
        return allowed(cls, message)

    def execute(self, context):
        objects, leftovers = [], []
        for obj in _bound_selection(context) + _leftover_selection(context):
            linked = geometry.not_editable_here(obj)
            if linked:
                self.report({"ERROR"}, f"Not unbound: {linked}")
            else:
                (objects if is_bound(obj) else leftovers).append(obj)
        for obj in leftovers:
            writing.remove_leftovers(obj)
            self.report({"INFO"}, f"{obj.name}: removed the LBC weights it carried for no binding (from a bound mesh "
                                  "joined into it)")
        if not objects:
            return {"FINISHED"} if leftovers else {"CANCELLED"}
        for obj in objects:
            mesh_name = obj.data.name
            keeping = writing.remove(obj)
            if keeping:
                self.report({"WARNING"}, f"{obj.name}: unbound; its mesh data '{mesh_name}' keeps the weights, shared "
                                         f"with {', '.join(keeping)}, which stay bound")
        self.report({"INFO"}, f"Unbound {len(objects)} mesh(es)")
        return {"FINISHED"}


def _influence_targets(context):
    """The meshes whose influence to show: the active bound mesh, or every mesh bound to the active cage."""
    active = context.active_object
    if active is None:
        return []
    if is_bound(active):
        return [active]
    return bound_to(active, context.scene.objects)


class OBJECT_OT_lbc_show_influence(bpy.types.Operator):
    """Paint the weights of the selected cage vertex on the bound mesh (select a vertex of the cage in Edit Mode)"""

    bl_idname = "object.lbc_show_influence"
    bl_label = "Show Influence"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return allowed(cls, None if _influence_targets(context) else "Make a bound mesh or its cage active")

    def execute(self, context):
        shown = 0
        for mesh_obj in _influence_targets(context):
            cage = mesh_obj.lbc.cage
            if cage is None:
                self.report({"WARNING"}, f"The cage of '{mesh_obj.name}' was deleted")
                continue
            vertex = influence.selected_cage_vertex(cage)
            if vertex is None:
                self.report({"ERROR"}, f"Select a vertex of the cage '{cage.name}' (in Edit Mode)")
                return {"CANCELLED"}
            peak = influence.show(mesh_obj, vertex)
            self.report({"INFO"}, f"{mesh_obj.name}: cage vertex {vertex}, largest weight {peak:.3f}")
            shown += 1
        return {"FINISHED"} if shown else {"CANCELLED"}


class OBJECT_OT_lbc_hide_influence(bpy.types.Operator):
    """Remove the painted influence colors"""

    bl_idname = "object.lbc_hide_influence"
    bl_label = "Hide Influence"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        shown = any(obj.lbc.show_influence for obj in _influence_targets(context))
        return allowed(cls, None if shown else "No influence is shown")

    def execute(self, context):
        for mesh_obj in _influence_targets(context):
            influence.hide(mesh_obj)
        return {"FINISHED"}


class OBJECT_OT_lbc_save_shape_key(bpy.types.Operator):
    """Save the deformation the cage gives the active mesh now as a new shape key at value 0, as Mesh Deform's Save
    as Shape Key does (e.g. to sculpt a corrective shape on it); the binding stays"""

    bl_idname = "object.lbc_save_shape_key"
    bl_label = "Save as Shape Key"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        if obj is None or not is_bound(obj):
            return allowed(cls, "Make a bound mesh active")
        return allowed(cls, geometry.not_editable_here(obj))

    def execute(self, context):
        mesh_obj = context.active_object
        try:
            key = writing.save_shape_key(mesh_obj, context.evaluated_depsgraph_get())
        except CageError as error:
            self.report({"ERROR"}, f"Not saved: {error}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"{mesh_obj.name}: saved the deformation as the shape key '{key.name}' (value 0)")
        return {"FINISHED"}


CLASSES = (
    OBJECT_OT_lbc_bind,
    OBJECT_OT_lbc_rebind,
    OBJECT_OT_lbc_rebind_all,
    OBJECT_OT_lbc_unbind,
    OBJECT_OT_lbc_show_influence,
    OBJECT_OT_lbc_hide_influence,
    OBJECT_OT_lbc_save_shape_key,
)


register, unregister = bpy.utils.register_classes_factory(CLASSES)
