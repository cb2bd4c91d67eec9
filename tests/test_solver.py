"""solve_on_mesh against the authors' reference packs, and the solver's guarantees."""

from pathlib import Path

import numpy as np
import pytest

import lbc_core
from lbc_core.solver import solve_on_mesh

DATA = Path(__file__).parent / "data"
PACKS = ["LBClogo", "woody", "cactus", "Gil_Gecko"]


def load_pack(name):
    return dict(np.load(DATA / f"{name}.npz"))


def solve_pack(pack, **options):
    vertices = pack["vertices"]
    return solve_on_mesh(
        vertices, pack["triangles"], pack["boundary_vertex"], pack["boundary_weights"],
        vertices[pack["control_vertex"]], pack["tv_weights"], **options,
    )


def assert_quality(vertices, weights, controls, boundary_vertices=None, boundary_weights=None):
    """Issue #2 item 7: partition of unity 1e-9, reproduction 1e-9 of the diagonal, weights ≥ -1e-6, Lagrange."""
    diagonal = np.linalg.norm(np.ptp(vertices, axis=0))
    assert np.abs(weights.sum(axis=1) - 1).max() <= 1e-9
    assert np.abs(weights @ controls - vertices).max() <= 1e-9 * diagonal
    assert weights.min() >= -1e-6
    if boundary_vertices is not None:
        np.testing.assert_array_equal(weights[boundary_vertices], boundary_weights)


@pytest.mark.parametrize("name", PACKS)
def test_reaches_the_reference_objective_with_exact_constraints(name):
    pack = load_pack(name)
    result = solve_pack(pack)
    assert result.converged
    assert result.objective <= float(pack["objective_default"]) * 1.001
    controls = pack["vertices"][pack["control_vertex"]]
    assert_quality(pack["vertices"], result.weights, controls, pack["boundary_vertex"], pack["boundary_weights"])
    # Lagrange property: each control point has its own unit weight.
    np.testing.assert_array_equal(result.weights[pack["control_vertex"]], np.eye(len(controls)))


def test_result_is_local():
    pack = load_pack("woody")
    result = solve_pack(pack)
    n = result.weights.shape[1]
    active = (result.weights > 1e-3 / n).sum(axis=1)
    assert active.mean() < n / 4  # the reference reaches 4.5 of 26 on this cage


def test_objective_is_reported_in_input_units():
    pack = load_pack("LBClogo")
    scaled = dict(pack, vertices=pack["vertices"] * 3.0)
    base = solve_pack(pack)
    bigger = solve_pack(scaled)
    assert bigger.objective == pytest.approx(3.0 * base.objective, rel=1e-3)


def test_bad_shapes_are_refused():
    pack = load_pack("LBClogo")
    vertices = pack["vertices"]
    with pytest.raises(lbc_core.CageError, match="boundary_weights"):
        solve_on_mesh(vertices, pack["triangles"], pack["boundary_vertex"], pack["boundary_weights"][:, :3],
                      vertices[pack["control_vertex"]], pack["tv_weights"])
    with pytest.raises(lbc_core.CageError, match="tv_weights"):
        solve_on_mesh(vertices, pack["triangles"], pack["boundary_vertex"], pack["boundary_weights"],
                      vertices[pack["control_vertex"]], pack["tv_weights"][:10])


def test_memory_estimate_refuses_what_the_machine_cannot_hold():
    from lbc_core.solver import check_memory, estimate_memory

    assert estimate_memory(26, 3000, 2) == pytest.approx(120 * 26 * (2 * 3000 + 0.53 * 3000), rel=1e-6)
    check_memory(26, 3000, 2)  # the paper's 2D problems fit anywhere
    with pytest.raises(lbc_core.CageError, match="GiB"):
        check_memory(2000, 10**8, 3)


def test_the_forecast_tells_memory_and_time_before_a_solve():
    from lbc_core.solver import estimate_memory, solve_forecast

    small = solve_forecast(27, 8000, 3)
    assert small.startswith("solving 27 control points on about 8000 cells: about ") and " MB of memory" in small
    # The 1002-vertex cage: GiB and minutes, told up front.
    large = solve_forecast(1002, 8000, 3)
    assert f"{estimate_memory(1002, 8000, 3) / 2**30:.1f} GiB of memory and roughly" in large and " min" in large
    assert "beyond an hour" in solve_forecast(2000, 64000, 3)


def test_progress_says_the_time_left_once_the_residual_has_fallen():
    messages = []
    solve_pack(load_pack("woody"), progress=lambda fraction, message: messages.append(message))
    admm = [message for message in messages if message.startswith("ADMM iteration")]
    # The first check has nothing to extrapolate from (it used to say minutes for a solve of a second).
    assert "left" not in admm[0]
    assert all("left" in message for message in admm[1:]) and len(admm) > 2
