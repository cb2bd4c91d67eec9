"""Reading Blender: topology fingerprints, positions in mesh space, the snapshot of a bind request."""

import hashlib

import bpy
import numpy as np
import pytest

from lbc_addon import geometry
from lbc_addon.options import AddonOptions
from lbc_core import CageError
from helpers.blender_scenes import mesh_object, reset, sphere_in_box_scene

pytestmark = pytest.mark.blender


def _grid(name, size=3):
    """A flat size × size vertex grid of quads, vertex (r, c) at index r * size + c."""
    points = [[c, r, 0.0] for r in range(size) for c in range(size)]
    quads = [[r * size + c, r * size + c + 1, (r + 1) * size + c + 1, (r + 1) * size + c]
             for r in range(size - 1) for c in range(size - 1)]
    return mesh_object(name, points, quads)


def test_fingerprint_ignores_positions_and_winding_and_sees_reordered_vertices():
    reset()
    grid = _grid("Grid")
    before = geometry.topology_fingerprint(grid.data)
    assert before.startswith(geometry.FINGERPRINT_VERSION)
    grid.data.vertices[4].co.z = 1.0
    assert geometry.topology_fingerprint(grid.data) == before
    flipped = _grid("Flipped")
    flipped.data.flip_normals()  # every face's winding reversed, as Blender 5.2's Apply Scale does for a negative scale
    assert geometry.topology_fingerprint(flipped.data) == before
    relabelled = _grid("Relabelled")
    bpy.context.view_layer.objects.active = relabelled
    with bpy.context.temp_override(active_object=relabelled, object=relabelled):
        bpy.ops.object.mode_set(mode="EDIT")
        bpy.ops.mesh.select_all(action="SELECT")
        bpy.ops.mesh.sort_elements(type="REVERSE", elements={"VERT"})
        bpy.ops.object.mode_set(mode="OBJECT")
    assert geometry.topology_fingerprint(relabelled.data) != before


def test_fingerprints_of_the_version_before_still_match():
    """Bindings saved before the fingerprint left the winding out keep theirs: it hashed the corners too."""
    reset()
    grid = _grid("Grid")
    corners = np.empty(len(grid.data.loops), dtype=np.int64)
    grid.data.loops.foreach_get("vertex_index", corners)
    sizes = np.array([len(polygon.vertices) for polygon in grid.data.polygons], dtype=np.int64)
    edges = np.array([edge.vertices[:] for edge in grid.data.edges], dtype=np.int64)
    digest = hashlib.sha256()
    for part in (np.int64(len(grid.data.vertices)), edges, corners, sizes):
        digest.update(part.tobytes())
    assert geometry.topology_fingerprints(grid.data) == {digest.hexdigest()[:16],
                                                         geometry.topology_fingerprint(grid.data)}


def test_snapshot_of_a_flat_grid_cage_is_a_2d_request_on_its_outline():
    reset()
    cage = _grid("Cage", size=4)
    mesh = mesh_object("Mesh", [[1.2, 1.5, 0.0], [2.0, 0.5, 0.0]], [])
    request = geometry.snapshot(mesh, cage, bpy.context.evaluated_depsgraph_get())
    assert request.dimension == 2 and len(request.flat.loop) == 12  # the 4 inner vertices control nothing
    lifted = mesh_object("Lifted", [[1.2, 1.5, 0.5]], [])
    assert geometry.snapshot(lifted, cage, bpy.context.evaluated_depsgraph_get()).dimension == 3
    with pytest.raises(CageError, match="2D binding needs a flat cage"):
        geometry.snapshot(lifted, cage, bpy.context.evaluated_depsgraph_get(), AddonOptions(mode="2D"))


def test_positions_are_read_in_mesh_space_relative_to_the_cage():
    reset()
    cage = _grid("Cage")
    cage.location = (1.0, 2.0, 3.0)
    mesh = _grid("Mesh")
    mesh.scale = (2.0, 2.0, 2.0)
    bpy.context.view_layer.update()
    matrix = geometry.cage_to_mesh_matrix(cage, mesh)
    local = geometry.transform(matrix, geometry.vertex_positions(cage.data))
    assert np.allclose(local[0], [0.5, 1.0, 1.5])


def test_snapshot_refuses_shared_mesh_data_and_non_mesh_cages():
    mesh, cage = sphere_in_box_scene()
    twin = bpy.data.objects.new("Twin", mesh.data)
    bpy.context.scene.collection.objects.link(twin)
    with pytest.raises(CageError, match="shared by 2 objects"):
        geometry.snapshot(mesh, cage, bpy.context.evaluated_depsgraph_get())
    empty = bpy.data.objects.new("Empty", None)
    with pytest.raises(CageError, match="not a mesh"):
        geometry.snapshot(twin, empty, bpy.context.evaluated_depsgraph_get())


def test_snapshot_refuses_a_cage_of_edges_without_faces_and_says_so():
    reset()
    wire = mesh_object("Wire", [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.5]], [], edges=[(0, 1), (1, 2), (2, 0)])
    mesh = mesh_object("Mesh", [[0.5, 0.5, 1.0]], [])
    with pytest.raises(CageError, match="the cage 'Wire' has no faces: a cage is a closed surface"):
        geometry.snapshot(mesh, wire, bpy.context.evaluated_depsgraph_get())


def test_snapshot_names_the_mesh_and_its_nan_vertices_and_a_cage_vertex_at_infinity():
    """A new user's finds: with two meshes selected, a NaN vertex was refused as "1 of the points (7) ..." with no
    mesh named; a cage vertex at infinity (which Blender stores as 3.4e38) asked for a flat cage's outline."""
    mesh, cage = sphere_in_box_scene()
    mesh.data.vertices[7].co = (float("nan"), 0.0, 0.0)
    with pytest.raises(CageError, match=r"'Sphere' has 1 vertex with NaN or infinite coordinates \(7\)"):
        geometry.snapshot(mesh, cage, bpy.context.evaluated_depsgraph_get())
    mesh.data.vertices[7].co = (0.0, 0.0, 0.0)
    cage.data.vertices[2].co = (float("inf"), 0.0, 0.0)
    with pytest.raises(CageError, match=r"cage vertex 2 lies [0-9.]+e\+38 from the cage's middle"):
        geometry.snapshot(mesh, cage, bpy.context.evaluated_depsgraph_get())
