"""Operators: Make Cage (a new cage object around the selected meshes, or a vertex group of them) and Make Cage and
Bind (the same, then Bind with its default options).

As Bind: the meshes are read on the main thread (:func:`cage_scene.snapshot`), the cage is made on a worker thread
(:func:`cage_job.make` in a :class:`jobs.Worker`) with its progress in the status bar and Esc to cancel, and the
scene changes only when it succeeded (:func:`cage_scene.write`), in the operator's one undo step. In background mode,
and in Adjust Last Operation (which runs ``execute()``, see :mod:`lbc_addon.operators`), it runs synchronously and
prints its progress. Make Cage and Bind goes on, modal, to the bind of the meshes to the new cage (a second worker);
Esc there takes the cage out again, so a cancel changes nothing; a refused bind keeps the cage and says why.
"""

import bpy
from bpy.props import EnumProperty, FloatProperty, IntProperty, StringProperty

from . import cage_job, cage_scene, deformer, geometry, jobs, operators
from .core import CageError, Cancelled
from .options import AddonOptions
from .properties import bound_to

SYMMETRY_ITEMS = (
    ("NONE", "None", "A cage that follows the mesh's shape as it is"),
    ("X", "X", "A cage mirror-symmetric left to right: across the plane through the middle of the mesh's bounding box "
     "normal to the mesh's own X axis"),
    ("Y", "Y", "A cage mirror-symmetric across the plane through the middle of the mesh's bounding box normal to its "
     "own Y axis"),
    ("Z", "Z", "A cage mirror-symmetric across the plane through the middle of the mesh's bounding box normal to its "
     "own Z axis"),
)


def _poll_message(context, label):
    """Why ``label`` (Make Cage, or Make Cage and Bind) cannot run now, or None when it can."""
    busy = operators.busy_message(context, label)
    if busy:
        return busy
    meshes = cage_scene.cage_targets(context)
    if not meshes:
        if context.selected_objects:
            return geometry.not_a_mesh(context.selected_objects[0], "only meshes can be caged",
                                       "select the mesh(es) to put a cage around")
        return "Select the mesh(es) to put a cage around"
    active = context.active_object
    if active in meshes and bound_to(active, context.scene.objects):
        return f"'{active.name}' is the cage of bound meshes: select only the mesh(es) to put a new cage around"
    return None


def _bind_poll_message(meshes):
    """Why the meshes cannot be bound here, for Make Cage and Bind before it makes a cage, or None."""
    for obj in meshes:
        linked = geometry.not_editable_here(obj)
        if linked:
            return linked
        if obj.data.users > 1:
            return (f"The mesh data of '{obj.name}' is shared by {obj.data.users} objects and Bind stores its weights "
                    "there: make it single user first (Object > Relations > Make Single User), or Make Cage alone")
    return None


class _CageMaker:
    """What Make Cage and Make Cage and Bind share: their options, the snapshot, making the cage (modal or not) and
    writing it; ``binds`` says whether the meshes are then bound to it."""

    binds = False

    vertices: IntProperty(
        name="Vertices",
        description="The cage's vertex count, met within 15 %. 0: chosen for the mesh's shape. More: a cage that "
        "follows the mesh more closely, a slower bind",
        default=0,
        min=0,
        max=2000,
        soft_max=400,
    )
    margin: FloatProperty(
        name="Margin",
        description="The space between the mesh and the cage, a share of the mesh's bounding-box diagonal (0.01 is "
        "1 %). 0: lbc's default",
        default=0.0,
        min=0.0,
        max=0.2,
        step=0.1,
        precision=3,
    )
    symmetry: EnumProperty(name="Symmetry", description="Make the cage mirror-symmetric across one of the mesh's "
                           "own axes, for a symmetric character", items=SYMMETRY_ITEMS, default="NONE")
    vertex_group: StringProperty(
        name="Vertex Group",
        description="A partial cage: only this vertex group of the mesh (e.g. an arm), the faces with all their "
        "corners in it. Empty: the whole mesh",
        default="",
    )

    def cage_options(self):
        """The options, as :class:`~lbc_addon.cage_job.CageOptions` (checked)."""
        return cage_job.CageOptions(vertices=self.vertices, margin=self.margin,
                                    symmetry=None if self.symmetry == "NONE" else self.symmetry,
                                    vertex_group=self.vertex_group)

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        for name in ("vertices", "margin", "symmetry"):
            layout.prop(self, name)
        active = context.active_object
        if active is not None and active.type == "MESH":
            layout.prop_search(self, "vertex_group", active, "vertex_groups")
        else:
            layout.prop(self, "vertex_group")

    def snapshot(self, context):
        meshes = cage_scene.cage_targets(context)
        refused = _bind_poll_message(meshes) if self.binds else None
        if refused:
            raise CageError(refused)
        return cage_scene.snapshot(meshes, self.cage_options())

    def execute(self, context):
        try:
            request = self.snapshot(context)
            result = cage_job.make(request, jobs.printed_progress(label="LBC cage"))
            cage = cage_scene.write(request, result, select=not self.binds)
        except CageError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        self._report_cage(cage, request, result)
        if not self.binds:
            return {"FINISHED"}
        try:
            pairs = operators.solve_printing(_bind_requests(context, request, cage))
        except CageError as error:
            return self._bind_refused(request, cage, error)
        return self._bound(request, cage, pairs)

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        started = self.begin(context)
        if started == {"RUNNING_MODAL"}:
            context.window_manager.modal_handler_add(self)
        return started

    def begin(self, context):
        """Snapshot the meshes and start making their cage on a worker thread, for :meth:`modal` to follow."""
        try:
            request = self.snapshot(context)
        except CageError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        self._request, self._cage = request, None
        self._start(context, jobs.Worker([request], work=cage_job.make, activity="making a cage"), "LBC cage")
        return {"RUNNING_MODAL"}

    def _start(self, context, worker, label):
        """Run ``worker`` in its thread, its progress shown as "``label``: 42% …" in the status bar."""
        operators.running.append(worker)
        worker.start()
        self._worker, self._label = worker, label
        self._timer = context.window_manager.event_timer_add(0.1, window=context.window)
        context.workspace.status_text_set(f"{label}: starting (Esc to cancel)")

    def modal(self, context, event):
        worker = self._worker
        if event.type == "ESC":
            worker.cancel()
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}  # the UI stays usable; write() checks the meshes did not change meanwhile
        if not worker.done:
            state = "cancelling" if worker.cancelled else f"{100 * worker.fraction:.0f}% {worker.message}"
            context.workspace.status_text_set(f"{self._label}: {state} (Esc to cancel)")
            return {"RUNNING_MODAL"}
        if context.mode != "OBJECT" and not worker.cancelled and worker.error is None:
            # Selecting the cage and writing a binding wait for Object Mode, as Bind does.
            context.workspace.status_text_set(f"{self._label}: done; switch to Object Mode to finish (Esc to cancel)")
            return {"RUNNING_MODAL"}
        self._finish(context)
        if worker.cancelled or isinstance(worker.error, Cancelled):
            return self._cancelled()
        if worker.error is not None and self._cage is None:
            self.report({"ERROR"}, str(worker.error))
            return {"CANCELLED"}
        if worker.error is not None:
            return self._bind_refused(self._request, self._cage, worker.error)
        if self._cage is None:
            return self._cage_made(context, worker.results[0][1])
        return self._bound(self._request, self._cage, worker.results)

    def _cage_made(self, context, result):
        """Write the cage the worker made; Make Cage and Bind then binds the meshes to it on a second worker."""
        try:
            cage = cage_scene.write(self._request, result, select=not self.binds)
        except CageError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        self._report_cage(cage, self._request, result)
        if not self.binds:
            return {"FINISHED"}
        self._cage = cage
        try:
            requests = _bind_requests(context, self._request, cage)
        except CageError as error:
            return self._bind_refused(self._request, cage, error)
        self._start(context, jobs.Worker(requests), "LBC bind")
        return {"RUNNING_MODAL"}

    def _cancelled(self):
        """Esc: nothing changed; a cage Make Cage and Bind made before its bind was cancelled is taken out again."""
        if self._cage is not None:
            cage_scene.remove(self._cage)
        self.report({"WARNING"}, f"{self.bl_label} cancelled: nothing changed")
        return {"CANCELLED"}

    def cancel(self, context):
        """Blender ends the modal operator itself (its window closed, another file opened): stop the work."""
        self._worker.cancel()
        self._finish(context)

    def _finish(self, context):
        context.window_manager.event_timer_remove(self._timer)
        context.workspace.status_text_set(None)
        operators.running.remove(self._worker)

    def _report_cage(self, cage, request, result):
        """What was made, then the generator's warnings (Blender's status bar shows the last report)."""
        made = result.cage
        names = ", ".join(f"'{name}'" for name in request.mesh_names)
        part = f" (vertex group '{request.options.vertex_group}')" if request.options.vertex_group else ""
        self.report({"INFO"}, f"Made '{cage.name}' around {names}{part}: {made.vertex_count} vertices, "
                              f"{len(made.faces)} faces, in {result.seconds:.1f} s")
        for warning in made.warnings:
            self.report({"WARNING"}, f"{cage.name}: {warning}")

    def _bind_refused(self, request, cage, error):
        """The bind after the cage was refused: the cage stays (its making took the time), selected for a Bind."""
        cage_scene.select_for_bind(_meshes(request), cage)
        self.report({"ERROR"}, f"Made '{cage.name}', but the bind was refused: {error}")
        return {"FINISHED"}

    def _bound(self, request, cage, pairs):
        """Write the bindings; with a vertex group, the deformer moves only that part (the rest lies outside the
        partial cage, which it would follow by extrapolation)."""
        bound = operators.apply_all(self, pairs)
        group = request.options.vertex_group
        for mesh_obj in bound if group else ():
            deformer.set_inputs(deformer.find_modifier(mesh_obj), {"Vertex Group": group})
            mesh_obj.update_tag()
            self.report({"INFO"}, f"{mesh_obj.name}: only its vertex group '{group}' follows '{cage.name}' (the LBC "
                                  "modifier's Vertex Group); the vertices outside the partial cage stay still")
        cage_scene.select_for_bind(_meshes(request), cage)
        return {"FINISHED"}


def _meshes(request):
    """The request's meshes still in the file."""
    return [obj for obj in map(geometry.find_object, request.mesh_uids) if obj is not None]


def _bind_requests(context, request, cage):
    """The bind requests of the request's meshes to the new cage, with Bind's default options."""
    targets = [(mesh_obj, cage, AddonOptions()) for mesh_obj in _meshes(request)]
    return geometry.snapshots(targets, context.evaluated_depsgraph_get())[0]


class OBJECT_OT_lbc_make_cage(_CageMaker, bpy.types.Operator):
    """Make a closed cage around the selected meshes (or a vertex group of the active one): a new object drawn as a
    wire, named after the mesh, ready to Bind"""

    bl_idname = "object.lbc_make_cage"
    bl_label = "Make Cage"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return operators.allowed(cls, _poll_message(context, cls.bl_label))


class OBJECT_OT_lbc_make_cage_and_bind(_CageMaker, bpy.types.Operator):
    """Make a closed cage around the selected meshes (or a vertex group of them), then bind them to it with Bind's
    default options"""

    bl_idname = "object.lbc_make_cage_and_bind"
    bl_label = "Make Cage and Bind"
    bl_options = {"REGISTER", "UNDO"}
    binds = True

    @classmethod
    def poll(cls, context):
        message = _poll_message(context, cls.bl_label)
        return operators.allowed(cls, message or _bind_poll_message(cage_scene.cage_targets(context)))


CLASSES = (OBJECT_OT_lbc_make_cage, OBJECT_OT_lbc_make_cage_and_bind)


register, unregister = bpy.utils.register_classes_factory(CLASSES)
