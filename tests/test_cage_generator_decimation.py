"""The cage generator's manifold-keeping start (lbc_core.cage_generator.decimation): where fast-simplification pinches
a thin part."""

import numpy as np

from lbc_core.cage_generator.decimation import decimated
from lbc_core.cage_generator.extraction import iso_surface
from lbc_core.cage_generator.simplification import _fast_simplified, _simplified_surface, is_surface
from lbc_core.cage_generator.voxels import VoxelSolid


def solid(field_of, cells):
    """The VoxelSolid of a field given on the cube [-1.2, 1.2]³ sampled at ``cells`` points a side."""
    axis = np.linspace(-1.2, 1.2, cells)
    return VoxelSolid(field_of(*np.meshgrid(axis, axis, axis, indexing="ij")), np.full(3, -1.2), 2.4 / (cells - 1), 0)


def thin_torus(x, y, z):
    return 0.1 - np.sqrt((np.sqrt(x ** 2 + y ** 2) - 0.8) ** 2 + z ** 2)


def test_where_fast_simplification_pinches_a_thin_part_the_start_is_decimated():
    vertices, triangles = iso_surface(solid(thin_torus, 21))
    assert not is_surface(*_fast_simplified(vertices, triangles, 80), 1e-9)  # a pinched, non-manifold torus
    assert _simplified_surface(vertices, triangles, 80, 1e-9) is None
    points, faces = _simplified_surface(vertices, triangles, 80, 1e-9, decimate=True)
    assert is_surface(points, faces, 1e-9) and len(points) == 40
    again = decimated(vertices, triangles, 40)
    assert is_surface(*again, 1e-9) and len(again[0]) == 40
    assert np.array_equal(again[0], decimated(vertices, triangles, 40)[0])  # the same every time
