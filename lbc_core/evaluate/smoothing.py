"""Smooth evaluation of the coordinates at the points: a moving least-squares fit of the solver's P1 solution.

The solver's coordinates are linear inside each cell, so a deformed smooth surface creases where it crosses a cell
face. Here a point's coordinates are instead the value at the point of the linear function that best fits, by
least squares weighted with a smooth compactly supported kernel, the coordinates at the domain vertices within a
radius of it (moving least squares). The fit is a fixed linear map of the vertex values, smooth in the point, and it
reproduces any linear function of the vertices exactly; the coordinates at the vertices sum to 1 and reproduce the
vertices, so the fitted coordinates sum to 1 and reproduce the point, before any correction. What the fit can lose,
non-negativity where a coordinate's support ends, the reduction restores on each point's support
(:mod:`lbc_core.evaluate.reduction`).

Near the cage the fit fades into the plain P1 interpolation, by each point's own distance to the cage: a point on the
cage gets the interpolated boundary values, and a point on a cage vertex is that vertex's alone (Lagrange). Where the
cage is one cell across (a finger, a toe) every domain vertex lies on the cage, yet its inner points are fitted.
"""

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..kernel.constraints import solve_symmetric
from ..kernel.progress import Progress
from .groups import PointGroups
from .interpolation import FacetSearch
from .reachability import DomainPaths, corners_of

# Smooth ↔ local, 0 to 1: how wide the smooth evaluation's fit reaches (radius_for) and how much the
# add-on's thinning keeps (lbc_core.evaluate.thinning.floor_for). 0.5 folds the joints of a real character less than
# Mesh Deform for 1.1-1.35 times the influences of 0 (bench/RESULTS.md, "Joints as smooth as Mesh Deform's").
DEFAULT_SMOOTHNESS = 0.5
# The fit's radius in median cell edges at smoothness 0 and 1 (BindOptions.smoothness): wider is smoother and costs
# more influences per point (bench/RESULTS.md, "Joints as smooth as Mesh Deform's").
RADIUS_EDGES = 2.0
SMOOTH_RADIUS_EDGES = 4.0
# The radius where the cage is thick, and the local depths (median cell edges) over which the radius grows to it.
# 3 creases bent limbs less but costs a fifth more influences and twice the warm re-bind, so it is not the default
# (bench/RESULTS.md, "A wider fit where the cage is thick").
DEEP_RADIUS_EDGES = RADIUS_EDGES
DEPTH_EDGES = (0.2, 0.8)
# Distance from the cage (median cell edges, each point's own) over which the fit fades into the P1
# interpolation (bench/RESULTS.md, "The smooth evaluation's fade into P1: over a quarter of a cell edge instead of
# one").
FADE_EDGES = 0.25
# A fit whose moment matrix is this ill-conditioned (too few or coplanar vertices in reach) is not used.
MAX_CONDITION = 1e8
# An outside point's extrapolated row that misses the point by more than this (unit frame) is not used: it follows
# its closest point (bench/RESULTS.md, "Points outside the cage extrapolate in every bind").
EXTRAPOLATION_MISS = 1e-6
_CHUNK = 1 << 14  # points fitted at a time: bounds the (point, vertex) pairs held
# The side of the cubes whose points are fitted as one block, in median cell edges: smaller cubes search fewer
# vertices beyond each point's reach, larger ones make fewer, larger blocks (1: a third of the time of 0.5 or 2 on
# the demo; bench/RESULTS.md, "The bind outside the solve, cheaper").
CUBE_EDGES = 2.0


class SmoothInterpolation:
    """The (m, N) interpolation matrix from a domain's vertices to points, rows computed on demand.

    Row i is (1 - β_i) times the point's P1 barycentric row plus β_i times its moving least-squares row, where β
    rises smoothly from 0 on the cage to 1 at ``fade`` from it. The fit's radius may be wider where the cage is
    thick than across thin parts, where a wide fit would reach across the gaps between them (fingers, toes). Every
    row sums to 1 and reproduces the point. A point
    outside the cage, bound to its closest domain point q, reproduces q, unless ``points`` and ``outside`` are given:
    then its row is q's P1 row plus the offset p - q times the gradient of the fit at q (:func:`fit_gradients`), so it
    reproduces p itself (where the fit at q can: else q's row), and the part outside turns with the cage around it
    instead of only following q (a tip poking out of a curled tentacle's cage stays a tip; bench/RESULTS.md). Such a
    row may hold negative weights: no non-negative weights reproduce a point outside the hull of their control
    points. Used like a CSR matrix by :func:`lbc_core.evaluate.reduction.interpolate_and_reduce`: ``shape``, row slices,
    ``linear`` and ``outside``.

    Parameters
    ----------
    vertices : (N, d) float array
        Domain mesh vertices.
    cells : (F, d+1) int array
        Domain mesh cells (their boundary is the cage).
    located : (m, N) scipy.sparse.csr_matrix
        The points' P1 barycentric rows (:func:`lbc_core.evaluate.interpolation.interpolation_matrix`).
    radius_edges, fade_edges : float
        The fit's radius near the cage and the fade's width, in median cell edge lengths.
    deep_radius_edges : float
        The fit's radius where the cage is thick: it grows to it with the local depth across ``depth_edges``
        (:meth:`radius_at`).
    depth_edges : (float, float)
        The local depths (median cell edge lengths) between which the radius grows.
    reach : float
        Scales every length above: the median edge of a mesh whose previous evaluation is kept in part.
    progress : Progress, optional
        Checked for cancellation before each chunk of rows (:class:`~lbc_core.errors.Cancelled`).
    points : (m, d) float array, optional
        The points themselves (``located`` holds where the outside ones are bound).
    outside : (m,) bool array, optional
        The points outside the cage (:func:`~lbc_core.evaluate.interpolation.interpolation_matrix`'s flags), whose rows
        extrapolate to the point; with ``points``.
    through_domain : bool
        Weigh the fitted vertices by their paths through the domain (:mod:`lbc_core.evaluate.reachability`), so that a
        fit wider than a gap between parts of the cage does not reach across it; False: every vertex in the ball.
    """

    def __init__(self, vertices, cells, located, radius_edges=RADIUS_EDGES, fade_edges=FADE_EDGES, progress=None,
                 points=None, outside=None, deep_radius_edges=DEEP_RADIUS_EDGES, depth_edges=DEPTH_EDGES, reach=1.0,
                 through_domain=True):
        self.vertices = np.asarray(vertices, dtype=float)
        self.located = sp.csr_matrix(located)
        self.shape = self.located.shape
        if (points is None) != (outside is None):
            raise ValueError("give both the points and their outside flags, or neither")
        self.outside = None if outside is None else np.asarray(outside, dtype=bool)
        self.points = None if points is None else np.asarray(points, dtype=float)
        self.progress = Progress.of(progress)
        edge = reach * median_edge(self.vertices, cells)
        self.radius = radius_edges * edge
        self.deep_radius = max(deep_radius_edges, radius_edges) * edge
        self.depths = (depth_edges[0] * edge, depth_edges[1] * edge)
        self.fade = fade_edges * edge
        self.tree = cKDTree(self.vertices)
        self.scale = self.deep_radius
        # The fade follows each point's own distance to the cage. The corners' distances bound it from below (it is
        # 1-Lipschitz), so only the points that bound leaves within the fade are searched. A widening fit needs every
        # vertex's (radius_at); else the corners' suffice (at most N searches), the fit through the domain's too.
        self.boundary = FacetSearch(self.vertices, np.asarray(cells))
        needed = (np.arange(len(self.vertices)) if self.deep_radius > self.radius
                  else np.unique(self.located.indices))
        self.vertex_depth = np.zeros(len(self.vertices))
        self.vertex_depth[needed] = np.sqrt(self.boundary.closest(self.vertices[needed], self.progress.check).squared)
        self.paths = (DomainPaths(self.vertices, cells, self.deep_radius, self.vertex_depth,
                                  np.unique(self.located.indices), self.progress) if through_domain else None)
        # The fit is computed by blocks of nearby points (lbc_core.evaluate.groups), in the frame scaled by the
        # largest radius; ``order`` keeps each cube's points together, for callers that take rows in chunks.
        self.positions = self.located @ self.vertices
        self.groups = PointGroups(self.positions, self.vertices, self.tree, CUBE_EDGES * edge, self.deep_radius)
        self.order = self.groups.order

    @property
    def linear(self):
        """(m, N) CSR: the points' P1 barycentric rows, which meet every constraint wherever the vertices' coordinates
        do (the reduction's fallback where the fit overshoots)."""
        return self.located

    def __getitem__(self, rows):
        """Rows ``rows`` (a slice or an int array) of the matrix, as CSR."""
        indices = self._indices(rows)
        blocks = []
        for start in range(0, len(indices), _CHUNK):
            self.progress.check()
            blocks.append(self._rows(indices[start:start + _CHUNK]))
        return sp.vstack(blocks, format="csr") if blocks else self.located[indices]

    def products(self, rows, weights, vertices):
        """``(self[rows] @ weights, self[rows] @ vertices)`` without the rows: each block's fit applied to the
        weights at its candidate vertices, a dense product (the rows' 125 pairs a point, held one by one, cost three
        times as much; bench/RESULTS.md, "The bind outside the solve, cheaper").

        Parameters
        ----------
        rows : slice or (k,) int array
        weights : (N, n) scipy.sparse.csr_matrix
        vertices : (N, d) float array

        Returns
        -------
        (k, n) scipy.sparse.csr_matrix, (k, d) float array
        """
        indices = self._indices(rows)
        parts = []
        for start in range(0, len(indices), _CHUNK):
            self.progress.check()
            parts.append(self._products(indices[start:start + _CHUNK], sp.csr_matrix(weights), vertices))
        if not parts:
            return sp.csr_matrix((0, weights.shape[1])), np.zeros((0, np.shape(vertices)[1]))
        return sp.vstack([part[0] for part in parts], format="csr"), np.vstack([part[1] for part in parts])

    def _indices(self, rows):
        if isinstance(rows, slice):
            return np.arange(*rows.indices(self.shape[0]))
        return np.asarray(rows, dtype=np.int64).ravel()

    def _products(self, indices, weights, vertices):
        linear = self.located[indices]
        k, n = len(indices), weights.shape[1]
        fitted = np.zeros((k, np.shape(vertices)[1]))
        fits = np.zeros(k, dtype=bool)
        entries = [(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0))]
        for block, candidates, coefficients, fit in self._fit_blocks(indices, linear):
            fits[block] = fit
            near, used = _dense_rows(weights, candidates)
            # The positions ride along as the last columns: one product.
            product = coefficients @ np.hstack([near, vertices[candidates]])
            fitted[block] = product[:, len(used):]
            row, column = np.nonzero(product[:, :len(used)])
            entries.append((block[row], used[column], product[row, column]))
        blend = np.where(fits, self._blend(linear, indices), 0.0)
        row, column, value = (np.concatenate(parts) for parts in zip(*entries))
        full = (sp.diags(1.0 - blend) @ (linear @ weights)
                + sp.csr_matrix((value * blend[row], (row, column)), shape=(k, n))).tocsr()
        positions = (1.0 - blend)[:, None] * (linear @ vertices) + blend[:, None] * fitted
        outside = self._outside_of(indices)
        if outside.any():  # their rows extrapolate (rare): as rows
            extrapolated = self._rows(indices[outside])
            kept = sp.diags((~outside).astype(float)) @ full
            kept.eliminate_zeros()
            placement = sp.csr_matrix((np.ones(outside.sum()), (np.flatnonzero(outside), np.arange(outside.sum()))),
                                      shape=(k, int(outside.sum())))
            full = (kept + placement @ (extrapolated @ weights)).tocsr()
            positions[outside] = extrapolated @ vertices
        return full, positions

    def _outside_of(self, indices):
        return np.zeros(len(indices), dtype=bool) if self.outside is None else self.outside[indices]

    def _blend(self, linear, indices):
        """The fit's share of each row (before the fits that fail are left out): 0 on the cage to 1 at the fade."""
        return fade_in(self.distance_to_cage(linear, self.positions[indices]) / self.fade)

    def _fit_blocks(self, indices, linear):
        """The fit's rows of the points ``indices`` (their barycentric rows ``linear``), block by block:
        (positions in ``indices``, candidate vertices (C,), coefficients (g, C), fits (g,)) per block, the
        coefficients applied to values at the candidates giving the fit's values at the points (0 rows where
        there is no usable fit). The kernel's sums first, block by block, then every point's fit at once."""
        corners, shares = corners_of(linear)
        touched = np.zeros(len(indices), dtype=bool) if self.paths is None else self.paths.touched(corners)
        d = self.vertices.shape[1]
        sums = np.zeros((len(indices), 1 + d + d * (d + 1) // 2))
        centre, ratio = np.zeros((len(indices), d)), np.ones(len(indices))
        blocks = []
        for block, cube in self.groups.blocks(indices):
            origin = self.groups.centres[cube]
            centre[block] = (self.positions[indices[block]] - origin) / self.scale
            candidates, near = self._candidates(cube, origin, centre[block])
            weight, ratio[block] = self._kernel_block(centre[block], near, candidates)
            blocks.append((block, candidates, near, weight))
        if touched.any():
            self.paths.apply_factors([(block, candidates, weight) for block, candidates, _, weight in blocks],
                                     corners, shares)
        for block, _, near, weight in blocks:
            sums[block] = weight @ moment_basis(near)
        constants, slopes, fits = fit_coefficients(sums, centre, ratio, [0])
        for block, candidates, near, weight in blocks:
            weight *= constants[block] + slopes[block, :, 0] @ near.T
            yield block, candidates, weight, fits[block]

    def _candidates(self, cube, origin, centre):
        """The cube's candidate vertices within the fit's reach of the box around the block's points (``centre``,
        scaled): most blocks lie on a surface, flatter than their cube. Returns them and their scaled positions."""
        candidates = self.groups.candidates(cube)
        near = (self.vertices[candidates] - origin) / self.scale
        outside_box = np.maximum(centre.min(axis=0) - near, 0.0) + np.maximum(near - centre.max(axis=0), 0.0)
        kept = np.einsum("ja,ja->j", outside_box, outside_box) <= 1.0 + 1e-9  # the reach is the scale
        return candidates[kept], near[kept]

    def _kernel_block(self, centre, near, candidates):
        """The kernel's weights (g, C) of a block's points (``centre``, scaled) for its candidates (``near``,
        scaled), and each point's scale over its radius (g,)."""
        # |p - v|² = |p|² - 2 p·v + |v|², one matrix product (the block's frame keeps every term about 1).
        ones = np.ones((len(centre), 1))
        squared = (np.hstack([centre, np.einsum("ka,ka->k", centre, centre)[:, None], ones])
                   @ np.hstack([-2.0 * near, np.ones((len(near), 1)), np.einsum("ja,ja->j", near, near)[:, None]]).T)
        np.maximum(squared, 0.0, out=squared)
        ratio = self.scale / self._block_radius(squared, candidates)
        if self.deep_radius != self.radius:
            squared *= (ratio * ratio)[:, None]
        np.minimum(squared, 1.0, out=squared)  # the kernel (1 - r²)², in place
        np.subtract(1.0, squared, out=squared)
        return np.square(squared, out=squared), ratio

    def _block_radius(self, squared, candidates):
        """:meth:`radius_at` for a block's points, from their squared distances to its candidates (scaled)."""
        if self.deep_radius == self.radius:
            return np.full(len(squared), self.radius)
        near = squared_kernel(squared * (self.scale / self.radius) ** 2)
        mass = near.sum(axis=1)
        return self._widened((near @ self.vertex_depth[candidates]) / np.maximum(mass, np.finfo(float).tiny))

    def _widened(self, depth):
        low, high = self.depths
        return self.radius + (self.deep_radius - self.radius) * fade_in((depth - low) / (high - low))

    def _rows(self, indices):
        linear = self.located[indices]
        points = self.positions[indices]
        k = len(indices)
        fits = np.zeros(k, dtype=bool)
        entries = [(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0))]
        for block, candidates, coefficients, fit in self._fit_blocks(indices, linear):
            fits[block] = fit
            row, column = np.nonzero(coefficients)
            entries.append((block[row], candidates[column], coefficients[row, column]))
        blend = np.where(fits, self._blend(linear, indices), 0.0)
        row, column, value = (np.concatenate(parts) for parts in zip(*entries))
        fitted = sp.csr_matrix((value * blend[row], (row, column)), shape=(k, self.shape[1]))
        rows = (sp.diags(1.0 - blend) @ linear + fitted).tocsr()
        rows.eliminate_zeros()
        outside = np.flatnonzero(self._outside_of(indices))
        if not len(outside):
            return rows
        # Outside: the bound point's row (P1 there, on the cage) plus the offset times the fit's gradient there.
        offset = self.points[indices[outside]] - points[outside]
        extrapolated = linear[outside]
        for axis, gradient in enumerate(fit_gradients(self.vertices, self.tree, points[outside], self.radius)):
            extrapolated = extrapolated + sp.diags(offset[:, axis]) @ gradient
        # Where the fit there is missing or too poorly conditioned to reproduce the point, it follows q alone.
        missed = (np.abs(extrapolated @ self.vertices - self.points[indices[outside]]).max(axis=1)
                  > EXTRAPOLATION_MISS)
        if missed.any():
            extrapolated = (sp.diags((~missed).astype(float)) @ extrapolated
                            + sp.diags(missed.astype(float)) @ linear[outside]).tocsr()
            extrapolated.eliminate_zeros()
        inside = sp.diags(np.isin(np.arange(k), outside, invert=True).astype(float)) @ rows
        inside.eliminate_zeros()
        placement = sp.csr_matrix((np.ones(len(outside)), (outside, np.arange(len(outside)))),
                                  shape=(k, len(outside)))
        return (inside + placement @ extrapolated).tocsr()

    def radius_at(self, distances):
        """The fit's radius (length units) at points whose :func:`neighbour_distances` are ``distances``: the
        radius near the cage, growing smoothly to the deep radius with the local depth, the kernel-weighted mean of
        the domain vertices' distances to the cage within the near radius. Smooth in the point (a point's own
        distance kinks on the medial axis), and small across a part one or two cells thick, where every vertex lies
        on or near the cage."""
        if self.deep_radius == self.radius:
            return np.full(distances.shape[0], self.radius)
        near = distances.copy()
        near.data = kernel(near.data / self.radius)
        mass = np.asarray(near.sum(axis=1)).ravel()
        return self._widened((near @ self.vertex_depth) / np.maximum(mass, np.finfo(float).tiny))

    def distance_to_cage(self, linear, points):
        """Each point's distance to the cage where it is below the fade, else a lower bound of it at least the fade.

        Parameters
        ----------
        linear : (k, N) CSR
            The points' barycentric rows.
        points : (k, d) float array
            ``linear @ vertices``.

        Returns
        -------
        (k,) float array
        """
        counts = np.diff(linear.indptr)
        owner = np.repeat(np.arange(len(points)), counts)
        below = self.vertex_depth[linear.indices] - np.linalg.norm(points[owner] - self.vertices[linear.indices],
                                                                    axis=1)
        lower = np.full(len(points), -np.inf)
        np.maximum.at(lower, owner, below)
        distance = np.maximum(lower, 0.0)
        near = np.flatnonzero(lower < self.fade)
        if len(near):
            distance[near] = np.sqrt(self.boundary.closest(points[near], self.progress.check).squared)
        return distance


def radius_for(smoothness):
    """The fit's radius in median cell edges for a smoothness in [0, 1] (:class:`lbc_core.binding.options.BindOptions`):
    :data:`RADIUS_EDGES` at 0 to :data:`SMOOTH_RADIUS_EDGES` at 1, linearly."""
    return RADIUS_EDGES + (SMOOTH_RADIUS_EDGES - RADIUS_EDGES) * float(smoothness)


def moving_least_squares(vertices, tree, points, radius):
    """Moving least-squares rows: the value at each point of the kernel-weighted least-squares linear fit.

    Parameters
    ----------
    vertices : (N, d) float array
    tree : scipy.spatial.cKDTree of ``vertices``
    points : (k, d) float array
    radius : float or (k,) float array
        The kernel's support radius (length units), one for all points or one per point.

    Returns
    -------
    rows : (k, N) scipy.sparse.csr_matrix
        Row i applied to values at the vertices gives the fit's value at point i; it sums to 1 and reproduces the
        point (``rows @ vertices == points`` up to rounding). Rows of points with no usable fit are empty.
    fits : (k,) bool array
        Points whose neighbourhood holds enough vertices, not all in a plane, for a well-conditioned fit.

    Examples
    --------
    >>> import numpy as np
    >>> from scipy.spatial import cKDTree
    >>> grid = np.stack(np.meshgrid(*[np.linspace(0, 1, 5)] * 2), -1).reshape(-1, 2)
    >>> rows, fits = moving_least_squares(grid, cKDTree(grid), np.array([[0.4, 0.55]]), 0.5)
    >>> bool(fits[0]), np.allclose(rows @ grid, [[0.4, 0.55]])
    (True, True)
    """
    (rows,), fits = _fit_rows(vertices, neighbour_distances(tree, points, np.max(radius)), points, radius, [0])
    return rows, fits


def fit_gradients(vertices, tree, points, radius):
    """The gradient of the moving least-squares linear fit at each point, as rows: ``d`` (k, N) CSR matrices, the
    k-th giving, applied to values at the vertices, the fit's slope along axis k (per length unit). Each sums to 0,
    and applied to the vertices' coordinates gives the unit vector of its axis (rows of points with no usable fit:
    empty). Same parameters as :func:`moving_least_squares`."""
    d = points.shape[1]
    rows, _ = _fit_rows(vertices, neighbour_distances(tree, points, np.max(radius)), points, radius,
                        list(range(1, d + 1)))
    scale = np.broadcast_to(np.asarray(radius, dtype=float), (len(points),))
    for gradient in rows:
        gradient.data /= np.repeat(scale, np.diff(gradient.indptr))
    return rows


def _fit_rows(vertices, distances, points, radius, terms):
    """Rows giving the fit's coefficients ``terms`` (0: the value at the point; 1 + a: the slope along axis a, per
    radius) at each point, from its :func:`neighbour_distances` within at least ``radius``: ([(k, N) CSR per term],
    fits (k,) bool)."""
    k, d = points.shape
    radius = np.broadcast_to(np.asarray(radius, dtype=float), (k,))
    weight = distances.copy()
    weight.data = kernel(weight.data / radius[_row_of_each(weight)])
    weight.eliminate_zeros()
    owner = _row_of_each(weight)
    # The kernel's sums in the frame scaled by the largest radius, then the coefficients rescaled per point.
    scale = radius.max()
    local, centre, ratio = vertices / scale, points / scale, scale / radius
    constants, slopes, fits = fit_coefficients(weight @ moment_basis(local), centre, ratio, terms)
    pair_local = [local[weight.indices, axis] for axis in range(d)]
    result = []
    for term in range(len(terms)):
        factor = np.ascontiguousarray(constants[:, term])[owner]
        for axis in range(d):
            factor += np.ascontiguousarray(slopes[:, axis, term])[owner] * pair_local[axis]
        # Its own index arrays: eliminate_zeros prunes them in place, and the next term needs the kernel's.
        rows = sp.csr_matrix((weight.data * factor, weight.indices.copy(), weight.indptr.copy()), shape=weight.shape)
        rows.eliminate_zeros()
        result.append(rows)
    return result, fits


def moment_basis(local):
    """(N, 1 + d + d(d+1)/2): 1, the coordinates and their products a ≤ b at each vertex (the fit's moments are
    their kernel-weighted sums)."""
    d = local.shape[1]
    products = [local[:, a] * local[:, b] for a in range(d) for b in range(a, d)]
    return np.column_stack([np.ones(len(local)), local] + products)


def fit_coefficients(sums, centre, ratio, terms):
    """The fit's coefficients at each point from its kernel-weighted sums of :func:`moment_basis` (scaled frame).

    Parameters
    ----------
    sums : (k, 1 + d + d(d+1)/2) float array
    centre : (k, d) float array
        The points, in the frame of the sums.
    ratio : (k,) float array
        The frame's scale over each point's radius.
    terms : list of int
        0: the value at the point; 1 + a: the slope along axis a, per radius.

    Returns
    -------
    constants : (k, T), slopes : (k, d, T)
        Vertex j's factor for term t is ``constants[:, t] + slopes[:, :, t] · local_j`` (times its kernel weight).
    fits : (k,) bool
        Points whose moments are well conditioned (the others' coefficients are 0).
    """
    k, d = centre.shape
    # Moments of the basis b = [1, (v - p) / radius] under the kernel, from sums of K, K v and K v vᵀ.
    upper = [(a, b) for a in range(d) for b in range(a, d)]
    mass = sums[:, 0]
    first = (sums[:, 1:d + 1] - centre * sums[:, :1]) * ratio[:, None]  # Σ K (v - p) / r
    second = np.empty((k, d, d))
    for column, (a, b) in enumerate(upper):
        # Σ K (v_a - p_a)(v_b - p_b) = Σ K v_a v_b - p_a Σ K v_b - p_b Σ K v_a + p_a p_b Σ K
        second[:, a, b] = second[:, b, a] = (sums[:, 1 + d + column] - centre[:, a] * sums[:, 1 + b]
                                             - centre[:, b] * sums[:, 1 + a]
                                             + centre[:, a] * centre[:, b] * mass) * ratio ** 2
    moments = np.empty((k, d + 1, d + 1))
    moments[:, 0, 0], moments[:, 0, 1:], moments[:, 1:, 0], moments[:, 1:, 1:] = mass, first, first, second
    fits = well_conditioned(moments)
    # Coefficient t of the fit = e_tᵀ M⁻¹ Σ K b w: vertex j's factor is K_j b_j · M⁻¹ e_t (M is symmetric), an
    # affine function of the vertex, c_t + g_t · local_j, whose c_t and g_t are the point's.
    usable = np.where(fits[:, None, None], moments, np.eye(d + 1))
    solved = np.stack([solve_symmetric(usable, np.broadcast_to(np.eye(d + 1)[term], (k, d + 1)))
                       for term in terms], axis=2)
    slopes = solved[:, 1:] * (ratio * fits)[:, None, None]
    constants = solved[:, 0] * fits[:, None] - np.einsum("ka,kat->kt", centre, slopes)
    return constants, slopes, fits


def _dense_rows(matrix, rows):
    """Rows ``rows`` of a CSR matrix as a dense array over the columns they use: ((len(rows), u) array, (u,) columns)."""
    starts = matrix.indptr[rows]
    counts = matrix.indptr[rows + 1] - starts
    position = np.repeat(starts - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
    columns = matrix.indices[position]
    marked = np.zeros(matrix.shape[1], dtype=bool)
    marked[columns] = True
    used = np.flatnonzero(marked)
    dense = np.zeros((len(rows), len(used)))
    dense[np.repeat(np.arange(len(rows)), counts), np.searchsorted(used, columns)] = matrix.data[position]
    return dense, used


def _row_of_each(matrix):
    """The row of each stored entry of a CSR matrix."""
    return np.repeat(np.arange(matrix.shape[0]), np.diff(matrix.indptr))


def neighbour_distances(tree, points, reach):
    """(k, N) CSR: the distance from each point to each vertex of ``tree`` within ``reach``; a point on a vertex
    holds the smallest positive float there, so that the pair is stored (columns unsorted within rows)."""
    pairs = cKDTree(points).sparse_distance_matrix(tree, reach, output_type="coo_matrix")
    pairs.has_canonical_format = True  # each pair once: no sum or sort needed
    distances = pairs.tocsr()
    _, on_vertex = tree.query(points, distance_upper_bound=0.0)
    hit = np.flatnonzero(on_vertex < tree.n)
    if len(hit):
        distances = distances + sp.csr_matrix((np.full(len(hit), np.finfo(float).tiny), (hit, on_vertex[hit])),
                                              shape=distances.shape)
    return sp.csr_matrix(distances)


def well_conditioned(matrices):
    """Which symmetric positive semi-definite matrices have λ_min > λ_max / MAX_CONDITION.

    Most pass a cheap sufficient test, λ_min ≥ det / λ_max^(D-1) ≥ det / trace^(D-1) (twice over, for rounding), and
    λ_max ≤ trace; only the others get their eigenvalues computed, so the answer is the eigenvalues' own.

    Parameters
    ----------
    matrices : (k, D, D) float array

    Returns
    -------
    (k,) bool array
    """
    size = matrices.shape[-1]
    trace = np.trace(matrices, axis1=1, axis2=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        passes = np.linalg.det(matrices) / trace ** (size - 1) > 2.0 * trace / MAX_CONDITION
    answer = passes.copy()
    doubtful = np.flatnonzero(~passes)
    if len(doubtful):
        eigenvalues = np.linalg.eigvalsh(matrices[doubtful])
        answer[doubtful] = eigenvalues[:, 0] > eigenvalues[:, -1] / MAX_CONDITION
    return answer


def squared_kernel(t):
    """:func:`kernel` at r = √t, from the squared ratio t (no square root)."""
    t = np.clip(t, 0.0, 1.0)
    return (1.0 - t) ** 2


def kernel(r):
    """The fit's weight (1 - r²)² at r = distance / radius, 0 beyond 1: continuously differentiable, so the fitted
    coordinates are, and a deformed smooth surface keeps continuous normals; flatter than Wendland's C² kernel, so
    a smaller radius (fewer vertices per point) smooths as much (bench/RESULTS.md)."""
    r = np.clip(r, 0.0, 1.0)
    return (1.0 - r * r) ** 2


def fade_in(t):
    """Smootherstep: 0 at t ≤ 0, 1 at t ≥ 1, with zero first and second derivatives at both ends."""
    t = np.clip(t, 0.0, 1.0)
    return t ** 3 * (t * (6.0 * t - 15.0) + 10.0)


def median_edge(vertices, cells):
    """Median edge length of a simplicial mesh (length units)."""
    cells = np.asarray(cells)
    corners = cells.shape[1]
    lengths = [np.linalg.norm(vertices[cells[:, a]] - vertices[cells[:, b]], axis=1)
               for a in range(corners) for b in range(a + 1, corners)]
    return float(np.median(np.concatenate(lengths)))
