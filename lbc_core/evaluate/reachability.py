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

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from ..kernel.geometry import row_keys
from ..kernel.progress import Progress

# Detours through the domain, in fit radii, over which a vertex's weight in the fit fades out (bench/RESULTS.md,
# "Joints as smooth as Mesh Deform's": inside one part a path along tetrahedral edges is at most about 1.3 times the
# straight line, less than NEAR radii longer, so the fit is left alone there).
NEAR = 0.75
FAR = 1.5
# Dijkstra's dense (sources, N) output per call, in entries, and its sources per call at most.
_ENTRIES_PER_CALL = 1 << 20
_SOURCES_PER_CALL = 64
# A search limit this much (relative) past a pair's FAR detour proves its factor exactly 0 without its path.
_MARGIN = 1e-9
# One corner in this many searched up to NEAR first, as a sample of where the gaps are.
_SAMPLE_EVERY = 8


class DomainPaths:
    """The blocked pairs (corner, vertex) of a domain mesh for a fit of a given radius, and each point's factor per
    fitted vertex.

    A corner's pairs need its shortest paths only up to its reach plus :data:`FAR` radii (beyond, every factor is
    0), and to show a pair unblocked only up to its reach plus :data:`NEAR` radii. So each corner is searched up to
    NEAR first, and again up to FAR only if that left a pair's factor undecided (a pair across a gap); a corner whose
    nearest sampled corner needed FAR is searched up to FAR at once. The paths within a bound are exact whatever the
    bound, so every factor is that of the pair's shortest path, as an unbounded search would find it
    (bench/RESULTS.md, "The fit through the domain, cheaper").

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

    Attributes
    ----------
    keys : (b,) int64 array
        The blocked pairs, corner * N + vertex, sorted.
    factors : (b,) float array
        Their factors (:func:`path_factor`).
    searches, reached : int
        The work: searches from a corner, and the vertices they reached, summed.
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
        wanted = np.asarray(depth) < reach
        if corners is not None:
            chosen = np.zeros(self.count, dtype=bool)
            chosen[np.asarray(corners, dtype=np.int64)] = True
            wanted &= chosen
        search = _Search(vertices, graph, reach, self.radius, progress)
        found = _search_by_sample(search, np.flatnonzero(wanted))
        keys = np.concatenate([part.keys for part in found])
        order = np.argsort(keys, kind="stable")
        self.keys, self.factors = keys[order], np.concatenate([part.factors for part in found])[order]
        self.searches, self.reached = search.searches, search.reached
        self.has_blocked = np.zeros(self.count, dtype=bool)
        self.has_blocked[self.keys // max(self.count, 1)] = True
        # Each blocked pair's place in ``factors``, plus 1, at (corner, vertex): a lookup by binary search in the
        # corner's row, shorter than one over every key.
        self._places = sp.csr_array((np.arange(1, len(self.keys) + 1, dtype=float),
                                     (self.keys // max(self.count, 1), self.keys % max(self.count, 1))),
                                    shape=(self.count, self.count))

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
        corners, shares = corners_of(sp.csr_matrix(linear))
        touched = np.flatnonzero(self.touched(corners))
        if not len(touched):
            return factor
        # The pairs of the points a blocked corner touches, and each one's point (its row in ``touched``).
        counts = np.diff(distances.indptr)[touched]
        owner = np.repeat(np.arange(len(touched)), counts)
        pairs = np.repeat(distances.indptr[touched] - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
        factor[pairs] = self._mean_factors(corners[touched], shares[touched], owner,
                                           distances.indices[pairs].astype(np.int64))
        return factor

    def apply_factors(self, blocks, corners, shares):
        """Multiply blocks' kernel weights by their factors, as :meth:`factors_of` gives them, in place: only the
        pairs of points with a blocked corner and a weight, looked up in one call for all the blocks (a call costs
        milliseconds whatever its size).

        Parameters
        ----------
        blocks : list of (positions (g,), candidates (C,), weight (g, C)) triples
            Each block's points (rows of ``corners``), candidate vertices and kernel weights.
        corners, shares : (k, c) arrays
            The points' :func:`corners_of`.
        """
        found = []
        for block, candidates, weight in blocks:
            touched = np.flatnonzero(self.touched(corners[block]))
            rows, slots = np.nonzero(weight[touched] != 0)
            found.append((touched[rows], slots, block[touched[rows]], np.asarray(candidates, dtype=np.int64)[slots]))
        points = np.concatenate([entry[2] for entry in found])
        if not len(points):
            return
        factors = self._mean_factors(corners[points], shares[points], np.arange(len(points)),
                                     np.concatenate([entry[3] for entry in found]))
        start = 0
        for (_, _, weight), (rows, slots, _, _) in zip(blocks, found):
            weight[rows, slots] *= factors[start:start + len(rows)]
            start += len(rows)

    def touched(self, corners):
        """Which points (rows of ``corners``, :func:`corners_of`) have a corner with blocked pairs: (k,) bool."""
        return (self.has_blocked[np.maximum(corners, 0)] & (corners >= 0)).any(axis=1)

    def _mean_factors(self, corners, shares, owner, targets):
        """The barycentric mean of the corners' factors of each pair (point ``owner``, vertex ``targets``)."""
        blocked = self.has_blocked[np.maximum(corners, 0)] & (corners >= 0)
        total = np.zeros(len(owner))
        for slot in range(corners.shape[1]):
            # A corner without blocked pairs adds its share times 1, as a search that finds nothing would.
            value = np.ones(len(owner))
            look = np.flatnonzero(blocked[:, slot][owner])
            if len(look):
                place = np.asarray(self._places[corners[owner[look], slot], targets[look]], dtype=np.int64)
                value[look] = np.where(place > 0, self.factors[place - 1], 1.0)
            total += shares[:, slot][owner] * value
        return total


def path_factor(detours):
    """1 - smootherstep of the detour (fit radii) between NEAR and FAR: 1 at NEAR or less, 0 from FAR (and for no
    path within the search: infinity)."""
    t = np.clip((np.asarray(detours, dtype=float) - NEAR) / (FAR - NEAR), 0.0, 1.0)
    return np.clip(1.0 - t ** 3 * (t * (6.0 * t - 15.0) + 10.0), 0.0, 1.0)


def corners_of(linear):
    """Each row's corners and their weights, (k, c) each, in the order of the barycentric CSR ``linear``'s rows (-1
    and 0 where a row has fewer corners)."""
    counts = np.diff(linear.indptr)
    slots = np.arange(int(counts.max(initial=0)))
    has = slots[None, :] < counts[:, None]
    if not len(linear.indices):
        return np.full(has.shape, -1, dtype=np.int64), np.zeros(has.shape)
    at = np.minimum(linear.indptr[:-1, None] + slots[None, :], len(linear.indices) - 1)
    return np.where(has, linear.indices[at], -1).astype(np.int64), np.where(has, linear.data[at], 0.0)


def _search_by_sample(search, sources):
    """Every source's blocked pairs, as :class:`_Found` parts: a sample of the sources searched up to NEAR first
    tells where gaps lie; a source whose nearest sampled one needed FAR is searched up to FAR at once (a choice of
    bound, not of results), the others up to NEAR and again up to FAR if that left a factor undecided."""
    sampled = np.zeros(len(sources), dtype=bool)
    sampled[::_SAMPLE_EVERY] = True
    sample = search.run(sources[sampled], NEAR)
    by_gap = np.isin(sources, sample.unresolved)
    predicted = np.zeros(len(sources), dtype=bool)
    if sampled.any():
        _, nearest = cKDTree(search.vertices[sources[sampled]]).query(search.vertices[sources])
        predicted = by_gap[np.flatnonzero(sampled)[nearest]] & ~sampled
    rest = search.run(sources[~sampled & ~predicted], NEAR)
    far = search.run(np.concatenate([sources[predicted], sample.unresolved, rest.unresolved]), FAR)
    return sample, rest, far


class _Found(NamedTuple):
    """What a round of searches found: the blocked pairs' keys and factors, and the sources it left undecided."""

    keys: np.ndarray
    factors: np.ndarray
    unresolved: np.ndarray


class _Search:
    """Dijkstra searches from the corners of a domain's edge graph, a chunk of sources per call, each call bounded by
    its sources' farthest reach plus a detour: the shortest paths within the bound are exact (the same lengths
    whatever the bound), so a pair's factor is the same as that of an unbounded search wherever the bound decides it.

    Parameters
    ----------
    vertices : (N, d) float array
    graph : (N, N) CSR, symmetric
        The edges weighted by length (:func:`_edge_graph`).
    reach : (N,) float array
        Each vertex's reach: the fit's radius plus its longest edge.
    radius : float
    progress : Progress
    """

    def __init__(self, vertices, graph, reach, radius, progress):
        self.vertices, self.graph, self.reach, self.radius, self.progress = vertices, graph, reach, radius, progress
        self.tree = cKDTree(vertices)
        # The longest search any pair needs: beyond it every factor is 0.
        self.longest = reach.max(initial=0.0) + FAR * radius
        self.searches = self.reached = 0

    def run(self, sources, detour):
        """Search from ``sources`` up to their reach plus ``detour`` radii (:data:`NEAR` or :data:`FAR`): a _Found
        with the blocked pairs of the sources it decided, and those it left undecided (a pair unreached within a
        bound too short to show its factor 0)."""
        count = len(self.vertices)
        sources = sources[np.argsort(self.reach[sources], kind="stable")]  # alike bounds in one call
        size = max(1, min(_SOURCES_PER_CALL, _ENTRIES_PER_CALL // max(count, 1)))
        keys, factors, unresolved = [np.zeros(0, dtype=np.int64)], [np.zeros(0)], [np.zeros(0, dtype=np.int64)]
        for start in range(0, len(sources), size):
            self.progress.check()
            chunk = sources[start:start + size]
            limit = min(self.longest, (self.reach[chunk].max() + detour * self.radius) * (1.0 + _MARGIN))
            paths = dijkstra(self.graph, indices=chunk, limit=limit)
            self.searches += len(chunk)
            self.reached += int(np.isfinite(paths).sum())
            rows, targets, straight = self._pairs(chunk)
            detours = paths[rows, targets] - straight
            blocked = ~(detours <= NEAR * self.radius)
            # Unreached: longer than the limit; its factor is 0 if the limit is FAR radii past the straight line.
            undecided = np.isinf(detours) & (limit < self.longest) & (limit - straight < FAR * self.radius *
                                                                      (1.0 + _MARGIN))
            left = np.zeros(len(chunk), dtype=bool)
            left[rows[undecided]] = True
            kept = blocked & ~left[rows]
            keys.append(chunk[rows[kept]].astype(np.int64) * count + targets[kept])
            factors.append(path_factor(detours[kept] / self.radius))
            unresolved.append(chunk[left])
        return _Found(np.concatenate(keys), np.concatenate(factors), np.concatenate(unresolved))

    def _pairs(self, chunk):
        """The pairs (row in ``chunk``, vertex) within each source's reach: rows, vertices, and their straight
        distances (a tiny one for a vertex and itself)."""
        reach = self.reach[chunk]
        near = cKDTree(self.vertices[chunk]).sparse_distance_matrix(self.tree, reach.max(), output_type="coo_matrix")
        close = near.data < reach[near.row]
        return (near.row[close], near.col[close].astype(np.int64),
                np.maximum(near.data[close], np.finfo(float).tiny))


def _edge_graph(vertices, cells):
    """The domain's edges as a symmetric sparse graph weighted by length, and each vertex's longest edge."""
    corners = cells.shape[1]
    n = len(vertices)
    ends = np.concatenate([cells[:, [a, b]] for a in range(corners) for b in range(a + 1, corners)])
    # Each edge once, as one number (low * n + high): np.unique over numbers is several times faster than over rows.
    key = np.unique(row_keys(np.sort(ends, axis=1), max(n, 1)))
    low, high = key // max(n, 1), key % max(n, 1)
    length = np.linalg.norm(vertices[low] - vertices[high], axis=1)
    graph = sp.csr_matrix((np.concatenate([length, length]), (np.concatenate([low, high]),
                                                              np.concatenate([high, low]))), shape=(n, n))
    longest = np.zeros(n)
    np.maximum.at(longest, low, length)
    np.maximum.at(longest, high, length)
    return graph, longest
