"""The K-slot weight cache in mesh attributes."""

import numpy as np
import pytest
import scipy.sparse as sp

from lbc_addon import storage
from helpers.blender_scenes import mesh_state, sphere_in_box_scene

pytestmark = pytest.mark.blender


def test_slot_arrays_pad_rows_and_map_columns_to_cage_vertices():
    weights = sp.csr_matrix(np.array([[0.5, 0.0, 0.5], [0.2, 0.3, 0.5], [0.0, 1.0, 0.0]]))
    index, weight = storage.slot_arrays(weights, np.array([7, 3, 9]))
    assert index.shape == weight.shape == (3, 3)
    assert index.dtype == np.int32 and weight.dtype == np.float32
    assert index[0].tolist() == [7, 9, 0] and weight[0].tolist() == [0.5, 0.5, 0.0]
    assert index[2, 0] == 3 and weight[2].tolist() == [1.0, 0.0, 0.0]


def test_rest_offsets_are_the_weighted_cage_positions():
    cage = np.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0]])
    index = np.array([[0, 1], [1, 2]], dtype=np.int32)
    weight = np.array([[0.25, 0.75], [0.5, 0.5]], dtype=np.float32)
    assert np.allclose(storage.rest_offsets(index, weight, cage), [[0.75, 0, 0], [0.5, 1.0, 0]])


def test_write_read_remove_round_trip_leaves_the_mesh_as_it_was():
    mesh, _ = sphere_in_box_scene()
    before = mesh_state(mesh)
    count = len(mesh.data.vertices)
    rng = np.random.default_rng(0)
    index = rng.integers(0, 8, size=(count, 4)).astype(np.int32)
    weight = rng.random((count, 4)).astype(np.float32)
    storage.write(mesh.data, index, weight, rng.random((count, 3)))
    assert storage.slot_count(mesh.data) == 4
    read_index, read_weight = storage.read(mesh.data)
    assert np.array_equal(read_index, index) and np.array_equal(read_weight, weight)
    assert all(a.name.startswith(".") for a in mesh.data.attributes if "lbc" in a.name)
    storage.remove(mesh.data)
    assert mesh_state(mesh) == before


def test_memory_counts_the_bytes_of_the_attributes_written():
    mesh, _ = sphere_in_box_scene()
    count = len(mesh.data.vertices)
    before = {attribute.name for attribute in mesh.data.attributes}
    storage.write(mesh.data, np.zeros((count, 5), np.int32), np.zeros((count, 5), np.float32), np.zeros((count, 3)))
    item_bytes = {"INT": 4, "FLOAT": 4, "FLOAT_VECTOR": 12}
    written = sum(len(attribute.data) * item_bytes[attribute.data_type] for attribute in mesh.data.attributes
                  if attribute.name not in before)
    assert storage.memory_bytes(count, 5) == written
