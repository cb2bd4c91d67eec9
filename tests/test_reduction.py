"""Reduction: sparse weights that keep partition of unity, reproduction and non-negativity."""

import numpy as np
import scipy.sparse as sp

from lbc_core.evaluate.reduction import interpolate_and_reduce

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def reduce_weights(weights, controls, positions, threshold, tolerance, **keywords):
    """The reduction alone: each point located at a domain vertex of its own, which holds its weights (m, n)."""
    return interpolate_and_reduce(sp.identity(len(weights), format="csr"), weights, controls, positions, threshold,
                                  tolerance, **keywords)


def bilinear_weights(points):
    x, y = points[:, 0], points[:, 1]
    return np.stack([(1 - x) * (1 - y), x * (1 - y), x * y, (1 - x) * y], axis=1)


def test_reduce_drops_small_weights_and_restores_linear_precision():
    # Eight control points on a circle; weights spread a little onto all of them.
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    controls = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    rng = np.random.default_rng(1)
    points = rng.uniform(-0.5, 0.5, (300, 2))
    dense = np.abs(rng.normal(0, 1e-5, (300, 8)))
    # Main weights: barycentric coordinates in a fan triangle (centroid, i, i+1) replaced by three control points.
    for row, p in enumerate(points):
        k = int(np.floor((np.arctan2(p[1], p[0]) % (2 * np.pi)) / (2 * np.pi / 8)))
        a, b, c = controls[k], controls[(k + 1) % 8], controls[(k + 4) % 8]
        bary = np.linalg.solve(np.array([[a[0], b[0], c[0]], [a[1], b[1], c[1]], [1, 1, 1]]), [p[0], p[1], 1])
        dense[row, [k, (k + 1) % 8, (k + 4) % 8]] += bary
    dense /= dense.sum(axis=1, keepdims=True)
    threshold = 1e-3 / 8
    reduced = reduce_weights(dense, controls, dense @ controls, threshold, tolerance=1e-9)
    assert reduced.nnz < dense.size / 2
    assert reduced.data.min() >= 0
    values = reduced.toarray()
    assert np.abs(values.sum(axis=1) - 1).max() < 1e-12
    assert np.abs(values @ controls - dense @ controls).max() < 1e-9


def test_reduce_keeps_more_support_where_the_reduced_one_cannot_reproduce():
    controls = SQUARE
    point = np.array([[0.5, 0.004]])
    # Two big weights on the bottom edge, small ones above: dropping them cannot reproduce y = 0.004.
    weights = np.array([[0.498, 0.498, 0.002, 0.002]])
    reduced = reduce_weights(weights, controls, point, threshold=0.01, tolerance=1e-12)
    values = reduced.toarray()
    assert np.abs(values @ controls - point).max() < 1e-12
    assert values.min() >= 0 and abs(values.sum() - 1) < 1e-12


class Overshooting:
    """A stand-in for a smooth interpolation: its rows, which may overshoot, and the barycentric ``linear`` rows of
    the same points."""

    def __init__(self, rows, linear):
        self.rows, self.linear, self.shape = sp.csr_matrix(rows), sp.csr_matrix(linear), rows.shape

    def __getitem__(self, rows):
        return self.rows[rows]


def test_a_point_whose_smooth_row_cannot_meet_the_constraints_is_reduced_from_its_linear_row():
    # Domain vertices at the square's corners, each holding its own control point's coordinate 1.
    points = np.array([[0.25, 0.75], [0.5, 0.5]])
    linear = bilinear_weights(points)
    # Row 0 overshoots along the square's mode (1, -1, 1, -1), which sums to 0 and moves no point: it still sums to 1
    # and reproduces (0.25, 0.75), but its positive weights (corners (0, 0) and (1, 1)) cannot reproduce a point off
    # their diagonal. Row 1 is the barycentric one.
    smooth = linear.copy()
    smooth[0] += 1.5 * np.array([1.0, -1.0, 1.0, -1.0])
    assert np.abs(smooth @ SQUARE - points).max() < 1e-12 and smooth[0].min() < -1
    located = Overshooting(smooth, linear)
    reduced = interpolate_and_reduce(located, np.eye(4), SQUARE, SQUARE, threshold=1e-3, tolerance=1e-12).toarray()
    assert reduced.min() >= 0
    assert np.abs(reduced.sum(axis=1) - 1).max() < 1e-12
    assert np.abs(reduced @ SQUARE - points).max() < 1e-12
    np.testing.assert_allclose(reduced, linear, atol=1e-12)  # row 0 from its barycentric row


def test_reduce_reports_each_round_of_chunks_of_rows_and_stops_on_cancel(monkeypatch):
    import pytest

    import lbc_core.evaluate.reduction as reduction
    from lbc_core.errors import Cancelled
    from lbc_core.kernel.parallel import CHUNKS_PER_ROUND, worker_count

    monkeypatch.setattr(reduction, "ROWS_PER_CHUNK", 100)
    threads = worker_count()
    rng = np.random.default_rng(4)
    points = rng.uniform(0.0, 1.0, (100 * CHUNKS_PER_ROUND, 2))  # chunks of 100 rows, one per thread a round
    weights = bilinear_weights(points)
    fractions, messages = [], []
    reduce_weights(weights, SQUARE, points, 1e-3, 1e-9,
                   progress=lambda fraction, message: fractions.append(fraction) or messages.append(message))
    m = len(points)
    assert fractions == pytest.approx([100 * first / m for first in range(0, CHUNKS_PER_ROUND, threads)] + [1.0])
    # each round says how far it is (a new user watched 97 % for 2-4 s with nothing new)
    assert messages[1] == f"reducing the weights: {100 * threads} of {m} points done"
    chunks = []
    reduce_rows = reduction._reduce_rows
    monkeypatch.setattr(reduction, "_reduce_rows", lambda *arguments: chunks.append(1) or reduce_rows(*arguments))
    with pytest.raises(Cancelled):
        reduce_weights(weights, SQUARE, points, 1e-3, 1e-9, cancel=lambda: len(chunks) >= threads)
    assert len(chunks) == threads  # the first round ran, the second never started
