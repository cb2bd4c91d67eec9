"""The K-slot weight cache in mesh attributes."""

import numpy as np
import scipy.sparse as sp

from lbc_addon import storage
from blender_scenes import mesh_state, sphere_in_box_scene


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


def test_memory_is_eight_bytes_per_slot_and_twelve_for_the_rest_offset():
    assert storage.memory_bytes(1000, 16) == 1000 * (16 * 8 + 12)


def test_cap_slots_keeps_the_largest_weights_and_restores_the_constraints():
    rng = np.random.default_rng(1)
    cage = rng.random((12, 3))
    count, slots = 200, 10
    index = np.stack([rng.permutation(12)[:slots] for _ in range(count)]).astype(np.int32)
    weight = rng.random((count, slots)) ** 3
    weight[:, -2:] = 0.0  # padded slots
    weight = (weight / weight.sum(axis=1, keepdims=True)).astype(np.float32)
    reproduced = storage.rest_offsets(index, weight, cage)
    capped_index, capped_weight = storage.cap_slots(index, weight, cage, reproduced, 6)
    assert capped_index.shape == capped_weight.shape == (count, 6)
    assert capped_index.dtype == np.int32 and capped_weight.dtype == np.float32
    largest = np.argsort(-weight, axis=1, kind="stable")[:, :6]
    assert np.array_equal(capped_index, np.take_along_axis(index, largest, axis=1))
    assert capped_weight.min() >= 0
    np.testing.assert_allclose(capped_weight.sum(axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(storage.rest_offsets(capped_index, capped_weight, cage), reproduced, atol=1e-5)
    assert storage.cap_slots(index, weight, cage, reproduced, 10)[1] is weight  # within the cap: unchanged


def test_cap_slots_grows_the_cap_where_the_largest_weights_cannot_reproduce_the_vertex():
    # A vertex at (0.5, 0.4, 0) weighted on a square's corners: its two largest weights (opposite corners, on the
    # diagonal x = y) cannot reproduce it; three (a triangle around it) can.
    cage = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1]])
    index = np.array([[0, 2, 1, 3, 4]], dtype=np.int32)
    weight = np.array([[0.35, 0.25, 0.25, 0.15, 0.0]], dtype=np.float32)
    reproduced = storage.rest_offsets(index, weight, cage)
    capped_index, capped_weight = storage.cap_slots(index, weight, cage, reproduced, 2)
    assert capped_index.shape == (1, 3)
    np.testing.assert_allclose(storage.rest_offsets(capped_index, capped_weight, cage), reproduced, atol=1e-6)
