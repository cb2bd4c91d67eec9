"""2D backends: the cage polygon filled with triangles.

``mesh_delaunay`` (bundled, the one "auto" uses): the reference solver's boundary samples, a hexagonal lattice
inside, scipy's Delaunay triangulation, boundary recovery by splitting missing boundary pieces (a bounded number of
rounds), three Laplacian smoothing passes; no worse angles than Triangle's on the paper's cages (see
tests/test_meshing.py). ``mesh_triangle``: Shewchuk's Triangle with the reference solver's switches (``pzYq33a<A>``,
maximum area 1.6 × mean), only when asked for by name.
"""

import numpy as np
import scipy.sparse as sp
from scipy.spatial import Delaunay, cKDTree

from ..errors import CageError
from ..kernel.geometry import distance_to_segments, orient_positive, winding_numbers
from .common import bary_positions, cell_edges, far_points, on_common, raw_mesh, rows_in, smooth, split_counts

# 2D sizing as in the reference solver (bldeng/LBC): maximum triangle area 1.6 × mean, boundary spacing 1.6 × the
# side of an equilateral triangle of half that area, minimum angle 33°.
_AREA_FACTOR = 1.6
_SPACING_FACTOR = 1.6
_TRIANGLE_MIN_ANGLE = 33
_SMOOTHING_PASSES = 3
# Each round splits every missing boundary piece in two; pieces halve at most this often before the cage is refused.
_RECOVERY_ROUNDS = 40
# Interior lattice points stay this far (× boundary spacing) from the cage: beyond half a boundary piece they are
# outside every piece's diametral circle, so the boundary pieces are Delaunay edges.
_LATTICE_MARGIN = 0.7


def triangle_module():
    """Shewchuk's Triangle (the optional ``triangle`` package), or None when it is not installed."""
    try:
        import triangle
    except ImportError:
        return None
    return triangle


def _reference_sizes_2d(cage, cells):
    """Maximum triangle area and boundary spacing of the reference solver for about ``cells`` triangles.

    Returns
    -------
    max_area : float, in squared cage units
    spacing : float, in cage units
    """
    max_area = _AREA_FACTOR * cage.measure / cells
    return max_area, _SPACING_FACTOR * np.sqrt(2.0 / np.sqrt(3.0) * max_area)


class _PolygonBoundary:
    """Samples along the cage polygon, each at a parameter t in [0, 1) on one cage edge.

    The control points are the samples at t = 0, so they come first, in cage order, at their exact positions.
    """

    def __init__(self, cage, spacing):
        self.cage = cage
        corners = cage.vertices[cage.facets]
        counts = split_counts(np.linalg.norm(corners[:, 1] - corners[:, 0], axis=1), spacing)
        self.params = [np.arange(m) / m for m in counts]

    def split(self, facet, t0, t1):
        """Add the midpoint of the piece [t0, t1] of a cage edge."""
        self.params[facet] = np.sort(np.append(self.params[facet], 0.5 * (t0 + t1)))

    def samples(self):
        """Current samples, control points first.

        Returns
        -------
        points : (P, 2) float array, bary-combinations of the edge ends
        facet : (P,) int array, the cage edge of each sample
        bary : (P, 2) float array, (1 - t, t)
        segments : (S, 2) int array, consecutive samples along the polygon (S = P)
        segment_facet : (S,) int array, the cage edge each segment is a piece of
        segment_params : (S, 2) float array, the t range [t0, t1] of each segment on its cage edge
        """
        cage = self.cage
        n = cage.n_control_points
        start = cage.facets[:, 0]  # control point i starts exactly one edge: the one with t = 0 at it
        facet, t, ids, seg_params, seg_facet = [], [], [], [], []
        next_id = n
        for k, params in enumerate(self.params):
            inner = params[1:]
            facet.append(np.full(len(inner), k))
            t.append(inner)
            chain = np.r_[start[k], next_id + np.arange(len(inner)), cage.facets[k, 1]]
            next_id += len(inner)
            ids.append(np.stack([chain[:-1], chain[1:]], axis=1))
            seg_params.append(np.stack([params, np.r_[params[1:], 1.0]], axis=1))
            seg_facet.append(np.full(len(params), k))
        order = np.argsort(start)
        facet = np.concatenate([order] + facet)
        t = np.concatenate([np.zeros(n)] + t)
        bary = np.stack([1.0 - t, t], axis=1)
        points = bary_positions(cage, facet, bary)
        return points, facet, bary, np.concatenate(ids), np.concatenate(seg_facet), np.concatenate(seg_params)



def mesh_triangle(cage, cells, steps):
    """Triangle with the reference solver's switches: no Steiner points on the boundary, 33° minimum angle."""
    triangle = triangle_module()
    if triangle is None:
        raise ImportError(
            "meshing method 'triangle' needs the optional package triangle (pip install triangle); "
            "use method='delaunay' instead"
        )
    steps(0.0, "sampling the cage polygon")
    max_area, spacing = _reference_sizes_2d(cage, cells)
    points, facet, bary, segments, _, _ = _PolygonBoundary(cage, spacing).samples()
    steps(0.2, "triangulating (Triangle)")
    area = np.format_float_positional(max_area, trim="-")  # Triangle's switch parser reads no exponents
    result = triangle.triangulate(dict(vertices=points, segments=segments), f"pzYq{_TRIANGLE_MIN_ANGLE}a{area}")
    vertices, triangles = result["vertices"], result["triangles"]
    if not np.array_equal(vertices[: len(points)], points):
        raise CageError("Triangle moved the boundary samples; the cage may be degenerate: use method='delaunay'")
    steps(0.9, "checking the triangulation")
    return raw_mesh(vertices, triangles, np.arange(len(points)), facet, bary)


def mesh_delaunay(cage, cells, steps):
    """Boundary samples as for Triangle, a hexagonal lattice inside, Delaunay, boundary recovery, smoothing."""
    steps(0.0, "sampling the cage polygon")
    _, spacing = _reference_sizes_2d(cage, cells)
    boundary = _PolygonBoundary(cage, spacing)
    n_boundary = len(boundary.samples()[0])
    # A triangulated polygon with B boundary and I interior vertices has 2 I + B - 2 triangles.
    lattice = _polygon_lattice(cage, max(0, (cells - n_boundary + 2) // 2), _LATTICE_MARGIN * spacing)
    far = far_points(cage.vertices)
    steps(0.2, "triangulating (Delaunay)")
    for _ in range(_RECOVERY_ROUNDS):
        steps.check()
        points, facet, bary, segments, segment_facet, segment_params = boundary.samples()
        lattice = _outside_diametral_circles(lattice, points, segments)
        simplices = Delaunay(np.concatenate([points, lattice, far])).simplices
        missing = ~rows_in(np.sort(segments, axis=1), cell_edges(simplices))
        if not missing.any():
            break
        for k in np.flatnonzero(missing):
            boundary.split(segment_facet[k], *segment_params[k])
    else:
        raise CageError(
            "could not make the mesh follow the cage polygon: remove very short edges or very sharp spikes "
            "from the cage"
        )
    steps(0.7, "keeping the triangles inside the cage")
    vertices = np.concatenate([points, lattice])
    triangles = simplices[np.all(simplices < len(vertices), axis=1)]
    # Three samples of one cage edge are collinear: their (flat) triangle is neither inside nor outside.
    triangles = triangles[~on_common(_polygon_incidence(cage, facet), triangles)]
    inside = winding_numbers(cage.vertices, cage.facets, vertices[triangles].mean(axis=1), steps.check) > 0.5
    triangles = orient_positive(vertices, triangles[inside])
    steps(0.8, "smoothing")
    vertices = smooth(vertices, triangles, np.arange(len(points), len(vertices)), _SMOOTHING_PASSES, steps)
    steps(0.9, "checking the triangulation")
    return raw_mesh(vertices, triangles, np.arange(len(points)), facet, bary)


def _polygon_incidence(cage, facet):
    """(P, E) sparse 0/1 matrix: which cage edges each boundary sample lies on (control points, first, on two).

    Parameters
    ----------
    facet : (P,) int array, the cage edge of each sample; the first n samples are the control points, each at the
        start of its edge.
    """
    n = cage.n_control_points
    ending = np.empty(n, dtype=np.int64)
    ending[cage.facets[:, 1]] = np.arange(len(cage.facets))
    rows = np.concatenate([np.arange(len(facet)), np.arange(n)])
    cols = np.concatenate([facet, ending])
    return sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(facet), len(cage.facets)))


def _polygon_lattice(cage, count, margin):
    """About ``count`` points of a hexagonal lattice inside the cage polygon, at least ``margin`` from its edges.

    Returns
    -------
    (I, 2) float array
    """
    if count == 0:
        return np.zeros((0, 2))
    spacing = np.sqrt(2.0 * cage.measure / (np.sqrt(3.0) * count))
    # The margin band holds no points: rescale the spacing a few times until the count comes out right.
    for _ in range(3):
        low, high = cage.vertices.min(axis=0), cage.vertices.max(axis=0)
        rows = np.arange(low[1], high[1] + spacing, spacing * np.sqrt(3.0) / 2.0)
        cols = np.arange(low[0] - spacing, high[0] + spacing, spacing)
        x = cols[None, :] + 0.5 * spacing * (np.arange(len(rows)) % 2)[:, None]
        points = np.stack([x.ravel(), np.repeat(rows, len(cols))], axis=1)
        corners = cage.vertices[cage.facets]
        keep = winding_numbers(cage.vertices, cage.facets, points) > 0.5
        keep[keep] = distance_to_segments(points[keep], corners[:, 0], corners[:, 1]) >= margin
        points = points[keep]
        if len(points) == 0:
            break
        spacing *= np.sqrt(len(points) / count)
    return points


def _outside_diametral_circles(points, boundary_points, segments):
    """Drop the points inside the diametral circle (sphere) of any boundary segment; such points would stop the
    segment from being a Delaunay edge."""
    if len(points) == 0:
        return points
    a, b = boundary_points[segments[:, 0]], boundary_points[segments[:, 1]]
    centres, radii = 0.5 * (a + b), 0.5 * np.linalg.norm(b - a, axis=1)
    near = cKDTree(points).query_ball_point(centres, radii)
    drop = np.unique(np.concatenate([np.asarray(i, dtype=np.int64) for i in near] + [np.zeros(0, np.int64)]))
    return np.delete(points, drop, axis=0)

