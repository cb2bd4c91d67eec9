"""Panels: the same content in the Properties editor (Object tab) and the 3D view's sidebar (LBC tab)."""

import textwrap

import bpy

from . import cage_scene, deformer, diagnosis, geometry, storage
from .core import format_size
from .diagnosis import NoteKind, edited_since_bind
from .properties import bound_to, is_bound

# Above this mean the panel suggests Max Influences: where each vertex feels most of a small cage's vertices (a 50k
# sphere in Blender's Cylinder: all 64, which Thinning leaves), a cap of 24 made a frame 7.5 → 4.1 ms, Mesh Deform's
# 4.7 (bench/RESULTS.md); the gargoyle and Suzanne in their cages have 15-20.
MANY_INFLUENCES = 32
SUGGESTED_INFLUENCES = 24


def draw_binding(layout, obj):
    """State, figures and actions of a bound mesh."""
    settings = obj.lbc
    ok = settings.state == "FOLLOWING"
    notes = diagnosis.notes(obj) if ok else ()
    box = layout.box()
    box.label(text=settings.status or "Bound",
              icon="CHECKMARK" if ok and not any(note.problem for note in notes) else "ERROR")
    for note in notes:  # a lasting problem first (a cage too small, the mesh out of its cage), then advice
        if note.kind == NoteKind.EDITED_SINCE_BIND:
            box.label(text="The cage was edited since the bind,", icon="INFO")
            box.label(text="and the mesh follows the edit: Rebind to make it the rest shape")
            box.operator("object.lbc_rebind", icon="FILE_REFRESH")
        else:
            wrapped_label(box, note.text, icon="ERROR" if note.problem else "INFO")
    if settings.cage is None:  # deleted: bind to another cage (Bind's poll says what to select)
        box.operator("object.lbc_bind", icon="MOD_MESHDEFORM")
    elif not ok:
        box.operator("object.lbc_rebind", icon="FILE_REFRESH")
    draw_modifier_inputs(layout, obj)
    column = layout.column(align=True)
    column.label(text=f"Cage: {settings.cage.name if settings.cage else '(deleted)'}", icon="MESH_CUBE")
    column.label(text=f"{settings.dimension}D binding, {settings.control_points} control points")
    column.label(text=f"{len(obj.data.vertices)} mesh vertices, {settings.outside} outside the cage")
    column.label(text=f"Influences per vertex: mean {settings.mean_influences:.1f}, max {settings.slots}")
    if settings.mean_influences > MANY_INFLUENCES and not settings.influences:
        wrapped_label(column, f"Each vertex follows most of the cage's vertices here, which Thinning leaves: Bind "
                      f"with Max Influences (e.g. {SUGGESTED_INFLUENCES}) for faster frames, if the deformation it "
                      "gives suits (it follows fewer cage vertices, and a bent smooth mesh may crease)", icon="INFO")
    column.label(text=blend_size_label(obj))
    column.label(text=f"Bind time: {settings.bind_seconds:.1f} s")
    if settings.bind_report:  # warm (what was solved again) or from scratch (why)
        column.label(text=settings.bind_report[:1].upper() + settings.bind_report[1:])
    others = settings.warnings
    for note in notes:  # said in the state's box already
        others = _without(others, note.text)
    if others:
        wrapped_label(layout, others, icon="INFO")
    row = layout.row(align=True)
    row.operator("object.lbc_rebind", icon="FILE_REFRESH")
    row.operator("object.lbc_unbind", icon="X")
    layout.operator("object.lbc_save_shape_key", icon="SHAPEKEY_DATA")
    draw_influence(layout, obj)


def blend_size_label(obj):
    """What the binding adds to a .blend saved uncompressed: the weights in the mesh and the deformer's node group
    (measured at bind time, :func:`node_group.saved_bytes`), within 2 % of what such a save adds; Blender 5 compresses
    files by default, which keeps about a fifth to a third of it (bench/RESULTS.md, "What a binding adds to the
    .blend")."""
    settings = obj.lbc
    weights = storage.memory_bytes(len(obj.data.vertices), settings.slots)
    group = settings.node_group_bytes
    if not group:  # bound before the group's size was measured
        return f"In the .blend, uncompressed: weights {format_size(weights)}, and the deformer's node group"
    return (f"In the .blend, uncompressed: {format_size(weights + group)} (weights {format_size(weights)}, deformer "
            f"{format_size(group)})")


def _without(warnings, warning):
    """The bind's warnings, joined by "; " (``Object.lbc.warnings``), without ``warning`` ("" leaves them whole)."""
    if not warning:
        return warnings
    return "; ".join(part for part in warnings.replace(warning, "").split("; ") if part.strip())


def wrapped_label(layout, text, icon="NONE"):
    """A long text as lines of labels as wide as the panel (a label does not wrap: a 300-character warning showed
    only its start, and its advice came last), the icon on the first line."""
    region = bpy.context.region
    width = 60 if region is None else max(30, int(region.width / (7 * bpy.context.preferences.system.ui_scale)))
    column = layout.column(align=True)
    for number, line in enumerate(textwrap.wrap(text, width)):
        column.label(text=line, icon=icon if number == 0 else "BLANK1")


def draw_modifier_inputs(layout, obj):
    """The artist's inputs of the LBC modifier (Strength, vertex group mask), where they live: on the modifier."""
    modifier = deformer.find_modifier(obj)
    if modifier is None:
        return
    if deformer.input_identifier(modifier, "Strength") is None:
        return  # a binding made before these inputs existed: Rebind adds them

    def where(name):
        return deformer.input_property(modifier, deformer.input_identifier(modifier, name))

    column = layout.column(align=True)
    column.prop(*where("Strength"), text="Strength")
    row = column.row(align=True)
    row.prop_search(*where("Vertex Group"), obj, "vertex_groups", text="Vertex Group")
    row.prop(*where("Invert Vertex Group"), text="", icon="ARROW_LEFTRIGHT")


def draw_influence(layout, obj):
    row = layout.row(align=True)
    row.operator("object.lbc_show_influence", icon="COLOR")
    if obj.lbc.show_influence:
        row.operator("object.lbc_hide_influence", icon="HIDE_ON")
        layout.label(text=f"Showing cage vertex {obj.lbc.influence_vertex}")


def draw(layout, context):
    """Whatever fits the active object: a bound mesh, a cage with bound meshes, or a selection ready to bind."""
    obj = context.active_object
    if obj is None:
        layout.label(text="Select the mesh(es), then the cage (active)")
        draw_make_cage(layout, context)
        return
    if is_bound(obj):
        draw_binding(layout, obj)
        return
    leftovers = geometry.leftover_weights(obj)
    if leftovers:
        size = format_size(storage.memory_bytes(len(obj.data.vertices), storage.slot_count(obj.data)))
        box = layout.box()
        box.label(text=f"Carries LBC weights for no binding ({size}), from a bound mesh joined into it", icon="INFO")
        box.operator("object.lbc_unbind", icon="TRASH", text="Remove the LBC Weights")
    meshes = bound_to(obj, context.scene.objects)
    if meshes:
        layout.label(text=f"Cage of {len(meshes)} mesh(es):", icon="MOD_MESHDEFORM")
        for mesh_obj in meshes:
            following = mesh_obj.lbc.state == "FOLLOWING"
            problems = [note for note in diagnosis.notes(mesh_obj) if note.problem] if following else []
            layout.label(text=f"{mesh_obj.name}: {mesh_obj.lbc.status}",
                         icon="ERROR" if problems or not following else "NONE")
            for note in problems:  # lasting: the cage's panel shows them as long as they last
                wrapped_label(layout, note.text, icon="BLANK1")
        if any(edited_since_bind(mesh_obj.lbc) for mesh_obj in meshes):
            layout.label(text="Edited since the bind: the meshes follow the edit.", icon="INFO")
            layout.label(text="Rebind All makes it their rest shape")
        layout.operator("object.lbc_rebind_all", icon="FILE_REFRESH")
        if obj.mode == "EDIT":
            layout.label(text="Select a cage vertex, then:")
            draw_influence(layout, meshes[0])
    to_bind = [o for o in context.selected_objects if o.type == "MESH" and o != obj]
    swapped = geometry.swapped_selection(obj, to_bind) if to_bind else None
    if swapped:
        wrapped_label(layout, swapped, icon="ERROR")
    else:
        layout.label(text=f"Bind {len(to_bind)} selected mesh(es) to '{obj.name}':" if to_bind
                     else "Select the mesh(es), then the cage (active)")
    layout.operator("object.lbc_bind", icon="MOD_MESHDEFORM")
    if not meshes and not swapped:  # the active object is no cage of bound meshes, nor a mesh in its cage's place
        draw_make_cage(layout, context)


def draw_make_cage(layout, context):
    """Make Cage and Make Cage and Bind, for the selected meshes (none selected: nothing)."""
    meshes = cage_scene.cage_targets(context)
    if not meshes:
        return
    box = layout.box()
    if len(meshes) == 1:
        box.label(text=f"No cage yet? Make one around '{meshes[0].name}':", icon="MESH_ICOSPHERE")
    else:
        box.label(text=f"Or make one cage around the {len(meshes)} selected meshes:", icon="MESH_ICOSPHERE")
    row = box.row(align=True)
    row.operator("object.lbc_make_cage", icon="MESH_ICOSPHERE")
    row.operator("object.lbc_make_cage_and_bind", icon="MOD_MESHDEFORM")


class OBJECT_PT_lbc(bpy.types.Panel):
    bl_label = "LBC Cage Binding"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        return context.active_object is not None and context.active_object.type == "MESH"

    def draw(self, context):
        draw(self.layout, context)


class VIEW3D_PT_lbc(bpy.types.Panel):
    bl_label = "LBC Cage Binding"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "LBC"

    def draw(self, context):
        draw(self.layout, context)


CLASSES = (OBJECT_PT_lbc, VIEW3D_PT_lbc)


register, unregister = bpy.utils.register_classes_factory(CLASSES)
