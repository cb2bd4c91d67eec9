"""Reading Blender meshes: topology fingerprints, flatness, the outline of a flat cage."""

import bpy
import numpy as np
import pytest

from lbc_addon import geometry
from lbc_core import CageError
from blender_scenes import mesh_object, reset


def _grid(name, size=3):
    """A flat size × size vertex grid of quads, vertex (r, c) at index r * size + c."""
    points = [[c, r, 0.0] for r in range(size) for c in range(size)]
    quads = [[r * size + c, r * size + c + 1, (r + 1) * size + c + 1, (r + 1) * size + c]
             for r in range(size - 1) for c in range(size - 1)]
    return mesh_object(name, points, quads)


def test_fingerprint_ignores_positions_and_sees_topology():
    reset()
    grid = _grid("Grid")
    before = geometry.topology_fingerprint(grid.data)
    grid.data.vertices[4].co.z = 1.0
    assert geometry.topology_fingerprint(grid.data) == before
    other = _grid("Other")
    other.data.polygons[0].vertices = (1, 4, 3, 0)  # the same face, its corners rotated
    assert geometry.topology_fingerprint(other.data) != before


def test_flat_frame_finds_the_plane_of_a_tilted_flat_scene():
    rotation = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    square = np.array([[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0]], dtype=float) @ rotation.T + 5.0
    inside = np.array([[1, 1, 0], [0.5, 1.5, 0]], dtype=float) @ rotation.T + 5.0
    origin, axes = geometry.flat_frame(square, inside)
    flat = (square - origin) @ axes.T
    assert np.allclose(np.linalg.norm(flat[1] - flat[0]), 2.0)
    lifted = inside + rotation[:, 2] * 0.01
    assert geometry.flat_frame(square, lifted) is None
    assert geometry.flat_frame(np.vstack([square, square[0] + rotation[:, 2]]), inside) is None


def test_boundary_loop_of_a_filled_grid_walks_its_border():
    reset()
    loop = geometry.boundary_loop(_grid("Grid").data)
    assert len(loop) == 8 and 4 not in loop  # the centre vertex controls nothing
    ring = [0, 1, 2, 5, 8, 7, 6, 3]
    start = ring.index(loop[0])
    walked = ring[start:] + ring[:start]
    assert list(loop) in (walked, [walked[0]] + walked[1:][::-1])


def test_boundary_loop_of_a_wire_polygon_and_of_an_ngon():
    reset()
    wire = mesh_object("Wire", [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [], edges=[(0, 1), (2, 3), (1, 2), (3, 0)])
    assert sorted(geometry.boundary_loop(wire.data)) == [0, 1, 2, 3]
    ngon = mesh_object("Ngon", [[np.cos(a), np.sin(a), 0] for a in np.linspace(0, 6, 7)], [[0, 1, 2, 3, 4, 5, 6]])
    loop = list(geometry.boundary_loop(ngon.data))
    assert loop in ([0, 1, 2, 3, 4, 5, 6], [0, 6, 5, 4, 3, 2, 1])


def test_boundary_loop_refuses_branching_or_several_outlines():
    reset()
    branching = mesh_object("Branch", [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 2, 0]], [],
                            edges=[(0, 1), (1, 2), (2, 3), (3, 0), (2, 4)])
    with pytest.raises(CageError, match="not one closed loop"):
        geometry.boundary_loop(branching.data)
    square = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    two = mesh_object("Two", square + [[x + 3, y, z] for x, y, z in square], [[0, 1, 2, 3], [4, 5, 6, 7]])
    with pytest.raises(CageError, match="several loops"):
        geometry.boundary_loop(two.data)


def test_positions_are_read_in_mesh_space_relative_to_the_cage():
    reset()
    cage = _grid("Cage")
    cage.location = (1.0, 2.0, 3.0)
    mesh = _grid("Mesh")
    mesh.scale = (2.0, 2.0, 2.0)
    bpy.context.view_layer.update()
    matrix = geometry.cage_to_mesh_matrix(cage, mesh)
    local = geometry.to_local(matrix, geometry.vertex_positions(cage.data))
    assert np.allclose(local[0], [0.5, 1.0, 1.5])
