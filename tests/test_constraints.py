"""Constraints: the least-norm correction that restores partition of unity and reproduction on a support, and the
solver's projection of its clamped output."""

import numpy as np

from lbc_core.kernel.constraints import constraint_residuals, project_onto_constraints, restore_constraints

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def bilinear_weights(points):
    x, y = points[:, 0], points[:, 1]
    return np.stack([(1 - x) * (1 - y), x * (1 - y), x * y, (1 - x) * y], axis=1)


def test_restore_fixes_perturbed_weights_exactly():
    rng = np.random.default_rng(0)
    points = rng.uniform(0.1, 0.9, (200, 2))
    noisy = bilinear_weights(points) + rng.normal(0, 1e-4, (200, 4))
    fixed = restore_constraints(noisy, SQUARE, points)
    unity, reproduction = constraint_residuals(fixed, SQUARE, points)
    assert unity.max() < 1e-13 and reproduction.max() < 1e-13
    assert fixed.min() >= 0
    assert np.abs(fixed - noisy).max() < 1e-3


def test_restore_clamps_negatives_and_keeps_constraints():
    points = np.array([[0.5, 0.5]])
    weights = np.array([[0.5, -1e-5, 0.5, 1e-5]])
    fixed = restore_constraints(weights, SQUARE, points)
    assert fixed.min() >= 0
    unity, reproduction = constraint_residuals(fixed, SQUARE, points)
    assert unity.max() < 1e-14 and reproduction.max() < 1e-14


def test_restore_gives_the_same_with_shared_and_per_point_slots():
    rng = np.random.default_rng(2)
    points = rng.uniform(0.05, 0.95, (100, 2))
    weights = bilinear_weights(points) + rng.normal(0, 3e-2, (100, 4))  # large enough to clamp some
    columns = np.broadcast_to(np.arange(4), weights.shape)
    shared = restore_constraints(weights, SQUARE, points)
    per_point = restore_constraints(weights, SQUARE, points, columns)
    assert (weights < 0).any() and np.abs(shared - per_point).max() < 1e-12
    assert np.allclose(constraint_residuals(shared, SQUARE, points), constraint_residuals(per_point, SQUARE, points,
                                                                                          columns), atol=1e-14)


def test_the_solver_projection_keeps_zeros_and_grows_a_support_that_cannot_reproduce():
    points = np.array([[0.5, 0.5], [0.5, 0.9]])
    # Point 0 keeps its zeros; point 1 is left with two opposite corners, which cannot reproduce it off their diagonal.
    clamped = np.array([[0.25, 0.0, 0.5, 0.25], [0.5, 0.0, 0.5, 0.0]])
    unclamped = bilinear_weights(points)
    projected = project_onto_constraints(clamped, unclamped, SQUARE, points)
    unity, reproduction = constraint_residuals(projected, SQUARE, points)
    assert unity.max() < 1e-12 and reproduction.max() < 1e-12 and projected.min() >= 0
    assert projected[0, 1] == 0.0
    assert np.count_nonzero(projected[1]) > 2


def test_projection_takes_in_other_control_points_where_the_candidates_cannot_reproduce_the_point():
    # The iterate is positive on two opposite corners only: no weights on them reproduce a point off their diagonal.
    points = np.array([[0.3, 0.6]])
    clamped = np.array([[0.5, 0.0, 0.5, 0.0]])
    unclamped = np.array([[0.5, -0.1, 0.5, -0.2]])
    projected = project_onto_constraints(clamped, unclamped, SQUARE, points)
    unity, reproduction = constraint_residuals(projected, SQUARE, points)
    assert unity.max() < 1e-12 and reproduction.max() < 1e-12 and projected.min() >= 0


def test_projection_finds_the_weights_off_a_plane_its_candidates_all_lie_in():
    # Five control points of the gargoyle's cage L10 and a domain vertex 1.4e-4 off the plane of the first three,
    # whose iterate was positive on those three only (3000 cells). Growing the support by the candidates' size, then
    # taking in the other two at a tiny weight, dropped them again: the row was left 3.4e-5 off partition of unity.
    controls = np.array([[0.041879, 0.247219, 0.101472], [0.060128, 0.283689, -0.080511],
                         [0.149222, 0.208004, 0.003787], [-0.052135, 0.236593, -0.08668], [0.176048, 0.226018, 0.142043]])
    points = np.array([[0.112362, 0.233182, -0.006909]])
    clamped = np.array([[0.121551, 0.267438, 0.611812, 0.0, 0.0]])
    unclamped = np.where(clamped > 0, clamped, -1e-5)
    projected = project_onto_constraints(clamped, unclamped, controls, points)
    unity, reproduction = constraint_residuals(projected, controls, points)
    assert unity.max() < 1e-12 and reproduction.max() < 1e-12 and projected.min() >= 0
    assert projected[0, 3] == 0.0  # the nearest such weights: none on the point on the plane's far side


def test_the_batched_symmetric_solve_agrees_with_lapack_and_takes_it_for_a_singular_matrix():
    from lbc_core.kernel.constraints import solve_symmetric

    rng = np.random.default_rng(3)
    factors = rng.random((200, 4, 9))
    matrices = factors @ np.swapaxes(factors, 1, 2) + 1e-3 * np.eye(4)
    vectors = rng.random((200, 4))
    matrices[5] = np.diag([1.0, -2.0, 3.0, 4.0])  # a negative pivot: LAPACK's answer
    solved = solve_symmetric(matrices, vectors)
    assert np.abs(solved - np.linalg.solve(matrices, vectors[:, :, None])[:, :, 0]).max() < 1e-9


def test_rows_of_alike_lengths_are_grouped_each_once():
    from lbc_core.kernel.constraints import alike_lengths

    counts = np.random.default_rng(5).integers(0, 40, 3000)
    groups = alike_lengths(counts, 100)
    assert np.array_equal(np.sort(np.concatenate(groups)), np.arange(len(counts)))
    assert all(len(rows) >= 100 for rows in groups[:-1])
    longest = [counts[rows].max() for rows in groups]
    assert longest == sorted(longest) and len(groups) > 2
