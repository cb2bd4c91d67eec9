"""A new user's first cage: Blender's Cylinder as it comes (32 sides, n-gon caps) around a mesh, bound with the
add-on's operator at the default resolution. This cage used to hang the 3D mesher, and one vertex of each
cap used to move the whole cap (its fan's apex)."""

import bpy
import numpy as np
import pytest

from helpers.blender_scenes import bind, evaluated_positions, positions, reset

pytestmark = pytest.mark.blender


def test_blender_cylinder_cage_binds_and_deforms():
    reset()
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6)
    mesh = bpy.context.active_object
    bpy.ops.mesh.primitive_cylinder_add()
    cage = bpy.context.active_object
    assert max(len(p.vertices) for p in cage.data.polygons) == 32  # the n-gon caps, as Blender makes them
    assert bind(mesh, cage) == {"FINISHED"}
    assert mesh.lbc.is_bound
    rest = positions(mesh.data)
    np.testing.assert_allclose(evaluated_positions(mesh), rest, atol=1e-5)
    # Each top rim vertex raised by 0.3 in turn: each moves the sphere about as far (0.010-0.018 on an ico sphere; the
    # cap split into a fan from vertex 5, as it was, that vertex moved it by 0.104 and others by as little as 0).
    moves = []
    for vertex in cage.data.vertices:
        if vertex.co.z > 0:
            vertex.co.z += 0.3
            cage.data.update()
            moves.append(np.abs(evaluated_positions(mesh) - rest).max())
            vertex.co.z -= 0.3
    assert len(moves) == 32 and 0.005 < min(moves) and max(moves) < 3 * min(moves)
    for vertex in cage.data.vertices:  # move the cage up by 0.5: the mesh follows
        vertex.co.z += 0.5
    cage.data.update()
    moved = evaluated_positions(mesh)
    np.testing.assert_allclose(moved, rest + [0.0, 0.0, 0.5], atol=1e-4)
