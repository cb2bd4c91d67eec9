"""Baseline coordinates to compare LBC with: mean value, harmonic and (optionally) bounded biharmonic.

Each ``bind_*`` function returns the same :class:`~lbc_core.binding.record.Binding` as :func:`lbc_core.bind`, so that
every statistic and plot works on each scheme. The harmonic and bounded biharmonic baselines are solved on the same
:class:`~lbc_core.meshing.DomainMesh` with the same Dirichlet boundary values as LBC (pass ``domain=binding.domain``
to share an LBC binding's mesh); mean value coordinates have a closed form, evaluated at the points themselves and
at the domain mesh's vertices (so that the locality statistics see them on the same mesh as the others).

References: Hormann & Floater, "Mean value coordinates for arbitrary planar polygons", ACM TOG 25(4), 2006;
Ju, Schaefer & Warren, "Mean value coordinates for closed triangular meshes", SIGGRAPH 2005;
Joshi et al., "Harmonic coordinates for character articulation", SIGGRAPH 2007;
Jacobson et al., "Bounded biharmonic weights for real-time deformation", SIGGRAPH 2011.
"""


import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..binding.options import BindOptions
from ..binding.pipeline import check_cage_and_points
from ..binding.record import Binding, BindOutcome
from ..errors import CageError
from ..evaluate.interpolation import interpolation_matrix
from ..kernel.fem import stiffness_matrix
from ..kernel.frame import UnitFrame
from ..kernel.geometry import polygon_mean_value_coordinates
from ..kernel.progress import Laps, Progress
from ..meshing import mesh_domain
from ..solve.boundary import boundary_weights

# A point closer than this fraction of the cage's bounding-box diagonal to a vertex, edge or face is on it.
ON_CAGE_TOLERANCE = 1e-10
# Entries of the (chunk, facets) work arrays per chunk: bounds the memory to a few tens of MB.
CHUNK_ENTRIES = 200_000


def mean_value_coordinates(cage, points, progress=None, cancel=None):
    """Mean value coordinates of points with respect to a cage, in closed form.

    2D: Hormann and Floater's formula for arbitrary simple polygons, with tan(α/2) taken from whichever of its two
    equivalent forms does not cancel. 3D: Ju, Schaefer and Warren's formula for closed triangle meshes. Points on a
    vertex, an edge or a facet get the linear interpolant there (the continuous limit). Points outside the cage get
    the formula's extension, which still sums to one and reproduces linear functions.

    Parameters
    ----------
    cage : Cage
    points : (m, d) float array
        In the cage's units and dimension.
    progress : callable(fraction, message), Progress or None
    cancel : callable() -> bool or None
        Checked between chunks; raises :class:`Cancelled` when it returns True.

    Returns
    -------
    (m, n) float array
        One row per point, one column per control point; rows sum to 1.
    """
    progress = Progress.of(progress, cancel)
    points = np.asarray(points, dtype=float)
    # Over the surface's vertices, a poked n-gon's centre among them; its column is passed on to the n-gon's control
    # points at the end, as its boundary values are.
    vertices, facets = cage.surface_vertices, cage.facets
    tolerance = ON_CAGE_TOLERANCE * cage.bbox_diagonal
    chunk = max(1, CHUNK_ENTRIES // len(facets))
    # 3D: facet corner -> surface vertex, scattering per-corner contributions (chunk, 3E) into (chunk, S) in one
    # product (2D needs none: the polygon's vertices are in order).
    scatter = None if cage.dim == 2 else sp.csr_matrix(
        (np.ones(facets.size), (np.arange(facets.size), facets.ravel())), shape=(facets.size, len(vertices))
    )
    weights = np.empty((len(points), len(vertices)))
    for start in range(0, len(points), chunk):
        progress(start / len(points), "mean value coordinates")
        stop = min(start + chunk, len(points))
        if cage.dim == 2:  # the control points run around the polygon (facets (i, i + 1) or (i + 1, i))
            weights[start:stop] = polygon_mean_value_coordinates(vertices, points[start:stop], tolerance)
        else:
            weights[start:stop] = _mvc_3d(vertices, facets, scatter, points[start:stop], tolerance)
    progress(1.0, "mean value coordinates: done")
    if cage.centres:
        weights = weights @ cage.surface_values  # a centre's column to its n-gon's control points
    return weights


def _mvc_3d(vertices, facets, scatter, x, tolerance):
    """Mean value coordinates of a chunk of points x (k, 3) for the outward triangles ``facets`` (E, 3)."""
    s = vertices[None, :, :] - x[:, None, :]  # (k, n, 3)
    distance = np.linalg.norm(s, axis=2)  # (k, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = s / distance[:, :, None]
    # Corner j of each facet and its two neighbours j+1, j-1 (cyclically), all (k, E, 3[corner], 3[xyz]).
    corner_u = u[:, facets]
    d = distance[:, facets]  # (k, E, 3)
    nxt, prv = [1, 2, 0], [2, 0, 1]
    # θ_j, the arc opposite corner j, as 2 atan2(|a - b|, |a + b|): accurate for every angle, unlike arccos or
    # arcsin near π, which matters where a point nears an edge.
    a, b = corner_u[:, :, nxt], corner_u[:, :, prv]
    theta = 2.0 * np.arctan2(np.linalg.norm(a - b, axis=3), np.linalg.norm(a + b, axis=3))
    h = theta.sum(axis=2) / 2.0  # (k, E)
    sin_theta = np.sin(theta)
    sin_adjacent = sin_theta[..., nxt] * sin_theta[..., prv]  # the two arcs meeting at corner j
    with np.errstate(divide="ignore", invalid="ignore"):  # NaN rows: points on a control point, snapped below
        volume = np.linalg.det(corner_u)  # (k, E), signed
    with np.errstate(divide="ignore", invalid="ignore"):
        # Cosine and sine of the spherical triangle's angle at corner j. Ju et al. take the sine as
        # sqrt(1 - cos²), which loses all precision near a facet (cos → -1); [u1, u2, u3] / (sin b sin c) does not.
        c = 2.0 * np.sin(h)[..., None] * np.sin(h[..., None] - theta) / sin_adjacent - 1.0
        sine = volume[..., None] / sin_adjacent
        per_corner = (theta - c[..., nxt] * theta[..., prv] - c[..., prv] * theta[..., nxt]) / (
            d * sin_theta[..., nxt] * sine[..., prv]
        )
    # A point in a facet's plane but outside the facet: the facet subtends no solid angle and adds nothing.
    per_corner[np.any(np.abs(sine) <= 1e-12, axis=2)] = 0.0
    weights = np.asarray(per_corner.reshape(len(x), -1) @ scatter)
    with np.errstate(divide="ignore", invalid="ignore"):
        weights /= weights.sum(axis=1, keepdims=True)
    # [s1, s2, s3] = 2 × area × height, and [u1, u2, u3] = [s1, s2, s3] / (d1 d2 d3).
    corners = vertices[facets]
    double_area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    height = np.abs(volume) * d.prod(axis=2) / double_area
    _snap_to_facets(weights, vertices, facets, x, height, tolerance)
    _snap_to_vertices(weights, distance, tolerance)
    return weights


def _snap_to_facets(weights, vertices, facets, x, height, tolerance):
    """Points on a facet (edges included) get the linear interpolant on it, the limit of the coordinates there.

    ``height`` (k, E) is each point's distance to each facet's plane; only pairs within ``tolerance`` are examined.
    """
    points, candidates = np.nonzero(height <= tolerance)
    if len(points) == 0:
        return
    corners = vertices[facets[candidates]]  # (c, 3, 3)
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    double_area = np.linalg.norm(normal, axis=1)
    # Signed areas of the sub-triangles opposite each corner over the facet's: the barycentric coordinates of the
    # point's projection on the facet's plane.
    rel = corners - x[points, None, :]
    sub = np.cross(rel[:, [1, 2, 0]], rel[:, [2, 0, 1]])  # (c, 3, 3)
    bary = np.einsum("cjx,cx->cj", sub, normal) / double_area[:, None] ** 2
    # Within the tolerance of an edge counts as inside: bary_j × height of corner j is the distance to edge j.
    edge_length = np.linalg.norm(corners[:, [1, 2, 0]] - corners[:, [2, 0, 1]], axis=2)
    inside = np.all(bary * double_area[:, None] >= -tolerance * edge_length, axis=1)
    points, candidates, bary = points[inside], candidates[inside], bary[inside]
    rows, first = np.unique(points, return_index=True)
    local = np.clip(bary[first], 0.0, None)
    local /= local.sum(axis=1, keepdims=True)
    weights[rows] = 0.0
    for j in range(3):
        np.add.at(weights, (rows, facets[candidates[first], j]), local[:, j])


def _snap_to_vertices(weights, distance, tolerance):
    """Points on a control point get the Kronecker delta there (the formulas divide by the distance)."""
    rows, cols = np.nonzero(distance <= tolerance)
    weights[rows] = 0.0
    weights[rows, cols] = 1.0


def harmonic_weights(domain, boundary_values):
    """Harmonic coordinates on a domain mesh: P1 Laplace equations with the given Dirichlet values.

    One sparse LU factorisation of the interior block of the stiffness matrix solves all n coordinates at once.

    Parameters
    ----------
    domain : DomainMesh
    boundary_values : (B, n) float array
        Values at ``domain.boundary_vertices`` (from :func:`lbc_core.solve.boundary.boundary_weights`).

    Returns
    -------
    (N, n) float array
        Coordinate values at the domain's vertices.
    """
    stiffness = stiffness_matrix(domain.vertices, domain.cells)
    fixed = np.asarray(domain.boundary_vertices)
    free = np.setdiff1d(np.arange(len(domain.vertices)), fixed)
    weights = np.zeros((len(domain.vertices), boundary_values.shape[1]))
    weights[fixed] = boundary_values
    if len(free):
        interior = stiffness[free][:, free].tocsc()
        rhs = -(stiffness[free][:, fixed] @ boundary_values)
        # The interior block is symmetric positive definite: a symmetric fill-reducing ordering suits it.
        weights[free] = spla.splu(interior, permc_spec="MMD_AT_PLUS_A").solve(rhs)
    return weights


def bbw_weights(domain, boundary_values):
    """Bounded biharmonic weights (Jacobson et al. 2011) through libigl's ``igl.bbw``, rows normalised to sum to 1.

    Parameters
    ----------
    domain : DomainMesh
    boundary_values : (B, n) float array

    Returns
    -------
    (N, n) float array

    Raises
    ------
    ImportError
        When libigl's Python package (``pip install libigl``) is not installed.
    """
    import igl

    weights = igl.bbw(
        np.ascontiguousarray(domain.vertices, dtype=np.float64),
        np.ascontiguousarray(domain.cells, dtype=np.int64),
        np.ascontiguousarray(domain.boundary_vertices, dtype=np.int64),
        np.ascontiguousarray(boundary_values, dtype=np.float64),
    )
    # BBW bounds each weight to [0, 1] but leaves partition of unity to a normalisation (as the paper advises).
    return weights / weights.sum(axis=1, keepdims=True)


def bind_mvc(cage_vertices, cage_faces, points, *, domain=None, cells=None, progress=None, cancel=None):
    """Bind points to a cage with mean value coordinates (dense, closed form).

    Parameters
    ----------
    cage_vertices, cage_faces, points, cells, progress, cancel
        As for :func:`lbc_core.bind`.
    domain : DomainMesh or None
        The mesh the statistics evaluate the coordinates on; None meshes the cage (pass an LBC binding's
        ``domain`` to compare on the same mesh).

    Returns
    -------
    Binding with scheme "mvc"; ``weights`` holds every entry (MVC are nowhere zero inside the cage).
    """
    return _bind_baseline("mvc", cage_vertices, cage_faces, points, domain, cells, progress, cancel)


def bind_harmonic(cage_vertices, cage_faces, points, *, domain=None, cells=None, progress=None, cancel=None):
    """Bind points to a cage with harmonic coordinates, solved on the domain mesh, interpolated linearly to points.

    Parameters and returns as :func:`bind_mvc`, with scheme "harmonic".
    """
    return _bind_baseline("harmonic", cage_vertices, cage_faces, points, domain, cells, progress, cancel)


def bind_bbw(cage_vertices, cage_faces, points, *, domain=None, cells=None, progress=None, cancel=None):
    """Bind points with bounded biharmonic weights (needs libigl: ``pip install libigl``).

    Parameters and returns as :func:`bind_mvc`, with scheme "bbw".

    Raises
    ------
    ImportError
        When libigl is not installed.
    """
    import igl  # noqa: F401  (fail before meshing when the optional dependency is missing)

    return _bind_baseline("bbw", cage_vertices, cage_faces, points, domain, cells, progress, cancel)


def bbw_available():
    """Whether libigl's Python package, which provides bounded biharmonic weights, can be imported."""
    try:
        import igl  # noqa: F401
    except ImportError:
        return False
    return True


def _check_domain_of(domain, cage):
    """A domain passed in must be a mesh of this very cage: its boundary indexes the cage's facets."""
    control = np.asarray(domain.control_vertices)
    boundary_facet = np.asarray(domain.boundary_facet)
    same = (
        domain.dim == cage.vertices.shape[1]
        and len(control) == len(cage.vertices)
        and (len(boundary_facet) == 0 or boundary_facet.max() < len(cage.facets))
        and np.array_equal(np.asarray(domain.vertices)[control], cage.vertices)
    )
    if not same:
        raise CageError(
            f"the domain passed is a mesh of another cage (its control points are not this cage's "
            f"{len(cage.vertices)} vertices); pass the domain of a binding made with this cage, or leave domain out"
        )


def _bind_baseline(scheme, cage_vertices, cage_faces, points, domain, cells, progress, cancel):
    laps = Laps()
    progress = Progress.of(progress, cancel)
    cage, points = check_cage_and_points(cage_vertices, cage_faces, points)
    # As in lbc_core.bind, every stage computes in the unit frame.
    frame = UnitFrame.of(cage)
    unit_cage, unit_points = frame.cage_to_unit(cage), frame.to_unit(points)
    if domain is None:
        unit_domain = mesh_domain(unit_cage, cells, progress=progress.part(0.0, 0.4))
        domain = frame.domain_from_unit(unit_domain, cage)
        laps.lap("meshing")
    else:
        _check_domain_of(domain, cage)
        unit_domain = frame.domain_to_unit(domain)
    laps.restart()
    if scheme == "mvc":
        domain_weights = mean_value_coordinates(unit_cage, unit_domain.vertices, progress.part(0.4, 0.6))
    else:
        progress(0.4, f"{scheme} coordinates: solving")
        solve = harmonic_weights if scheme == "harmonic" else bbw_weights
        domain_weights = solve(unit_domain, boundary_weights(unit_domain, unit_cage))
    laps.lap("solve")
    located, outside, _ = interpolation_matrix(
        unit_domain.vertices, unit_domain.cells, unit_points, progress=progress.part(0.6, 0.8)
    )
    if scheme == "mvc":  # the closed form at the points themselves, not its interpolant
        weights = mean_value_coordinates(unit_cage, unit_points, progress.part(0.8, 1.0))
    else:
        weights = located @ domain_weights
    laps.lap("interpolation")
    progress(1.0, "bound")
    return Binding(
        cage=cage,
        rest_cage_vertices=cage.vertices.copy(),
        weights=sp.csr_matrix(weights),
        domain=domain,
        domain_weights=domain_weights,
        outside=outside,
        points=points,
        scheme=scheme,
        options=BindOptions(cells=cells),
        outcome=BindOutcome(cells=len(domain.cells)),
        timings=laps.seconds,
    )
