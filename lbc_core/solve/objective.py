"""The LBC objective: weighted total variation of piecewise-linear coordinate functions.

For P1 weights the gradient is constant on each cell, so the total variation of coordinate i is exactly
sum over cells of measure * |grad w_i|. The objective weights each cell's term by the TV weight omega (the squared
normalised geodesic distance in the reference). It is evaluated in the mesh's own units, so it scales with length
in 2D (area * 1/length) and with length^2 in 3D.
"""

import numpy as np
import scipy.sparse as sp

from ..kernel.fem import gradient_operator


def tv_objective(vertices, cells, weights, tv_weights):
    """Weighted total variation sum_c sum_i omega_ci |c| |grad w_i on c|.

    Parameters
    ----------
    vertices : (N, d) float array
        Mesh vertices, d = 2 (triangles) or 3 (tetrahedra), in the units the objective is wanted in.
    cells : (F, d+1) int array
    weights : (N, n) float array
        Coordinate values at the vertices (one column per control point).
    tv_weights : (F, n) float array
        Non-negative per-cell weight of each coordinate's total variation.

    Returns
    -------
    float
        The objective, in length^(d-1) units (the TV weights are dimensionless).
    """
    G, measures = gradient_operator(vertices, cells)
    n_cells, corners = np.shape(cells)
    # On the sparse pattern of the gradients (the pairs where a coordinate varies), not dense (F, d, n) arrays:
    # local coordinates make it a few percent of F × n.
    gradients = (G @ sp.csr_matrix(np.asarray(weights, dtype=float))).tocoo()  # rows f d + k
    squares = sp.csr_matrix((gradients.data ** 2, (gradients.row // (corners - 1), gradients.col)),
                            shape=(n_cells, gradients.shape[1])).tocoo()  # duplicates (the d components) summed
    omega = np.asarray(tv_weights)[squares.row, squares.col]
    return float(np.sum(omega * measures[squares.row] * np.sqrt(squares.data)))
