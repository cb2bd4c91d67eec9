"""Piecewise-linear (P1) finite elements on triangle and tetrahedron meshes.

Shared by the geodesic, solver and baseline stages. A mesh is ``vertices`` (N, d) and ``cells`` (F, d+1) with
d = 2 (triangles) or d = 3 (tetrahedra). Gradient rows are stored cell-major: row ``c * d + k`` is the k-th
component of the gradient on cell c, so a (d F, n) array reshapes to (F, d, n).
"""

import numpy as np
import scipy.sparse as sp

from .geometry import row_keys


def cell_gradients(vertices, cells):
    """Gradients of the d+1 barycentric basis functions on every cell, and the cells' measures.

    Parameters
    ----------
    vertices : (N, d) float array
    cells : (F, d+1) int array

    Returns
    -------
    gradients : (F, d+1, d) float array, in 1 / length units
    measures : (F,) float array, unsigned area (d = 2) or volume (d = 3)
    """
    vertices = np.asarray(vertices, dtype=float)
    cells = np.asarray(cells)
    d = vertices.shape[1]
    # Coordinates as contiguous (F,) arrays: [k][j] is coordinate k of corner j (numpy is slow on 2-4 wide axes).
    corners = np.ascontiguousarray(vertices.T)[:, np.ascontiguousarray(cells.T)]  # (d, d+1, F)
    edges = corners[:, 1:] - corners[:, :1]  # (d, d, F): [k][j] is coordinate k of the edge from corner 0 to j+1
    # The gradients of basis functions 1..d are the rows of inv(edges)ᵀ, i.e. the adjugate's rows over the
    # determinant, written out in closed form (numpy's batched inverse costs ~1 µs per cell).
    if d == 2:
        (ax, bx), (ay, by) = edges
        det = ax * by - ay * bx
        adjugate = [[by, -bx], [-ay, ax]]
    else:
        a, b, c = edges[:, 0], edges[:, 1], edges[:, 2]
        adjugate = [_cross(b, c), _cross(c, a), _cross(a, b)]
        det = a[0] * adjugate[0][0] + a[1] * adjugate[0][1] + a[2] * adjugate[0][2]
    # Flat cells (a repeated corner leaves a round-off determinant, not an exact 0) get zero gradients and measure.
    lengths = np.sqrt(np.sum(edges * edges, axis=0))  # (d, F)
    degenerate = np.abs(det) <= 1e-13 * np.prod(lengths, axis=0)
    det[degenerate] = 0.0
    measures = np.abs(det) / (2.0 if d == 2 else 6.0)
    inverse_det = 1.0 / np.where(degenerate, 1.0, det)
    inverse_det[degenerate] = 0.0
    gradients = np.empty((len(cells), d + 1, d))
    for k in range(d):
        gradients[:, 0, k] = 0.0
        for j in range(d):
            gradients[:, j + 1, k] = adjugate[j][k] * inverse_det
            gradients[:, 0, k] -= gradients[:, j + 1, k]
    return gradients, measures


def _cross(u, v):
    """Cross products of (3, F) arrays of vectors."""
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


def gradient_operator(vertices, cells):
    """Sparse map from vertex values to per-cell gradients.

    Returns
    -------
    G : (d F, N) scipy.sparse.csr_matrix, cell-major rows (see the module docstring)
    measures : (F,) float array
    """
    vertices = np.asarray(vertices, dtype=float)
    cells = np.asarray(cells)
    n_cells, corners = cells.shape
    d = corners - 1
    gradients, measures = cell_gradients(vertices, cells)
    # Every row holds exactly the d+1 corners of its cell, so the CSR arrays are written directly.
    indices = np.repeat(cells, d, axis=0).ravel()  # row c d + k: the corners of cell c
    data = np.transpose(gradients, (0, 2, 1)).ravel()  # (F, d, d+1): component k of each corner's gradient
    indptr = np.arange(0, n_cells * d * corners + 1, corners)
    G = sp.csr_matrix((data, indices, indptr), shape=(n_cells * d, len(vertices)))
    return G, measures


def stiffness_matrix(vertices, cells):
    """The P1 stiffness (cotangent Laplacian) matrix L with L_ij = ∫ ∇φ_i · ∇φ_j, positive semi-definite.

    Returns
    -------
    (N, N) scipy.sparse.csr_matrix, in length^(d-2) units
    """
    G, measures = gradient_operator(vertices, cells)
    d = np.asarray(vertices).shape[1]
    return (G.T @ sp.diags(np.repeat(measures, d)) @ G).tocsr()


def lumped_mass(cells, measures, n_vertices):
    """Lumped P1 mass per vertex: each cell's measure shared equally among its corners.

    Parameters
    ----------
    cells : (F, d+1) int array
    measures : (F,) float array, from :func:`cell_gradients` or :func:`gradient_operator`
    n_vertices : int

    Returns
    -------
    (N,) float array, in length^d units
    """
    cells = np.asarray(cells)
    corners = cells.shape[1]
    return np.bincount(cells.ravel(), np.repeat(measures / corners, corners), minlength=n_vertices)


def boundary_facets(cells):
    """Facets (edges of triangles, triangles of tetrahedra) that belong to exactly one cell.

    Returns
    -------
    (E, d) int array of vertex indices, each facet's indices sorted
    """
    cells = np.asarray(cells)
    corners = cells.shape[1]
    facets = np.concatenate([np.delete(cells, k, axis=1) for k in range(corners)])
    facets = np.sort(facets, axis=1)
    # Each facet as one number: sorting those is several times faster than np.unique over rows, in the same order.
    keys = row_keys(facets, int(cells.max()) + 1 if cells.size else 1)
    _, first, counts = np.unique(keys, return_index=True, return_counts=True)
    return facets[first[counts == 1]]
