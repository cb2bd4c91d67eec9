"""The speed baseline must stay a faithful copy of the reference ADMM: same iterations, same objective."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/ is not an installed package
from bench.reference_admm import reference_admm  # noqa: E402

DATA = Path(__file__).parent / "data"


def test_baseline_matches_the_reference_on_lbclogo():
    pack = np.load(DATA / "LBClogo.npz")
    result = reference_admm(pack["vertices"], pack["triangles"], pack["boundary_vertex"], pack["boundary_weights"],
                            pack["tv_weights"])
    assert result["iterations"] == int(pack["iterations_default"])
    assert result["objective"] == pytest.approx(float(pack["objective_default"]), rel=1e-9)
    weights = result["weights"]
    # Same trajectory as the C++ code, so the same weights up to accumulated round-off (observed 1e-14).
    np.testing.assert_allclose(weights, pack["weights_default"], rtol=0, atol=1e-8)
    # Partition of unity and linear reproduction hold to round-off on the returned (unclamped) Z.
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-12)
    control_points = pack["vertices"][pack["control_vertex"]]
    np.testing.assert_allclose(weights @ control_points, pack["vertices"], atol=1e-9 * np.abs(control_points).max())
