"""Checks of the shared Blender test scenes themselves."""

import numpy as np
import pytest

from helpers.blender_scenes import GARGOYLE, MESH_MATRIX, gargoyle_scene, mesh_state, positions, sphere_in_box_scene
from lbc_core.io import read_mesh

pytestmark = pytest.mark.blender


def test_gargoyle_scene_has_the_data_files_geometry_in_world_space():
    mesh, cage = gargoyle_scene("L10")
    vertices, _ = read_mesh(GARGOYLE / "mesh.off")
    assert len(mesh.data.vertices) == len(vertices) == 2674
    assert len(cage.data.vertices) == 67
    world = positions(mesh.data) @ np.array(MESH_MATRIX)[:3, :3].T + np.array(MESH_MATRIX)[:3, 3]
    assert np.abs(world - vertices).max() < 1e-5


def test_mesh_state_sees_a_single_changed_value():
    mesh, _ = sphere_in_box_scene()
    before = mesh_state(mesh)
    mesh.data.vertices[7].co.x += 1e-3
    assert mesh_state(mesh) != before
