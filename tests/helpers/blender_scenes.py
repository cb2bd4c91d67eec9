"""Scenes and helpers the Blender add-on tests share (headless, with the bpy module).

The test_addon_* modules import from here; the bound gargoyle fixtures built from these are in conftest.py.
"""

from pathlib import Path

import bpy  # noqa: I001  (first: importing bpy makes bmesh importable)
import bmesh
import numpy as np
from mathutils import Matrix

import lbc_addon
from lbc_core.io import read_mesh

ROOT = Path(__file__).resolve().parents[2]
GARGOYLE = ROOT / "tests" / "data" / "cages-3d" / "gargoyle"
CELLS = 2000  # small domain meshes keep each bind at a few seconds

# The mesh and the cage get different object transforms, with their data moved so that they meet in world space:
# the bind and the deformer must work in the mesh's local space (Object Info in relative mode).
MESH_MATRIX = Matrix.LocRotScale((0.3, -0.2, 0.1), Matrix.Rotation(0.4, 3, "Z").to_quaternion(), (1.5, 1.5, 1.5))
CAGE_MATRIX = Matrix.LocRotScale((-0.5, 0.25, 0.0), Matrix.Rotation(-0.3, 3, "X").to_quaternion(), (0.8, 1.0, 1.2))


def register_addon():
    """Register the add-on once for the session (registration survives factory resets)."""
    if not hasattr(bpy.types.Object, "lbc"):
        lbc_addon.register()


def reset():
    """An empty scene."""
    register_addon()
    bpy.ops.wm.read_factory_settings(use_empty=True)


def undo_context():
    """A context with the window and 3D view ed.undo_push and ed.undo need (the bpy module has one window)."""
    window = bpy.context.window_manager.windows[0]
    area = next(area for area in window.screen.areas if area.type == "VIEW_3D")
    return bpy.context.temp_override(window=window, screen=window.screen, area=area)


def delete_with_x(obj):
    """What X in the 3D view does: bpy.ops.object.delete on the selection."""
    with bpy.context.temp_override(selected_objects=[obj], active_object=obj, object=obj):
        assert bpy.ops.object.delete() == {"FINISHED"}


def gargoyle_alone(path, link):
    """A new empty file with only the bound 'Gargoyle' of the .blend at ``path`` appended (or linked) into its scene:
    its cage comes along indirectly, in no collection. Returns the mesh object."""
    bpy.ops.wm.read_homefile(use_empty=True)
    with bpy.data.libraries.load(str(path), link=link) as (_, target):
        target.objects = ["Gargoyle"]
    mesh = target.objects[0]
    bpy.context.scene.collection.objects.link(mesh)
    return mesh


def mesh_object(name, vertices, faces, matrix=Matrix.Identity(4), edges=()):
    """A new mesh object linked to the scene, with ``vertices`` given in world space."""
    vertices = np.asarray(vertices, dtype=float)
    local = np.array(matrix.inverted(), dtype=float)
    vertices = vertices @ local[:3, :3].T + local[:3, 3]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(vertices.tolist(), [list(e) for e in edges], [[int(i) for i in f] for f in faces])
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    obj.matrix_world = matrix
    bpy.context.scene.collection.objects.link(obj)
    return obj


def gargoyle_scene(level="L10"):
    """The gargoyle (2674 vertices) and one of its nested cages; returns (mesh, cage)."""
    reset()
    vertices, faces = read_mesh(GARGOYLE / "mesh.off")
    cage_vertices, cage_faces = read_mesh(GARGOYLE / f"cage_{level}.obj")
    mesh = mesh_object("Gargoyle", vertices, faces, MESH_MATRIX)
    cage = mesh_object("Cage", cage_vertices, cage_faces, CAGE_MATRIX)
    return mesh, cage


def sphere_in_box_scene():
    """An ico sphere (42 vertices) inside a box cage (8 vertices); returns (mesh, cage)."""
    reset()
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=0.8)
    mesh = bpy.context.active_object
    mesh.name = "Sphere"
    box = np.array([[x, y, z] for x in (-1.2, 1.2) for y in (-1.1, 1.3) for z in (-1.0, 1.4)])
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    cage = mesh_object("Box", box, faces, CAGE_MATRIX)
    return mesh, cage


def bind(mesh, cage, **options):
    """Bind through the operator, as a user would: the meshes selected, the cage active."""
    with bpy.context.temp_override(active_object=cage, object=cage, selected_objects=[mesh, cage]):
        return bpy.ops.object.lbc_bind(**options)


def positions(mesh):
    """A ``bpy.types.Mesh``'s vertex positions, (m, 3) float64."""
    values = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", values)
    return values.reshape(-1, 3).astype(np.float64)


def evaluated_positions(obj):
    """Vertex positions after the modifiers (local space), read through the depsgraph."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        return positions(mesh)
    finally:
        evaluated.to_mesh_clear()


def diagonal(obj):
    """Bounding-box diagonal of an object's mesh, local space."""
    points = positions(obj.data)
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def _attribute_bytes(attribute):
    """An attribute's values as raw bytes, for bit-for-bit comparisons."""
    field = {"FLOAT_VECTOR": "vector", "FLOAT_COLOR": "color", "BYTE_COLOR": "color", "FLOAT2": "vector",
             "INT32_2D": "value", "QUATERNION": "value", "FLOAT4X4": "value", "STRING": None}.get(attribute.data_type,
                                                                                                   "value")
    if field is None or len(attribute.data) == 0:
        return b""
    width = {"FLOAT_VECTOR": 3, "FLOAT_COLOR": 4, "BYTE_COLOR": 4, "FLOAT2": 2, "INT32_2D": 2, "QUATERNION": 4,
             "FLOAT4X4": 16}.get(attribute.data_type, 1)
    dtype = {"INT": np.int32, "INT8": np.int8, "BOOLEAN": bool, "INT32_2D": np.int32}.get(attribute.data_type,
                                                                                         np.float32)
    values = np.empty(len(attribute.data) * width, dtype=dtype)
    attribute.data.foreach_get(field, values)
    return values.tobytes()


def mesh_state(obj):
    """Everything "bit for bit" covers: the mesh data with every attribute, vertex groups, the modifier stack, the
    object's custom properties, the node groups of the file."""
    mesh = obj.data
    return {
        "attributes": sorted(
            (a.name, a.domain, a.data_type, _attribute_bytes(a)) for a in mesh.attributes
        ),
        "active_color": mesh.color_attributes.active_color_name,
        "counts": (len(mesh.vertices), len(mesh.edges), len(mesh.polygons), len(mesh.loops)),
        "vertex_groups": [group.name for group in obj.vertex_groups],
        "modifiers": [(m.name, m.type, m.show_viewport, m.show_render) for m in obj.modifiers],
        "active_modifier": obj.modifiers.active.name if obj.modifiers.active else None,
        "object_properties": sorted(obj.keys()),
        "mesh_properties": sorted(mesh.keys()),
        "node_groups": sorted(group.name for group in bpy.data.node_groups),
    }


def suzanne_in_box_scene(cuts=9):
    """Suzanne subdivided (``cuts`` 9: 48,612 vertices) in a 56-vertex box cage (a cube subdivided with 2 cuts).

    The box is Suzanne's bounding box grown by 10 %; returns (mesh, cage).
    """
    reset()
    bpy.ops.mesh.primitive_monkey_add()
    mesh = bpy.context.active_object
    mesh.name = "Suzanne"
    _subdivide(mesh.data, cuts)
    points = positions(mesh.data)
    low, high = points.min(axis=0), points.max(axis=0)
    center, half = (low + high) / 2, 0.55 * (high - low)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    cage = mesh_object("Box", center + corners * half, faces)
    _subdivide(cage.data, 2)
    return mesh, cage


def _subdivide(mesh, cuts):
    """Cut every edge of a ``bpy.types.Mesh`` ``cuts`` times, filling faces with a grid."""
    edit = bmesh.new()
    edit.from_mesh(mesh)
    bmesh.ops.subdivide_edges(edit, edges=edit.edges[:], cuts=cuts, use_grid_fill=True)
    edit.to_mesh(mesh)
    edit.free()
    mesh.update()


def cube_scene(cuts=2, matrix=MESH_MATRIX):
    """A cube subdivided with ``cuts`` (2: 56 vertices) named 'Cube', with its own transform; returns it."""
    reset()
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    cube.name = "Cube"
    _subdivide(cube.data, cuts)
    cube.matrix_world = matrix
    return cube
