"""A user's session with the built extension, run by test_addon_install.py in a Python that has only what Blender
ships (bpy, numpy): install the zip through Blender's installer, enable, bind (operator and script API), follow the
cage, refuse a bad cage, save, reopen without and with the extension, rebind, unbind. It ends with a plain
interpreter exit, as a background script does.

    python -S extension_session.py ZIP OTHER_ZIP RESULT_JSON BLEND_FILE

OTHER_ZIP is the zip built for the other Python ABI, whose Blender range excludes this Blender: it must be refused.
"""

import importlib
import importlib.machinery
import importlib.util
import json
import os
import re
import sys

import bpy
import numpy as np

ARCHIVE, OTHER_ARCHIVE, RESULT, BLEND = sys.argv[1:5]
MODULE = "bl_ext.user_default.lbc"
BUNDLED = ("scipy", "potpourri3d", "cholespy")
result = {}


def positions(obj, evaluated=False):
    """(m, 3) vertex positions of the object's mesh, after its modifiers when ``evaluated``."""
    owner = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()) if evaluated else obj
    mesh = owner.to_mesh() if evaluated else obj.data
    values = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", values)
    if evaluated:
        owner.to_mesh_clear()
    return values.reshape(-1, 3)


def state(obj):
    """What an unbind or a refused bind must leave exactly as it was."""
    return [positions(obj).tobytes().hex(), sorted(a.name for a in obj.data.attributes),
            [m.name for m in obj.modifiers], sorted(g.name for g in bpy.data.node_groups)]


def shift_x(obj):
    """[min, max] of the x shift of the deformed mesh from its rest positions."""
    shift = positions(obj, evaluated=True)[:, 0] - positions(obj)[:, 0]
    return [float(shift.min()), float(shift.max())]


def run_operator(operator, active, selected):
    with bpy.context.temp_override(active_object=active, object=active, selected_objects=selected):
        return sorted(operator())


result["importable_before"] = [name for name in (*BUNDLED, "lbc_core", "lbc_addon") if importlib.util.find_spec(name)]
# Blender 4.2.0 reports the refusal as an error message but returns FINISHED: look for the installed package.
bpy.ops.extensions.package_install_files(filepath=OTHER_ARCHIVE, repo="user_default", enable_on_install=True)
result["other_installed"] = os.path.exists(os.path.join(bpy.utils.user_resource("EXTENSIONS"), "user_default", "lbc"))
result["install"] = sorted(bpy.ops.extensions.package_install_files(filepath=ARCHIVE, repo="user_default",
                                                                    enable_on_install=True))
result["enabled"] = MODULE in bpy.context.preferences.addons
api = importlib.import_module(f"{MODULE}.api")
result["lbc_core"] = sys.modules[f"{MODULE}.lbc_core"].__file__
result["bundled"] = {name: importlib.import_module(name).__file__ for name in BUNDLED}
# Compiled modules built for another Python than this one (Blender 4.2.0's installer does not sort wheels by ABI).
own_suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
site = os.path.dirname(os.path.dirname(result["bundled"]["scipy"]))
result["site_packages"] = sorted(os.listdir(site))
result["other_abi"] = sorted(name for _, _, names in os.walk(site) for name in names
                             if re.search(r"\.cpython-\d+-", name) and not name.endswith(own_suffix))

bpy.ops.wm.read_homefile(use_empty=True)
bpy.ops.mesh.primitive_uv_sphere_add(radius=0.7)
sphere = bpy.context.active_object
bpy.ops.mesh.primitive_ico_sphere_add(radius=0.5, location=(0.1, 0.0, 0.0))
ico = bpy.context.active_object
bpy.ops.mesh.primitive_cube_add(size=2.0)
cage = bpy.context.active_object
sphere_rest = state(sphere)

result["bind_operator"] = run_operator(lambda: bpy.ops.object.lbc_bind(cells=1000), cage, [sphere, cage])
result["bind_api"] = api.bind(ico, cage, cells=1000).control_points
cage.location.x += 0.5
result["moved"] = [shift_x(sphere), shift_x(ico)]

# An open cage (a box without its +x face) is refused before any work, the mesh left as it was.
box = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
open_mesh = bpy.data.meshes.new("Open")
open_mesh.from_pydata(box, [], [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4)])
open_cage = bpy.data.objects.new("Open", open_mesh)
bpy.context.scene.collection.objects.link(open_cage)
bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5)
lone = bpy.context.active_object
lone_before = state(lone)
try:
    api.bind(lone, open_cage, cells=1000)
    result["bad_cage"] = "bound"
except api.CageError as error:
    result["bad_cage"] = str(error)
result["bad_cage_untouched"] = state(lone) == lone_before
try:
    run_operator(lambda: bpy.ops.object.lbc_bind(cells=1000), open_cage, [lone, open_cage])
    result["bad_cage_operator"] = "bound"
except RuntimeError as error:  # in a script, an operator's error report is raised
    result["bad_cage_operator"] = str(error)
result["bad_cage_operator_untouched"] = state(lone) == lone_before

bpy.ops.wm.save_as_mainfile(filepath=BLEND)
bpy.ops.preferences.addon_disable(module=MODULE)
bpy.ops.wm.open_mainfile(filepath=BLEND)
result["reopened_without"] = [MODULE in bpy.context.preferences.addons, shift_x(bpy.data.objects["Sphere"])]
bpy.ops.preferences.addon_enable(module=MODULE)
bpy.ops.wm.open_mainfile(filepath=BLEND)
sphere, cage = bpy.data.objects["Sphere"], bpy.data.objects["Cube"]
result["reopened_with"] = [[api.status(sphere).ok, api.status(sphere).message], shift_x(sphere)]
result["rebind"] = run_operator(bpy.ops.object.lbc_rebind, sphere, [sphere])
result["rest_after_rebind"] = shift_x(sphere)  # bound again to the cage where it stands now
cage.location.x += 0.25
result["moved_after_rebind"] = shift_x(sphere)
result["unbind"] = run_operator(bpy.ops.object.lbc_unbind, sphere, [sphere])
result["unbound_exactly"] = state(sphere)[:3] == sphere_rest[:3]
api.unbind(bpy.data.objects["Icosphere"])
result["modifiers_after_api_unbind"] = [m.name for m in bpy.data.objects["Icosphere"].modifiers]
result["node_groups_left"] = sorted(group.name for group in bpy.data.node_groups)

with open(RESULT, "w") as handle:
    json.dump(result, handle)
print("session done", flush=True)
