"""Geodesic distances inside the cage (heat method) and the TV weights built from them (the paper's Section 3.3).

The heat method's distances are checked against the straight line, which bounds every distance inside the domain
from below; where they fall far under it (the flattened tetrahedra of a very thin cage, on which the heat step
oscillates in sign; a 2D strip 1/500 as wide as long), the distances along the mesh's edges replace them.

The total variation of coordinate i is weighted per cell by ω = ρ(D_i), with D_i the geodesic distance from control
point i normalised to [0, 1]: far from its control point a coordinate pays more for varying, which keeps it local.
"""

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from ..kernel import fem
from ..kernel.factor import Factor
from ..kernel.progress import Progress


def _constant(d):
    """ρ = 1, written over ``d``."""
    d[...] = 1.0
    return d


# ρ of each weighting, by name; the paper's first (lbc_core.binding.options.WEIGHTINGS lists these names for the
# options). They work in place on the (F, n) array tv_weights made for them: a fresh one costs as much as the
# arithmetic.
WEIGHTINGS = {
    "quadratic": lambda d: np.multiply(d, d, out=d),
    "linear": lambda d: d,
    "sqrt": lambda d: np.sqrt(d, out=d),
    "constant": _constant,
}
# The heat method's check, in shares: of the pairs farther apart than FAR_SHARE of the largest straight-line distance,
# at most MOST_BELOW under BELOW_STRAIGHT times their straight line, on at most CHECKED_VERTICES vertices, evenly
# spread (bench/RESULTS.md, "Geodesic distances on very thin cages").
FAR_SHARE, BELOW_STRAIGHT, MOST_BELOW = 0.25, 0.8, 0.01
CHECKED_VERTICES = 2000
# Sources whose distances are computed together in 3D: bounds the (3 F, sources) gradient arrays and the time between
# two cancel checks (8 sources take 0.1-0.3 s on 64k tetrahedra).
SOURCES_PER_CHUNK = 8


def geodesic_distances(vertices, cells, sources, progress=None, cancel=None):
    """Heat-method geodesic distance from each source vertex to every vertex of the mesh; where the heat method fails
    (:func:`heat_distances_sound`), the shortest paths along the mesh's edges (:func:`edge_distances`).

    Triangles use potpourri3d's heat method; tetrahedra a P1 finite-element heat method (Crane et al. 2013):
    diffuse for time h² (h the mean edge length), normalise the gradient, and solve a Poisson problem.

    Parameters
    ----------
    vertices : (N, d) float array
    cells : (F, d+1) int array, triangles (d = 2) or tetrahedra (d = 3)
    sources : (n,) int array of vertex indices
    progress : callable(fraction, message) or Progress, optional
    cancel : callable returning bool, optional
        Polled between sources (2D) or chunks of sources (3D); when it returns True, :class:`Cancelled` is raised.

    Returns
    -------
    (N, n) float array, non-negative, in the units of ``vertices``; column i is 0 at ``sources[i]``
    """
    progress = Progress.of(progress, cancel)
    vertices = np.asarray(vertices, dtype=float)
    heat = _heat_distances_triangles if vertices.shape[1] == 2 else _heat_distances_tetrahedra
    distances = heat(vertices, cells, sources, progress.part(0.0, 0.8))
    if not heat_distances_sound(vertices, sources, distances):
        distances = edge_distances(vertices, cells, sources, progress.part(0.8, 1.0))
    progress(1.0, "geodesic distances: done")
    return distances


def heat_distances_sound(vertices, sources, distances):
    """Whether heat-method distances keep to the straight line's lower bound (see FAR_SHARE).

    Parameters
    ----------
    vertices : (N, d) float array
    sources : (n,) int array
    distances : (N, n) float array, from the heat method

    Returns
    -------
    bool
    """
    rows = np.arange(0, len(vertices), max(1, len(vertices) // CHECKED_VERTICES))
    straight = np.linalg.norm(vertices[rows, None, :] - vertices[np.asarray(sources)][None], axis=2)
    far = straight > FAR_SHARE * straight.max()
    if not far.any():
        return True
    return np.mean(distances[rows][far] < BELOW_STRAIGHT * straight[far]) <= MOST_BELOW


def edge_distances(vertices, cells, sources, progress=None):
    """Shortest paths along the mesh's edges from each source (Dijkstra): never below the straight line, on any
    cells, at the price of some length where a path zigzags (across a 1/50 plate, under 1.1 × the straight line at
    the median).

    Parameters
    ----------
    vertices : (N, d) float array
    cells : (F, d+1) int array
    sources : (n,) int array
    progress : callable(fraction, message) or Progress, optional

    Returns
    -------
    (N, n) float array, in the units of ``vertices``
    """
    progress = Progress.of(progress)
    cells = np.asarray(cells)
    corners = cells.shape[1]
    edges = np.unique(np.sort(np.concatenate([cells[:, [a, b]] for a in range(corners) for b in range(a)]), axis=1),
                      axis=0)
    lengths = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    graph = sp.csr_matrix((lengths, (edges[:, 0], edges[:, 1])), shape=(len(vertices), len(vertices)))
    sources = np.asarray(sources)
    distances = np.empty((len(vertices), len(sources)))
    for start in range(0, len(sources), SOURCES_PER_CHUNK):
        progress(start / len(sources), "geodesic distances: along the mesh's edges (the heat method failed on "
                                       "this thin mesh)")
        chunk = sources[start:start + SOURCES_PER_CHUNK]
        distances[:, start:start + len(chunk)] = dijkstra(graph, directed=False, indices=chunk).T
    return distances


def _heat_distances_triangles(vertices, cells, sources, progress):
    import potpourri3d

    progress(0.0, "geodesic distances: preparing")
    solver = potpourri3d.MeshHeatMethodDistanceSolver(np.c_[vertices, np.zeros(len(vertices))], np.asarray(cells))
    columns = []
    for count, source in enumerate(sources):
        progress(count / len(sources), f"geodesic distances: solving, {count} of {len(sources)} cage vertices done")
        columns.append(solver.compute_distance(int(source)))
    return np.maximum(np.stack(columns, axis=1), 0.0)


def _heat_distances_tetrahedra(vertices, cells, sources, progress):

    progress(0.0, "geodesic distances: preparing")
    n_vertices = len(vertices)
    cells = np.asarray(cells)
    edges = np.concatenate([cells[:, [a, b]] for a in range(4) for b in range(a + 1, 4)])
    h = np.mean(np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1))
    G, measures = fem.gradient_operator(vertices, cells)
    volume_weights = sp.diags(np.repeat(measures, 3))
    stiffness = (G.T @ volume_weights @ G).tocsr()
    mass = sp.diags(fem.lumped_mass(cells, measures, n_vertices))
    progress.check()
    heat_solver = Factor(sp.tril(mass + h * h * stiffness).tocoo(), np.float64)
    progress.check()
    # The Poisson problem is singular (constants): pin vertex 0, then shift each column to 0 at its source.
    free = np.arange(1, n_vertices)
    poisson_lower = sp.tril(stiffness[free][:, free]).tocoo()
    progress.check()
    poisson_solver = Factor(poisson_lower, np.float64)

    sources = np.asarray(sources)
    distances = np.zeros((n_vertices, len(sources)))
    for start in range(0, len(sources), SOURCES_PER_CHUNK):
        progress(0.1 + 0.9 * start / len(sources),
                 f"geodesic distances: solving, {start} of {len(sources)} cage vertices done")
        chunk = sources[start:start + SOURCES_PER_CHUNK]
        impulses = np.zeros((n_vertices, len(chunk)))
        impulses[chunk, np.arange(len(chunk))] = 1.0
        heat = heat_solver.solve(impulses)
        gradients = (G @ heat).reshape(len(cells), 3, -1)
        norms = np.linalg.norm(gradients, axis=1, keepdims=True)
        directions = -gradients / np.where(norms > 0, norms, 1.0)
        divergence = G.T @ (volume_weights @ directions.reshape(len(cells) * 3, -1))
        block = np.zeros((n_vertices, len(chunk)))
        block[free] = poisson_solver.solve(np.ascontiguousarray(divergence[free]))
        block -= block[chunk, np.arange(len(chunk))]
        distances[:, start:start + len(chunk)] = block
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
    cells = np.asarray(cells)
    # The mean over each cell's corners as a sparse product: no (F, d+1, n) temporary (340 MB at 64k tetrahedra).
    corners = cells.shape[1]
    averaging = sp.csr_matrix(
        (np.full(cells.size, 1.0 / corners), cells.ravel(), np.arange(0, cells.size + 1, corners)),
        shape=(len(cells), len(distances)),
    )
    cell_distance = averaging @ (distances / largest if largest > 0 else distances)
    if callable(weighting):
        rho = weighting
    elif weighting in WEIGHTINGS:
        rho = WEIGHTINGS[weighting]
    else:
        raise ValueError(f"unknown weighting {weighting!r}: use one of {sorted(WEIGHTINGS)} or a callable")
    weights = np.asarray(rho(cell_distance), dtype=float)
    # min ≥ 0 fails on NaN and -inf, a finite max on +inf: two reductions, no (F, n) temporaries.
    if weights.shape != cell_distance.shape or not (weights.min() >= 0 and np.isfinite(weights.max())):
        raise ValueError("the weighting function must return finite, non-negative values of the same shape")
    return weights
