"""What Object.lbc remembers: the options a rebind reuses, nothing on objects never bound."""

import bpy
import pytest

from lbc_addon.properties import WEIGHTING_ITEMS, is_bound
from lbc_core.binding.options import WEIGHTINGS
from helpers.blender_scenes import bind, sphere_in_box_scene

pytestmark = pytest.mark.blender


def test_weighting_choices_are_lbc_cores():
    assert {identifier for identifier, _, _ in WEIGHTING_ITEMS} == set(WEIGHTINGS)


def test_bind_options_are_stored_and_reused_by_rebind(monkeypatch):
    mesh, cage = sphere_in_box_scene()
    options = {"cells": 800, "weighting": "linear", "epsilon": 0.01, "tolerance": 1e-3, "thinning": 2e-3,
               "influences": 5, "mode": "3D", "mesher": "delaunay"}
    assert bind(mesh, cage, **options) == {"FINISHED"}
    stored = mesh.lbc.bind_options()
    assert stored.cells == 800 and stored.weighting == "linear" and stored.mode == "3D"
    assert stored.influences == 5 and mesh.lbc.slots <= 5 and stored.mesher == "delaunay"
    assert abs(stored.epsilon - 0.01) < 1e-7 and abs(stored.thinning - 2e-3) < 1e-9
    from lbc_addon import geometry

    seen = []
    original = geometry.snapshot
    monkeypatch.setattr(geometry, "snapshot", lambda *args: seen.append(args[3]) or original(*args))
    with bpy.context.temp_override(active_object=mesh, object=mesh, selected_objects=[mesh]):
        assert bpy.ops.object.lbc_rebind() == {"FINISHED"}
    assert seen == [stored]


def test_objects_never_bound_get_no_property_group():
    mesh, cage = sphere_in_box_scene()
    assert not is_bound(mesh) and not is_bound(cage)
    assert "lbc" not in mesh.keys() and "lbc" not in cage.keys()
    bpy.context.evaluated_depsgraph_get()  # the add-on's depsgraph check looks at every object
    assert "lbc" not in mesh.keys() and "lbc" not in cage.keys()


def test_a_file_saved_before_the_cells_rename_keeps_its_cell_count(tmp_path):
    mesh, cage = sphere_in_box_scene()
    assert bind(mesh, cage, cells=600) == {"FINISHED"}
    mesh.lbc.cells = 0
    mesh.lbc["resolution"] = 600  # where versions before the rename stored the option
    name, path = mesh.name, str(tmp_path / "before_rename.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    reopened = bpy.data.objects[name]
    assert reopened.lbc.cells == 600 and reopened.lbc.get("resolution") is None


def test_the_dimension_choices_are_the_ones_the_options_check_accepts():
    from lbc_addon import options
    from lbc_addon.properties import MODE_ITEMS

    assert sorted(item[0] for item in MODE_ITEMS) == sorted(options.MODES)


def test_the_mesher_choices_are_lbc_cores_bundled_meshers_of_3d_cages():
    """CONTRIBUTING.md's "Adding a mesher backend": the Mesher menu offers "auto" and every bundled 3D mesher."""
    from lbc_addon.properties import MESHER_ITEMS
    from lbc_core.meshing import MESHERS, method_names

    bundled = [name for name, mesher in MESHERS[3].items() if mesher.bundled]
    assert [item[0] for item in MESHER_ITEMS] == [method_names(3)[0]] + bundled
