"""Points grouped by the small cube they lie in, with each cube's candidate vertices: the smooth fit's layout.

The moving least-squares fit (:mod:`lbc_core.evaluate.smoothing`) weighs, for each point, the domain vertices within
a radius of it: about 125 of them at the default smoothness, so the demo's 64k points make 8 million (point, vertex)
pairs. Pairs held one by one (a sparse distance matrix, a sparse matrix of rows, its product with the coordinates)
cost an index and a scattered read each; grouped by cube they are dense blocks. Every point of a cube of side ``side``
lies within ``side`` √d / 2 of its centre, so the vertices within ``reach`` of any of them lie within ``reach + side``
√d / 2 of the centre: one search per cube, and each point's pairs are a row of a dense (points, candidates) block,
whose sums and products are matrix products (bench/RESULTS.md, "The bind outside the solve, cheaper").
"""

import numpy as np
from scipy.spatial import cKDTree

# The most points of one cube taken as one block: bounds a block's memory (points × candidates × 8 bytes, a few
# arrays of it) on a dense mesh in a coarse domain.
MOST_POINTS_PER_BLOCK = 1024


class PointGroups:
    """The points' cubes, an order that keeps each cube's points together, and each cube's candidate vertices.

    Parameters
    ----------
    points : (m, d) float array
    vertices : (N, d) float array
    tree : scipy.spatial.cKDTree of ``vertices``
    side : float
        The cubes' side (length units, > 0).
    reach : float
        The farthest vertex any point may need (length units).

    Attributes
    ----------
    cube : (m,) int array
        Each point's cube (a row of ``centres``).
    order : (m,) int array
        The points sorted by cube (then by index): cubes in slabs, so that consecutive points lie close together.
    centres : (c, d) float array
    """

    def __init__(self, points, vertices, tree, side, reach):
        points = np.asarray(points, dtype=float)
        d = points.shape[1]
        cells = np.floor(points / side).astype(np.int64)
        low = cells.min(axis=0) if len(cells) else np.zeros(d, dtype=np.int64)
        cells -= low
        extent = cells.max(axis=0) + 1 if len(cells) else np.ones(d, dtype=np.int64)
        key = np.ravel_multi_index(tuple(cells.T), tuple(extent)) if len(cells) else np.zeros(0, dtype=np.int64)
        keys, self.cube = np.unique(key, return_inverse=True)
        self.cube = self.cube.ravel()
        self.order = np.argsort(self.cube, kind="stable")
        self.centres = (np.stack(np.unravel_index(keys, tuple(extent)), axis=1) + low + 0.5) * side
        # A point lies within side √d / 2 of its cube's centre; the margin keeps rounding from losing a vertex.
        search = (reach + side * np.sqrt(d) / 2) * (1 + 1e-9) + 1e-12 * side
        found = cKDTree(self.centres).sparse_distance_matrix(tree, search, output_type="coo_matrix").tocsr()
        found.sort_indices()
        self._starts, self._candidates = found.indptr, found.indices.astype(np.int64)
        self.vertices = np.asarray(vertices, dtype=float)

    def candidates(self, cube):
        """The vertices within reach of some point of ``cube``, sorted (and a few more)."""
        return self._candidates[self._starts[cube]:self._starts[cube + 1]]

    def blocks(self, rows):
        """The given points (an int array of indices) as blocks: (positions in ``rows``, cube) pairs, each block the
        points of ``rows`` in one cube (at most :data:`MOST_POINTS_PER_BLOCK`), in ``rows``' order within it."""
        rows = np.asarray(rows, dtype=np.int64)
        if not len(rows):
            return []
        cubes = self.cube[rows]
        ranked = np.argsort(cubes, kind="stable")
        ends = np.flatnonzero(np.diff(cubes[ranked])) + 1
        found = []
        for part in np.split(ranked, ends):
            for start in range(0, len(part), MOST_POINTS_PER_BLOCK):
                block = part[start:start + MOST_POINTS_PER_BLOCK]
                found.append((block, int(cubes[block[0]])))
        return found
