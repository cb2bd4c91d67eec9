"""Locating points in a triangle or tetrahedron mesh: the sparse barycentric interpolation matrix.

A point inside the domain (the union of the cells) gets its barycentric coordinates in a cell containing it. A point
outside the domain, or in an internal void, is bound to the closest point of the boundary facets and gets that point's
barycentric coordinates in its facet.

Cells are found through a uniform grid of buckets over the domain's bounding box: each cell is registered in the
buckets it may overlap, the cell holding the bucket's centre first, and a point is tested against the cells of its
bucket, one candidate per round for all points at once. Membership uses signed distances to the cells' facet planes,
so the tolerance is a length. Closest facets are found exactly through a bounding volume hierarchy of the boundary
facets. Everything is vectorised over batches of points, so memory stays bounded whatever their number.
"""

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..errors import CageError
from ..kernel import fem
from ..kernel.geometry import closest_on_facets
from ..kernel.progress import Progress

TOLERANCE = 1e-12  # relative to the domain's bounding-box diagonal: points this close to the domain are inside

_CHUNK = 1 << 16  # points handled per batch: bounds memory and spaces the progress / cancel calls
_TRAVERSAL_BATCH = 1 << 13  # points descending the facet hierarchy together: bounds the (point, box) pairs held
_LEAF_SIZE = 4  # facets per leaf of the facet hierarchy
_REGISTRATION_BATCH = 1 << 18  # (cell, bucket) pairs examined at once while building the grid
_MAX_REGISTRATIONS = 1 << 23  # (cell, bucket) pairs a grid may hold: bounds the grid's memory
_MAX_BUCKETS = 1 << 22  # bounds the grid's offsets array


def interpolation_matrix(vertices, cells, points, progress=None, cancel=None):
    """Barycentric coordinates of points in a simplicial mesh, outside points bound to the closest domain point.

    Parameters
    ----------
    vertices : (N, d) float array
        Mesh vertices, d = 2 or 3.
    cells : (F, d+1) int array
        Triangles (d = 2) or tetrahedra (d = 3). Their union is the domain; it may be non-convex or have voids, and
        the mesh need not be Delaunay.
    points : (m, d) float array
        Points to locate, in the vertices' length units.
    progress : callable(fraction, message) or Progress, optional
        Called with fraction in [0, 1], non-decreasing.
    cancel : callable() -> bool, optional
        Polled between steps and batches; when it returns True, :class:`~lbc_core.errors.Cancelled` is raised.

    Returns
    -------
    P : (m, N) scipy.sparse.csr_matrix
        Row i holds the barycentric coordinates (non-negative, summing to 1, zeros not stored) of point i in a cell
        containing it (at most d+1 entries), or, for an outside point, of its closest domain point in a boundary
        facet (at most d entries). ``P @ vertices`` reproduces inside points and gives the bound points.
    outside : (m,) bool array
        True where the point is farther than ``TOLERANCE`` times the bounding-box diagonal from the domain.
    distance : (m,) float array
        0 inside, else the distance from the point to the domain, in length units.

    Raises
    ------
    ValueError
        Arrays of the wrong shape, or no cells.
    CageError
        Non-finite vertices or points, or only flat cells.
    Cancelled
        ``cancel()`` returned True.
    """
    progress = Progress.of(progress, cancel)
    vertices, cells, points = _validated(vertices, cells, points)
    n_vertices, d = vertices.shape
    n_points = len(points)
    progress(0.0, "interpolation: indexing the cells")

    corners = vertices[cells]  # (F, d+1, d)
    lo, hi = corners.min(axis=(0, 1)), corners.max(axis=(0, 1))
    # Centring keeps the rounding of the plane equations near eps times the diagonal, far below the tolerance.
    centre = (lo + hi) / 2
    vertices, corners = vertices - centre, corners - centre
    tol = TOLERANCE * float(np.linalg.norm(hi - lo))
    planes, heights = _cell_planes(corners)
    # A cell this flat holds no volume of its own: its points are within (d+1) tol of another cell or of the
    # boundary, where the tolerance or the closest-facet search finds them. In the others, a point is farther than
    # tol from at least one facet plane, so its coordinates never all snap to 0 below.
    usable = np.flatnonzero(heights.min(axis=1) > (d + 1) * tol)
    if usable.size == 0:
        raise CageError("The domain mesh has no cell of non-zero area or volume; check the cage and its meshing.")
    grid = _build_grid(corners, planes, usable, tol, n_points, progress.check)
    facet_search = None  # built on the first point found in no cell

    columns = np.zeros((n_points, d + 1), dtype=np.intp)
    values = np.zeros((n_points, d + 1))
    outside = np.zeros(n_points, dtype=bool)
    distance = np.zeros(n_points)
    for start in range(0, n_points, _CHUNK):
        progress(0.05 + 0.95 * start / n_points, "interpolation: locating points")
        stop = min(start + _CHUNK, n_points)
        chunk = points[start:stop] - centre
        cell, signed = _locate(grid, planes, chunk, tol)
        found = np.flatnonzero(cell >= 0)
        # Signed distances to the facet planes over the heights are the barycentric coordinates. A point within tol
        # of a facet plane is on it: its coordinate is 0 (not rounding noise, nor slightly negative), so a point on
        # a vertex or an edge uses that vertex or edge alone; renormalising keeps the row a convex combination.
        found_signed = signed[found]
        bary = np.where(found_signed > tol, found_signed / heights[cell[found]], 0.0)
        values[start + found] = bary / bary.sum(axis=1, keepdims=True)
        columns[start + found] = cells[cell[found]]
        lost = np.flatnonzero(cell < 0)
        if lost.size:
            if facet_search is None:
                facet_search = FacetSearch(vertices, cells)
            squared, facet, bary = facet_search.closest(chunk[lost], progress.check)
            gap = np.sqrt(squared)
            values[start + lost, :d] = bary
            columns[start + lost, :d] = facet_search.facets[facet]
            outside[start + lost] = gap > tol
            distance[start + lost] = np.where(gap > tol, gap, 0.0)
    progress(1.0, "interpolation: done")
    return _csr(columns, values, n_vertices), outside, distance


def _validated(vertices, cells, points):
    """The inputs as arrays of the right types, or an error saying what is wrong."""
    vertices = np.asarray(vertices, dtype=float)
    cells = np.asarray(cells)
    points = np.asarray(points, dtype=float)
    if vertices.ndim != 2 or vertices.shape[1] not in (2, 3):
        raise ValueError(f"vertices must be (N, 2) or (N, 3), got shape {vertices.shape}")
    d = vertices.shape[1]
    if cells.ndim != 2 or cells.shape[1] != d + 1 or len(cells) == 0 or not np.issubdtype(cells.dtype, np.integer):
        raise ValueError(f"cells must be a non-empty (F, {d + 1}) int array, got {cells.dtype} {cells.shape}")
    if cells.min() < 0 or cells.max() >= len(vertices):
        raise ValueError("cells index vertices that do not exist")
    if points.ndim != 2 or points.shape[1] != d:
        raise ValueError(f"points must be (m, {d}), got shape {points.shape}")
    if not np.isfinite(vertices).all():
        raise CageError("The mesh has non-finite vertex coordinates.")
    if not np.isfinite(points).all():
        raise CageError("Some points to bind have non-finite coordinates (NaN or infinity); fix or remove them.")
    return vertices, cells.astype(np.intp, copy=False), points


def _csr(columns, values, n_columns):
    """A CSR matrix from fixed-width rows, zeros dropped, in canonical form (sorted column indices).

    Parameters
    ----------
    columns : (m, k) int array
    values : (m, k) float array
    n_columns : int

    Returns
    -------
    (m, n_columns) scipy.sparse.csr_matrix
    """
    keep = values > 0
    indptr = np.concatenate([[0], np.cumsum(keep.sum(axis=1))])
    matrix = sp.csr_matrix((values[keep], columns[keep], indptr), shape=(len(columns), n_columns))
    matrix.sort_indices()
    return matrix


# --- cells ---------------------------------------------------------------------------------------------------------


def _cell_planes(corners):
    """The facet planes of every cell, as signed distance functions positive inside.

    Parameters
    ----------
    corners : (F, d+1, d) float array

    Returns
    -------
    planes : (F, d+1, d+1) float array
        Plane k is the facet opposite corner k: ``planes[c, k, :d] @ x + planes[c, k, d]`` is the signed distance
        (length units) from x to that facet's line / plane, positive on the corner's side. Unit normals from the
        facet's own corners stay accurate for slivers, where inverting the edge matrix would not.
    heights : (F, d+1) float array
        Distance from each corner to its opposite facet (0 for a degenerate facet).
    """
    n_cells, n_corners, d = corners.shape
    planes = np.zeros((n_cells, n_corners, d + 1))
    heights = np.zeros((n_cells, n_corners))
    for k in range(n_corners):
        facet = np.delete(corners, k, axis=1)  # (F, d, d)
        normal = _facet_normals(facet)
        length = np.linalg.norm(normal, axis=1)
        normal /= np.where(length > 0, length, 1.0)[:, None]
        height = np.einsum("fj,fj->f", normal, corners[:, k] - facet[:, 0])
        normal *= np.where(height < 0, -1.0, 1.0)[:, None]
        planes[:, k, :d] = normal
        planes[:, k, d] = -np.einsum("fj,fj->f", normal, facet[:, 0])
        heights[:, k] = np.abs(height)
    return planes, heights


def _facet_normals(facet):
    """Normals (not normalised) of segments (d = 2) or triangles (d = 3).

    Parameters
    ----------
    facet : (F, d, d) float array of corner coordinates

    Returns
    -------
    (F, d) float array, zero for degenerate facets
    """
    if facet.shape[2] == 2:
        edge = facet[:, 1] - facet[:, 0]
        return np.stack([-edge[:, 1], edge[:, 0]], axis=1)
    return np.cross(facet[:, 1] - facet[:, 0], facet[:, 2] - facet[:, 0])


def _signed_distances(planes, points):
    """Signed distances of each point to the d+1 facet planes of its candidate cell.

    Parameters
    ----------
    planes : (n, d+1, d+1) float array, one cell's planes per point
    points : (n, d) float array

    Returns
    -------
    (n, d+1) float array, length units, all >= 0 inside the cell
    """
    d = points.shape[1]
    signed = planes[:, :, d].copy()
    for j in range(d):
        signed += planes[:, :, j] * points[:, j, None]
    return signed


def _row_min(values):
    """Least entry of each row of a narrow (n, k) array: column by column, much faster than min(axis=1) there."""
    least = values[:, 0].copy()
    for column in range(1, values.shape[1]):
        np.minimum(least, values[:, column], out=least)
    return least


# --- bucket grid ---------------------------------------------------------------------------------------------------


class _Grid(NamedTuple):
    """Uniform buckets over the domain's bounding box; bucket b holds ``cells[start[b]:start[b+1]]``."""

    lo: np.ndarray  # (d,) corner of the box
    hi: np.ndarray  # (d,) opposite corner
    spacing: float  # bucket edge length
    shape: np.ndarray  # (d,) buckets per axis
    start: np.ndarray  # (B+1,) offsets into cells
    cells: np.ndarray  # (R,) cell indices


def _build_grid(corners, planes, usable, tol, n_points, check):
    """Register every usable cell in the buckets it may overlap.

    A cell goes in the buckets overlapped by its bounding box grown by tol, except those entirely outside one of
    its facet planes: slanted cells (most of them) thus skip many buckets of their bounding box, and points test
    fewer candidates. Within a bucket, cells are sorted by how deep the bucket's centre lies in them.

    Parameters
    ----------
    corners : (F, d+1, d) float array
    planes : (F, d+1, d+1) float array, from :func:`_cell_planes`
    usable : (U,) int array, the cells to register
    tol : float, length units
    n_points : int, points to be located (the spacing balances grid size against candidates per point)
    check : callable, called between blocks of cells (raises to cancel)

    Returns
    -------
    _Grid
    """
    lo, hi = corners.min(axis=(0, 1)), corners.max(axis=(0, 1))
    cell_lo = corners[usable].min(axis=1) - tol
    cell_hi = corners[usable].max(axis=1) + tol
    spacing = _grid_spacing(cell_lo, cell_hi, lo, hi, n_points)
    shape = _grid_shape(lo, hi, spacing)
    first = _bucket_coordinates(cell_lo, lo, spacing, shape)
    span = _bucket_coordinates(cell_hi, lo, spacing, shape) - first + 1  # (U, d) buckets per axis
    sizes = np.prod(span, axis=1)
    # How far a bucket reaches along each facet normal from its centre: half the bucket's extent along it.
    reach = 0.5 * spacing * np.abs(planes[usable, :, :-1]).sum(axis=2)  # (U, d+1)
    # Blocks of cells with a bounded number of registrations keep the temporaries small.
    cumulative = np.cumsum(sizes)
    bounds = list(np.searchsorted(cumulative, np.arange(_REGISTRATION_BATCH, cumulative[-1], _REGISTRATION_BATCH)))
    pieces_bucket, pieces_cell, pieces_depth = [], [], []
    for begin, stop in zip([0, *bounds], [*bounds, len(sizes)]):
        check()
        owner, coordinates = _enumerate_blocks(first[begin:stop], span[begin:stop], sizes[begin:stop])
        cell = usable[begin + owner]
        signed = _signed_distances(planes[cell], lo + (coordinates + 0.5) * spacing)  # at the bucket's centre
        kept = _row_min(signed + reach[begin + owner]) >= -tol
        pieces_bucket.append(np.ravel_multi_index(tuple(coordinates[kept].T), tuple(shape)))
        pieces_cell.append(cell[kept])
        pieces_depth.append(_row_min(signed[kept]))
    bucket = np.concatenate(pieces_bucket)
    # Within a bucket, the cell holding the bucket's centre most deeply comes first: most points of the bucket lie
    # in it or in the next few, so the search usually ends in a round or two.
    order = np.lexsort((-np.concatenate(pieces_depth), bucket))
    start = np.concatenate([[0], np.cumsum(np.bincount(bucket, minlength=int(np.prod(shape))))])
    return _Grid(lo, hi, spacing, shape, start, np.concatenate(pieces_cell)[order])


def _enumerate_blocks(first, span, sizes):
    """Every bucket of each cell's block of buckets.

    Parameters
    ----------
    first : (U, d) int array, the block's lowest bucket coordinates
    span : (U, d) int array, the block's buckets per axis
    sizes : (U,) int array, product of span

    Returns
    -------
    owner : (R,) int array, row of first
    coordinates : (R, d) int array, bucket coordinates
    """
    owner = np.repeat(np.arange(len(sizes)), sizes)
    counter = np.arange(len(owner)) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    coordinates = np.empty((len(owner), span.shape[1]), dtype=np.intp)
    # A mixed-radix counter, last axis fastest.
    for axis in reversed(range(span.shape[1])):
        axis_span = span[owner, axis]
        coordinates[:, axis] = first[owner, axis] + counter % axis_span
        counter //= axis_span
    return owner, coordinates


def _grid_shape(lo, hi, spacing):
    return np.maximum(np.ceil((hi - lo) / spacing), 1).astype(np.intp)


def _bucket_coordinates(x, lo, spacing, shape):
    """Integer bucket coordinates (n, d) of positions x (n, d), clamped to the grid."""
    return np.clip(np.floor((x - lo) / spacing), 0, shape - 1).astype(np.intp)


def _grid_spacing(cell_lo, cell_hi, lo, hi, n_points):
    """The bucket size minimising an estimate of the work of building the grid and locating the points.

    Registering a cell in a bucket costs about three candidate tests. With the deepest cell first in each bucket, a
    point takes about 1 + R / (10 B) tests (R registrations of bounding boxes, B buckets; measured on a jittered
    tetrahedral grid), and every round of tests costs a fixed overhead, about 100 tests, per batch of points. Sizes
    are tried by factors of sqrt(2) from a quarter to 16 times the size giving one cell per bucket.

    Returns
    -------
    float, length units
    """
    d = len(lo)
    extent = np.maximum(hi - lo, np.max(hi - lo) * 1e-6)
    typical = (np.prod(extent) / len(cell_lo)) ** (1.0 / d)
    n_batches = -(-n_points // _CHUNK)
    best_cost, best_spacing = np.inf, typical
    for spacing in typical * 2.0 ** (np.arange(-4, 9) / 2.0):
        shape = _grid_shape(lo, hi, spacing)
        n_buckets = float(np.prod(shape.astype(float)))
        span = _bucket_coordinates(cell_hi, lo, spacing, shape) - _bucket_coordinates(cell_lo, lo, spacing, shape)
        registrations = float(np.prod(span + 1.0, axis=1).sum())
        if n_buckets > _MAX_BUCKETS or registrations > _MAX_REGISTRATIONS:
            continue
        per_bucket = registrations / n_buckets
        cost = 3 * registrations + n_points * (1 + per_bucket / 10) + 100 * n_batches * per_bucket
        if cost < best_cost:
            best_cost, best_spacing = cost, spacing
    return best_spacing


def _locate(grid, planes, points, tol):
    """A cell containing each point (within tol), testing the candidates of its bucket one round at a time.

    Parameters
    ----------
    grid : _Grid
    planes : (F, d+1, d+1) float array, from :func:`_cell_planes`
    points : (n, d) float array
    tol : float, length units

    Returns
    -------
    cell : (n,) int array, -1 where no cell contains the point
    signed : (n, d+1) float array, the point's signed distances to its cell's facet planes
    """
    n, d = points.shape
    cell = np.full(n, -1, dtype=np.intp)
    signed = np.zeros((n, d + 1))
    in_box = np.all((points >= grid.lo - tol) & (points <= grid.hi + tol), axis=1)
    coordinates = _bucket_coordinates(points, grid.lo, grid.spacing, grid.shape)
    bucket = np.ravel_multi_index(tuple(coordinates.T), tuple(grid.shape))
    first = grid.start[bucket]
    count = np.where(in_box, grid.start[bucket + 1] - first, 0)
    active = np.flatnonzero(count > 0)
    round_ = 0
    while active.size:
        candidate = grid.cells[first[active] + round_]
        distances = _signed_distances(planes[candidate], points[active])
        hit = _row_min(distances) >= -tol
        cell[active[hit]] = candidate[hit]
        signed[active[hit]] = distances[hit]
        round_ += 1
        active = active[~hit & (count[active] > round_)]
    return cell, signed


# --- boundary facets -----------------------------------------------------------------------------------------------


class FacetSearch:
    """Exact closest points on the boundary facets of a mesh.

    The facet of the nearest centroid (a KD-tree query) gives each point a first distance; a bounding volume
    hierarchy then visits, level by level for all points at once, only the boxes nearer than that distance, and the
    facets of the leaves reached are evaluated exactly. A box is never farther than the facets it holds, so no
    closer facet is missed, and large facets need no special care.

    Parameters
    ----------
    vertices : (N, d) float array
    cells : (F, d+1) int array
    """

    def __init__(self, vertices, cells):
        self.facets = fem.boundary_facets(cells)  # (E, d) vertex indices
        self.corners = vertices[self.facets]  # (E, d, d)
        centroids = self.corners.mean(axis=1)
        self.tree = cKDTree(centroids)
        self.leaves, self.box_lo, self.box_hi = _bounding_volume_hierarchy(self.corners, centroids)

    def closest(self, points, check):
        """The closest boundary point of each point.

        Parameters
        ----------
        points : (n, d) float array
        check : callable, called between batches of points (raises to cancel)

        Returns
        -------
        _Best: squared distance (n,) in length^2 units, facet (n,) row of ``self.facets``, bary (n, d) the
        barycentric coordinates of the closest point in that facet
        """
        n = len(points)
        _, first = self.tree.query(points)
        squared, bary = closest_on_facets(points, self.corners[first])
        best = _Best(squared, first, bary)
        for start in range(0, n, _TRAVERSAL_BATCH):
            check()
            self._descend(points, np.arange(start, min(start + _TRAVERSAL_BATCH, n)), best)
        return best

    def _descend(self, points, batch, best):
        """Improve best for the points in batch with every facet of every leaf nearer than their best distance."""
        point, node = batch, np.zeros(len(batch), dtype=np.intp)
        for lo, hi in zip(self.box_lo[1:], self.box_hi[1:]):
            point = np.repeat(point, 2)
            node = (2 * node[:, None] + np.arange(2)).ravel()
            keep = _box_squared_distance(points[point], lo[node], hi[node]) < best.squared[point]
            point, node = point[keep], node[keep]
        facet = self.leaves[node]  # (pairs, leaf size), -1 for padding
        pair, slot = np.nonzero(facet >= 0)
        point, facet = point[pair], facet[pair, slot]
        squared, bary = closest_on_facets(points[point], self.corners[facet])
        # The least distance per point: sort by (point, distance) and take each point's first entry.
        order = np.lexsort((squared, point))
        first = order[np.flatnonzero(np.diff(point[order], prepend=-1))]
        better = squared[first] < best.squared[point[first]]
        first = first[better]
        best.squared[point[first]] = squared[first]
        best.facet[point[first]] = facet[first]
        best.bary[point[first]] = bary[first]


class _Best(NamedTuple):
    """The closest boundary points found so far, updated in place."""

    squared: np.ndarray  # (n,) squared distance, length^2 units
    facet: np.ndarray  # (n,) row of the boundary facets
    bary: np.ndarray  # (n, d) barycentric coordinates in that facet


def _bounding_volume_hierarchy(corners, centroids):
    """A complete binary tree of axis-aligned boxes over facets grouped along a Morton (Z-order) curve.

    Parameters
    ----------
    corners : (E, d, d) float array, each facet's corners
    centroids : (E, d) float array

    Returns
    -------
    leaves : (2^depth, _LEAF_SIZE) int array, facet indices, -1 for padding
    box_lo, box_hi : lists of depth+1 arrays, level l of shape (2^l, d): the boxes of the level's nodes, children
        of node i being 2 i and 2 i + 1 on the next level; empty nodes have lo = +inf, hi = -inf (never visited)
    """
    n_facets, d = centroids.shape
    order = np.argsort(_morton_codes(centroids), kind="stable")
    depth = int(np.ceil(np.log2(max(1, -(-n_facets // _LEAF_SIZE)))))
    leaves = np.full(2**depth * _LEAF_SIZE, -1, dtype=np.intp)
    leaves[:n_facets] = order
    leaves = leaves.reshape(2**depth, _LEAF_SIZE)
    facet_lo = np.vstack([corners.min(axis=1), np.full((1, d), np.inf)])  # the extra row answers index -1
    facet_hi = np.vstack([corners.max(axis=1), np.full((1, d), -np.inf)])
    box_lo, box_hi = [facet_lo[leaves].min(axis=1)], [facet_hi[leaves].max(axis=1)]
    for _ in range(depth):
        box_lo.insert(0, box_lo[0].reshape(-1, 2, d).min(axis=1))
        box_hi.insert(0, box_hi[0].reshape(-1, 2, d).max(axis=1))
    return leaves, box_lo, box_hi


def _morton_codes(positions):
    """Z-order curve keys (n,) of positions (n, d): sorting by them keeps nearby positions together."""
    n, d = positions.shape
    bits = 63 // d
    lo, extent = positions.min(axis=0), np.ptp(positions, axis=0)
    quantised = ((positions - lo) / np.where(extent > 0, extent, 1.0) * (2**bits - 1)).astype(np.uint64)
    codes = np.zeros(n, dtype=np.uint64)
    for bit in range(bits):
        for axis in range(d):
            codes |= ((quantised[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(bit * d + axis)
    return codes


def _box_squared_distance(points, lo, hi):
    """Squared distances (n,) from points (n, d) to the boxes [lo, hi] (n, d); 0 inside, inf for empty boxes."""
    gap = np.maximum(np.maximum(lo - points, points - hi), 0.0)
    return np.einsum("ij,ij->i", gap, gap)
