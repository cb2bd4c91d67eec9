"""One sparse Cholesky factorisation, solved for one or many right-hand sides (cholespy, else SuperLU)."""

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


class Factor:
    """A factorisation of a symmetric positive definite matrix that solves for many right-hand sides in one call.

    Example
    -------
    >>> import scipy.sparse as sp
    >>> Factor(sp.coo_matrix(np.array([[4.0, 0.0], [1.0, 3.0]])), np.float64).solve(np.array([5.0, 4.0]))
    array([1., 1.])
    """

    def __init__(self, lower, dtype):
        """``lower``: the matrix's lower triangle as a scipy COO matrix (duplicate entries are summed)."""
        try:
            import cholespy

            solver_class = cholespy.CholeskySolverF if dtype == np.float32 else cholespy.CholeskySolverD
            self._solver = solver_class(lower.shape[0], lower.row, lower.col, lower.data, cholespy.MatrixType.COO)
            self._kind = "cholespy"
        except ImportError:
            lower = lower.tocsc()
            self._solver = spla.splu((lower + sp.tril(lower, k=-1).T).tocsc(), permc_spec="MMD_AT_PLUS_A")
            self._kind = "splu"
        self.dtype = dtype

    def solve(self, rhs):
        """(N,) or (N, k) right-hand sides → the solutions, in the factor's precision."""
        if self._kind == "cholespy":
            rhs = np.ascontiguousarray(rhs, dtype=self.dtype)
            out = np.empty_like(rhs)
            self._solver.solve(rhs, out)
            return out
        return self._solver.solve(rhs).astype(self.dtype)
