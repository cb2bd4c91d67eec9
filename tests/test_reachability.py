"""The smooth fit through the domain (lbc_core.evaluate.reachability): it does not reach across a gap between parts."""

import numpy as np

from lbc_core.evaluate.interpolation import interpolation_matrix
from lbc_core.evaluate.reachability import FAR, NEAR, path_factor
from lbc_core.evaluate.smoothing import SmoothInterpolation, radius_for

from test_smoothing import _cubes


def u_shape():
    """Two prongs of 3 × 2 × 14 unit cubes side by side, one cube apart, joined by a base 7 × 2 × 2: a domain whose
    parts face each other across a gap narrower than a wide fit (fingers side by side)."""
    vertices, cells = _cubes(7, 2, 16)
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
