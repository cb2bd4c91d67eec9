"""The LBC objective: weighted total variation of piecewise-linear coordinate functions.

For P1 weights the gradient is constant on each cell, so the total variation of coordinate i is exactly
sum over cells of measure * |grad w_i|. The objective weights each cell's term by the TV weight omega (the squared
normalised geodesic distance in the reference). It is evaluated in the mesh's own units, so it scales with length
in 2D (area * 1/length) and with length^2 in 3D.
"""

import numpy as np

from .fem import gradient_operator


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
    gradients = (G @ np.asarray(weights, dtype=float)).reshape(n_cells, corners - 1, -1)  # (F, d, n)
    norms = np.sqrt(np.einsum("fkn,fkn->fn", gradients, gradients))
    return float(np.sum(np.asarray(tv_weights) * measures[:, None] * norms))
