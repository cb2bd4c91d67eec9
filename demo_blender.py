"""Blender demo: the gargoyle bound to a 67-vertex cage with LBC, beside Blender's own Mesh Deform.

    .venv/bin/python demo_blender.py

Runs headless with the bpy module: builds the scene from tests/data/cages-3d/gargoyle (mesh.off, cage_L10.obj),
binds through the add-on's operator, binds Mesh Deform on the same mesh and cage, poses the cage, saves
out/blender_demo.blend and renders with Workbench into out/:

    blender_rest.png          the mesh in its cage at rest
    blender_lbc.png           posed with LBC
    blender_meshdeform.png    the same pose with Mesh Deform
    blender_influence.png     the weights of one cage vertex painted on the mesh (paper's Fig. 7)

and prints bind times, per-frame deform times and .blend sizes of both deformers.
"""

import argparse
import os
import sys
import time
from pathlib import Path

import bpy
import numpy as np
from mathutils import Vector

import lbc_addon
from lbc_addon import deformer, influence
from lbc_core.io import read_mesh

ROOT = Path(__file__).resolve().parent
DATA = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"
OUT = ROOT / "out"


def mesh_object(name, vertices, faces):
    """A mesh object from arrays; the data is y-up, Blender is z-up: the object stands it upright."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(np.asarray(vertices, dtype=float).tolist(), [], [[int(i) for i in f] for f in faces])
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    obj.rotation_euler = (np.pi / 2, 0.0, 0.0)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def build_scene(cage_level):
    """The gargoyle and its cage (drawn as a wireframe), a camera and Workbench settings."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = mesh_object("Gargoyle", *read_mesh(DATA / "mesh.off"))
    cage = mesh_object("Cage", *read_mesh(DATA / f"cage_{cage_level}.obj"))
    cage.display_type = "WIRE"
    cage.hide_render = True
    # Renders show the cage through a wireframe copy sharing its mesh data (a Wireframe modifier on the cage
    # itself would change the geometry the deformer samples).
    wire = bpy.data.objects.new("Cage Wireframe", cage.data)
    wire.rotation_euler = cage.rotation_euler
    wire.hide_select = True
    wire.modifiers.new("Wireframe", "WIREFRAME").thickness = 0.004
    scene_collection = bpy.context.scene.collection
    scene_collection.objects.link(wire)
    scene = bpy.context.scene
    scene.world = bpy.data.worlds.new("World")  # an opaque background
    scene.world.color = (0.16, 0.17, 0.19)
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x, scene.render.resolution_y = 640, 640
    scene.display.shading.light = "STUDIO"
    scene.display.shading.show_cavity = True
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    scene.camera = camera
    camera.location = (1.0, 1.75, 0.45)  # in front of the gargoyle, a little to its left
    direction = Vector((0.0, 0.0, 0.0)) - camera.location
    camera.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()
    camera.data.lens = 70
    bpy.context.view_layer.update()
    return mesh, cage


def cage_positions(cage):
    values = np.empty(len(cage.data.vertices) * 3, dtype=np.float32)
    cage.data.vertices.foreach_get("co", values)
    return values.reshape(-1, 3).astype(np.float64)


def set_cage_positions(cage, positions):
    cage.data.vertices.foreach_set("co", np.asarray(positions, dtype=np.float32).ravel())
    cage.data.update()


def posed(rest, amount=1.0):
    """A pose of the cage (its data is y-up, the gargoyle faces -z): the upper part bends forward, the wings fold."""
    posed = rest.copy()
    height = (rest[:, 1] - rest[:, 1].min()) / np.ptp(rest[:, 1])
    bend = -amount * 0.6 * np.clip((height - 0.45) / 0.55, 0, 1) ** 2
    pivot = np.array([0.0, rest[:, 1].min() + 0.45 * np.ptp(rest[:, 1]), 0.0])
    relative = rest - pivot
    cos, sin = np.cos(bend), np.sin(bend)
    posed[:, 1] = pivot[1] + cos * relative[:, 1] - sin * relative[:, 2]
    posed[:, 2] = pivot[2] + sin * relative[:, 1] + cos * relative[:, 2]
    wing = np.abs(rest[:, 0]) / np.abs(rest[:, 0]).max()
    posed[:, 0] *= 1 - amount * 0.35 * wing ** 2 * height
    return posed


def render(path):
    bpy.context.scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)


def frame_time(cage, rest, frames):
    """Median milliseconds of the depsgraph update that follows a change of the cage, over ``frames`` poses."""
    times = []
    for frame in range(frames):
        set_cage_positions(cage, posed(rest, 0.5 + 0.5 * np.sin(frame / 5)))
        start = time.perf_counter()
        bpy.context.evaluated_depsgraph_get()
        times.append(time.perf_counter() - start)
    set_cage_positions(cage, rest)
    return 1000 * float(np.median(times))


def moved_by_one_cage_vertex(mesh, cage, rest, step=7):
    """Mean number of mesh vertices that move when one cage vertex moves (every ``step``-th cage vertex is tried)."""
    counts = []
    scale = np.linalg.norm(np.ptp(rest, axis=0))
    before = evaluated_positions(mesh)
    for vertex in range(0, len(rest), step):
        moved = rest.copy()
        moved[vertex] += (rest[vertex] - rest.mean(axis=0)) / np.linalg.norm(rest[vertex] - rest.mean(axis=0)) * 0.03 \
            * scale
        set_cage_positions(cage, moved)
        after = evaluated_positions(mesh)
        counts.append(int(np.count_nonzero(np.linalg.norm(after - before, axis=1) > 1e-6 * scale)))
    set_cage_positions(cage, rest)
    return float(np.mean(counts))


def saved_size(path):
    """Bytes of the scene saved as a copy (uncompressed, as Blender saves by default)."""
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    return path.stat().st_size


def toggle_mesh_deform_binding(mesh, modifier):
    """Blender's Bind button: binds an unbound Mesh Deform modifier, unbinds a bound one."""
    with bpy.context.temp_override(object=mesh, active_object=mesh):
        bpy.ops.object.meshdeform_bind(modifier=modifier.name)


def subdivide(mesh, levels):
    """Apply ``levels`` of Catmull-Clark subdivision: a denser mesh, as in production (levels 2: 64k vertices)."""
    if levels:
        modifier = mesh.modifiers.new("Subdivision", "SUBSURF")
        modifier.levels = levels
        with bpy.context.temp_override(object=mesh, active_object=mesh):
            bpy.ops.object.modifier_apply(modifier=modifier.name)


def main(argv=None):
    parser = argparse.ArgumentParser(description="LBC in Blender beside Mesh Deform")
    parser.add_argument("--cage", default="L10", help="gargoyle cage level, L08 (168 vertices) to L16 (6)")
    parser.add_argument("--subdivide", type=int, default=2,
                        help="subdivision levels applied to the gargoyle first (0: its 2674 vertices; 2: 64k)")
    parser.add_argument("--cells", type=int, default=0, help="cells of the LBC domain mesh; 0: lbc_core's default")
    parser.add_argument("--precision", type=int, default=5, help="Mesh Deform precision (Blender's default: 5)")
    parser.add_argument("--frames", type=int, default=30, help="frames timed per deformer")
    args = parser.parse_args(argv)
    OUT.mkdir(exist_ok=True)
    lbc_addon.register()
    mesh, cage = build_scene(args.cage)
    subdivide(mesh, args.subdivide)
    rest = cage_positions(cage)
    print(f"gargoyle: {len(mesh.data.vertices)} vertices, cage {args.cage}: {len(rest)} vertices")

    render(OUT / "blender_rest.png")
    unbound_size = saved_size(OUT / "blender_demo_unbound.blend")
    no_deformer_frame = frame_time(cage, rest, args.frames)

    start = time.perf_counter()
    with bpy.context.temp_override(active_object=cage, object=cage, selected_objects=[mesh, cage]):
        assert bpy.ops.object.lbc_bind(cells=args.cells) == {"FINISHED"}
    lbc_bind = time.perf_counter() - start
    lbc = mesh.modifiers[deformer.MODIFIER_NAME]
    print(f"LBC: bound in {lbc_bind:.1f} s, K = {mesh.lbc.slots} slots, {mesh.lbc.mean_influences:.1f} influences "
          f"per vertex on average, {mesh.lbc.outside} vertices outside the cage")

    mesh_deform = mesh.modifiers.new("Mesh Deform", "MESH_DEFORM")
    mesh_deform.object = cage
    mesh_deform.precision = args.precision
    start = time.perf_counter()
    toggle_mesh_deform_binding(mesh, mesh_deform)
    md_bind = time.perf_counter() - start
    print(f"Mesh Deform: bound in {md_bind:.1f} s at precision {args.precision}")

    # Each deformer alone, on the same rest mesh and the same cage poses.
    figures = {}
    for name, active, other in (("LBC", lbc, mesh_deform), ("Mesh Deform", mesh_deform, lbc)):
        other.show_viewport = other.show_render = False
        active.show_viewport = active.show_render = True
        figures[name] = (frame_time(cage, rest, args.frames), moved_by_one_cage_vertex(mesh, cage, rest))
        set_cage_positions(cage, posed(rest))
        render(OUT / f"blender_{'lbc' if name == 'LBC' else 'meshdeform'}.png")
        set_cage_positions(cage, rest)

    # What each binding adds to the saved scene.
    mesh_deform.show_viewport = mesh_deform.show_render = False
    lbc.show_viewport = lbc.show_render = True
    both_size = saved_size(OUT / "blender_demo_both.blend")
    toggle_mesh_deform_binding(mesh, mesh_deform)  # unbind
    lbc_size = saved_size(OUT / "blender_demo_lbc_only.blend")
    toggle_mesh_deform_binding(mesh, mesh_deform)  # bound again, hidden, for comparison in the saved scene

    # The weights of one cage vertex (the top one), painted as in the paper's Fig. 7.
    top = int(np.argmax(rest[:, 1]))
    influence.show(mesh, top)
    bpy.context.scene.display.shading.color_type = "VERTEX"
    bpy.data.objects["Cage Wireframe"].hide_render = True
    render(OUT / "blender_influence.png")
    influence.hide(mesh)
    bpy.context.scene.display.shading.color_type = "MATERIAL"
    bpy.data.objects["Cage Wireframe"].hide_render = False

    set_cage_positions(cage, posed(rest))
    bpy.ops.wm.save_as_mainfile(filepath=str(OUT / "blender_demo.blend"))

    print()
    print(f"{len(mesh.data.vertices)} mesh vertices, {len(rest)} cage vertices{'':6}{'LBC':>12}{'Mesh Deform':>14}")
    print(f"{'bind (s)':48}{lbc_bind:12.2f}{md_bind:14.2f}")
    print(f"{'deform (ms/frame, depsgraph update)':48}{figures['LBC'][0]:12.2f}{figures['Mesh Deform'][0]:14.2f}"
          f"   (no deformer: {no_deformer_frame:.2f})")
    print(f"{'binding data in the .blend (MB)':48}{(lbc_size - unbound_size) / 1e6:12.2f}"
          f"{(both_size - lbc_size) / 1e6:14.2f}   (scene without: {unbound_size / 1e6:.2f})")
    print(f"{'mesh vertices moved by one cage vertex (mean)':48}{figures['LBC'][1]:12.0f}"
          f"{figures['Mesh Deform'][1]:14.0f}")
    print(f"\nwrote {OUT / 'blender_demo.blend'} (posed; LBC on, Mesh Deform bound but off) and out/blender_*.png")


def positions(mesh):
    values = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", values)
    return values.reshape(-1, 3).astype(np.float64)


def evaluated_positions(obj):
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = evaluated.to_mesh()
    try:
        return positions(mesh)
    finally:
        evaluated.to_mesh_clear()


if __name__ == "__main__":
    main()
    sys.stdout.flush()
    # The bpy 4.5.4 module can deadlock in a static destructor of its sound code at exit; everything is written.
    os._exit(0)
