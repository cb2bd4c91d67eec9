"""The frames: UnitFrame (exact power-of-two scaling, centring, a domain mapped back with its contract kept bitwise)
and MeshingFrame (a thin cage stretched for the mesher, mapped back)."""

import numpy as np
import pytest

from lbc_core.cage.make import make_cage
from lbc_core.kernel.frame import ASPECT_FLOOR, MeshingFrame, UnitFrame
from lbc_core.meshing import mesh_domain

CUBE_FACES = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]


def box(size, offset):
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    return corners * size + offset


@pytest.mark.parametrize("size", [3e-9, 0.7, 1.0, 5e8])
def test_the_frame_centres_and_scales_by_a_power_of_two(size):
    cage = make_cage(box(size, size * np.array([1e6, -2.5, 7.0])), CUBE_FACES)
    frame = UnitFrame.of(cage)
    assert np.log2(frame.scale) == np.round(np.log2(frame.scale))
    unit = frame.cage_to_unit(cage)
    assert 2**-0.5 <= unit.bbox_diagonal <= 2**0.5
    np.testing.assert_allclose(unit.vertices.min(axis=0) + unit.vertices.max(axis=0), 0.0, atol=1e-9)
    assert np.array_equal(unit.facets, cage.facets) and np.array_equal(unit.vertex_map, cage.vertex_map)
    # Scaling by a power of two is exact: only the translation rounds, by at most an ulp of the coordinates.
    back = frame.from_unit(unit.vertices)
    assert np.all(np.abs(back - cage.vertices) <= np.spacing(np.abs(cage.vertices).max()))


def test_a_domain_maps_back_with_control_and_boundary_vertices_exact():
    cage = make_cage(box(1.0, [1e6, 1e6, -1e6]), CUBE_FACES)
    frame = UnitFrame.of(cage)
    unit_domain = mesh_domain(frame.cage_to_unit(cage), 400)
    domain = frame.domain_from_unit(unit_domain, cage)
    assert domain.vertices[domain.control_vertices].tobytes() == cage.vertices.tobytes()
    corners = cage.surface_vertices[cage.facets[domain.boundary_facet]]
    bary = domain.boundary_bary
    combination = bary[:, 0, None] * corners[:, 0] + bary[:, 1, None] * corners[:, 1]
    combination = combination + bary[:, 2, None] * corners[:, 2]
    assert np.array_equal(domain.vertices[domain.boundary_vertices], combination)
    # Interior vertices are the frame's vertices mapped back, to an ulp of the coordinates.
    difference = np.abs(domain.vertices - frame.from_unit(unit_domain.vertices))
    assert difference.max() <= 4 * np.spacing(1e6)
    assert np.array_equal(domain.cells, unit_domain.cells)


def test_the_meshing_frame_stretches_a_thin_cage_and_maps_back_exactly():
    rotation = np.linalg.qr(np.random.default_rng(2).normal(size=(3, 3)))[0]
    slab = np.array([[x, y, z] for x in (0, 4.0) for y in (0, 2.0) for z in (0, 0.01)]) @ rotation.T + 7.0
    frame = MeshingFrame(slab)
    local = frame.to_local(slab)
    extents = np.sort(np.linalg.svd(local - local.mean(axis=0), compute_uv=False))
    assert extents[0] >= 0.99 * ASPECT_FLOOR * extents[-1]  # as thick as the floor allows, not 1/400 of it
    np.testing.assert_allclose(frame.to_world(local), slab, atol=1e-12)
