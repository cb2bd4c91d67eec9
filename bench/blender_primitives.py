"""Blender's own primitives as cages: does each mesh at the default cells, and how long does it take?

    .venv/bin/python bench/blender_primitives.py [--baseline REV] [--cells N] [--applied]

The cages are made by bpy as an artist would: the Cube subdivided 1 to 15 times (Subdivide, grid fill), the
Cylinder with 8 to 64 sides and 0 to 8 loop cuts (n-gon and triangle-fan caps), UV and ico spheres, tori and cones.
With ``--applied`` each is first rotated, scaled unevenly and moved (seeded, a different pose per cage, up to 100 units
away) and Apply > All Transforms is run, so that its float32 positions carry Blender's rounding, as an artist's
posed cage does. Each is meshed by ``lbc_core.meshing.mesh_domain`` in a process of its own code: the current tree, then (with
``--baseline``) the revision REV exported by ``git archive``, one after the other on the same machine. Prints one
line per cage and code (seconds, cells or the refusal), then the refusals and total seconds of each.
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def cases(applied=False):
    """(name, vertices (V, 3) float array, faces list of index lists) for every primitive; ``applied``: each posed
    and its transforms applied first."""
    import bpy  # first: bmesh is importable only once bpy is
    import bmesh
    import numpy as np

    rng = np.random.default_rng(0)

    def taken(obj, cuts=0, only_vertical=False):
        if cuts:
            bm = bmesh.new()
            bm.from_mesh(obj.data)
            edges = [e for e in bm.edges if not only_vertical or abs(e.verts[0].co.z - e.verts[1].co.z) > 1e-6]
            bmesh.ops.subdivide_edges(bm, edges=edges, cuts=cuts, use_grid_fill=True)
            bm.to_mesh(obj.data)
            bm.free()
        if applied:
            obj.rotation_euler = rng.uniform(0.0, 2.0 * np.pi, 3)
            obj.scale = rng.uniform(0.3, 3.0, 3)
            obj.location = rng.uniform(-100.0, 100.0, 3)
            bpy.context.view_layer.update()
            with bpy.context.temp_override(selected_editable_objects=[obj], active_object=obj, object=obj):
                bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
        vertices = np.array([v.co[:] for v in obj.data.vertices])
        faces = [list(p.vertices) for p in obj.data.polygons]
        bpy.data.objects.remove(obj)
        return vertices, faces

    made = []
    for cuts in (1, 2, 3, 4, 6, 8, 9, 11, 13, 15):
        bpy.ops.mesh.primitive_cube_add(size=2)
        made.append((f"cube, {cuts} cuts", *taken(bpy.context.object, cuts)))
    for sides in (8, 16, 32, 64):
        for cuts in (0, 2, 4, 8):
            for fill in ("NGON", "TRIFAN"):
                bpy.ops.mesh.primitive_cylinder_add(vertices=sides, depth=2, end_fill_type=fill)
                made.append((f"cylinder, {sides} sides, {cuts} loop cuts, {fill.lower()} caps",
                             *taken(bpy.context.object, cuts, only_vertical=True)))
    for segments, rings in ((8, 4), (16, 8), (32, 16), (48, 24), (64, 32)):
        bpy.ops.mesh.primitive_uv_sphere_add(segments=segments, ring_count=rings)
        made.append((f"UV sphere {segments} × {rings}", *taken(bpy.context.object)))
    for level in (1, 2, 3, 4):
        bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=level)
        made.append((f"ico sphere, {level} subdivisions", *taken(bpy.context.object)))
    for major, minor in ((12, 6), (24, 8), (48, 12)):
        bpy.ops.mesh.primitive_torus_add(major_segments=major, minor_segments=minor)
        made.append((f"torus {major} × {minor}", *taken(bpy.context.object)))
    for sides in (8, 32, 64):
        for fill in ("NGON", "TRIFAN"):
            bpy.ops.mesh.primitive_cone_add(vertices=sides, end_fill_type=fill)
            made.append((f"cone, {sides} sides, {fill.lower()} cap", *taken(bpy.context.object)))
    return made


def measure(cells, applied):
    """Mesh every primitive with the lbc_core first on sys.path; print a line each and the totals."""
    from lbc_core import meshing
    from lbc_core.cage.make import make_cage
    from lbc_core.errors import CageError

    refused, total = 0, 0.0
    for name, vertices, faces in cases(applied):
        start = time.perf_counter()
        try:
            outcome = f"{len(meshing.mesh_domain(make_cage(vertices, faces), cells=cells).cells)} cells"
        except CageError as error:
            refused += 1
            outcome = f"refused: {str(error)[:120]}"
        seconds = time.perf_counter() - start
        total += seconds
        print(f"  {name} ({len(vertices)} vertices): {seconds:.2f} s, {outcome}", flush=True)
    print(f"  refused {refused}; {total:.1f} s in all; load average {os.getloadavg()[0]:.1f}", flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", help="a git revision to measure after the current tree")
    parser.add_argument("--cells", type=int, default=8000)
    parser.add_argument("--applied", action="store_true", help="pose each cage and apply its transforms first")
    parser.add_argument("--measure", help=argparse.SUPPRESS)  # the tree whose lbc_core one child process measures
    args = parser.parse_args(argv)
    if args.measure:
        sys.path.insert(0, args.measure)
        measure(args.cells, args.applied)
        os._exit(0)  # bpy 4.5 may hang at exit
    trees = [("current tree", str(ROOT))]
    with tempfile.TemporaryDirectory() as exported:
        if args.baseline:
            archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.baseline, "lbc_core"], check=True,
                                     capture_output=True).stdout
            subprocess.run(["tar", "-x", "-C", exported], input=archive, check=True)
            trees.append((args.baseline, exported))
        for label, tree in trees:
            print(f"{label}, {args.cells} cells{', posed and applied' if args.applied else ''}:", flush=True)
            subprocess.run([sys.executable, __file__, "--measure", tree, "--cells", str(args.cells)]
                           + ["--applied"] * args.applied, check=True)


if __name__ == "__main__":
    main()
