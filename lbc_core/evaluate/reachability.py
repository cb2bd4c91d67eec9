"""Which domain vertices a point's smooth fit may use: those it reaches through the domain, not across a gap.

The moving least-squares fit (:mod:`lbc_core.evaluate.smoothing`) weighs the domain vertices within a ball around the
point. Where two parts of the cage face each other across a gap narrower than the ball (fingers side by side, an arm
along the body, the legs), the ball holds the other part's vertices too, whose coordinates belong to other control
points: the fit mixes them in, and a wide fit folds such parts when they move apart (bench/RESULTS.md, "Joints as smooth
as Mesh Deform's"). Here a vertex is weighed by its *detour*: how much longer the shortest path along the domain's edges
from a cell corner to it is than the straight line. A pair (corner c, vertex j) whose detour is more than :data:`NEAR`
fit radii is *blocked*, by 1 - smootherstep of the detour between :data:`NEAR` and :data:`FAR` radii (0 beyond, and
where no path that short exists). A point's factor for vertex j is the barycentric mean of its cell corners' factors,
so it is continuous in the point. Inside one part, paths along tetrahedral edges are about as long as straight lines
(at most about 1.3 times), nothing is blocked and the fit is the plain one, as smooth.
"""

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from ..kernel.progress import Progress

# Detours through the domain, in fit radii, over which a vertex's weight in the fit fades out (bench/RESULTS.md,
# "Joints as smooth as Mesh Deform's": inside one part a path along tetrahedral edges is at most about 1.3 times the
# straight line, less than NEAR radii longer, so the fit is left alone there).
NEAR = 0.75
FAR = 1.5
_SOURCES_PER_CALL = 256  # Dijkstra's sources at a time: bounds its dense (sources, N) output


class DomainPaths:
    """The blocked pairs (corner, vertex) of a domain mesh for a fit of a given radius, and each point's factor per
    fitted vertex.

    Parameters
    ----------
    vertices : (N, d) float array
    cells : (F, d+1) int array
    radius : float
        The fit's largest radius (length units).
    depth : (N,) float array
        Each vertex's distance to the cage: a vertex deeper than the fit's reach has nothing across a gap within it.
    corners : (k,) int array, optional
        The vertices whose pairs are wanted (the corners of the points' cells); None: every vertex.
    progress : Progress, optional
        Checked between rounds of sources.
    """

    def __init__(self, vertices, cells, radius, depth, corners=None, progress=None):
        progress = Progress.of(progress)
        vertices = np.asarray(vertices, dtype=float)
        graph, longest = _edge_graph(vertices, np.asarray(cells))
        self.radius = float(radius)
        self.count = len(vertices)
        # A point's fit reaches vertices within the radius, and its cell's corners lie within their longest edge of
        # it; a vertex deeper than that has the whole ball inside the domain.
        reach = self.radius + longest
        tree = cKDTree(vertices)
        near = tree.sparse_distance_matrix(tree, reach.max(initial=0.0), output_type="coo_matrix")
        wanted = np.asarray(depth) < reach
        if corners is not None:
            wanted &= np.isin(np.arange(self.count), corners)
        close = (near.data < reach[near.row]) & wanted[near.row]
        # Each pair's straight distance (a tiny one for a vertex and itself, so that the pair is stored).
        pairs = sp.csr_matrix((np.maximum(near.data[close], np.finfo(float).tiny), (near.row[close], near.col[close])),
                              shape=(self.count, self.count))
        limit = reach.max(initial=0.0) + FAR * self.radius
        pairs.sort_indices()  # so the keys below come out sorted: sources in order, then targets
        sources = np.flatnonzero(np.diff(pairs.indptr))
        keys, factors = [np.zeros(0, dtype=np.int64)], [np.zeros(0)]
        for start in range(0, len(sources), _SOURCES_PER_CALL):
            progress.check()
            chunk = sources[start:start + _SOURCES_PER_CALL]
            paths = dijkstra(graph, directed=False, indices=chunk, limit=limit)
            lo, hi = pairs.indptr[chunk[0]], pairs.indptr[chunk[-1] + 1]
            rows = np.repeat(np.arange(len(chunk)), np.diff(pairs.indptr)[chunk])
            targets = pairs.indices[lo:hi].astype(np.int64)
            detour = paths[rows, targets] - pairs.data[lo:hi]
            blocked = ~(detour <= NEAR * self.radius)
            keys.append(chunk[rows[blocked]].astype(np.int64) * self.count + targets[blocked])
            factors.append(path_factor(detour[blocked] / self.radius))
        self.keys, self.factors = np.concatenate(keys), np.concatenate(factors)
        self.has_blocked = np.zeros(self.count, dtype=bool)
        self.has_blocked[self.keys // max(self.count, 1)] = True

    def factors_of(self, linear, distances):
        """Each stored pair's factor (0 to 1) in ``distances``: the points' (rows of ``linear``, their barycentric
        rows) barycentric mean of their corners' factors for that vertex.

        Parameters
        ----------
        linear : (k, N) CSR
        distances : (k, N) CSR
            The pairs of the fit (:func:`lbc_core.evaluate.smoothing.neighbour_distances`).

        Returns
        -------
        (nnz,) float array, in the order of ``distances.data``
        """
        factor = np.ones(distances.nnz)
        if not len(self.keys):
            return factor
        linear = sp.csr_matrix(linear)
        corner_rows = np.repeat(np.arange(linear.shape[0]), np.diff(linear.indptr))
        touched = np.unique(corner_rows[self.has_blocked[linear.indices]])
        if not len(touched):
            return factor
        counts = np.diff(distances.indptr)
        owner = np.repeat(np.arange(distances.shape[0]), counts)
        pairs = np.flatnonzero(np.isin(owner, touched))
        factor[pairs] = 0.0
        targets = distances.indices[pairs].astype(np.int64)
        for corner_slot in range(int(np.diff(linear.indptr).max())):
            corner, share = _corner(linear, owner[pairs], corner_slot)
            key = corner * self.count + targets
            at = np.minimum(np.searchsorted(self.keys, key), len(self.keys) - 1)
            found = self.keys[at] == key
            factor[pairs] += share * np.where(found, self.factors[at], 1.0)
        return factor


def path_factor(detours):
    """1 - smootherstep of the detour (fit radii) between NEAR and FAR: 1 at NEAR or less, 0 from FAR (and for no
    path within the search: infinity)."""
    t = np.clip((np.asarray(detours, dtype=float) - NEAR) / (FAR - NEAR), 0.0, 1.0)
    return np.clip(1.0 - t ** 3 * (t * (6.0 * t - 15.0) + 10.0), 0.0, 1.0)


def _corner(linear, rows, slot):
    """The ``slot``-th corner of each row in ``rows`` of the barycentric CSR ``linear`` and its weight (-1 and 0 for a
    row with fewer corners)."""
    counts = np.diff(linear.indptr)[rows]
    has = counts > slot
    at = linear.indptr[rows] + np.minimum(slot, np.maximum(counts - 1, 0))
    corner = np.where(has, linear.indices[at], -1).astype(np.int64)
    share = np.where(has, linear.data[at], 0.0)
    return corner, share


def _edge_graph(vertices, cells):
    """The domain's edges as a symmetric sparse graph weighted by length, and each vertex's longest edge."""
    corners = cells.shape[1]
    pairs = np.concatenate([cells[:, [a, b]] for a in range(corners) for b in range(a + 1, corners)])
    pairs = np.unique(np.sort(pairs, axis=1), axis=0)
    length = np.linalg.norm(vertices[pairs[:, 0]] - vertices[pairs[:, 1]], axis=1)
    n = len(vertices)
    graph = sp.csr_matrix((length, (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    longest = np.zeros(n)
    np.maximum.at(longest, pairs[:, 0], length)
    np.maximum.at(longest, pairs[:, 1], length)
    return graph, longest
