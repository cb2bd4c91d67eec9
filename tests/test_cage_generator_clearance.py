"""The cage generator's clearance (lbc_core.cage_generator.clearance): the parts of a cage lbc's mesher needs apart."""

import numpy as np

from lbc_core.cage_generator.clearance import TETRAHEDRA_PER_CUBE, facing_gaps, mesher_side, narrow_gaps
from lbc_core.cage_generator.extraction import iso_surface
from lbc_core.cage_generator.hull import ProgressiveHull
from lbc_core.cage_generator.simplification import is_surface
from lbc_core.cage_generator.voxels import VoxelSolid
from lbc_core.meshing import tetrahedra


def solid(field_of, cells):
    """The VoxelSolid of a field given on the cube [-1.2, 1.2]³ sampled at ``cells`` points a side."""
    axis = np.linspace(-1.2, 1.2, cells)
    return VoxelSolid(field_of(*np.meshgrid(axis, axis, axis, indexing="ij")), np.full(3, -1.2), 2.4 / (cells - 1), 0)


def two_balls(gap, radius=0.5):
    def field(x, y, z):
        return np.maximum(radius - np.sqrt((x - radius - gap / 2) ** 2 + y ** 2 + z ** 2),
                          radius - np.sqrt((x + radius + gap / 2) ** 2 + y ** 2 + z ** 2))
    return field


def test_the_mesher_side_is_the_meshers_own():
    assert TETRAHEDRA_PER_CUBE == tetrahedra._TETS_PER_CUBE
    assert mesher_side(8000.0 / TETRAHEDRA_PER_CUBE) == 1.0  # at the default 8000 cells


def test_a_sharp_fold_is_a_gap_and_a_sharp_ridge_is_not():
    # Two triangles on the edge (0, 1) along x, opening 10° apart; outward normals facing each other (a valley) or
    # away from each other (a ridge, the same triangles turned over).
    angle = np.radians(5.0)
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0.5, np.cos(angle), np.sin(angle)],
                         [0.5, np.cos(angle), -np.sin(angle)]], dtype=float)
    valley = np.array([[[0, 2, 1]], [[0, 1, 3]]])
    ridge = valley[:, :, ::-1]
    gap = facing_gaps(vertices, valley[0], valley[1])[0]
    assert 0.0 < gap < 0.2
    assert np.isinf(facing_gaps(vertices, ridge[0], ridge[1])[0])


def test_the_hull_keeps_two_parts_facing_each_other_apart():
    vertices, triangles = iso_surface(solid(two_balls(0.15), 11))
    clearance = 0.05
    free = ProgressiveHull(vertices, triangles, 1e-9)
    kept = ProgressiveHull(vertices, triangles, 1e-9, clearance=clearance)
    assert free.simplify(24) == 24 and kept.simplify(24) == 24
    assert len(narrow_gaps(*free.result(), clearance))  # without the clearance the two balls' cages nearly touch
    assert not len(narrow_gaps(*kept.result(), clearance))
    assert is_surface(*kept.result(), 1e-9)
