"""Issue #2's acceptance: bind every cage we ship, check quality at the mesh's vertices, print the locality."""

from pathlib import Path

import numpy as np
import pytest

import lbc_core
from lbc_core.io import read_cage, read_mesh

DATA = Path(__file__).parent / "data"
CAGES_2D = ["woody", "Gil_Gecko", "cactus", "LBClogo"]
GARGOYLE = [f"L{level:02d}" for level in range(8, 17)]


def inside_grid(polygon, per_side=80):
    from matplotlib.path import Path as PolygonPath

    axes = [np.linspace(low, high, per_side) for low, high in zip(polygon.min(axis=0), polygon.max(axis=0))]
    grid = np.stack(np.meshgrid(*axes), axis=-1).reshape(-1, 2)
    return grid[PolygonPath(polygon).contains_points(grid)]


def check(binding, points, cage_vertices):
    weights = binding.weights
    diagonal = binding.cage.bbox_diagonal
    n = binding.cage.n_control_points
    assert np.abs(np.asarray(weights.sum(axis=1)).ravel() - 1).max() <= 1e-9
    assert np.abs(weights @ binding.rest_cage_vertices - points).max() <= 1e-9 * diagonal
    assert weights.data.min() >= -1e-6
    rng = np.random.default_rng(0)
    d = points.shape[1]
    matrix, shift = np.eye(d) + 0.3 * rng.normal(size=(d, d)), rng.normal(size=d)
    moved = binding.deform(cage_vertices @ matrix.T + shift)
    assert np.abs(moved - (points @ matrix.T + shift)).max() <= 1e-6 * diagonal
    counts = binding.influence_counts()
    print(f"{n} control points: {counts.mean():.2f} per point on average, max {counts.max()}")
    if n >= 20:
        assert counts.mean() < n / 2


@pytest.mark.parametrize("name", CAGES_2D)
def test_2d_cages(name):
    cage, _ = read_cage(DATA / f"{name}-control-edgeset.obj")
    cage = cage[:, :2]
    points = inside_grid(cage)
    check(lbc_core.bind(cage, None, points), points, cage)


@pytest.mark.parametrize("level", GARGOYLE)
def test_gargoyle_cages(level):
    cage, faces = read_cage(DATA / "cages-3d" / "gargoyle" / f"cage_{level}.obj")
    points, _ = read_mesh(DATA / "cages-3d" / "gargoyle" / "mesh.off")
    binding = lbc_core.bind(cage, faces, points)
    assert binding.outside_count == 0
    check(binding, points, cage)


def test_clothing_cage():
    cage, faces = read_cage(DATA / "cages-3d" / "clothing" / "cage.obj")
    points, _ = read_mesh(DATA / "cages-3d" / "clothing" / "mesh.obj")
    binding = lbc_core.bind(cage, faces, points)
    assert binding.outside_count == 0
    check(binding, points, cage)
    # The posed cage that ships with the garment deforms it to finite, bounded positions.
    posed, _ = read_cage(DATA / "cages-3d" / "clothing" / "cage_deformed.obj")
    moved = binding.deform(posed)
    assert np.all(np.isfinite(moved))
    assert np.all(moved.min(axis=0) >= posed.min(axis=0) - 1e-9) and np.all(moved.max(axis=0) <= posed.max(axis=0) + 1e-9)
