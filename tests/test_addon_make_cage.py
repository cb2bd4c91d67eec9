"""Make Cage and Make Cage and Bind through bpy.ops, their modal run, undo and redo, and api.make_cage: a new cage
object around the selected meshes (or a vertex group), which binds them with no vertex outside."""

import subprocess
import sys
from pathlib import Path

import bpy  # noqa: I001  (first: importing bpy makes mathutils importable)
import numpy as np
import pytest
from mathutils import Matrix

from lbc_addon import api, cage_maker
from lbc_addon.operators import running
from lbc_addon.properties import is_bound
from helpers.blender_scenes import (
    bind,
    cube_scene,
    diagonal,
    evaluated_positions,
    mesh_object,
    positions,
    sphere_in_box_scene,
    undo_context,
)

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parents[1]
VERTICES = 20  # a coarse cage: each one is made in seconds


def _make(meshes, active=None, operator="lbc_make_cage", **options):
    """Run Make Cage (or Make Cage and Bind) as a user does: the meshes selected, the first (or ``active``) active."""
    active = active or meshes[0]
    with bpy.context.temp_override(active_object=active, object=active, selected_objects=list(meshes)):
        return getattr(bpy.ops.object, operator)(**{"vertices": VERTICES, **options})


def _world(obj):
    """An object's vertices in world space, (m, 3)."""
    matrix = np.array(obj.matrix_world)
    return positions(obj.data) @ matrix[:3, :3].T + matrix[:3, 3]


def _scene_state():
    """What Make Cage may change: the objects and meshes of the file, the selection, the active object."""
    layer = bpy.context.view_layer
    layer.update()  # an object removed leaves its base in the layer until then
    return (sorted(bpy.data.objects.keys()), sorted(bpy.data.meshes.keys()),
            sorted(obj.name for obj in layer.objects if obj.select_get()),
            layer.objects.active.name if layer.objects.active else None)


def test_make_cage_puts_a_wire_cage_in_the_cubes_collection_and_frame_that_binds_it_with_none_outside(capfd):
    cube = cube_scene()
    props = bpy.data.collections.new("Props")
    bpy.context.scene.collection.children.link(props)
    props.objects.link(cube)
    bpy.context.scene.collection.objects.unlink(cube)
    assert _make([cube]) == {"FINISHED"}
    cage = bpy.data.objects["CubeCage"]
    assert "Made 'CubeCage' around 'Cube': " in capfd.readouterr().out
    assert cage.display_type == "WIRE" and cage.hide_render and cage.parent is None
    assert [collection.name for collection in cage.users_collection] == ["Props"]
    assert np.allclose(np.array(cage.matrix_world), np.array(cube.matrix_world))
    assert abs(len(cage.data.vertices) - VERTICES) <= 0.15 * VERTICES
    layer = bpy.context.view_layer
    assert layer.objects.active == cage and {obj.name for obj in layer.objects if obj.select_get()} == {"Cube",
                                                                                                        "CubeCage"}
    assert bind(cube, cage, cells=1000) == {"FINISHED"}
    assert cube.lbc.outside == 0 and cube.lbc.state == "FOLLOWING"


def test_several_meshes_get_one_cage_around_them_all_in_the_first_ones_frame():
    cube = cube_scene()
    other = mesh_object("Block", _world(cube) * [0.5, 0.5, 2.0] + [2.0, 0.0, 0.5], [list(face.vertices) for face in
                                                                                       cube.data.polygons],
                        Matrix.Translation((1.0, 0.0, 0.0)) @ Matrix.Rotation(0.7, 4, "Y"))
    assert _make([cube, other], vertices=30) == {"FINISHED"}
    cage = bpy.data.objects["CubeCage"]
    assert np.allclose(np.array(cage.matrix_world), np.array(cube.matrix_world))
    for mesh in (cube, other):
        assert api.bind(mesh, cage, cells=1000).outside == 0


def test_a_vertex_group_gives_a_partial_cage_around_its_faces_from_a_script(capsys):
    cube = cube_scene(matrix=Matrix.Identity(4))
    group = cube.vertex_groups.new(name="Top")
    top = [vertex.index for vertex in cube.data.vertices if vertex.co.z > 0.3]
    group.add(top, 1.0, "REPLACE")
    gone = mesh_object("Gone", [(0, 0, 0)], [])
    bpy.context.view_layer.update()
    bpy.data.objects.remove(gone)  # a script's removal leaves a gap in the view layer until it updates again
    made = api.make_cage(cube, vertices=VERTICES, vertex_group="Top")
    printed = capsys.readouterr().out
    assert "LBC cage: 100% cage made" in printed and "LBC cage:   0% " in printed
    assert made.name == "CubeCage" and made.cage == bpy.data.objects["CubeCage"] and made.meshes == ("Cube",)
    assert abs(made.vertices - VERTICES) <= 0.15 * VERTICES and made.faces == len(made.cage.data.polygons)
    assert made.volume > 0 and 0 < made.clearance < made.mean_distance and made.seconds > 0
    # Around the top faces only (z from 1/3 to 1), not the cube's lower part.
    z = positions(made.cage.data)[:, 2]
    assert z.min() > 0.2 and z.max() > 1.0


def _refuse_work(vertices, faces, **options):
    """lbc_core's generate_cage where no work may start: its own first checks, then a failure."""
    from lbc_core.cage_generator.mesh_input import input_mesh

    input_mesh(vertices, faces)
    raise AssertionError("the cage would have been made")


def test_a_missing_or_empty_group_a_non_mesh_and_edit_mode_are_refused_before_any_work(monkeypatch):
    monkeypatch.setattr(cage_maker.cage_job, "generate_cage", _refuse_work)
    cube = cube_scene()
    cube.vertex_groups.new(name="Empty")
    corners = cube.vertex_groups.new(name="Corners")
    corners.add([0, 1], 1.0, "REPLACE")  # two vertices: no whole face
    before = _scene_state()
    for group, message in (("Arm", "'Cube' has no vertex group 'Arm' \\(its groups: 'Empty', 'Corners'\\)"),
                           ("Empty", "the vertex group 'Empty' of 'Cube' has nothing to cage \\(it holds no vertex\\)"),
                           ("Corners", "has nothing to cage \\(its 2 vertices make no whole face\\)")):
        with pytest.raises(RuntimeError, match=message):
            _make([cube], vertex_group=group)
    handle = bpy.data.objects.new("Handle", None)
    bpy.context.scene.collection.objects.link(handle)
    with pytest.raises(RuntimeError, match=r"'Handle' \(Empty\) is not a mesh, and only meshes can be caged"):
        _make([handle])
    with pytest.raises(RuntimeError, match="Select the mesh"):
        _make([], active=handle)
    with pytest.raises(api.CageError, match=r"only meshes can be caged: select the mesh\(es\) to put a cage around$"):
        api.make_cage([cube, handle])  # in the button's words
    with bpy.context.temp_override(active_object=cube, object=cube, selected_objects=[cube]):
        bpy.ops.object.mode_set(mode="EDIT")
        with pytest.raises(RuntimeError, match="Make Cage works in Object Mode"):
            bpy.ops.object.lbc_make_cage()
        bpy.ops.object.mode_set(mode="OBJECT")
    bpy.data.objects.remove(handle)
    plane = mesh_object("Plane", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 1, 2, 3)])
    with pytest.raises(api.CageError, match=r"the mesh is flat \(all of it in one plane\)"):
        api.make_cage(plane)
    bpy.data.meshes.remove(plane.data)
    assert _scene_state() == before


def test_a_cage_of_bound_meshes_active_is_not_caged_again():
    mesh, cage = sphere_in_box_scene()
    assert bind(mesh, cage, cells=1000) == {"FINISHED"}
    with pytest.raises(RuntimeError, match="'Box' is the cage of bound meshes: select only the mesh"):
        _make([mesh, cage], active=cage)


class _Event:
    def __init__(self, kind):
        self.type, self.value = kind, "PRESS"


class _ModalHarness(cage_maker._CageMaker):
    """Drives Make Cage's modal() the way Blender's event loop does in the UI, with a stand-in window manager and
    status bar (the headless bpy module has no event loop)."""

    bl_label = "Make Cage"

    def __init__(self, binds=False, **options):
        self.binds, self.bl_label = binds, "Make Cage and Bind" if binds else "Make Cage"
        self.vertices, self.margin, self.symmetry, self.vertex_group = VERTICES, 0.0, "NONE", ""
        for name, value in options.items():
            setattr(self, name, value)
        self.reports, self.status = [], []
        manager = type("WindowManager", (), {"event_timer_add": lambda _self, *_args, **_kw: object(),
                                             "event_timer_remove": lambda _self, timer: None})()
        workspace = type("Workspace", (), {"status_text_set": lambda _self, text: self.status.append(text)})()
        self.context = type("Context", (), {"window_manager": manager, "workspace": workspace, "window": None,
                                            "mode": "OBJECT", "selected_objects": bpy.context.selected_objects,
                                            "active_object": bpy.context.active_object,
                                            "evaluated_depsgraph_get": lambda _self: bpy.context.
                                            evaluated_depsgraph_get()})()

    def report(self, kinds, message):
        self.reports.append((set(kinds), message))

    def run(self, cancel_in=None):
        """Begin, then send timer events until modal() finishes (Esc once the status bar shows ``cancel_in``)."""
        assert self.begin(self.context) == {"RUNNING_MODAL"}
        while True:
            if cancel_in and self.status and (self.status[-1] or "").startswith(cancel_in):
                assert self.modal(self.context, _Event("ESC")) == {"RUNNING_MODAL"}
            result = self.modal(self.context, _Event("TIMER"))
            if result != {"RUNNING_MODAL"}:
                return result
            self._worker._thread.join(0.05)


def _selecting(meshes):
    """Select ``meshes`` in the view layer, the first active (what the harness's context reads)."""
    layer = bpy.context.view_layer
    for obj in layer.objects:
        obj.select_set(obj in meshes)
    layer.objects.active = meshes[0]


def test_esc_while_a_cage_is_made_leaves_the_scene_unchanged():
    cube = cube_scene()
    _selecting([cube])
    before = _scene_state()
    harness = _ModalHarness()
    assert harness.run(cancel_in="LBC cage") == {"CANCELLED"}
    assert ({"WARNING"}, "Make Cage cancelled: nothing changed") in harness.reports
    assert _scene_state() == before and not running and harness.status[-1] is None


def test_a_mesh_moved_while_its_cage_is_made_gets_no_cage_and_is_told_why():
    cube = cube_scene()
    _selecting([cube])
    harness = _ModalHarness()
    assert harness.begin(harness.context) == {"RUNNING_MODAL"}
    cube.location.x += 1.0  # the UI stays usable meanwhile
    before = _scene_state()
    harness._worker._thread.join()
    assert harness.modal(harness.context, _Event("TIMER")) == {"CANCELLED"}
    assert harness.reports == [({"ERROR"}, "'Cube' was moved or edited while its cage was made: nothing was made; "
                                           "make the cage again")]
    assert _scene_state() == before and not running


def test_esc_during_the_bind_of_make_cage_and_bind_takes_the_cage_out_again():
    cube = cube_scene()
    _selecting([cube])
    before = _scene_state()
    harness = _ModalHarness(binds=True)
    assert harness.run(cancel_in="LBC bind") == {"CANCELLED"}
    assert any(text.startswith("LBC cage: ") for text in harness.status if text)
    assert ({"WARNING"}, "Make Cage and Bind cancelled: nothing changed") in harness.reports
    assert _scene_state() == before and not is_bound(cube) and not running


def test_modal_make_cage_and_bind_shows_both_stages_and_leaves_the_mesh_bound_and_following():
    cube = cube_scene()
    _selecting([cube])
    harness = _ModalHarness(binds=True)
    assert harness.run() == {"FINISHED"}
    stages = [text.split(":")[0] for text in harness.status if text]
    assert stages.index("LBC cage") < stages.index("LBC bind") and harness.status[-1] is None
    cage = bpy.data.objects["CubeCage"]
    messages = [message for _, message in harness.reports]
    made = next(number for number, text in enumerate(messages) if text.startswith("Made 'CubeCage' around 'Cube': "))
    assert any(text.startswith("Bound 'Cube' to 'CubeCage' in ") for text in messages[made + 1:])
    assert is_bound(cube) and cube.lbc.cage == cage and cube.lbc.outside == 0
    assert bpy.context.view_layer.objects.active == cage
    cage.location.z += 0.5  # the cage moves in its own frame, the cube's: the cube follows it exactly
    expected = positions(cube.data) + np.array(cube.matrix_world.inverted().to_3x3()) @ np.array([0.0, 0.0, 0.5])
    assert np.abs(evaluated_positions(cube) - expected).max() < 1e-5 * diagonal(cube)


def test_undo_removes_the_cage_and_a_redo_makes_it_with_other_vertices():
    cube = cube_scene()
    with undo_context():
        bpy.ops.ed.undo_push(message="before")
        before = _scene_state()
        assert _make([cube]) == {"FINISHED"}
        bpy.ops.ed.undo_push(message="Make Cage")
        assert "CubeCage" in bpy.data.objects
        assert bpy.ops.ed.undo() == {"FINISHED"}
        assert _scene_state() == before and "CubeCage" not in bpy.data.meshes
        # A redo in Adjust Last Operation: the undo above, then execute() with the changed option.
        cube = bpy.data.objects["Cube"]
        with bpy.context.temp_override(active_object=cube, object=cube, selected_objects=[cube]):
            assert bpy.ops.object.lbc_make_cage("EXEC_DEFAULT", vertices=40) == {"FINISHED"}
    cage = bpy.data.objects["CubeCage"]  # the name is free again after the undo
    assert abs(len(cage.data.vertices) - 40) <= 6


def test_make_cage_and_bind_of_a_vertex_group_moves_that_part_only(capfd):
    cube = cube_scene(matrix=Matrix.Identity(4))
    top = [vertex.index for vertex in cube.data.vertices if vertex.co.z > 0.3]
    cube.vertex_groups.new(name="Top").add(top, 1.0, "REPLACE")
    assert _make([cube], operator="lbc_make_cage_and_bind", vertex_group="Top") == {"FINISHED"}
    out = capfd.readouterr().out
    assert "Made 'CubeCage' around 'Cube' (vertex group 'Top'): " in out
    assert "Cube: only its vertex group 'Top' follows 'CubeCage'" in out
    cage = bpy.data.objects["CubeCage"]
    assert is_bound(cube) and cube.lbc.cage == cage and bpy.context.view_layer.objects.active == cage
    cage.location.x += 0.25
    moved = np.abs(evaluated_positions(cube) - positions(cube.data)).max(axis=1)
    inside = np.zeros(len(moved), dtype=bool)
    inside[top] = True
    assert np.allclose(moved[inside], 0.25, atol=1e-5) and np.allclose(moved[~inside], 0.0)


def test_make_cage_and_bind_refuses_shared_mesh_data_before_making_a_cage():
    cube = cube_scene()
    twin = bpy.data.objects.new("Twin", cube.data)  # Alt+D: Bind stores its weights in the shared data
    bpy.context.scene.collection.objects.link(twin)
    with pytest.raises(RuntimeError, match="The mesh data of 'Cube' is shared by 2 objects"):
        _make([cube], operator="lbc_make_cage_and_bind")
    assert "CubeCage" not in bpy.data.objects


def test_symmetry_x_makes_a_cage_that_is_its_own_mirror_image_in_the_mesh_s_frame():
    """Symmetry X mirrors the cage across the plane through the mesh's bounding-box middle, normal to the mesh's own
    x axis (not the world's): the cage of a rotated, off-centre mesh maps onto itself under that mirror."""
    cube = cube_scene()
    data = cube.data
    for vertex in data.vertices:
        if vertex.co.x > 0 and vertex.co.z > 0:
            vertex.co.z += 0.3  # no longer symmetric about x itself: the cage is made around it and its mirror
    cube.location = (2.0, -1.0, 0.5)
    cube.rotation_euler = (0.3, 0.0, 0.7)
    made = api.make_cage(cube, vertices=VERTICES, symmetry="x")
    local = positions(made.cage.data)
    low, high = positions(data).min(axis=0), positions(data).max(axis=0)
    mirrored = local.copy()
    mirrored[:, 0] = (low[0] + high[0]) - mirrored[:, 0]
    nearest = np.linalg.norm(mirrored[:, None, :] - local[None, :, :], axis=2).min(axis=1)
    assert nearest.max() < 1e-5 * diagonal(cube)  # Blender keeps positions in float32
    assert not np.allclose(local[:, 2], local[:, 2].mean())  # a real cage, not a degenerate one


def test_cage_job_makes_a_cage_without_bpy():
    script = (
        "import sys; sys.modules['bpy'] = None  # any import of bpy now fails\n"
        "from lbc_addon import cage_job\n"
        "from lbc_core.cage_generator.shapes import box\n"
        "vertices, faces = box()\n"
        "request = cage_job.CageRequest((1,), ('Box',), vertices, faces, None, cage_job.CageOptions(vertices=8), '')\n"
        "result = cage_job.make(request)\n"
        "print(result.cage.vertex_count, len(cage_job.face_lists(result.cage.faces)) == len(result.cage.faces))\n"
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "8 True"
