"""Flat cages: the plane of a flat scene, the outline of a flat cage, the 2D request both the CLI and Blender bind."""

import numpy as np
import pytest

from lbc_core import CageError
from lbc_core.cage.planar import boundary_loop, flat_frame, flatten, reframed


def grid(size=3):
    """A flat size × size vertex grid of quads in z = 0, vertex (r, c) at index r * size + c."""
    points = np.array([[c, r, 0.0] for r in range(size) for c in range(size)])
    quads = [[r * size + c, r * size + c + 1, (r + 1) * size + c + 1, (r + 1) * size + c]
             for r in range(size - 1) for c in range(size - 1)]
    return points, quads


def test_flat_frame_finds_the_plane_of_a_tilted_flat_scene():
    rotation = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    square = np.array([[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0]], dtype=float) @ rotation.T + 5.0
    inside = np.array([[1, 1, 0], [0.5, 1.5, 0]], dtype=float) @ rotation.T + 5.0
    origin, axes = flat_frame(square, inside)
    flat = (square - origin) @ axes.T
    assert np.allclose(np.linalg.norm(flat[1] - flat[0]), 2.0)
    lifted = inside + rotation[:, 2] * 0.01
    assert flat_frame(square, lifted) is None
    assert flat_frame(np.vstack([square, square[0] + rotation[:, 2]]), inside) is None


def test_boundary_loop_of_a_filled_grid_walks_its_border():
    loop = boundary_loop(grid()[1])
    assert len(loop) == 8 and 4 not in loop  # the centre vertex controls nothing
    ring = [0, 1, 2, 5, 8, 7, 6, 3]
    start = ring.index(loop[0])
    walked = ring[start:] + ring[:start]
    assert list(loop) in (walked, [walked[0]] + walked[1:][::-1])


def test_boundary_loop_of_a_wire_polygon_and_of_an_ngon():
    assert sorted(boundary_loop([], edges=[(0, 1), (2, 3), (1, 2), (3, 0)])) == [0, 1, 2, 3]
    assert list(boundary_loop([[0, 1, 2, 3, 4, 5, 6]])) in ([0, 1, 2, 3, 4, 5, 6], [0, 6, 5, 4, 3, 2, 1])


def test_boundary_loop_refuses_branching_or_several_outlines():
    with pytest.raises(CageError, match="not one closed loop"):
        boundary_loop([], edges=[(0, 1), (1, 2), (2, 3), (3, 0), (2, 4)])
    with pytest.raises(CageError, match="several loops"):
        boundary_loop([[0, 1, 2, 3], [4, 5, 6, 7]])
    with pytest.raises(CageError, match="no outline"):
        boundary_loop([])


def test_flatten_gives_the_outline_polygon_and_the_points_in_the_plane():
    vertices, quads = grid(4)
    points = np.array([[1.2, 1.5, 0.0], [2.0, 0.5, 0.0]])
    flat = flatten(vertices, quads, points)
    assert len(flat.loop) == 12 and flat.polygon.shape == (12, 2) and flat.points.shape == (2, 2)
    # The plane's coordinates keep distances: the outline's edges are 1 long, the points as far apart as in 3D.
    assert np.allclose(np.linalg.norm(np.diff(flat.polygon, axis=0), axis=1), 1.0)
    assert np.isclose(np.linalg.norm(flat.points[1] - flat.points[0]), np.linalg.norm(points[1] - points[0]))
    assert flatten(vertices, quads, points + [0.0, 0.0, 0.1]) is None


@pytest.mark.parametrize("bad", [np.nan, 3.4028234663852886e38])
def test_flatten_names_a_nan_or_far_off_cage_vertex_before_fitting_the_plane(bad):
    # A new user's NaN vertex broke the plane's SVD (LinAlgError); Blender's infinity (its largest float) made the
    # other vertices look flat and asked for an outline.
    vertices, quads = grid(3)
    vertices[4, 2] = bad
    with pytest.raises(CageError, match=r"cage vertex \(?4"):
        flatten(vertices, quads, np.array([[1.0, 1.0, 0.0]]))


def test_reframed_keeps_another_frame_of_the_plane_and_refuses_to_leave_it():
    square = np.array([[0, 0, 2], [1, 0, 2], [1, 1, 2], [0, 1, 2]], dtype=float)
    points = np.array([[0.5, 0.5, 2.0]])
    flat = flatten(square, [[0, 1, 2, 3]], points)
    moved = square.copy()
    moved[2, :2] = [1.3, 1.2]  # in the plane: its own frame would shift every vertex
    again = reframed(flatten(moved, [[0, 1, 2, 3]], points), moved, points, flat.origin, flat.axes)
    changed = np.flatnonzero(np.abs(again.polygon - flat.polygon).max(axis=1) > 1e-12)
    assert flat.loop[changed].tolist() == [2]
    np.testing.assert_allclose(again.points, flat.points)
    lifted = moved.copy()
    lifted[2, 2] += 0.1  # out of that plane
    assert reframed(flat, lifted, points, flat.origin, flat.axes) is None
