"""Geodesic distances inside the cage (heat method) and the TV weights built from them (the paper's Section 3.3).

The total variation of coordinate i is weighted per cell by ω = ρ(D_i), with D_i the geodesic distance from control
point i normalised to [0, 1]: far from its control point a coordinate pays more for varying, which keeps it local.
"""

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import fem
from .errors import Cancelled

WEIGHTINGS = {
    "constant": lambda d: np.ones_like(d),
    "linear": lambda d: d,
    "quadratic": lambda d: d * d,
    "sqrt": np.sqrt,
}


def geodesic_distances(vertices, cells, sources, cancel=None):
    """Heat-method geodesic distance from each source vertex to every vertex of the mesh.

    Triangles use potpourri3d's heat method; tetrahedra a P1 finite-element heat method (Crane et al. 2013):
    diffuse for time h² (h the mean edge length), normalise the gradient, and solve a Poisson problem.

    Parameters
    ----------
    vertices : (N, d) float array
    cells : (F, d+1) int array, triangles (d = 2) or tetrahedra (d = 3)
    sources : (n,) int array of vertex indices
    cancel : callable returning bool, optional

    Returns
    -------
    (N, n) float array, non-negative, in the units of ``vertices``; column i is 0 at ``sources[i]``
    """
    vertices = np.asarray(vertices, dtype=float)
    if vertices.shape[1] == 2:
        return _heat_distances_triangles(vertices, cells, sources, cancel)
    return _heat_distances_tetrahedra(vertices, cells, sources)


def _heat_distances_triangles(vertices, cells, sources, cancel):
    import potpourri3d

    solver = potpourri3d.MeshHeatMethodDistanceSolver(np.c_[vertices, np.zeros(len(vertices))], np.asarray(cells))
    columns = []
    for source in sources:
        if cancel is not None and cancel():
            raise Cancelled("cancelled while computing geodesic distances")
        columns.append(solver.compute_distance(int(source)))
    return np.maximum(np.stack(columns, axis=1), 0.0)


def _heat_distances_tetrahedra(vertices, cells, sources):
    n_vertices = len(vertices)
    cells = np.asarray(cells)
    edges = np.concatenate([cells[:, [a, b]] for a in range(4) for b in range(a + 1, 4)])
    h = np.mean(np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1))
    G, measures = fem.gradient_operator(vertices, cells)
    volume_weights = sp.diags(np.repeat(measures, 3))
    stiffness = (G.T @ volume_weights @ G).tocsc()
    mass = sp.diags(fem.lumped_mass(cells, measures, n_vertices))

    impulses = np.zeros((n_vertices, len(sources)))
    impulses[sources, np.arange(len(sources))] = 1.0
    heat = spla.splu((mass + h * h * stiffness).tocsc()).solve(impulses)

    gradients = (G @ heat).reshape(len(cells), 3, -1)
    norms = np.linalg.norm(gradients, axis=1, keepdims=True)
    directions = -gradients / np.where(norms > 0, norms, 1.0)
    divergence = G.T @ (volume_weights @ directions.reshape(len(cells) * 3, -1))

    # The Poisson problem is singular (constants): pin vertex 0, then shift each column to 0 at its source.
    free = np.arange(1, n_vertices)
    distances = np.zeros((n_vertices, len(sources)))
    distances[free] = spla.splu(stiffness[free][:, free].tocsc()).solve(divergence[free])
    distances -= distances[sources, np.arange(len(sources))]
    return np.maximum(distances, 0.0)


def tv_weights(cells, distances, weighting="quadratic"):
    """Per-cell TV weights ω = ρ(D) from vertex distances.

    D is each cell's mean vertex distance divided by the largest distance over all vertices and sources (so D lies in
    [0, 1]), as in the authors' reference.

    Parameters
    ----------
    cells : (F, d+1) int array
    distances : (N, n) float array, from :func:`geodesic_distances`
    weighting : {"constant", "linear", "quadratic", "sqrt"} or callable
        ρ; a callable maps a (F, n) array in [0, 1] to non-negative weights of the same shape.

    Returns
    -------
    (F, n) float array, dimensionless
    """
    largest = distances.max()
    normalised = distances / largest if largest > 0 else distances
    cell_distance = normalised[np.asarray(cells)].mean(axis=1)
    if callable(weighting):
        rho = weighting
    elif weighting in WEIGHTINGS:
        rho = WEIGHTINGS[weighting]
    else:
        raise ValueError(f"unknown weighting {weighting!r}: use one of {sorted(WEIGHTINGS)} or a callable")
    weights = np.asarray(rho(cell_distance), dtype=float)
    if weights.shape != cell_distance.shape or not np.all(np.isfinite(weights)) or np.any(weights < 0):
        raise ValueError("the weighting function must return finite, non-negative values of the same shape")
    return weights
