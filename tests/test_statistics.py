"""Locality statistics: the exact per-cell measures against closed forms and sampling, P and Q on functions whose
answer is known, and the reference LBC weights more local than harmonic and mean value coordinates on one mesh."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial import Delaunay

from lbc_core.compare.baselines import harmonic_weights, mean_value_coordinates
from lbc_core.cage.make import make_cage
from lbc_core.io import read_cage
from lbc_core.compare.statistics import (
    _fraction_below,
    deform_seconds,
    influence,
    influence_counts,
    influence_threshold,
    locality,
    memory_bytes,
)

DATA = Path(__file__).parent / "data"


def grid_mesh(dim, count=9):
    """A Delaunay mesh of the unit square or cube on a regular grid (duck-typed DomainMesh: vertices, cells)."""
    axis = np.linspace(0.0, 1.0, count)
    vertices = np.stack(np.meshgrid(*[axis] * dim, indexing="ij"), axis=-1).reshape(-1, dim)
    return SimpleNamespace(vertices=vertices, cells=Delaunay(vertices).simplices)


@pytest.mark.parametrize(
    "values, s, expected",
    [
        ([0.0, 0.0, 1.0], 0.5, 0.75),  # triangle: all but the corner triangle scaled by 1/2
        ([0.0, 1.0, 1.0], 0.5, 0.25),  # triangle: the corner triangle scaled by 1/2
        ([0.0, 0.0, 0.0, 1.0], 0.5, 0.875),  # tetrahedron: 1 - (1/2)^3
        ([0.0, 1.0, 1.0, 1.0], 0.5, 0.125),
        ([0.0, 0.0, 1.0, 1.0], 0.5, 0.5),  # the prism case, half by symmetry
        ([0.0, 0.0, 1.0, 1.0], 0.25, 0.15625),  # the prism: λ2 + λ3 ~ Beta(2, 2), CDF 3s² - 2s³
        ([2.0, 2.0, 2.0], 2.0, 1.0),  # constant and equal to s: counted by <=
    ],
)
def test_fraction_closed_forms(values, s, expected):
    assert _fraction_below(np.array([values]), s, strict=False)[0] == pytest.approx(expected, abs=1e-14)


@pytest.mark.parametrize("dim", [2, 3])
def test_fraction_matches_sampling(dim):
    rng = np.random.default_rng(dim)
    values = np.sort(rng.normal(size=(40, dim + 1)), axis=1)
    values[:10, 1] = values[:10, 0]  # ties, as where coordinates vanish on whole cells
    samples = rng.dirichlet(np.ones(dim + 1), size=100_000)
    for s in (-0.4, 0.0, 0.7):
        sampled = np.mean(samples @ values.T <= s, axis=0)
        np.testing.assert_allclose(_fraction_below(values, s, strict=False), sampled, atol=0.006)


def test_strict_differs_only_on_constant_cells():
    values = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert _fraction_below(values, 0.0, strict=True).tolist() == [0.0, 0.0]
    assert _fraction_below(values, 0.0, strict=False).tolist() == [1.0, 0.0]


@pytest.mark.parametrize("dim", [2, 3])
def test_locality_of_linear_functions_is_exact(dim):
    # w = x and w = 1 - x are at most t on a slab of width t: P(t) = t on any mesh of the unit square or cube.
    mesh = grid_mesh(dim, count=6)
    x = mesh.vertices[:, 0]
    thresholds = np.array([0.0, 0.013, 0.3, 0.5, 0.99, 1.0, 2.0])
    np.testing.assert_allclose(
        locality(mesh, np.column_stack([x, 1.0 - x]), thresholds), np.minimum(thresholds, 1.0), atol=1e-13
    )


def test_locality_counts_zero_regions_and_absolute_values():
    mesh = grid_mesh(2)
    x = mesh.vertices[:, 0]
    weights = np.column_stack([np.zeros_like(x), -x])  # |w| is what counts
    np.testing.assert_allclose(locality(mesh, weights, [0.0, 0.25]), [0.5, 0.625], atol=1e-13)


def test_influence_fraction():
    mesh = grid_mesh(2, count=21)
    x = mesh.vertices[:, 0]
    weights = np.column_stack([np.ones_like(x), np.where(x > 0.5, x, 0.0), np.zeros_like(x)])
    ks, q = influence(mesh, weights)
    assert ks.tolist() == [1, 2, 3]
    # Counted at cell centroids: every cell right of x = 0.5 (its centroid value is at least 0.55 / 3 > τ), none left.
    assert q[0] == pytest.approx(1.0)
    assert q[1] == pytest.approx(0.5)
    assert q[2] == 0.0
    assert influence(mesh, weights, ks=[0, 4])[1].tolist() == pytest.approx([1.0, 0.0])


def test_influence_counts_and_memory():
    n = 4
    tau = influence_threshold(n)
    assert tau == 1e-3 / n
    dense = np.array([[1.0, 0.0, 0.0, 0.0], [0.5, 0.5, 2 * tau, -2 * tau], [1.0, tau, -tau, 0.0]])
    assert influence_counts(dense).tolist() == [1, 4, 1]
    assert influence_counts(sp.csr_matrix(dense)).tolist() == [1, 4, 1]
    assert memory_bytes(dense) == 3 * 4 * 8
    sparse = sp.csr_matrix(dense)  # 8 stored entries, 4 row pointers
    assert memory_bytes(sparse) == 8 * 8 + 8 * 4 + 4 * 4
    seconds = deform_seconds(sparse, np.ones((4, 3)), min_total=0.01)
    assert 0.0 < seconds < np.inf  # a time per deform, measured over at least min_total


def test_reference_lbc_is_more_local_than_harmonic_and_mvc():
    """On the reference solver's own woody mesh, with its boundary values, Eq. 20 and 21 rank LBC first."""
    pack = np.load(DATA / "woody.npz")
    mesh = SimpleNamespace(vertices=pack["vertices"], cells=pack["triangles"], boundary_vertices=pack["boundary_vertex"])
    cage = make_cage(read_cage(DATA / "woody-control-edgeset.obj")[0])
    n = cage.n_control_points
    schemes = {
        "lbc": pack["weights_tight"],
        "harmonic": harmonic_weights(mesh, pack["boundary_weights"]),
        "mvc": mean_value_coordinates(cage, mesh.vertices),
    }
    tau = influence_threshold(n)
    p = {name: locality(mesh, w, [tau])[0] for name, w in schemes.items()}
    counts = {name: influence_counts(w).mean() for name, w in schemes.items()}
    q8 = {name: influence(mesh, w, ks=[8])[1][0] for name, w in schemes.items()}
    assert p["lbc"] > 0.75 > 0.1 > p["harmonic"] > p["mvc"]
    assert counts["lbc"] < 6 < 20 < counts["harmonic"] < counts["mvc"]
    assert q8["lbc"] < 0.05 and q8["harmonic"] > 0.95 and q8["mvc"] > 0.95
