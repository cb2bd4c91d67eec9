""""Show influence": one cage vertex's weights painted on the mesh, and removed again without a trace."""

import bpy
import numpy as np
import pytest

from lbc_addon import influence, storage
from helpers.blender_scenes import (
    mesh_state,
)

pytestmark = pytest.mark.blender


def _view_shading():
    return [space.shading.color_type for space in influence._views().values()]


def test_show_paints_the_selected_cage_vertex_and_hide_removes_it(bound_gargoyle):
    mesh, cage = bound_gargoyle
    before, shading = mesh_state(mesh), _view_shading()
    for vertex in cage.data.vertices:
        vertex.select = vertex.index == 12
    assert influence.selected_cage_vertex(cage) == 12
    with bpy.context.temp_override(active_object=mesh, object=mesh, selected_objects=[mesh]):
        assert bpy.ops.object.lbc_show_influence() == {"FINISHED"}
    attribute = mesh.data.color_attributes[influence.ATTRIBUTE_NAME]
    colors = np.empty(len(attribute.data) * 4, dtype=np.float32)
    attribute.data.foreach_get("color", colors)
    colors = colors.reshape(-1, 4)
    index, weight = storage.read(mesh.data)
    influenced = np.any((index == 12) & (weight > 0), axis=1)
    # Vertices the cage vertex does not move keep the ramp's zero color; the others do not.
    zero = influence.ramp(np.zeros(1))[0, :3]
    assert np.allclose(colors[~influenced, :3], zero)
    assert not np.any(np.all(np.isclose(colors[influenced, :3], zero), axis=1))
    assert mesh.data.color_attributes.active_color_name == influence.ATTRIBUTE_NAME
    assert set(_view_shading()) == {"VERTEX"}
    with bpy.context.temp_override(active_object=mesh, object=mesh, selected_objects=[mesh]):
        assert bpy.ops.object.lbc_hide_influence() == {"FINISHED"}
    after = mesh_state(mesh)
    # Hiding also clears the add-on's bookkeeping of what was shown, the rest is as before.
    assert after == before
    assert _view_shading() == shading


def test_hiding_gives_each_view_its_own_color_type_back_once_no_mesh_shows_influence(bound_gargoyle):
    """A reviewer's finding: one color type was kept per mesh, so a view already on attribute colors was set to
    another view's type, and hiding one of two meshes showing influence turned the other's colors off."""
    mesh, cage = bound_gargoyle
    second = mesh.copy()
    second.data = mesh.data.copy()
    bpy.context.scene.collection.objects.link(second)
    bpy.context.window.screen.areas[2].type = "VIEW_3D"  # a second 3D view
    first_view, second_view = influence._views().values()
    first_view.shading.color_type, second_view.shading.color_type = "VERTEX", "OBJECT"  # the artist's choices
    influence.show(mesh, 3)
    influence.show(second, 3)
    assert _view_shading() == ["VERTEX", "VERTEX"]
    influence.hide(mesh)
    assert _view_shading() == ["VERTEX", "VERTEX"]  # the second mesh still shows its influence
    influence.hide(second)
    assert [first_view.shading.color_type, second_view.shading.color_type] == ["VERTEX", "OBJECT"]
    influence.show(mesh, 3)
    influence.show(second, 3)
    bpy.data.objects.remove(mesh)  # the first shown deleted: its record was the views' only one (a tester)
    influence.hide(second)
    assert [first_view.shading.color_type, second_view.shading.color_type] == ["VERTEX", "OBJECT"]


def test_show_influence_from_the_cage_paints_every_mesh_bound_to_it(bound_gargoyle):
    mesh, cage = bound_gargoyle
    cage.data.vertices[3].select = True
    with bpy.context.temp_override(active_object=cage, object=cage, selected_objects=[cage]):
        assert bpy.ops.object.lbc_show_influence() == {"FINISHED"}
    assert mesh.lbc.show_influence and mesh.lbc.influence_vertex == influence.selected_cage_vertex(cage)


def test_ramp_goes_from_dark_blue_to_red():
    colors = influence.ramp(np.array([0.0, 1.0, 2.0]))
    assert colors[0, 2] > colors[0, 0] and colors[1, 0] > colors[1, 2]
    assert np.array_equal(colors[1], colors[2]) and np.all(colors[:, 3] == 1)


def test_a_welded_copy_shows_the_weights_of_the_vertex_it_was_welded_to():
    """A code review's finding: the slots hold only the kept vertex, so selecting its copy painted zeros."""
    assert influence.kept_vertex("7:3,9:4", 9) == 4 and influence.kept_vertex("7:3,9:4", 3) == 3
    assert influence.kept_vertex("", 5) == 5
