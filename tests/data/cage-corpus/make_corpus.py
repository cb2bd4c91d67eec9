"""Make cage-corpus.npz: Blender's primitives and artist-style cages, exactly as bpy 4.5 makes them.

Run from the repository root:  python tests/data/cage-corpus/make_corpus.py
Each cage is stored as ``<name>/vertices`` (n, 3) float64 and ``<name>/faces`` (flattened corner indices) with
``<name>/sizes`` (corners per face), so n-gons stay n-gons.
"""

from pathlib import Path

import bpy  # first: bpy makes bmesh and mathutils importable
import bmesh
import numpy as np
from mathutils import Matrix

OUT = Path(__file__).with_name("cage-corpus.npz")


def grab():
    """Vertices and faces of the active object's mesh, in world space, and delete the object."""
    obj = bpy.context.active_object
    mesh = obj.data
    matrix = np.array(obj.matrix_world)
    vertices = np.array([v.co[:] for v in mesh.vertices], dtype=float)
    vertices = vertices @ matrix[:3, :3].T + matrix[:3, 3]
    faces = [list(p.vertices) for p in mesh.polygons]
    bpy.data.objects.remove(obj)
    return vertices, faces


def with_bmesh(edit):
    """Apply ``edit(bm)`` to the active object's mesh."""
    obj = bpy.context.active_object
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    edit(bm)
    bm.to_mesh(obj.data)
    bm.free()


def primitives():
    ops = bpy.ops.mesh
    yield "cube", lambda: ops.primitive_cube_add()
    for sides in (3, 5, 8, 16, 32, 64):
        yield f"cylinder-{sides}-ngon", lambda s=sides: ops.primitive_cylinder_add(vertices=s)
        yield f"cylinder-{sides}-fan", lambda s=sides: ops.primitive_cylinder_add(vertices=s, end_fill_type="TRIFAN")
        yield f"cone-{sides}-ngon", lambda s=sides: ops.primitive_cone_add(vertices=s)
        yield f"cone-{sides}-fan", lambda s=sides: ops.primitive_cone_add(vertices=s, end_fill_type="TRIFAN")
    yield "uv-sphere", lambda: ops.primitive_uv_sphere_add(segments=16, ring_count=8)
    yield "ico-sphere", lambda: ops.primitive_ico_sphere_add(subdivisions=2)
    yield "torus", lambda: ops.primitive_torus_add(major_segments=24, minor_segments=8)
    yield "monkey-hull", monkey_hull


def monkey_hull():
    """Suzanne's convex hull: Suzanne itself is open (eyes apart, holes), a cage made from her is her hull."""
    bpy.ops.mesh.primitive_monkey_add()
    def edit(bm):
        hull = bmesh.ops.convex_hull(bm, input=bm.verts[:])
        bmesh.ops.delete(bm, geom=hull["geom_interior"] + hull["geom_unused"], context="VERTS")
        bmesh.ops.delete(bm, geom=[f for f in bm.faces if f not in set(hull["geom"])], context="FACES")
    with_bmesh(edit)


def rings(sides, count):
    """A prism of ``sides`` sides cut into ``count`` rings, n-gon caps."""
    def make():
        bpy.ops.mesh.primitive_cylinder_add(vertices=sides, depth=2.0)
        if count > 1:
            def cut(bm):
                side = [e for e in bm.edges if abs(e.verts[0].co.z - e.verts[1].co.z) > 1e-6]
                bmesh.ops.subdivide_edges(bm, edges=side, cuts=count - 1, use_grid_fill=False)
            with_bmesh(cut)
    return make


def grid_box():
    bpy.ops.mesh.primitive_cube_add()
    with_bmesh(lambda bm: bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=2, use_grid_fill=True))


def extrude(bm, face, offset=None, keep=False):
    """Extrude one face (deleted unless ``keep``) along ``offset``; returns the new cap face."""
    made = bmesh.ops.extrude_face_region(bm, geom=[face])
    cap = [g for g in made["geom"] if isinstance(g, bmesh.types.BMFace)][0]
    if not keep:
        bmesh.ops.delete(bm, geom=[face], context="FACES_ONLY")
    if offset is not None:
        bmesh.ops.translate(bm, verts=cap.verts[:], vec=offset)
    return cap


def limbs():
    """A box with two arms and a leg extruded from it, as an artist blocks out a figure."""
    bpy.ops.mesh.primitive_cube_add()
    def edit(bm):
        bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=2, use_grid_fill=True)
        bm.faces.ensure_lookup_table()
        for axis, sign, length in ((0, 1, 1.5), (0, -1, 1.5), (2, -1, 1.0)):
            centre = [f for f in bm.faces if abs(f.calc_center_median()[axis] - sign) < 1e-6
                      and sum(abs(c) for k, c in enumerate(f.calc_center_median()) if k != axis) < 1e-6][0]
            offset = [0.0, 0.0, 0.0]
            offset[axis] = sign * length / 2
            cap = extrude(bm, centre, offset)
            extrude(bm, cap, offset)
    with_bmesh(edit)


def bent_tube():
    """A 12-sided tube along a quarter circle: 8 segments, n-gon caps."""
    bpy.ops.mesh.primitive_circle_add(vertices=12, radius=0.25, fill_type="NGON", rotation=(0.0, np.pi / 2, 0.0),
                                      location=(0.0, 2.0, 0.0))
    bpy.ops.object.transform_apply(location=True, rotation=True)
    def edit(bm):
        bm.faces.ensure_lookup_table()
        face = bm.faces[0]
        for step in range(8):
            face = extrude(bm, face, keep=step == 0)
            bmesh.ops.rotate(bm, verts=face.verts[:], cent=(0.0, 0.0, 0.0),
                             matrix=Matrix.Rotation(np.pi / 16, 3, "Z"))
        bmesh.ops.recalc_face_normals(bm, faces=bm.faces[:])
    with_bmesh(edit)


def thin_plate():
    bpy.ops.mesh.primitive_cube_add(scale=(1.0, 0.6, 0.02))
    bpy.ops.object.transform_apply(scale=True)


def near_coplanar_quads():
    """A subdivided box whose top face vertices are nudged up and down by 1e-4 (non-planar quads)."""
    grid_box()
    def edit(bm):
        rng = np.random.default_rng(1)
        for v in bm.verts:
            if abs(v.co.z - 1.0) < 1e-6:
                v.co.z += 1e-4 * rng.uniform(-1.0, 1.0)
    with_bmesh(edit)


def artist():
    yield "grid-box", grid_box
    yield "limbs", limbs
    yield "bent-tube", bent_tube
    yield "thin-plate", thin_plate
    yield "near-coplanar-quads", near_coplanar_quads
    for sides, count in ((8, 2), (8, 5), (8, 9), (16, 3), (32, 2)):
        yield f"prism-{sides}-rings-{count}", rings(sides, count)


def main():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    arrays = {}
    for name, make in [*primitives(), *artist()]:
        make()
        vertices, faces = grab()
        arrays[f"{name}/vertices"] = vertices
        arrays[f"{name}/faces"] = np.array([c for f in faces for c in f], dtype=np.int64)
        arrays[f"{name}/sizes"] = np.array([len(f) for f in faces], dtype=np.int64)
        print(f"{name}: {len(vertices)} vertices, {len(faces)} faces, largest {max(len(f) for f in faces)}-gon")
    np.savez_compressed(OUT, **arrays)


if __name__ == "__main__":
    main()
