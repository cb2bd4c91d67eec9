"""The smooth fit through the domain (lbc_core.evaluate.reachability): it does not reach across a gap between parts."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from lbc_core.evaluate import reachability
from lbc_core.evaluate.interpolation import interpolation_matrix
from lbc_core.evaluate.reachability import FAR, NEAR, DomainPaths, path_factor
from lbc_core.evaluate.smoothing import SmoothInterpolation, median_edge, neighbour_distances, radius_for

from test_smoothing import _cubes


def u_shape(width=7):
    """Two prongs of 3 × 2 × 14 unit cubes side by side (the second ``width`` - 4 cubes wide), one cube apart,
    joined by a base ``width`` × 2 × 2: a domain whose parts face each other across a gap narrower than a wide fit
    (fingers side by side)."""
    vertices, cells = _cubes(width, 2, 16)
    low = vertices[cells].min(axis=1)
    kept = ~((low[:, 0] >= 3) & (low[:, 0] < 4) & (low[:, 2] >= 2))  # the slot: x in [3, 4] above the base
    cells = cells[kept]
    used = np.unique(cells)
    renumber = np.full(len(vertices), -1)
    renumber[used] = np.arange(len(used))
    return vertices[used], renumber[cells]


def fitted_rows(through_domain):
    vertices, cells = u_shape()
    points = np.array([[x, 1.0, z] for x in (2.2, 2.6, 2.9) for z in (11.0, 12.5, 14.0)])  # one prong, by the slot
    located, _, _ = interpolation_matrix(vertices, cells, points)
    smooth = SmoothInterpolation(vertices, cells, located, radius_edges=radius_for(1.0), through_domain=through_domain)
    return vertices, points, smooth[0:len(points)]


def test_a_wide_fit_does_not_reach_across_the_gap_to_the_other_prong():
    vertices, points, rows = fitted_rows(through_domain=True)
    # The other prong's vertices across the slot: straight within the fit's radius, 17 units or more around the slot.
    other_prong = np.flatnonzero((vertices[:, 0] >= 4) & (vertices[:, 2] >= 9))
    assert abs(rows[:, other_prong]).max() == 0.0
    assert np.abs(np.asarray(rows.sum(axis=1)).ravel() - 1.0).max() < 1e-12
    assert np.abs(rows @ vertices - points).max() < 1e-12
    # The ball alone reaches it: 1.3 units across the slot, a radius of 4 median edges (5.7 units).
    _, _, plain = fitted_rows(through_domain=False)
    assert abs(plain[:, other_prong]).max() > 1e-3


def test_a_fit_inside_one_part_is_the_plain_fit():
    """Where every path is about as long as the straight line, nothing is blocked: the same rows as the ball's."""
    vertices, cells = _cubes(8, 8, 8)
    points = np.random.default_rng(0).uniform(1.0, 7.0, (50, 3))
    located, _, _ = interpolation_matrix(vertices, cells, points)
    rows = [SmoothInterpolation(vertices, cells, located, radius_edges=radius_for(1.0), through_domain=through)
            [0:len(points)] for through in (True, False)]
    assert abs(rows[0] - rows[1]).max() < 1e-12


def test_the_factor_fades_smoothly_between_near_and_far_detours():
    detours = np.array([0.0, NEAR, (NEAR + FAR) / 2, FAR, 10.0, np.inf])
    assert path_factor(detours).tolist() == [1.0, 1.0, 0.5, 0.0, 0.0, 0.0]


def brute_force(vertices, cells, radius, sources):
    """The blocked pairs of ``sources`` from unbounded searches over the whole domain, as the definition reads:
    (sorted keys, factors), and the vertices a search bounded only at the largest reach plus FAR radii reaches."""
    n = len(vertices)
    ends = np.unique(np.sort(np.concatenate([cells[:, [a, b]] for a in range(4) for b in range(a + 1, 4)]), axis=1),
                     axis=0)
    length = np.linalg.norm(vertices[ends[:, 0]] - vertices[ends[:, 1]], axis=1)
    paths = dijkstra(sp.csr_matrix((length, (ends[:, 0], ends[:, 1])), shape=(n, n)), directed=False,
                     indices=sources)
    longest = np.zeros(n)
    np.maximum.at(longest, ends.ravel(), np.repeat(length, 2))
    reach = radius + longest
    straight = np.sqrt(((vertices[sources, None] - vertices[None]) ** 2).sum(axis=-1))
    detour = paths - np.maximum(straight, np.finfo(float).tiny)
    rows, targets = np.nonzero((straight < reach[sources, None]) & ~(detour <= NEAR * radius))
    work = int((paths <= reach.max() + FAR * radius).sum())
    return sources[rows] * n + targets, path_factor(detour[rows, targets] / radius), work


def test_bounded_searches_find_the_unbounded_factors_with_less_work():
    """Every corner's blocked pairs and factors as unbounded shortest paths give them, bit for bit, and each point's
    factors as their corners' barycentric mean, for less work: a corner away from the slot is searched only as far
    as showing its pairs unblocked takes."""
    vertices, cells = u_shape(width=24)
    radius = radius_for(0.0) * median_edge(vertices, cells)
    paths = DomainPaths(vertices, cells, radius, np.zeros(len(vertices)))
    keys, factors, work = brute_force(vertices, cells, radius, np.arange(len(vertices)))
    assert ((factors > 0) & (factors < 1)).any() and (factors == 0).any()  # pairs across the slot, faded and cut
    assert np.array_equal(paths.keys, keys) and np.array_equal(paths.factors, factors)
    assert paths.searches < 1.2 * len(vertices) and paths.reached < 0.8 * work
    points = np.array([[x, 1.0, z] for x in (-0.2, 2.6, 2.9, 4.4) for z in (3.0, 8.5, 14.0)])  # one just outside
    located, _, _ = interpolation_matrix(vertices, cells, points)
    distances = neighbour_distances(cKDTree(vertices), points, radius)
    stored, expected = dict(zip(keys.tolist(), factors.tolist())), []
    for row in range(len(points)):
        corners, shares = located[row].indices, located[row].data
        for target in distances[row].indices:
            total = 0.0  # in the row's order, as the sum is taken; 1 where no corner has a blocked pair
            for corner, share in zip(corners, shares):
                total += share * stored.get(corner * len(vertices) + target, 1.0)
            expected.append(total if paths.has_blocked[corners].any() else 1.0)
    assert np.array_equal(paths.factors_of(located, distances), expected) and min(expected) < 0.5


@pytest.mark.parametrize("sample_every, sources_per_call", [(1, 256), (8, 64), (10_000, 1)])
def test_the_search_bounds_change_the_work_not_the_factors(monkeypatch, sample_every, sources_per_call):
    """How the corners are sampled and grouped into calls picks each search's bound, never a factor."""
    vertices, cells = u_shape()
    radius = radius_for(0.5) * median_edge(vertices, cells)
    reference = DomainPaths(vertices, cells, radius, np.zeros(len(vertices)))
    monkeypatch.setattr(reachability, "_SAMPLE_EVERY", sample_every)
    monkeypatch.setattr(reachability, "_SOURCES_PER_CALL", sources_per_call)
    again = DomainPaths(vertices, cells, radius, np.zeros(len(vertices)))
    assert np.array_equal(again.keys, reference.keys) and np.array_equal(again.factors, reference.factors)
    assert len(reference.keys) and again.searches >= len(vertices)
