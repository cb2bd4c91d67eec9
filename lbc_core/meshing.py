"""Domain meshing: fill a cage with triangles (2D) or tetrahedra (3D) whose boundary lies exactly on the cage.

Every method returns a :class:`DomainMesh` with the same guarantees, which the later stages rely on:

* control point i is mesh vertex ``control_vertices[i]`` at exactly (bitwise) ``cage.vertices[i]`` (Lagrange);
* every mesh vertex on the cage is listed in ``boundary_vertices`` with the facet it lies on and its barycentric
  coordinates there, and its position is that barycentric combination of the facet's corners, evaluated as
  ``sum_k bary[k] * corner[k]`` from k = 0 upward; so boundary values, linear on each facet, are exact;
* the mesh's boundary facets tile the cage's facets (no boundary facet straddles a cage edge), and every cell is
  positively oriented.

Methods
-------
2D ``"triangle"``: Shewchuk's Triangle with the reference solver's settings (switches ``pzYq33a<A>``, maximum area
1.6 × mean; optional: Triangle's licence is not GPL-compatible). 2D ``"delaunay"``: the same boundary samples, a
hexagonal lattice inside, scipy's Delaunay triangulation, boundary recovery by splitting missing boundary pieces, three
Laplacian smoothing passes; no worse angles than Triangle's on the paper's cages (see tests/test_meshing.py).
3D ``"delaunay"``: a conforming Delaunay tetrahedralisation of samples on the cage's edges and facets plus a
body-centred cubic lattice inside, smoothed (optimal Delaunay) and with slivers perturbed away (see
:func:`_mesh_3d_delaunay`). ``"auto"`` is Triangle when importable, else Delaunay, in 2D, and Delaunay in 3D.

fTetWild (pytetwild) was measured and not used: its tetrahedra do not contain the cage vertices (misses up to 0.35 %
of the cage diagonal on the gargoyle cage_L08), its boundary lies only within an envelope of the cage and does not
follow the cage edges, so boundary values could not be exactly linear on the facets; it is also slower (2.3 to 5.0 s
for 11k to 19k tetrahedra on one thread, against 0.5 to 1.5 s here).
"""

from collections import namedtuple
from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, cKDTree

from .errors import CageError, Cancelled

DEFAULT_CELLS_2D = 3000  # the reference solver's resolution for the paper's 2D figures
# Chosen by fidelity and time. The clothing garment posed with its shipped cage pose moves by up to 48 % of its size;
# against a 16k-tetrahedra binding it is off by up to 1.3 % of its size at 4k tetrahedra and 0.8 % at 8k. A whole
# bind of the 168-control-point gargoyle cage_L08 on the 2-core test machine takes 10 s at 4k, 21 s at 8k, 33 s at
# 12k (the target is 60 s; meshing and geodesics stay under 10 % of it).
DEFAULT_CELLS_3D = 8000
METHODS = {2: ("auto", "triangle", "delaunay"), 3: ("auto", "delaunay")}

# 2D sizing as in the reference solver (bldeng/LBC): maximum triangle area 1.6 × mean, boundary spacing 1.6 × the
# side of an equilateral triangle of half that area, minimum angle 33°.
_AREA_FACTOR = 1.6
_SPACING_FACTOR = 1.6
_TRIANGLE_MIN_ANGLE = 33
_SMOOTHING_PASSES = 3
_RECOVERY_ROUNDS = 40
# Interior lattice points stay this far (× boundary spacing) from the cage: beyond half a boundary piece they are
# outside every piece's diametral circle, so the boundary pieces are Delaunay edges.
_LATTICE_MARGIN = 0.7
# 3D sizing: the Delaunay tetrahedra of a body-centred cubic lattice of cube side a are 12 per a^3; with the band
# along the surface and the smoothing, the meshes of the test cages have 7.9 to 11.4 per a^3 at 4k, 8.4 to 9.8 at 10k.
_TETS_PER_CUBE = 8.5
_COUNT_TOLERANCE = 0.1  # beyond this relative miss of the target cell count, mesh again with a corrected size
_SURFACE_SPACING = 1.0  # surface sample spacing, × the lattice cube side
_BAND = 0.7  # lattice points stay this far (× surface spacing) from the cage surface
_JITTER = 0.05  # random shift of lattice points, × their spacing
_ODT_SWEEPS = 2  # optimal-Delaunay smoothing steps of the lattice points
_SLIVER_ROUNDS = 3  # then rounds of random moves of the lattice corners of slivers ...
_SLIVER_RATIO = 0.15  # ... tetrahedra with a radius ratio below this
_PERTURBATION = 0.15  # the largest move per coordinate, × the lattice cube side


@dataclass
class DomainMesh:
    """A simplicial mesh of the region a cage encloses.

    Attributes
    ----------
    vertices : (N, d) float array
        Vertex positions, in the cage's units.
    cells : (F, d+1) int array
        Triangles (d = 2) or tetrahedra (d = 3), positively oriented (positive signed area / volume).
    boundary_vertices : (B,) int array
        Every mesh vertex lying on the cage boundary, control vertices included.
    boundary_facet : (B,) int array
        Index into ``cage.facets`` of a facet that each boundary vertex lies on.
    boundary_bary : (B, d) float array
        Barycentric coordinates of each boundary vertex in that facet: non-negative, summing to 1.
    control_vertices : (n,) int array
        Mesh vertex of each control point: ``vertices[control_vertices]`` equals ``cage.vertices`` bitwise.
    """

    vertices: np.ndarray
    cells: np.ndarray
    boundary_vertices: np.ndarray
    boundary_facet: np.ndarray
    boundary_bary: np.ndarray
    control_vertices: np.ndarray

    @property
    def dim(self):
        return self.vertices.shape[1]


def mesh_domain(cage, cells=None, method="auto", progress=None, cancel=None):
    """Mesh the region enclosed by a cage.

    Parameters
    ----------
    cage : lbc_core.cage.Cage
    cells : int or None
        About how many triangles / tetrahedra to make; None for DEFAULT_CELLS_2D or DEFAULT_CELLS_3D.
    method : str
        2D: "auto", "triangle" or "delaunay". 3D: "auto" or "delaunay".
    progress : callable(fraction, message) or None
        Told the fraction done (0 to 1) and what is being done.
    cancel : callable() -> bool or None
        Polled between steps; when it returns True, :class:`Cancelled` is raised.

    Returns
    -------
    DomainMesh

    Raises
    ------
    CageError
        When the cage cannot be meshed; the message says why and what to do.
    Cancelled
    """
    dim = cage.dim
    if method not in METHODS[dim]:
        raise ValueError(f"unknown {dim}D meshing method {method!r}: choose one of {', '.join(METHODS[dim])}")
    if cells is None:
        cells = DEFAULT_CELLS_2D if dim == 2 else DEFAULT_CELLS_3D
    if not cells >= 10:
        raise ValueError(f"the target cell count must be at least 10, got {cells}")
    step = _Steps(progress, cancel)
    if dim == 3:
        mesh = _mesh_3d_delaunay(cage, int(cells), step)
    elif method == "triangle" or (method == "auto" and _triangle_module() is not None):
        mesh = _mesh_2d_triangle(cage, int(cells), step)
    else:
        mesh = _mesh_2d_delaunay(cage, int(cells), step)
    step.done()
    return mesh


class _Steps:
    """Report progress and honour cancellation between steps."""

    def __init__(self, progress, cancel):
        self.progress = progress
        self.cancel = cancel

    def __call__(self, fraction, message):
        if self.cancel is not None and self.cancel():
            raise Cancelled("meshing was cancelled")
        if self.progress is not None:
            self.progress(float(fraction), message)

    def done(self):
        if self.progress is not None:
            self.progress(1.0, "done")


def _triangle_module():
    try:
        import triangle
    except ImportError:
        return None
    return triangle


# ----------------------------------------------------------------------------------------------------------- 2D


def _reference_sizes_2d(cage, cells):
    """Maximum triangle area and boundary spacing of the reference solver for about ``cells`` triangles.

    Returns
    -------
    max_area : float, in squared cage units
    spacing : float, in cage units
    """
    max_area = _AREA_FACTOR * cage.measure / cells
    return max_area, _SPACING_FACTOR * np.sqrt(2.0 / np.sqrt(3.0) * max_area)


def _split_counts(lengths, spacing):
    """Number of equal pieces for each cage edge so that no piece is longer than ``spacing``."""
    return np.maximum(1, np.ceil(lengths / spacing - 1e-9)).astype(np.int64)


class _PolygonBoundary:
    """Samples along the cage polygon, each at a parameter t in [0, 1) on one cage edge.

    The control points are the samples at t = 0, so they come first, in cage order, at their exact positions.
    """

    def __init__(self, cage, spacing):
        self.cage = cage
        corners = cage.vertices[cage.facets]
        counts = _split_counts(np.linalg.norm(corners[:, 1] - corners[:, 0], axis=1), spacing)
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
        points = _bary_positions(cage, facet, bary)
        return points, facet, bary, np.concatenate(ids), np.concatenate(seg_facet), np.concatenate(seg_params)


def _bary_positions(cage, facet, bary):
    """Positions sum_k bary[:, k] * corner_k of points given on cage facets, summed from k = 0 upward.

    Parameters
    ----------
    cage : Cage
    facet : (P,) int array
    bary : (P, d) float array

    Returns
    -------
    (P, d) float array
    """
    corners = cage.vertices[cage.facets[facet]]  # (P, d, d)
    points = bary[:, 0, None] * corners[:, 0]
    for k in range(1, bary.shape[1]):
        points = points + bary[:, k, None] * corners[:, k]
    # A one-hot bary gives the corner itself, but 1 * (-0.0) + 0 * c would turn -0.0 into +0.0: copy corners.
    at_corner = np.flatnonzero(np.max(bary, axis=1) == 1.0)
    points[at_corner] = corners[at_corner, np.argmax(bary[at_corner], axis=1)]
    return points


def _mesh_2d_triangle(cage, cells, step):
    """Triangle with the reference solver's switches: no Steiner points on the boundary, 33° minimum angle."""
    triangle = _triangle_module()
    if triangle is None:
        raise ImportError(
            "meshing method 'triangle' needs the optional package triangle (pip install triangle); "
            "use method='delaunay' instead"
        )
    step(0.0, "sampling the cage polygon")
    max_area, spacing = _reference_sizes_2d(cage, cells)
    points, facet, bary, segments, _, _ = _PolygonBoundary(cage, spacing).samples()
    step(0.2, "triangulating (Triangle)")
    area = np.format_float_positional(max_area, trim="-")  # Triangle's switch parser reads no exponents
    result = triangle.triangulate(dict(vertices=points, segments=segments), f"pzYq{_TRIANGLE_MIN_ANGLE}a{area}")
    vertices, triangles = result["vertices"], result["triangles"]
    if not np.array_equal(vertices[: len(points)], points):
        raise CageError("Triangle moved the boundary samples; the cage may be degenerate: use method='delaunay'")
    step(0.9, "checking the triangulation")
    return _finish(cage, vertices, triangles, np.arange(len(points)), facet, bary)


def _mesh_2d_delaunay(cage, cells, step):
    """Boundary samples as for Triangle, a hexagonal lattice inside, Delaunay, boundary recovery, smoothing."""
    step(0.0, "sampling the cage polygon")
    _, spacing = _reference_sizes_2d(cage, cells)
    boundary = _PolygonBoundary(cage, spacing)
    n_boundary = len(boundary.samples()[0])
    # A triangulated polygon with B boundary and I interior vertices has 2 I + B - 2 triangles.
    lattice = _polygon_lattice(cage, max(0, (cells - n_boundary + 2) // 2), _LATTICE_MARGIN * spacing)
    far = _far_points(cage.vertices)
    step(0.2, "triangulating (Delaunay)")
    for _ in range(_RECOVERY_ROUNDS):
        points, facet, bary, segments, segment_facet, segment_params = boundary.samples()
        lattice = _outside_diametral_circles(lattice, points, segments)
        simplices = Delaunay(np.concatenate([points, lattice, far])).simplices
        missing = ~_rows_in(np.sort(segments, axis=1), _cell_edges(simplices))
        if not missing.any():
            break
        for k in np.flatnonzero(missing):
            boundary.split(segment_facet[k], *segment_params[k])
    else:
        raise CageError(
            "could not make the mesh follow the cage polygon: remove very short edges or very sharp spikes "
            "from the cage, or use method='triangle'"
        )
    step(0.7, "keeping the triangles inside the cage")
    vertices = np.concatenate([points, lattice])
    triangles = simplices[np.all(simplices < len(vertices), axis=1)]
    # Three samples of one cage edge are collinear: their (flat) triangle is neither inside nor outside.
    triangles = triangles[~_on_common_facet(_polygon_incidence(cage, facet), triangles)]
    inside = _winding_number_2d(cage, vertices[triangles].mean(axis=1)) > 0.5
    triangles = _orient_positive(vertices, triangles[inside])
    step(0.8, "smoothing")
    vertices = _smooth(vertices, triangles, np.arange(len(points), len(vertices)))
    step(0.9, "checking the triangulation")
    return _finish(cage, vertices, triangles, np.arange(len(points)), facet, bary)


def _polygon_incidence(cage, facet):
    """(P, E) sparse 0/1 matrix: which cage edges each boundary sample lies on (control points, first, on two).

    Parameters
    ----------
    facet : (P,) int array, the cage edge of each sample; the first n samples are the control points, each at the
        start of its edge.
    """
    import scipy.sparse as sp

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
        keep = _winding_number_2d(cage, points) > 0.5
        keep[keep] = _segment_distance(points[keep], corners[:, 0], corners[:, 1]) >= margin
        points = points[keep]
        if len(points) == 0:
            break
        spacing *= np.sqrt(len(points) / count)
    return points


def _segment_distance(points, starts, ends):
    """Distance from each point to the nearest of the segments [starts, ends].

    Parameters
    ----------
    points : (P, d) float array
    starts, ends : (S, d) float arrays

    Returns
    -------
    (P,) float array
    """
    direction = ends - starts
    length2 = np.maximum(np.einsum("ij,ij->i", direction, direction), np.finfo(float).tiny)
    best = np.full(len(points), np.inf)
    for chunk in np.array_split(np.arange(len(points)), max(1, len(points) * len(starts) // 2_000_000)):
        offset = points[chunk, None, :] - starts[None]  # (p, S, d)
        t = np.clip(np.einsum("psd,sd->ps", offset, direction) / length2, 0.0, 1.0)
        gap = offset - t[..., None] * direction[None]
        best[chunk] = np.sqrt(np.min(np.einsum("psd,psd->ps", gap, gap), axis=1))
    return best


def _winding_number_2d(cage, points):
    """Winding number of the cage polygon around each point (1 inside, 0 outside, 1/2 on an edge).

    Returns
    -------
    (P,) float array
    """
    winding = np.zeros(len(points))
    for chunk in np.array_split(np.arange(len(points)), max(1, len(points) * len(cage.facets) // 2_000_000)):
        a = cage.vertices[cage.facets[:, 0]][None] - points[chunk, None]
        b = cage.vertices[cage.facets[:, 1]][None] - points[chunk, None]
        cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        dot = np.einsum("psd,psd->ps", a, b)
        winding[chunk] = np.arctan2(cross, dot).sum(axis=1) / (2.0 * np.pi)
    return winding


def _far_points(vertices):
    """Corners of a box three times the cage's size: they put every cage sample inside the convex hull, so samples
    along a straight cage edge are never hull points that qhull could drop as coplanar."""
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    centre, half = 0.5 * (low + high), 1.5 * (high - low).max()
    signs = np.array(np.meshgrid(*[[-1.0, 1.0]] * vertices.shape[1], indexing="ij")).reshape(vertices.shape[1], -1)
    return centre + half * signs.T


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


def _cell_edges(cells):
    """Unique edges of the cells, each sorted.

    Returns
    -------
    (E, 2) int array
    """
    k = cells.shape[1]
    edges = np.concatenate([cells[:, [i, j]] for i in range(k) for j in range(i + 1, k)])
    return np.unique(np.sort(edges, axis=1), axis=0)


def _rows_in(rows, table):
    """Whether each row of ``rows`` occurs in ``table`` (non-negative int arrays with the same number of columns).

    Returns
    -------
    (R,) bool array
    """
    if len(table) == 0 or len(rows) == 0:
        return np.zeros(len(rows), dtype=bool)
    base = int(max(rows.max(), table.max())) + 1  # rows become base-`base` numbers: exact below 2^63

    def keys(a):
        key = a[:, 0].astype(np.int64)
        for k in range(1, a.shape[1]):
            key = key * base + a[:, k]
        return key

    return np.isin(keys(rows), keys(table))


def _signed_measures(vertices, cells):
    """Signed area (2D) or volume (3D) of each cell.

    Returns
    -------
    (F,) float array
    """
    edges = vertices[cells[:, 1:]] - vertices[cells[:, :1]]
    return np.linalg.det(edges) / (2.0 if vertices.shape[1] == 2 else 6.0)


def _orient_positive(vertices, cells):
    """Swap two corners of the negatively oriented cells."""
    cells = cells.copy()
    flip = _signed_measures(vertices, cells) < 0
    cells[flip, :2] = cells[flip, 1::-1]
    return cells


def _smooth(vertices, cells, movable, passes=_SMOOTHING_PASSES):
    """Laplacian smoothing of the ``movable`` vertices; a pass that would invert or flatten a cell is undone and
    ends the smoothing.

    Returns
    -------
    (N, d) float array
    """
    import scipy.sparse as sp

    edges = _cell_edges(cells)
    n = len(vertices)
    adjacency = sp.coo_matrix((np.ones(2 * len(edges)), (edges.ravel(), edges[:, ::-1].ravel())), shape=(n, n))
    adjacency = adjacency.tocsr()
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    floor = 1e-3 * np.min(_signed_measures(vertices, cells))
    for _ in range(passes):
        moved = vertices.copy()
        moved[movable] = (adjacency[movable] @ vertices) / degree[movable, None]
        if np.min(_signed_measures(moved, cells)) <= floor:
            break
        vertices = moved
    return vertices


def _finish(cage, vertices, cells, boundary_vertices, boundary_facet, boundary_bary):
    """Check the mesh and pack it; the first n boundary vertices are the control points, in cage order."""
    n = cage.n_control_points
    control_vertices = boundary_vertices[:n]
    vertices = np.array(vertices, dtype=float)
    vertices[control_vertices] = cage.vertices
    cells = np.asarray(cells, dtype=np.int64)
    if len(cells) == 0 or np.min(_signed_measures(vertices, cells)) <= 0:
        raise CageError("the mesh has degenerate cells: the cage may be self-intersecting or have near-duplicate "
                        "vertices; check it and try a different cell count")
    if len(np.unique(cells)) != len(vertices):
        raise CageError("some mesh vertices belong to no cell: the cage may be self-intersecting; check it")
    return DomainMesh(
        vertices=vertices,
        cells=cells,
        boundary_vertices=np.asarray(boundary_vertices, dtype=np.int64),
        boundary_facet=np.asarray(boundary_facet, dtype=np.int64),
        boundary_bary=np.asarray(boundary_bary, dtype=float),
        control_vertices=np.asarray(control_vertices, dtype=np.int64),
    )


# ----------------------------------------------------------------------------------------------------------- 3D


def _mesh_3d_delaunay(cage, cells, step):
    """Conforming Delaunay tetrahedralisation of the cage.

    Samples on the cage edges (shared by the facets on both sides) and a hexagonal lattice on each facet are
    triangulated facet by facet (2D Delaunay); a body-centred cubic (BCC) lattice fills space, except for a band
    along the surface and the protecting spheres of the surface triangles (the sphere centred in the facet through a
    triangle's corners: if it holds no other sample, that triangle is a face of the 3D Delaunay tetrahedralisation).
    Surface triangles missing from the tetrahedralisation are refined (circumcentre insertion, or the split of the
    cage-edge piece it encroaches, as in Ruppert's algorithm) until every one is present. The cage surface then
    separates the tetrahedra into connected pieces; a piece is kept when the cage's winding number around it is 1.
    The lattice points then take two optimal-Delaunay smoothing steps and up to three sliver-perturbation rounds,
    each followed by the same conforming tetrahedralisation. When the cell count misses the target by more than
    10 % (thin or small cages), everything is done once more with a corrected lattice size.
    """
    side = (_TETS_PER_CUBE * cage.measure / cells) ** (1.0 / 3.0)
    samples, vertices, tets = _tetrahedralise(cage, side, step, 0.0, 0.6)
    ratio = len(tets) / cells
    if abs(ratio - 1.0) > _COUNT_TOLERANCE:  # thin or small cages: mostly surface band, fewer tetrahedra per volume
        samples, vertices, tets = _tetrahedralise(cage, side * ratio ** (1.0 / 3.0), step, 0.6, 0.9)
    step(0.9, "checking the tetrahedralisation")
    _check_boundary(cage, vertices, tets, samples.incidence)
    return _finish(cage, vertices, tets, np.arange(len(samples.points)), samples.facet, samples.bary)


def _tetrahedralise(cage, side, step, start, end):
    """The conforming Delaunay tetrahedralisation for a lattice of cube side ``side``, smoothed.

    Returns
    -------
    samples : _Samples, the surface samples (mesh vertices 0 to P - 1)
    vertices : (N, 3) float array
    tets : (T, 4) int array, positively oriented
    """
    rng = np.random.default_rng(0)  # fixed: the same cage always gives the same mesh
    step(start, "sampling the cage surface")
    spacing = _SURFACE_SPACING * side
    surface = _SurfaceSamples(cage, spacing, rng)
    samples = surface.samples()
    lattice = _bcc_lattice(cage, side, _BAND * spacing, samples.points, samples.subtriangles, rng)
    far = _far_points(cage.vertices)
    rounds = _ODT_SWEEPS + _SLIVER_ROUNDS + 1
    for round_ in range(rounds):
        step(start + (end - start) * (round_ + 1) / (rounds + 1), "tetrahedralising (Delaunay)")
        samples, lattice, delaunay = _conforming_delaunay(cage, surface, lattice, far)
        n_surface = len(samples.points)
        vertices = np.concatenate([samples.points, lattice, far])
        tets = _inside_tetrahedra(cage, vertices, delaunay.simplices, delaunay.neighbors, samples.incidence)
        used = np.unique(tets)
        unused = np.setdiff1d(np.arange(n_surface), used)
        if len(unused):  # a surface sample in no inside tetrahedron: the surface is not where the cage says
            raise CageError(_diagnose_unrecoverable(cage, np.unique(samples.facet[unused])))
        if round_ < _ODT_SWEEPS:
            # Lattice points outside the cage are dropped; the inside ones move to improve the tetrahedra.
            lattice = _odt_positions(vertices, tets, used[used >= n_surface])
        elif round_ < rounds - 1:
            # Sliver perturbation: Delaunay keeps slivers (flat tetrahedra with well-spaced corners) when their
            # corners are nearly co-spherical; moving a lattice corner a little makes most of them go away.
            bad = tets[_radius_ratios(vertices, tets) < _SLIVER_RATIO]
            movable = np.unique(bad[bad >= n_surface]) - n_surface
            if len(movable) == 0:
                break
            lattice = lattice.copy()
            lattice[movable] += _PERTURBATION * side * rng.uniform(-1.0, 1.0, (len(movable), 3))
    renumber = np.full(len(vertices), -1)
    renumber[used] = np.arange(len(used))  # the surface samples keep their numbers
    return samples, vertices[used], _orient_positive(vertices[used], renumber[tets])


def _conforming_delaunay(cage, surface, lattice, far):
    """Refine the surface samples until every facet triangle is a face of the Delaunay tetrahedralisation.

    Returns
    -------
    samples : _Samples
    lattice : (I, 3) float array, the lattice points kept (outside the protecting spheres)
    delaunay : scipy.spatial.Delaunay of the samples' points, lattice and far, in that order
    """
    for _ in range(_RECOVERY_ROUNDS):
        samples = surface.samples()
        lattice = _outside_protecting_spheres(lattice, samples.points, samples.subtriangles)
        delaunay = Delaunay(np.concatenate([samples.points, lattice, far]))
        is_face = _rows_in(np.sort(samples.subtriangles, axis=1), _cell_faces(delaunay.simplices))
        if is_face.all():
            return samples, lattice, delaunay
        surface.refine(np.flatnonzero(~is_face))
    raise CageError(_diagnose_unrecoverable(cage, np.unique(samples.subtriangle_facet[~is_face])))


def _odt_positions(vertices, tets, movable):
    """One optimal-Delaunay-triangulation smoothing step (Chen 2004): each movable vertex goes to the
    volume-weighted mean of the circumcentres of its tetrahedra.

    Parameters
    ----------
    vertices : (N, 3) float array
    tets : (T, 4) int array
    movable : (M,) int array, vertices not on the cage

    Returns
    -------
    (M, 3) float array, their new positions
    """
    corners = vertices[tets]
    edges = corners[:, 1:] - corners[:, :1]  # (T, 3, 3)
    volume = np.abs(np.linalg.det(edges)) / 6.0
    # The circumcentre c solves 2 (p_k - p_0) . (c - p_0) = |p_k - p_0|^2; a flat tetrahedron has weight 0.
    flat = volume <= 1e-12 * np.einsum("tkd,tkd->t", edges, edges) ** 1.5
    edges[flat] = np.eye(3)
    centres = corners[:, 0] + np.linalg.solve(2.0 * edges, np.einsum("tkd,tkd->tk", edges, edges)[..., None])[..., 0]
    volume[flat] = 0.0
    weight = np.bincount(tets.ravel(), np.repeat(volume, 4), minlength=len(vertices))
    moved = np.stack([np.bincount(tets.ravel(), np.repeat(volume * centres[:, d], 4), minlength=len(vertices))
                      for d in range(3)], axis=1)
    return moved[movable] / weight[movable, None]


_Samples = namedtuple("_Samples", "points facet bary subtriangles subtriangle_facet incidence")
_Samples.__doc__ = """The cage-surface samples of one refinement round.

points : (P, 3) float array
facet : (P,) int array, a facet each point lies on
bary : (P, 3) float array, its barycentric coordinates there
subtriangles : (S, 3) int array, point indices of the facets' triangles
subtriangle_facet : (S,) int array
incidence : (P, E) scipy.sparse.csr_matrix, 1 where a point lies on a facet (closed: edges and corners included)
"""


class _SurfaceSamples:
    """Samples on the cage's edges and facets and a Delaunay triangulation of each facet.

    Points are numbered control points first (in cage order), then the samples inside the cage edges (edge by edge,
    each edge's samples at parameters t in (0, 1) from its lower to its higher vertex index), then the samples inside
    the facets (facet by facet). The samples inside an edge are shared by the two facets on either side of it.
    """

    def __init__(self, cage, spacing, rng):
        self.cage = cage
        self.rng = rng
        facets = cage.facets
        corners = cage.vertices[facets]  # (F, 3, 3)
        # Facet edge k runs from corner k to corner k + 1.
        directed = np.stack([facets, np.roll(facets, -1, axis=1)], axis=2).reshape(-1, 2)
        self.edges, inverse = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True)
        self.facet_edges = inverse.reshape(-1, 3)
        self.edge_forward = (directed[:, 0] < directed[:, 1]).reshape(-1, 3)  # facet edge k runs low → high
        self.edge_owner = np.empty(len(self.edges), dtype=np.int64)
        self.edge_owner[self.facet_edges.ravel()] = np.repeat(np.arange(len(facets)), 3)
        lengths = np.linalg.norm(cage.vertices[self.edges[:, 1]] - cage.vertices[self.edges[:, 0]], axis=1)
        # Slightly uneven pieces: evenly split edges around a facet give co-circular samples (isosceles trapezoids),
        # whose Delaunay triangulation is ambiguous. At least two pieces per edge: then no sample-free circle runs
        # through the corners of a rectangular face (or sphere through those of a box), another such case.
        counts = np.maximum(2, _split_counts(lengths, spacing))
        self.edge_params = [(np.arange(1, m) + _JITTER * rng.uniform(-1.0, 1.0, m - 1)) / m for m in counts]
        # An orthonormal frame (origin, u, v) in each facet's plane, with u along edge 0 and the normal outward.
        self.origin = corners[:, 0]
        self.axis_u = corners[:, 1] - corners[:, 0]
        self.axis_u /= np.linalg.norm(self.axis_u, axis=1, keepdims=True)
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        self.axis_v = np.cross(normal / np.linalg.norm(normal, axis=1, keepdims=True), self.axis_u)
        self.corners_xy = np.stack([self._project(corners, k) for k in range(3)], axis=1)  # (F, 3, 2)
        # Maps a 2D offset from corner 0 to the barycentric coordinates of corners 1 and 2.
        self.to_bary = np.linalg.inv(np.stack([self.corners_xy[:, 1], self.corners_xy[:, 2]], axis=2))
        self.facet_bary = [self._facet_lattice(f, spacing) for f in range(len(facets))]
        self.triangulations = [None] * len(facets)  # per facet, in local numbering; None when out of date

    def _project(self, corners, k):
        """2D coordinates of every facet's corner k in its own frame. Returns (F, 2) float array."""
        offset = corners[:, k] - self.origin
        return np.stack([np.einsum("ij,ij->i", offset, self.axis_u), np.einsum("ij,ij->i", offset, self.axis_v)], 1)

    def to_plane(self, f, points):
        """2D coordinates of 3D points in facet f's frame. Returns (P, 2) float array."""
        offset = points - self.origin[f]
        return np.stack([offset @ self.axis_u[f], offset @ self.axis_v[f]], axis=1)

    def plane_bary(self, f, xy):
        """Barycentric coordinates in facet f of 2D points given in its frame. Returns (P, 3) float array."""
        b12 = xy @ self.to_bary[f].T
        return np.stack([1.0 - b12[:, 0] - b12[:, 1], b12[:, 0], b12[:, 1]], axis=1)

    def _facet_lattice(self, f, spacing):
        """Barycentric coordinates of jittered hexagonal lattice points in facet f, a margin away from its edges."""
        corners = self.corners_xy[f]
        low, high = corners.min(axis=0), corners.max(axis=0)
        rows = np.arange(low[1], high[1] + spacing, spacing * np.sqrt(3.0) / 2.0)
        cols = np.arange(low[0] - spacing, high[0] + spacing, spacing)
        x = cols[None, :] + 0.5 * spacing * (np.arange(len(rows)) % 2)[:, None]
        xy = np.stack([x.ravel(), np.repeat(rows, len(cols))], axis=1)
        # Jitter breaks the symmetric (co-circular, co-spherical) configurations that make Delaunay ambiguous.
        xy += _JITTER * spacing * self.rng.uniform(-1.0, 1.0, xy.shape)
        bary = self.plane_bary(f, xy)
        keep = np.all(bary > 0, axis=1)
        keep[keep] = _segment_distance(xy[keep], corners, np.roll(corners, -1, axis=0)) >= _LATTICE_MARGIN * spacing
        return bary[keep]

    def _edge_chain(self, f, k):
        """Indices into the edge's parameter list [0, params..., 1] in the order facet edge k runs, and the edge."""
        e = self.facet_edges[f, k]
        chain = np.arange(len(self.edge_params[e]) + 2)
        return (chain if self.edge_forward[f, k] else chain[::-1]), e

    def samples(self):
        """All current samples and the facets' triangulations.

        Returns
        -------
        _Samples
        """
        cage = self.cage
        n, n_facets = cage.n_control_points, len(cage.facets)
        facet_of_vertex = np.empty(n, dtype=np.int64)
        corner_of_vertex = np.empty(n, dtype=np.int64)
        facet_of_vertex[cage.facets.ravel()] = np.repeat(np.arange(n_facets), 3)
        corner_of_vertex[cage.facets.ravel()] = np.tile(np.arange(3), n_facets)
        facet, bary = [facet_of_vertex], [np.eye(3)[corner_of_vertex]]
        self.edge_start = np.cumsum([n] + [len(p) for p in self.edge_params])
        self.piece_ends = {}  # (edge, piece index) → its end points, for every piece of every cage edge
        for e, params in enumerate(self.edge_params):
            chain = np.r_[self.edges[e, 0], self.edge_start[e] + np.arange(len(params)), self.edges[e, 1]]
            self.piece_ends.update({(e, i): (int(p), int(q)) for i, (p, q) in enumerate(zip(chain[:-1], chain[1:]))})
            f = self.edge_owner[e]
            k = int(np.flatnonzero(self.facet_edges[f] == e)[0])
            b = np.zeros((len(params), 3))
            forward = self.edge_forward[f, k]
            b[:, k], b[:, (k + 1) % 3] = (1.0 - params, params) if forward else (params, 1.0 - params)
            facet.append(np.full(len(params), f))
            bary.append(b)
        self.piece_of = {tuple(sorted(ends)): piece for piece, ends in self.piece_ends.items()}
        self.facet_start = np.cumsum([self.edge_start[-1]] + [len(b) for b in self.facet_bary])
        for f, b in enumerate(self.facet_bary):
            facet.append(np.full(len(b), f))
            bary.append(b)
        facet, bary = np.concatenate(facet), np.concatenate(bary)
        points = _bary_positions(cage, facet, bary)
        subtriangles, subtriangle_facet = [], []
        for f in range(n_facets):
            local = self.local_points(f)
            if self.triangulations[f] is None:
                self.triangulations[f] = self._triangulate_facet(f, points[local])
            subtriangles.append(local[self.triangulations[f]])
            subtriangle_facet.append(np.full(len(self.triangulations[f]), f))
        self.subtriangle_facet = np.concatenate(subtriangle_facet)
        self.local_index = np.concatenate([np.arange(len(t)) for t in self.triangulations])
        self.points = points
        return _Samples(points, facet, bary, np.concatenate(subtriangles), self.subtriangle_facet,
                        self._incidence(len(points)))

    def _incidence(self, n_points):
        """(P, E) sparse 0/1 matrix: which facets each sample lies on (corners and edges belong to several)."""
        import scipy.sparse as sp

        cage = self.cage
        n_facets = len(cage.facets)
        owner = np.repeat(np.arange(n_facets), 3)
        rows, cols = [cage.facets.ravel()], [owner]
        for edge, f in zip(self.facet_edges.ravel(), owner):
            rows.append(np.arange(self.edge_start[edge], self.edge_start[edge + 1]))
            cols.append(np.full(len(rows[-1]), f))
        rows.append(np.arange(self.facet_start[0], self.facet_start[-1]))
        cols.append(np.repeat(np.arange(n_facets), np.diff(self.facet_start)))
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        return sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_points, n_facets))

    def local_points(self, f):
        """Point indices of facet f: its corners, then each facet edge's inner samples in order, then its inner
        samples."""
        parts = [self.cage.facets[f]]
        for k in range(3):
            chain, e = self._edge_chain(f, k)
            parts.append(self.edge_start[e] + chain[1:-1] - 1)
        parts.append(self.facet_start[f] + np.arange(len(self.facet_bary[f])))
        return np.concatenate(parts)

    def _edge_masks(self, f):
        """Bit k set for the local points of facet f on its edge k (corners lie on two edges)."""
        counts = [len(self.edge_params[e]) for e in self.facet_edges[f]]
        return np.concatenate([[0b101, 0b011, 0b110]] + [np.full(c, 1 << k) for k, c in enumerate(counts)]
                              + [np.zeros(len(self.facet_bary[f]), dtype=np.int64)])

    def _triangulate_facet(self, f, local_points):
        """Delaunay triangles of a facet's points in local numbering, oriented like the facet.

        Returns
        -------
        (T, 3) int array
        """
        xy = self.to_plane(f, local_points)
        simplices = Delaunay(np.concatenate([xy, _far_points(xy)])).simplices
        simplices = simplices[np.all(simplices < len(xy), axis=1)]
        # Three samples of one cage edge are collinear: such a triangle is flat, and lies outside when round-off
        # puts the middle one off the line.
        masks = self._edge_masks(f)[simplices]
        simplices = simplices[(masks[:, 0] & masks[:, 1] & masks[:, 2]) == 0]
        inside = np.all(self.plane_bary(f, xy[simplices].mean(axis=1)) > 0, axis=1)
        return _orient_positive(xy, simplices[inside])

    def refine(self, missing):
        """Refine the facets around the given missing subtriangles (indices into the last ``samples()`` output).

        Ruppert's rules: a piece of a cage edge whose diametral sphere holds another sample is split at its middle
        (no triangle through that piece could have an empty protecting sphere otherwise). A missing triangle with
        no such piece gets its circumcentre added to its facet, unless the circumcentre lies outside the facet or
        in the diametral circle of a piece of the facet's edges: then that piece is split instead.
        """
        pieces = {s: self._subtriangle_pieces(s) for s in missing}
        split = set(self._encroached_by_samples(set().union(*pieces.values())))
        inserted = {}
        for s in missing:
            if split & pieces[s]:
                continue
            f = self.subtriangle_facet[s]
            centre, radius = _circumcircle(self.to_plane(f, self.points[self._subtriangle(s)]))
            encroached = self._encroached_pieces(f, centre)
            if encroached or np.any(self.plane_bary(f, centre[None])[0] <= 0):
                split.update(encroached or [self._nearest_piece(f, centre)])
                continue
            accepted = inserted.setdefault(f, [])  # missing neighbours can share a circumcircle: insert it once
            if all(np.linalg.norm(centre - c) > 0.5 * radius for c in accepted):
                accepted.append(centre)
        for f, centres in inserted.items():
            self.facet_bary[f] = np.concatenate([self.facet_bary[f], self.plane_bary(f, np.array(centres))])
            self.triangulations[f] = None
        for e, piece in split:
            params = np.r_[0.0, self.edge_params[e], 1.0]
            self.edge_params[e] = np.sort(np.append(self.edge_params[e], 0.5 * (params[piece] + params[piece + 1])))
            for f in np.flatnonzero(np.any(self.facet_edges == e, axis=1)):
                self.triangulations[f] = None

    def _subtriangle(self, s):
        """Point indices of subtriangle s of the last ``samples()`` output. Returns (3,) int array."""
        f = self.subtriangle_facet[s]
        return self.local_points(f)[self.triangulations[f][self.local_index[s]]]

    def _subtriangle_pieces(self, s):
        """The (edge, piece index) pairs of the cage-edge pieces among subtriangle s's sides. Returns a set."""
        triangle = self._subtriangle(s)
        sides = (tuple(sorted((int(p), int(q)))) for p, q in zip(triangle, np.roll(triangle, -1)))
        return {self.piece_of[side] for side in sides if side in self.piece_of}

    def _encroached_by_samples(self, pieces):
        """The (edge, piece index) pairs among ``pieces`` whose diametral sphere holds a sample."""
        pieces = list(pieces)
        if not pieces:
            return []
        ends = np.array([self.piece_ends[piece] for piece in pieces])
        a, b = self.points[ends[:, 0]], self.points[ends[:, 1]]
        near = cKDTree(self.points).query_ball_point(0.5 * (a + b), 0.5 * np.linalg.norm(b - a, axis=1) * (1 - 1e-9))
        return [piece for piece, found, own in zip(pieces, near, ends) if set(found) - set(own)]

    def _pieces(self, f):
        """For each of facet f's edges: (edge, (m, 2) starts, (m, 2) ends) of its m pieces, in the facet's frame."""
        for k in range(3):
            e = self.facet_edges[f, k]
            a, b = self.cage.vertices[self.edges[e]]
            params = np.r_[0.0, self.edge_params[e], 1.0]
            ends = self.to_plane(f, (1.0 - params)[:, None] * a + params[:, None] * b)
            yield e, ends[:-1], ends[1:]

    def _encroached_pieces(self, f, centre):
        """(edge, piece) pairs of facet f's edge pieces whose diametral circle holds ``centre``."""
        found = []
        for e, start, end in self._pieces(f):
            middle, half = 0.5 * (start + end), 0.5 * np.linalg.norm(end - start, axis=1)
            found += [(e, int(i)) for i in np.flatnonzero(np.linalg.norm(centre - middle, axis=1) < half)]
        return found

    def _nearest_piece(self, f, centre):
        """(edge, piece) pair of facet f's edge piece nearest to ``centre``."""
        best_distance, best = np.inf, None
        for e, start, end in self._pieces(f):
            distance = _pair_segment_distance(np.repeat(centre[None], len(start), axis=0), start, end)
            i = int(np.argmin(distance))
            if distance[i] < best_distance:
                best_distance, best = distance[i], (e, i)
        return best


def _circumcircle(corners):
    """Centre and radius of the circle through three 2D points ((3, 2) array)."""
    a, b, c = corners
    ab, ac = b - a, c - a
    d = 2.0 * (ab[0] * ac[1] - ab[1] * ac[0])
    ux = (ac[1] * (ab @ ab) - ab[1] * (ac @ ac)) / d
    uy = (ab[0] * (ac @ ac) - ac[0] * (ab @ ab)) / d
    return a + np.array([ux, uy]), float(np.hypot(ux, uy))


def _circumspheres(points, triangles):
    """Centre (in the triangle's plane) and radius of the sphere through each triangle's corners.

    Parameters
    ----------
    points : (P, 3) float array
    triangles : (T, 3) int array

    Returns
    -------
    centres : (T, 3) float array
    radii : (T,) float array
    """
    a, b, c = (points[triangles[:, k]] for k in range(3))
    ab, ac = b - a, c - a
    normal = np.cross(ab, ac)
    offset = (np.einsum("ij,ij->i", ac, ac)[:, None] * np.cross(normal, ab)
              + np.einsum("ij,ij->i", ab, ab)[:, None] * np.cross(ac, normal))
    offset /= 2.0 * np.einsum("ij,ij->i", normal, normal)[:, None]
    return a + offset, np.linalg.norm(offset, axis=1)


def _outside_protecting_spheres(lattice, points, subtriangles):
    """Drop the lattice points inside (or on) the protecting sphere of any surface triangle."""
    if len(lattice) == 0:
        return lattice
    centres, radii = _circumspheres(points, subtriangles)
    near = cKDTree(lattice).query_ball_point(centres, radii * (1.0 + 1e-6))
    drop = np.unique(np.concatenate([np.asarray(i, dtype=np.int64) for i in near] + [np.zeros(0, np.int64)]))
    return np.delete(lattice, drop, axis=0)


def _bcc_lattice(cage, side, band, surface_points, subtriangles, rng):
    """Jittered body-centred cubic lattice points of cube side ``side`` inside the cage, except those closer than
    ``band`` to the cage surface.

    Returns
    -------
    (I, 3) float array
    """
    low = cage.vertices.min(axis=0) - side
    shape = np.ceil((cage.vertices.max(axis=0) + side - low) / side).astype(np.int64) + 1
    index = np.stack(np.meshgrid(*[np.arange(m) for m in shape], indexing="ij"), axis=-1).reshape(-1, 3)
    # Corners (i, j, k) then cube centres (i, j, k) + 1/2, numbered alike.
    points = low + side * np.concatenate([index, index + 0.5])
    points += _JITTER * side * rng.uniform(-1.0, 1.0, points.shape)
    # The nearest surface sample is at most one circumradius farther than the surface itself: only the points in
    # between need the exact distance.
    nearest, _ = cKDTree(surface_points).query(points)
    cover = _circumspheres(surface_points, subtriangles)[1].max()
    keep = nearest >= band
    unsure = np.flatnonzero(keep & (nearest < band + cover))
    keep[unsure] = _surface_distance(cage, points[unsure], band) >= band
    # A lattice edge (centre to one of its cube's corners) between two kept points stays within its half length
    # (at most 0.52 side with the jitter; band = 0.7 side) of one of them, so it cannot cross the surface: the kept
    # points connected by lattice edges are all inside or all outside, which one winding number per piece decides.
    centre = np.flatnonzero(np.all(index < shape - 1, axis=1))
    offsets = np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1).T
    corner = np.ravel_multi_index((index[centre][:, None, :] + offsets[None]).reshape(-1, 3).T, shape)
    centre = np.repeat(centre + len(index), len(offsets))
    linked = keep[centre] & keep[corner]
    inside = _inside_pieces(cage, points, keep, centre[linked], corner[linked])
    return points[keep & inside]


def _inside_pieces(cage, points, keep, ends_a, ends_b, priority=None):
    """Whether each point lies inside the cage, for graphs whose connected pieces are all inside or all outside.

    Parameters
    ----------
    points : (P, 3) float array
    keep : (P,) bool array, the points to classify (the others come out False)
    ends_a, ends_b : (L,) int arrays, the graph's links between kept points
    priority : (P,) float array or None
        The winding number is evaluated at the point of highest priority of each piece (default: any point).

    Returns
    -------
    (P,) bool array
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    graph = sp.coo_matrix((np.ones(len(ends_a)), (ends_a, ends_b)), shape=(len(points),) * 2)
    _, piece = connected_components(graph, directed=False)
    candidates = np.flatnonzero(keep)
    if priority is not None:
        candidates = candidates[np.argsort(-priority[candidates], kind="stable")]
    pieces, first = np.unique(piece[candidates], return_index=True)
    winding = _winding_number_3d(cage, points[candidates[first]])
    _check_winding(winding)
    inside = np.zeros(piece.max() + 1, dtype=bool)
    inside[pieces] = winding > 0.5
    return keep & inside[piece]


def _check_winding(winding):
    """Raise CageError unless every winding number (at points off the surface) is 0 or 1."""
    if np.any(np.abs(winding - np.round(winding)) > 0.1) or np.any((winding > 1.5) | (winding < -0.5)):
        raise CageError(
            "the cage surface overlaps itself (some space is enclosed twice or with the wrong orientation): "
            "make sure the cage does not pass through itself and that no part is inside-out"
        )


def _surface_distance(cage, points, reach):
    """Distance from each point to the cage surface, where it is below ``reach`` (inf beyond).

    Returns
    -------
    (P,) float array
    """
    corners = cage.vertices[cage.facets]
    centres = corners.mean(axis=1)
    radii = np.linalg.norm(corners - centres[:, None], axis=2).max(axis=1)
    # Only the (point, facet) pairs closer than `reach` + the facet's radius to the facet's centre can be in reach.
    near = cKDTree(centres).query_ball_point(points, reach + radii.max())
    point = np.repeat(np.arange(len(points)), [len(n) for n in near])
    facet = np.concatenate([np.asarray(n, dtype=np.int64) for n in near] + [np.zeros(0, np.int64)])
    distance = _triangle_distance(points[point], corners[facet])
    best = np.full(len(points), np.inf)
    np.minimum.at(best, point, distance)
    return best


def _triangle_distance(points, triangles):
    """Distance from each point to its triangle.

    Parameters
    ----------
    points : (P, 3) float array
    triangles : (P, 3, 3) float array, corners

    Returns
    -------
    (P,) float array
    """
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    normal = np.cross(b - a, c - a)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    height = np.einsum("ij,ij->i", points - a, normal)
    foot = points - height[:, None] * normal
    # The foot of the perpendicular is inside when it is on the inner side of all three edges.
    inner = np.ones(len(points), dtype=bool)
    for p, q in ((a, b), (b, c), (c, a)):
        inner &= np.einsum("ij,ij->i", np.cross(q - p, foot - p), normal) >= 0
    edge = np.min([_pair_segment_distance(points, p, q) for p, q in ((a, b), (b, c), (c, a))], axis=0)
    return np.where(inner, np.abs(height), edge)


def _pair_segment_distance(points, starts, ends):
    """Distance from each point to its own segment [start, end]. Returns (P,) float array."""
    direction = ends - starts
    length2 = np.maximum(np.einsum("ij,ij->i", direction, direction), np.finfo(float).tiny)
    t = np.clip(np.einsum("ij,ij->i", points - starts, direction) / length2, 0.0, 1.0)
    return np.linalg.norm(points - starts - t[:, None] * direction, axis=1)


def _cell_faces(tets):
    """The four faces of each tetrahedron, each sorted, face k opposite corner k of every tetrahedron in turn.

    Returns
    -------
    (4 T, 3) int array
    """
    return np.sort(np.concatenate([np.delete(tets, k, axis=1) for k in range(4)]), axis=1)


def _winding_number_3d(cage, points):
    """Generalised winding number of the cage around each point (solid angles, Van Oosterom and Strackee).

    Returns
    -------
    (P,) float array, 1 inside, 0 outside
    """
    corners = cage.vertices[cage.facets]
    winding = np.zeros(len(points))
    for chunk in np.array_split(np.arange(len(points)), max(1, len(points) * len(corners) // 1_000_000)):
        a, b, c = (corners[None, :, k] - points[chunk, None] for k in range(3))
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        det = np.einsum("pfd,pfd->pf", a, np.cross(b, c))
        dot = lambda x, y: np.einsum("pfd,pfd->pf", x, y)  # noqa: E731
        denominator = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb
        winding[chunk] = np.arctan2(det, denominator).sum(axis=1) / (2.0 * np.pi)
    return winding


def _inside_tetrahedra(cage, vertices, tets, neighbours, incidence):
    """The tetrahedra inside the cage, once every surface triangle is a face of the tetrahedralisation.

    Faces on the cage surface cut the tetrahedra into connected pieces, each inside or outside as a whole.
    Tetrahedra with all four corners on one facet are flat and belong to neither.

    Parameters
    ----------
    vertices : (N, 3) float array, the surface samples first
    tets, neighbours : (T, 4) int arrays, as scipy.spatial.Delaunay's simplices and neighbors
    incidence : (P, E) sparse matrix, which facets the P surface samples lie on

    Returns
    -------
    (T', 4) int array
    """
    cut = _on_common_facet(incidence, _cell_faces(tets)).reshape(4, len(tets)).T
    flat = _on_common_facet(incidence, tets)
    link = (neighbours >= 0) & ~cut & ~flat[:, None]
    link[link] = ~flat[neighbours[link]]
    owner = np.repeat(np.arange(len(tets))[:, None], 4, axis=1)
    # The winding number is evaluated at the centroid of each piece's largest tetrahedron, well off the surface.
    inside = _inside_pieces(cage, vertices[tets].mean(axis=1), ~flat, owner[link], neighbours[link],
                            priority=np.abs(_signed_measures(vertices, tets)))
    return tets[inside]


def _on_common_facet(incidence, rows):
    """Whether all the points of each row lie on one cage facet (indices past the samples lie on none).

    Parameters
    ----------
    incidence : (P, E) sparse matrix
    rows : (R, k) int array

    Returns
    -------
    (R,) bool array
    """
    result = np.all(rows < incidence.shape[0], axis=1)
    common = incidence[rows[result, 0]]
    for k in range(1, rows.shape[1]):
        common = common.multiply(incidence[rows[result, k]])
    result[result] = common.getnnz(axis=1) > 0
    return result


def _check_boundary(cage, vertices, tets, incidence):
    """Raise CageError unless the tetrahedra's boundary triangles lie on the cage facets and cover each exactly."""
    from .fem import boundary_facets

    boundary = boundary_facets(tets)
    on_facet = _on_common_facet(incidence, boundary)
    facet = np.asarray(incidence[boundary[on_facet, 0]].multiply(incidence[boundary[on_facet, 1]])
                       .multiply(incidence[boundary[on_facet, 2]]).argmax(axis=1)).ravel()
    area = 0.5 * np.linalg.norm(np.cross(vertices[boundary[on_facet, 1]] - vertices[boundary[on_facet, 0]],
                                         vertices[boundary[on_facet, 2]] - vertices[boundary[on_facet, 0]]), axis=1)
    corners = cage.vertices[cage.facets]
    facet_area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    covered = np.bincount(facet, area, minlength=len(facet_area))
    if not on_facet.all() or not np.allclose(covered, facet_area, rtol=1e-9, atol=1e-12 * facet_area.max()):
        raise CageError(
            "the tetrahedra do not fill the cage exactly: the cage may touch or pass through itself; "
            "check it for self-intersections and nearly touching parts"
        )


def _diagnose_unrecoverable(cage, facets):
    """The error message when the tetrahedra cannot be made to follow the cage near the given facets."""
    faces = np.unique(cage.facet_face[facets])
    listed = ", ".join(str(f) for f in faces[:10]) + (" ..." if len(faces) > 10 else "")
    return (f"could not make the tetrahedra follow the cage surface near its faces {listed} (numbered from 0 in "
            "input order): the cage may pass through itself, have nearly touching parts or very sharp edges there; "
            "fix those, or try a different cell count")


def _radius_ratios(vertices, tets):
    """3 × inradius / circumradius of each tetrahedron: 1 for a regular one, 0 for a flat one.

    Returns
    -------
    (T,) float array
    """
    corners = vertices[tets]
    edges = corners[:, 1:] - corners[:, :1]
    volume = np.abs(np.linalg.det(edges)) / 6.0
    faces = [(1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)]
    area = sum(0.5 * np.linalg.norm(np.cross(corners[:, b] - corners[:, a], corners[:, c] - corners[:, a]), axis=1)
               for a, b, c in faces)
    lengths2 = np.einsum("tkd,tkd->tk", edges, edges)
    numerator = (lengths2[:, 0, None] * np.cross(edges[:, 1], edges[:, 2]) + lengths2[:, 1, None]
                 * np.cross(edges[:, 2], edges[:, 0]) + lengths2[:, 2, None] * np.cross(edges[:, 0], edges[:, 1]))
    circumradius = np.linalg.norm(numerator, axis=1) / (12.0 * np.maximum(volume, np.finfo(float).tiny))
    return 9.0 * volume / (area * np.maximum(circumradius, np.finfo(float).tiny))
