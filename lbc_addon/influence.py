""""Show influence": one cage vertex's weights painted on the mesh as a color attribute (the paper's Fig. 7).

The colors live in a visible color attribute that :func:`hide` removes again, together with the display settings
:func:`show` changed, so showing and hiding leaves the mesh as it was.
"""

import bpy  # noqa: I001  (first: importing bpy makes bmesh importable from the bpy module)
import bmesh
import numpy as np

from . import storage
from .jobs import read_welded

ATTRIBUTE_NAME = "LBC Influence"

# A blue-to-red ramp like the paper's figures: weight 0 (not influenced) is dark blue.
_RAMP_STOPS = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
_RAMP_COLORS = np.array(
    [[0.02, 0.02, 0.25], [0.0, 0.35, 0.9], [0.1, 0.8, 0.3], [1.0, 0.85, 0.0], [0.85, 0.05, 0.0]]
)


def selected_cage_vertex(cage_obj):
    """The cage vertex to show: the active one of the selection history in edit mode, else the first selected.

    Returns None when no vertex is selected.
    """
    if cage_obj.mode == "EDIT":
        edit = bmesh.from_edit_mesh(cage_obj.data)
        active = edit.select_history.active
        if isinstance(active, bmesh.types.BMVert):
            return active.index
        selected = [v.index for v in edit.verts if v.select]
        return selected[0] if selected else None
    flags = np.zeros(len(cage_obj.data.vertices), dtype=bool)
    cage_obj.data.vertices.foreach_get("select", flags)
    selected = np.flatnonzero(flags)
    return int(selected[0]) if len(selected) else None


def kept_vertex(welded, cage_vertex):
    """The cage vertex whose slots hold ``cage_vertex``'s weights: the one it was welded to at bind time (the
    binding's "copy:kept,..." pairs), else itself."""
    pairs = read_welded(welded)
    kept = pairs[pairs[:, 0] == cage_vertex, 1]
    return int(kept[0]) if len(kept) else cage_vertex


def vertex_weights(mesh, cage_vertex):
    """Each mesh vertex's weight for one cage vertex, from the cached slots."""
    index, weight = storage.read(mesh)
    return np.where(index == cage_vertex, weight, 0.0).sum(axis=1)


def ramp(values):
    """(m,) values in [0, 1] to (m, 4) RGBA colors."""
    values = np.clip(values, 0.0, 1.0)
    rgb = np.stack([np.interp(values, _RAMP_STOPS, _RAMP_COLORS[:, c]) for c in range(3)], axis=1)
    return np.concatenate([rgb, np.ones((len(values), 1))], axis=1)


def _views():
    """{(screen name, area index): space} of the 3D views of every open window: their Solid shading is switched to
    attribute colors and back (a view is no ID, so it is remembered by its screen and place)."""
    return {
        (window.screen.name, index): space
        for window in bpy.context.window_manager.windows
        for index, area in enumerate(window.screen.areas)
        if area.type == "VIEW_3D"
        for space in area.spaces
        if space.type == "VIEW_3D"
    }


def _showing(mesh_obj):
    """The other objects showing their influence now."""
    return [obj for obj in bpy.data.objects if obj != mesh_obj and obj.lbc.show_influence]


def _restore_views(switched):
    """Give the 3D views :func:`show` switched (its "screen|area|color type;..." record) their color type back, where
    they still show attribute colors. A record of a color type alone (files saved before views were told apart)
    applies to every view."""
    views = _views()
    for entry in filter(None, switched.split(";")):
        *place, color_type = entry.rsplit("|", 2)
        targets = [views.get((place[0], int(place[1])))] if place else list(views.values())
        for space in targets:
            if space is not None and space.shading.color_type == "VERTEX":
                space.shading.color_type = color_type


def show(mesh_obj, cage_vertex):
    """Paint the weights of ``cage_vertex`` on a bound mesh and show colors in the 3D views' Solid shading.

    Returns the largest weight painted (the colors are scaled to it).
    """
    mesh = mesh_obj.data
    settings = mesh_obj.lbc
    values = vertex_weights(mesh, kept_vertex(settings.welded, cage_vertex))
    peak = float(values.max()) if len(values) else 0.0
    attribute = mesh.color_attributes.get(ATTRIBUTE_NAME)
    if attribute is None:
        settings.previous_color = mesh.color_attributes.active_color_name or ""
        attribute = mesh.color_attributes.new(ATTRIBUTE_NAME, "FLOAT_COLOR", "POINT")
    colors = ramp(values / peak if peak > 0 else values)
    attribute.data.foreach_set("color", colors.astype(np.float32).ravel())
    mesh.color_attributes.active_color = attribute
    # Every mesh showing influence keeps the whole record of the views switched, so that whichever is hidden last,
    # or left when another is deleted, gives them back.
    showing = _showing(mesh_obj)
    switched = {entry for obj in [mesh_obj] + showing for entry in obj.lbc.previous_color_type.split(";") if entry}
    for (screen, index), space in _views().items():
        # "VERTEX" is Solid shading's "Attribute" color: the active color attribute.
        if space.shading.color_type != "VERTEX":
            switched.add(f"{screen}|{index}|{space.shading.color_type}")
            space.shading.color_type = "VERTEX"
    for obj in [mesh_obj] + showing:
        obj.lbc.previous_color_type = ";".join(sorted(switched))
    settings.show_influence = True
    settings.influence_vertex = cage_vertex
    mesh.update()
    return peak


def hide(mesh_obj):
    """Remove the painted influence and give back the display settings :func:`show` changed."""
    settings = mesh_obj.lbc
    if not settings.show_influence:
        return
    mesh = mesh_obj.data
    attribute = mesh.color_attributes.get(ATTRIBUTE_NAME)
    if attribute is not None:
        mesh.color_attributes.remove(attribute)
    # By name: Blender 5.1 and 5.2 keep a removed attribute's name as the active color unless told otherwise.
    previous = settings.previous_color
    mesh.color_attributes.active_color_name = previous if previous in mesh.color_attributes else ""
    # While another mesh shows its influence the views stay on attribute colors; the last one hidden gives them back.
    if not _showing(mesh_obj):
        _restore_views(settings.previous_color_type)
    settings.show_influence = False
    settings.previous_color = ""
    settings.previous_color_type = ""
    mesh.update()
