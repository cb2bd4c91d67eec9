"""The panels: what they show for a bound mesh, a broken binding, a cage, and a selection ready to bind.

Panels need a UILayout, which only exists while Blender draws; the draw code is run here on a stand-in layout that
records the labels and operators it is given.
"""

import bpy  # noqa: I001  (first: importing bpy makes bmesh and mathutils importable)
import bmesh
import pytest
from mathutils import Matrix

from lbc_addon import api, ui
from helpers.blender_scenes import (
    delete_with_x,
    register_addon,
    sphere_in_box_scene,
)

pytestmark = pytest.mark.blender


class Layout:
    """Records what a panel draws: label texts and operator ids, through nested boxes, rows and columns."""

    def __init__(self, record=None, icons=None):
        self.record = record if record is not None else []
        self.icons = icons if icons is not None else {}  # label text -> its icon
        self.use_property_split = False

    def label(self, text="", icon="NONE"):
        self.record.append(("label", text))
        self.icons[text] = icon

    def operator(self, idname, icon="NONE", text=None):
        self.record.append(("operator", idname))

    def prop(self, data, name, **kwargs):
        self.record.append(("prop", kwargs.get("text", name)))

    def prop_search(self, data, name, search_data, search_name, **kwargs):
        assert hasattr(search_data, search_name)
        self.record.append(("prop", kwargs.get("text", name)))

    def box(self):
        return Layout(self.record, self.icons)

    def row(self, align=False):
        return Layout(self.record, self.icons)

    def column(self, align=False):
        return Layout(self.record, self.icons)

    def labels(self):
        return "\n".join(text for kind, text in self.record if kind == "label")

    def operators(self):
        return [name for kind, name in self.record if kind == "operator"]

    def props(self):
        return [name for kind, name in self.record if kind == "prop"]


def _draw(active, selected):
    layout = Layout()
    with bpy.context.temp_override(active_object=active, object=active, selected_objects=selected):
        ui.draw(layout, bpy.context)
    return layout


def test_bound_mesh_shows_state_figures_and_actions(bound_gargoyle):
    mesh, _ = bound_gargoyle
    layout = _draw(mesh, [mesh])
    text = layout.labels()
    assert "Following 'Cage'" in text and "Cage: Cage" in text
    assert "67 control points" in text and "2674 mesh vertices, 0 outside" in text
    assert f"max {mesh.lbc.slots}" in text and "In the .blend, uncompressed:" in text and "KB" in text
    assert {"object.lbc_rebind", "object.lbc_unbind", "object.lbc_show_influence"} <= set(layout.operators())
    assert "Max Influences" not in text  # 15-16 influences: no hint
    # The modifier's inputs, drawn from the modifier itself (one source of truth, also in the modifier panel).
    assert layout.props() == ["Strength", "Vertex Group", ""]


def test_a_long_warning_is_shown_whole_over_several_lines(bound_gargoyle):
    """A new user's find: the panel drew a 300-character warning on one label, which Blender does not wrap, so only
    its start showed and the advice at its end did not."""
    mesh, _ = bound_gargoyle
    warning = "cage faces 30 and 33 are split into fans of triangles: poke them " * 5
    mesh.lbc.warnings = warning
    try:
        lines = [text for kind, text in _draw(mesh, [mesh]).record if kind == "label"]
    finally:
        mesh.lbc.warnings = ""
    shown = [line for line in lines if line in warning]
    assert len(shown) > 1 and all(len(line) <= 60 for line in shown)
    assert " ".join(shown) == warning.strip()


def test_where_each_vertex_follows_most_of_the_cage_the_panel_suggests_max_influences():
    """A new user's find: in Blender's default Cylinder every vertex of a sphere inside keeps all 64 weights, and
    Thinning (which takes at most a tenth of a vertex's weight) leaves them, against what its tooltip said."""
    register_addon()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_cylinder_add()
    cage = bpy.context.active_object
    bpy.ops.mesh.primitive_ico_sphere_add(radius=0.5)
    sphere = bpy.context.active_object
    assert api.bind(sphere, cage, cells=2000).mean_influences > 60
    assert "Bind with Max Influences (e.g. 24)" in " ".join(_draw(sphere, [sphere]).labels().split("\n"))
    capped = api.bind(sphere, cage, cells=2000, influences=24)
    assert capped.mean_influences < 30
    # Vertices that 24 cage vertices cannot hold in place keep more, and the bind says so.
    assert any(warning.startswith("Max Influences 24: ") and "the fewest that can hold them in place" in warning
               for warning in capped.warnings)
    assert "Bind with Max Influences" not in " ".join(_draw(sphere, [sphere]).labels().split("\n"))


def test_a_cage_far_too_small_warns_in_the_state_with_the_share_outside_and_the_fix():
    """A user's find: with most of the mesh outside a cage scaled too small, the panel showed a green check and
    "Following", and the share outside and the fix (enlarge the cage) nowhere."""
    mesh, cage = sphere_in_box_scene()
    mesh.data.vertices[0].co.z = 3.0  # one stray vertex: a note, the state stays a check
    api.bind(mesh, cage, cells=1000)
    layout = _draw(mesh, [mesh])
    assert layout.icons["Following 'Box'"] == "CHECKMARK" and "Scale the cage up" not in layout.labels()
    mesh.data.transform(Matrix.Scale(1.5, 4))  # the sphere now pokes out of the box on every side
    summary = api.bind(mesh, cage, cells=1000)
    outside = summary.outside
    assert outside > 0.05 * 42
    warning = (f"{outside} of 42 vertices ({outside / 42:.0%}) lie outside the cage, which is too small for the mesh: "
               "they follow the cage only by extrapolation from the closest points inside it. Scale the cage up so "
               "it encloses the mesh, then Rebind")
    assert warning in summary.warnings
    layout = _draw(mesh, [mesh])
    line = f"Following 'Box', with {outside / 42:.0%} of the mesh outside it: the cage is too small"
    assert mesh.lbc.status == line and layout.icons[line] == "ERROR"
    text = " ".join(layout.labels().split("\n"))
    assert warning in text and text.count("lie outside the cage") == 1  # in the state's box, not again below
    state = api.status(mesh)  # what a pipeline reads says it too
    assert state.text == f"Following 'Box', with {outside / 42:.0%} of the mesh outside it: the cage is too small; {warning}"
    assert not state.ok and state.following and [note.kind for note in state.notes] == [api.NoteKind.CAGE_TOO_SMALL]


def test_deleted_cage_shows_why_and_offers_bind(bound_gargoyle):
    mesh, cage = bound_gargoyle
    delete_with_x(cage)
    bpy.context.evaluated_depsgraph_get()
    layout = _draw(mesh, [mesh])
    assert "The cage was deleted: the mesh is back at rest" in layout.labels() and "(deleted)" in layout.labels()
    assert layout.operators()[0] == "object.lbc_bind"


def test_cage_lists_its_meshes_and_a_selection_offers_bind(bound_gargoyle):
    mesh, cage = bound_gargoyle
    layout = _draw(cage, [cage])
    assert "Cage of 1 mesh(es)" in layout.labels() and "Gargoyle: Following" in layout.labels()
    assert "object.lbc_rebind_all" in layout.operators()
    mesh2, box = sphere_in_box_scene()
    layout = _draw(box, [mesh2, box])
    assert "Bind 1 selected mesh(es) to 'Box'" in layout.labels()
    assert layout.operators() == ["object.lbc_bind", "object.lbc_make_cage", "object.lbc_make_cage_and_bind"]
    assert "Or make one cage around the 2 selected meshes:" in layout.labels()


def test_a_mesh_selected_alone_is_offered_make_cage_and_a_cage_with_bound_meshes_is_not():
    mesh, box = sphere_in_box_scene()
    layout = _draw(mesh, [mesh])
    assert "No cage yet? Make one around 'Sphere':" in layout.labels()
    assert layout.operators()[-2:] == ["object.lbc_make_cage", "object.lbc_make_cage_and_bind"]
    with bpy.context.temp_override(active_object=mesh, object=mesh, selected_objects=[mesh]):
        assert bpy.ops.object.lbc_make_cage.poll() and bpy.ops.object.lbc_make_cage_and_bind.poll()
    api.bind(mesh, box, cells=1000)
    assert "object.lbc_make_cage" not in _draw(box, [mesh, box]).operators()
    assert "object.lbc_make_cage" not in _draw(mesh, [mesh]).operators()  # bound: its binding's panel


def test_a_dense_mesh_active_with_its_cage_selected_is_called_swapped_before_any_click():
    """A user's find: with a dense mesh active and its cage selected, the panel offered to bind the cage to the mesh,
    and the refusal came seconds after the click, muddled with the cage's size limit."""
    mesh, box = sphere_in_box_scene()
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=5, radius=0.8)  # 10242 vertices
    dense = bpy.context.active_object
    dense.name = "Mesh"
    text = " ".join(_draw(dense, [box, dense]).labels().split("\n"))
    assert text.endswith("'Mesh' is active and would be the cage; make the cage active (click it last) and select "
                         "the meshes to bind"), text
    assert "Bind 1 selected mesh(es)" not in text
    assert "Bind 1 selected mesh(es) to 'Box'" in _draw(box, [dense, box]).labels()
    assert "Bind 1 selected mesh(es) to 'Sphere'" in _draw(mesh, [box, mesh]).labels()  # a small "cage": its own errors


def test_a_cage_edited_at_rest_says_a_rebind_makes_the_edit_the_rest(bound_gargoyle):
    mesh, cage = bound_gargoyle
    hint, cage_hint = "Rebind to make it the rest shape", "Rebind All makes it their rest shape"
    assert hint not in _draw(mesh, [mesh]).labels() and cage_hint not in _draw(cage, [cage]).labels()
    cage.location.x += 0.2  # a pose, not an edit at rest
    cage.rotation_euler.z += 0.3
    assert hint not in _draw(mesh, [mesh]).labels()
    cage.data.vertices[5].co.z += 0.01  # an edit of the cage's own vertices
    cage.data.update()
    layout = _draw(mesh, [mesh])
    assert "The cage was edited since the bind," in layout.labels() and hint in layout.labels()
    assert layout.operators().count("object.lbc_rebind") == 2  # in the state's box as well as below
    assert cage_hint in _draw(cage, [cage]).labels()
    with bpy.context.temp_override(active_object=mesh, object=mesh, selected_objects=[mesh]):
        assert bpy.ops.object.lbc_rebind() == {"FINISHED"}
    assert hint not in _draw(mesh, [mesh]).labels() and cage_hint not in _draw(cage, [cage]).labels()
    # How a Rebind from a binding this session made went stays in the panel (warm, or from scratch and why).
    assert mesh.lbc.bind_report.startswith("bound from scratch: no earlier binding of it is in memory")  # the file's
    cage.data.vertices[5].co.z += 0.002
    cage.data.update()
    with bpy.context.temp_override(active_object=mesh, object=mesh, selected_objects=[mesh]):
        assert bpy.ops.object.lbc_rebind() == {"FINISHED"}
    report = mesh.lbc.bind_report
    assert report.startswith(("bound again from the previous binding: ", "bound from scratch: "))
    assert report[:1].upper() + report[1:] in _draw(mesh, [mesh]).labels()
    mesh.lbc.cage_shape = ""  # bound by a version that did not record the shape: no hint either way
    cage.data.vertices[5].co.z -= 0.012
    assert hint not in _draw(mesh, [mesh]).labels()


def test_a_loop_cut_on_the_cage_says_only_that_the_mesh_stays_undeformed(bound_gargoyle):
    """A user's find: after a loop cut on the cage, its panel said both that the mesh stays undeformed and that the
    meshes follow the edit."""
    mesh, cage = bound_gargoyle
    edit = bmesh.new()
    edit.from_mesh(cage.data)
    bmesh.ops.subdivide_edges(edit, edges=edit.edges[:1], cuts=1)
    edit.to_mesh(cage.data)
    edit.free()
    cage.data.update()
    bpy.context.evaluated_depsgraph_get()  # the depsgraph handler stops the deformer
    text = _draw(cage, [cage]).labels()
    assert "Gargoyle: The cage 'Cage' has 68 vertices, it was bound with 67: the mesh stays undeformed" in text
    assert "Edited since the bind" not in text and "Rebind All makes it their rest shape" not in text
    assert "The cage was edited since the bind," not in _draw(mesh, [mesh]).labels()


def test_moving_the_bound_mesh_alone_says_it_stays_with_its_cage_and_what_to_do():
    """A user's find, used to Mesh Deform: moving the bound mesh's object did nothing, and nothing said why."""
    mesh, cage = sphere_in_box_scene()
    api.bind(mesh, cage, cells=1000)
    hint = "'Sphere' was moved as an object since the bind, which does not move it"
    fix = "Undo the move, then move the cage instead, or parent the mesh to the cage (Ctrl+P) to move both together"

    def shown():
        bpy.context.view_layer.update()  # the transforms, as Blender updates them before it draws
        text = " ".join(_draw(mesh, [mesh]).labels().split("\n"))
        assert (hint in text) == (fix in text)
        return hint in text

    def parent(child, new_parent):  # as Ctrl+P: the child's own transform kept, the parent's undone at first
        child.parent = new_parent
        bpy.context.view_layer.update()
        child.matrix_parent_inverse = new_parent.matrix_world.inverted()

    assert not shown()
    rig = bpy.data.objects.new("Rig", None)
    bpy.context.scene.collection.objects.link(rig)
    parent(mesh, rig)
    parent(cage, rig)
    rig.location.y += 0.7  # both moved by one parent: the mesh follows its cage
    assert not shown()
    cage.location.x += 0.3  # the cage posed by its own transform
    assert not shown()
    mesh.location.x += 0.5
    mesh.rotation_euler.z += 0.2
    assert shown()
    mesh.location.x -= 0.5
    mesh.rotation_euler.z -= 0.2
    assert not shown()
    parent(mesh, cage)  # the fix: moved with its cage, nothing to say
    cage.location.z += 0.4
    cage.rotation_euler.x += 0.3
    assert not shown()
    mesh.parent = None
    mesh.location.y += 0.2
    assert shown()
    api.bind(mesh, cage, cells=1000)  # bound where it is now
    assert not shown()


def test_a_mesh_carrying_weights_of_no_binding_offers_to_remove_them():
    mesh, _ = sphere_in_box_scene()
    carrier = bpy.data.objects.new("Carrier", mesh.data.copy())
    bpy.context.scene.collection.objects.link(carrier)
    carrier.data.attributes.new(".lbc_index_0", "INT", "POINT")  # what a bound mesh joined into it brings
    carrier.data.attributes.new(".lbc_weight_0", "FLOAT", "POINT")
    layout = _draw(carrier, [carrier])
    assert "Carries LBC weights for no binding (" in layout.labels()
    assert layout.operators()[0] == "object.lbc_unbind"
    assert "Carries LBC weights" not in _draw(mesh, [mesh]).labels()


def test_panels_are_in_the_properties_editor_and_the_sidebar():
    register_addon()
    assert bpy.types.OBJECT_PT_lbc.bl_space_type == "PROPERTIES" and bpy.types.OBJECT_PT_lbc.bl_context == "object"
    assert bpy.types.VIEW3D_PT_lbc.bl_space_type == "VIEW_3D" and bpy.types.VIEW3D_PT_lbc.bl_region_type == "UI"
