"""Per-frame cost of the LBC deformer against Blender's Mesh Deform on the same mesh, cage and poses.

    PYTHONPATH=. .venv/bin/python bench/blender_deform.py [--frames 31] [--scenes suzanne,gargoyle] [--slots 0,12]

Headless, with the bpy module, everything in one process. Each variant is its own copy of the mesh (its own mesh
data, so its own attributes) and is linked into the scene only while it is measured, so every timed update evaluates
one deformer. Frames are interleaved: in each round every variant gets the same new pose of the cage, in a rotating
order, and the time of the depsgraph update that follows the cage edit (``evaluated_depsgraph_get``, the add-on's
depsgraph handler included) is recorded. Printed: the median over the rounds, the lower and upper quartiles, and the
load average before and after.

Scenes: Suzanne subdivided to 48,612 vertices in a 56-vertex box cage, and the demo's gargoyle (two Catmull-Clark
levels: 64,130 vertices) in its 67-vertex cage L10. Variants: no deformer, Mesh Deform (precision 5), LBC as bound,
and LBC with its slots capped (``--slots``; see :func:`lbc_addon.storage.cap_slots`) to see what K costs.
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import bpy  # noqa: E402

from blender_scenes import gargoyle_scene, positions, register_addon, suzanne_in_box_scene  # noqa: E402
from lbc_addon import api, deformer, storage  # noqa: E402


def gargoyle_subdivided():
    mesh, cage = gargoyle_scene("L10")
    subsurf = mesh.modifiers.new("Subdivision", "SUBSURF")
    subsurf.levels = 2
    with bpy.context.temp_override(object=mesh, active_object=mesh):
        bpy.ops.object.modifier_apply(modifier=subsurf.name)
    return mesh, cage


SCENES = {"suzanne": suzanne_in_box_scene, "gargoyle": gargoyle_subdivided}


def pose(rest, phase):
    """A smooth, non-affine pose of the cage: a twist about z and a bulge that vary with ``phase``."""
    center = rest.mean(axis=0)
    extent = np.ptp(rest, axis=0)
    relative = rest - center
    height = relative[:, 2] / extent[2]
    angle = 0.4 * np.sin(phase) * height
    cos, sin = np.cos(angle), np.sin(angle)
    posed = relative.copy()
    posed[:, 0] = cos * relative[:, 0] - sin * relative[:, 1]
    posed[:, 1] = sin * relative[:, 0] + cos * relative[:, 1]
    posed *= 1 + 0.15 * np.cos(phase) * (0.5 - np.abs(height))[:, None]
    return center + posed


def set_cage(cage, points):
    cage.data.vertices.foreach_set("co", np.asarray(points, dtype=np.float32).ravel())
    cage.data.update()


def copy_object(mesh, name):
    """An unlinked copy of ``mesh`` with its own mesh data (attributes included) and no LBC state."""
    copy = mesh.copy()
    copy.data = mesh.data.copy()
    copy.name = name
    if copy.is_property_set("lbc"):
        copy.property_unset("lbc")
    copy.modifiers.clear()
    return copy


def lbc_variant(bound, cage, name, slots):
    """A copy of the bound mesh deformed by LBC with at most ``slots`` slots (0: as bound)."""
    obj = copy_object(bound, name)
    index, weight = storage.read(obj.data)
    rest = storage.rest_offsets(index, weight, cage_rest_local(cage, obj))
    if slots:
        index, weight = storage.cap_slots(index, weight, cage_rest_local(cage, obj), rest, slots)
    storage.remove(obj.data)
    storage.write(obj.data, index, weight, storage.rest_offsets(index, weight, cage_rest_local(cage, obj)))
    deformer.attach(obj, cage, index.shape[1], len(cage.data.vertices))
    return obj


def cage_rest_local(cage, obj):
    matrix = np.array(obj.matrix_world.inverted() @ cage.matrix_world)
    return positions(cage.data) @ matrix[:3, :3].T + matrix[:3, 3]


def mesh_deform_variant(mesh, cage, name, precision):
    obj = copy_object(mesh, name)
    bpy.context.scene.collection.objects.link(obj)
    modifier = obj.modifiers.new("Mesh Deform", "MESH_DEFORM")
    modifier.object = cage
    modifier.precision = precision
    start = time.perf_counter()
    with bpy.context.temp_override(object=obj, active_object=obj):
        bpy.ops.object.meshdeform_bind(modifier=modifier.name)
    print(f"  Mesh Deform bound in {time.perf_counter() - start:.1f} s (precision {precision})")
    bpy.context.scene.collection.objects.unlink(obj)
    return obj


def deformation_error(obj, reference, cage, rest, scale):
    """Largest distance between ``obj``'s and ``reference``'s evaluated vertices over three poses, / ``scale``."""
    worst = 0.0
    for phase in (0.7, 2.1, 4.0):
        set_cage(cage, pose(rest, phase))
        worst = max(worst, float(np.abs(evaluated(obj) - evaluated(reference)).max()))
    set_cage(cage, rest)
    return worst / scale


def evaluated(obj):
    collection = bpy.context.scene.collection
    linked = obj.name not in collection.objects
    if linked:
        collection.objects.link(obj)
    evaluated_obj = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = evaluated_obj.to_mesh()
    try:
        return positions(mesh)
    finally:
        evaluated_obj.to_mesh_clear()
        if linked:
            collection.objects.unlink(obj)


def measure(variants, cage, rest, rounds):
    """Milliseconds of the depsgraph update after a cage edit, per variant: {name: array (rounds,)}."""
    collection = bpy.context.scene.collection
    times = {name: [] for name in variants}
    names = list(variants)
    for number in range(rounds):
        shift = number % len(names)
        for name in names[shift:] + names[:shift]:
            obj = variants[name]
            collection.objects.link(obj)
            set_cage(cage, pose(rest, 0.37 * number))
            bpy.context.evaluated_depsgraph_get()  # untimed: relations rebuilt after linking
            set_cage(cage, pose(rest, 0.37 * number + 0.2))
            start = time.perf_counter()
            bpy.context.evaluated_depsgraph_get()
            times[name].append(1000 * (time.perf_counter() - start))
            collection.objects.unlink(obj)
    set_cage(cage, rest)
    return {name: np.array(values) for name, values in times.items()}


def run_scene(name, slot_caps, rounds, precision):
    mesh, cage = SCENES[name]()
    rest = positions(cage.data)
    print(f"\n{name}: {len(mesh.data.vertices)} vertices, cage {len(rest)} vertices")
    start = time.perf_counter()
    summary = api.bind(mesh, cage)
    print(f"  LBC bound in {time.perf_counter() - start:.1f} s: K = {summary['slots']}, "
          f"{summary['mean_influences']:.1f} influences per vertex on average, {summary['outside']} outside")
    scale = float(np.linalg.norm(np.ptp(positions(mesh.data), axis=0)))
    bpy.context.scene.collection.objects.unlink(mesh)
    variants = {"no deformer": copy_object(mesh, "plain")}
    variants["Mesh Deform"] = mesh_deform_variant(mesh, cage, "meshdeform", precision)
    variants[f"LBC K={summary['slots']}"] = mesh
    for cap in slot_caps:
        if cap and cap < summary["slots"]:
            variants[f"LBC K={cap}"] = lbc_variant(mesh, cage, f"lbc{cap}", cap)
            error = deformation_error(variants[f"LBC K={cap}"], mesh, cage, rest, scale)
            print(f"  LBC K={cap}: largest difference to K={summary['slots']} over three poses {error:.2e} of the "
                  "mesh's diagonal")
    load = os.getloadavg()[0]
    times = measure(variants, cage, rest, rounds)
    print(f"  {rounds} interleaved frames each, load average {load:.2f} before, {os.getloadavg()[0]:.2f} after")
    print(f"  {'variant':16}{'median ms':>10}{'quartiles':>16}")
    for variant, values in times.items():
        low, mid, high = np.percentile(values, [25, 50, 75])
        print(f"  {variant:16}{mid:10.2f}{f'{low:.2f}-{high:.2f}':>16}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=31, help="timed frames per variant (interleaved rounds)")
    parser.add_argument("--scenes", default="suzanne,gargoyle")
    parser.add_argument("--slots", default="", help="comma-separated slot caps to measure besides the bound K")
    parser.add_argument("--precision", type=int, default=5, help="Mesh Deform precision")
    args = parser.parse_args(argv)
    register_addon()
    caps = [int(value) for value in args.slots.split(",") if value]
    for name in args.scenes.split(","):
        run_scene(name, caps, args.frames, args.precision)


if __name__ == "__main__":
    main()
    sys.stdout.flush()
    os._exit(0)  # bpy 4.5.4 can deadlock in its teardown at exit (see tests/conftest.py)
