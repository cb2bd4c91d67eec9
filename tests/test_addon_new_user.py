"""What a new user hit, each done as they did it: mesh and cage swapped in a script, Shift+D copies moved off or moved
with their cage, a cage too small, the .blend's size, a fine cage at few cells, Adjust Last Operation (F9); and the
add-on's typed boundary (its options record, the node group's warnings looked up by cause)."""

import os
import time

import bpy  # noqa: I001  (first: importing bpy makes bmesh and mathutils importable)
import numpy as np
import pytest
from mathutils import Matrix, Vector

import lbc_core
from lbc_addon import api, deformer, geometry, jobs, node_group, storage, ui
from lbc_addon.diagnosis import NoteKind
from lbc_addon.properties import is_bound
from helpers.blender_scenes import (
    _subdivide,
    evaluated_positions,
    mesh_object,
    positions,
    reset,
    sphere_in_box_scene,
    undo_context,
)
from test_addon_ui import _draw

pytestmark = pytest.mark.blender

CELLS = 1000


def test_a_dense_mesh_given_as_the_cage_is_refused_at_once_in_the_bind_button_s_words(monkeypatch):
    """A new user's script, api.bind(cage, character): 13.6 s of work on the 26k character, then "the cage has 52306
    faces…". Refused before any of the cage's evaluation, with the words Bind's greyed-out button gives."""
    reset()
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=5, radius=0.8)  # 10,242 vertices: more than a cage may have
    dense = bpy.context.active_object
    box = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    cage = mesh_object("Box", box, [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])
    work = []
    monkeypatch.setattr(geometry, "_cage_geometry", lambda *args: work.append(args))
    with pytest.raises(lbc_core.CageError) as refused:
        api.bind(cage, dense)
    button = geometry.swapped_selection(dense, [cage])
    assert button == (f"'{dense.name}' is active and would be the cage; make the cage active (click it last) and "
                      "select the meshes to bind")
    assert str(refused.value) == f"{button} (in a script: api.bind(mesh, cage), the mesh first)"
    assert work == [] and not is_bound(cage)


def _shift_d(objects, offset):
    """Shift+D as the 3D view does it on ``objects`` (selected, the last active), then the copies moved by
    ``offset``; returns the copies in the order of ``objects``."""
    with undo_context():
        for obj in bpy.context.view_layer.objects:
            obj.select_set(obj in objects)
        bpy.context.view_layer.objects.active = objects[-1]
        assert bpy.ops.object.duplicate(linked=False) == {"FINISHED"}
        copies = sorted(bpy.context.selected_objects, key=lambda copy: [o.name for o in objects].index(
            copy.name.rsplit(".", 1)[0]))
    for copy in copies:
        copy.location += Vector(offset)
    bpy.context.evaluated_depsgraph_get()
    return copies


def test_a_copy_moved_out_of_its_cage_is_said_to_be_outside_it_and_its_rebind_says_so_too():
    """A new user's find: a Shift+D copy of a bound mesh, moved away, read "Rebind to bind it where it is now"; Rebind
    then failed with "every vertex lies outside the cage (Select the mesh, then the cage last…)"."""
    mesh, cage = sphere_in_box_scene()
    api.bind(mesh, cage, cells=CELLS)
    (copy,) = _shift_d([mesh], (10.0, 0.0, 0.0))
    state = api.status(copy)
    assert state.following and not state.ok
    assert [note.kind for note in state.notes] == [NoteKind.OUTSIDE_ITS_CAGE]
    assert state.notes[0].text.startswith(f"'{copy.name}' was moved as an object out of its cage 'Box', which still "
                                          "places it where the cage is. Move it back into 'Box'")
    panel = " ".join(_draw(copy, [copy]).labels().split("\n"))
    assert "out of its cage 'Box'" in panel and "to bind it where it is now" not in panel
    with bpy.context.temp_override(active_object=copy, object=copy, selected_objects=[copy]):
        with pytest.raises(RuntimeError) as refused:
            bpy.ops.object.lbc_rebind()
    assert (f"every vertex of '{copy.name}' lies outside its cage 'Box' where '{copy.name}' is now: it was moved as an "
            "object out of the cage, which still places it") in str(refused.value)
    assert "Select the mesh, then the cage last" not in str(refused.value)
    copy.location.x -= 9.9  # moved back, but not where it was bound: a Rebind there binds it where it is
    assert [note.kind for note in api.status(copy).notes] == [NoteKind.MOVED_AS_AN_OBJECT]


def test_a_mesh_and_its_cage_duplicated_together_and_moved_deform_without_a_moved_note():
    """A new user's find: mesh and cage duplicated together and moved, the copy deformed correctly, yet its status
    said it "was moved as an object … Undo the move"."""
    mesh, cage = sphere_in_box_scene()
    api.bind(mesh, cage, cells=CELLS)
    mesh_copy, cage_copy = _shift_d([mesh, cage], (0.0, 4.0, 0.0))
    assert mesh_copy.lbc.cage == cage_copy  # Blender points the copy's binding to the copied cage
    assert np.abs(evaluated_positions(mesh_copy) - positions(mesh_copy.data)).max() < 1e-5  # at rest, where it is
    state = api.status(mesh_copy)
    assert state == api.Status(True, f"Following '{cage_copy.name}'", ())
    mesh_copy.location.z += 0.5  # then the copy alone moved: that move shows nothing, and is said
    assert [note.kind for note in api.status(mesh_copy).notes] == [NoteKind.MOVED_AS_AN_OBJECT]


def test_a_cage_too_small_is_a_lasting_state_in_both_panels_and_api_status():
    """A new user's find: with 58 % of the mesh outside a cage 20 % too small, the bind warned once, then the mesh
    read "Following 'Cage'", api.status said ok, and the cage's panel showed nothing."""
    mesh, cage = sphere_in_box_scene()
    mesh.data.transform(Matrix.Scale(1.5, 4))
    summary = api.bind(mesh, cage, cells=CELLS)
    share = summary.outside / len(mesh.data.vertices)
    bpy.context.evaluated_depsgraph_get()
    line = f"Following 'Box', with {share:.0%} of the mesh outside it: the cage is too small"
    assert mesh.lbc.status == line
    state = api.status(mesh)
    assert state.message == line and state.following and not state.ok
    cage_panel = _draw(cage, [cage])
    assert f"Sphere: {line}" in cage_panel.labels() and cage_panel.icons[f"Sphere: {line}"] == "ERROR"
    assert "Scale the cage up so it encloses the mesh" in " ".join(cage_panel.labels().split("\n"))
    mesh.data.transform(Matrix.Scale(1 / 1.5, 4))
    api.bind(mesh, cage, cells=CELLS)  # the fix: the mesh inside, bound again
    bpy.context.evaluated_depsgraph_get()
    assert api.status(mesh).ok and mesh.lbc.status == "Following 'Box'"
    assert _draw(cage, [cage]).icons["Sphere: Following 'Box'"] == "NONE"


def test_the_panel_s_blend_size_is_what_saving_the_bound_file_adds(tmp_path):
    """A new user's find: "Cache in the .blend" showed 609 KB where the file grew by 1.06 MB: the deformer's node
    group (about 3.8 kB a node) was not counted."""
    mesh, cage = sphere_in_box_scene()
    bpy.ops.mesh.primitive_uv_sphere_add(segments=64, ring_count=32, radius=0.7)  # 2018 vertices: weights to count
    body = bpy.context.active_object
    before = str(tmp_path / "before.blend")
    bpy.ops.wm.save_as_mainfile(filepath=before, compress=False)  # what the panel counts: Blender 5 compresses
    api.bind(body, cage, cells=CELLS)
    after = str(tmp_path / "after.blend")
    bpy.ops.wm.save_as_mainfile(filepath=after, compress=False)
    grown = os.path.getsize(after) - os.path.getsize(before)
    told = storage.memory_bytes(len(body.data.vertices), body.lbc.slots) + body.lbc.node_group_bytes
    assert abs(told - grown) <= 0.1 * grown, (told, grown)
    label = ui.blend_size_label(body)
    assert label.startswith(f"In the .blend, uncompressed: {lbc_core.addon_api.format_size(told)} (weights ")
    assert label in _draw(body, [body]).labels()


def _fine_cage_scene(cuts):
    """An ico sphere in a box cage subdivided with ``cuts`` cuts (6 (cuts + 1)² + 2 vertices); returns (mesh, cage)."""
    mesh, cage = sphere_in_box_scene()
    _subdivide(cage.data, cuts)
    return mesh, cage


def test_a_fine_cage_at_few_cells_says_its_cells_are_few_and_how_many_to_ask_for():
    """A new user's find: an 818-vertex cage at the default cells bound without a word on whether its resolution was
    enough; below 20 cells per cage vertex the deformation lies twice as far from a finer bind as at the default on
    ordinary cages (bench/RESULTS.md, "Few cells per control point")."""
    mesh, cage = _fine_cage_scene(4)  # 152 vertices
    summary = api.bind(mesh, cage, cells=2000)
    few = [warning for warning in summary.warnings if "few for so fine a cage" in warning]
    per = summary.cells / summary.control_points
    assert per < 20 and few == [
        f"the cage's 152 vertices have {per:.0f} cells each ({summary.cells} in all), few for so fine a cage: the "
        "weights are coarse. Bind again with Cells 4000 or more (a slower bind)"]
    assert [note.kind for note in api.status(mesh).notes] == [NoteKind.FEW_CELLS]
    assert api.status(mesh).ok  # advice, not a fault
    assert few[0] in " ".join(_draw(mesh, [mesh]).labels().split("\n"))
    again = api.bind(mesh, cage, cells=4000)
    assert not any("few for so fine a cage" in warning for warning in again.warnings)
    assert api.status(mesh).notes == ()


def _redo(mesh, cage, **changed):
    """Adjust Last Operation (F9) as Blender runs it (ED_undo_operator_repeat): undo the bind, then the operator's
    execute() with the panel's values, here ``changed``; returns (the mesh, seconds)."""
    bpy.ops.ed.undo()
    mesh, cage = bpy.data.objects[mesh], bpy.data.objects[cage]
    start = time.perf_counter()
    with bpy.context.temp_override(active_object=cage, object=cage, selected_objects=[mesh, cage]):
        assert bpy.ops.object.lbc_bind("EXEC_DEFAULT", **changed) == {"FINISHED"}
    return mesh, time.perf_counter() - start


def test_adjust_last_operation_binds_again_from_the_binding_it_replaces_when_the_solve_is_the_same(monkeypatch):
    """A new user's find: F9 bound again from scratch, on the main thread, without Esc. A redo whose options ask the
    same solve (Thinning, Max Influences; the Dimension Automatic or 3D of a 3D cage, Cells 0 or the default) starts
    from the binding the undo took away, kept in this session."""
    monkeypatch.setattr(jobs, "_previous", jobs.OrderedDict())
    mesh, cage = sphere_in_box_scene()
    with undo_context():
        bpy.ops.ed.undo_push(message="before bind")
        with bpy.context.temp_override(active_object=cage, object=cage, selected_objects=[mesh, cage]):
            assert bpy.ops.object.lbc_bind(cells=CELLS) == {"FINISHED"}
        bpy.ops.ed.undo_push(message="Bind to Cage")
        for changed in ({"cells": CELLS, "thinning": 0.01}, {"cells": CELLS, "mode": "3D", "mesher": "delaunay"}):
            mesh, _ = _redo("Sphere", "Box", **changed)
            assert mesh.lbc.bind_report.startswith("bound again from the previous binding: it was made for the cage "
                                                   "as it is now"), (changed, mesh.lbc.bind_report)
            bpy.ops.ed.undo_push(message="Bind to Cage")
        mesh, _ = _redo("Sphere", "Box", cells=2 * CELLS)  # another solve: from scratch, and it says why
        assert mesh.lbc.bind_report == "bound from scratch: its cells changed since its last bind"


def test_the_node_group_s_warnings_are_looked_up_by_cause_not_read_as_text(bound_gargoyle):
    """The panel tells why the modifier stops from the cause of the group's Warning node that shows the error, never
    from the error's words: reworded (another version, another language), it still says why."""
    if not node_group.HAS_WARNING_NODE:
        pytest.skip("Blender 4.2 has no Warning node: the modifier shows no error to look up")
    mesh, _ = bound_gargoyle
    group = deformer.find_modifier(mesh).node_group
    messages = node_group.stop_messages(mesh.lbc.cage_vertex_count, mesh.lbc.mesh_vertex_count)
    for cause, message in messages.items():
        assert node_group.warning_cause(group, node_group.WARNING_PREFIX + message) == cause
    assert node_group.warning_cause(group, messages[node_group.StopCause.DISABLED]) is None  # not the node's words
    warning = group.nodes[f"Stop: {node_group.StopCause.MESH_VERTICES.value}"]
    warning.inputs["Message"].default_value = "Das Netz hat eine andere Anzahl Punkte"  # reworded
    # A Geometry Nodes modifier above that subdivides, and one below that may change the count as well: only the
    # group's own error tells that the count reaching the deformer changed.
    tree = bpy.data.node_groups.new("Subdivide", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    subdivide = tree.nodes.new("GeometryNodeSubdivideMesh")
    tree.links.new(tree.nodes.new("NodeGroupInput").outputs[0], subdivide.inputs["Mesh"])
    tree.links.new(subdivide.outputs["Mesh"], tree.nodes.new("NodeGroupOutput").inputs[0])
    above = mesh.modifiers.new("Subdivide", "NODES")
    above.node_group = tree
    mesh.modifiers.move(len(mesh.modifiers) - 1, 0)
    mesh.modifiers.new("Weld", "WELD")
    bpy.context.evaluated_depsgraph_get()
    assert api.status(mesh).message == "T" + messages[node_group.StopCause.MESH_VERTICES][1:]
    assert not api.status(mesh).following


def test_the_mesher_option_is_stored_and_a_changed_mesher_that_runs_the_same_binds_warm():
    mesh, cage = sphere_in_box_scene()
    first = api.bind(mesh, cage, cells=CELLS, mesher="delaunay")
    assert mesh.lbc.mesher == "delaunay" and mesh.lbc.bind_options().mesher == "delaunay" and first.dimension == 3
    again = api.bind(mesh, cage, cells=CELLS)  # "auto" runs the same mesher: nothing to solve again
    assert again.rebind.startswith("bound again from the previous binding"), again.rebind
    with pytest.raises(lbc_core.CageError, match="mesher must be one of 'auto', 'delaunay', not 'triangle'"):
        api.bind(mesh, cage, mesher="triangle")
    assert mesh.lbc.mesher == "auto"
