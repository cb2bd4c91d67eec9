"""Binding: the whole pipeline from a cage and points to sparse coordinates, deformation, and files.

    cage → domain mesh → boundary values → geodesic TV weights → ADMM → interpolation to the points → reduction
"""

import json
import time
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from . import __version__
from .boundary import boundary_weights
from .cage import Cage, make_cage, real_array
from .errors import CageError
from .interpolation import interpolation_matrix
from .meshing import DomainMesh, mesh_domain
from .options import DEFAULT_CELLS, BindOptions
from .reduction import interpolate_and_reduce
from .parallel import thread_map, worker_count
from .solver import check_memory, solve_forecast, solve_on_mesh

# Deforming fewer points than this is faster on one thread.
PARALLEL_MIN_POINTS = 50_000
# Share of the progress bar each stage gets (the solve dominates).
_STAGES = {"meshing": (0.0, 0.08), "solve": (0.08, 0.92), "interpolation": (0.92, 1.0)}


@dataclass
class Binding:
    """Coordinates of a set of points with respect to a cage, ready to deform them.

    Attributes
    ----------
    cage : Cage
    rest_cage_vertices : (n, d) float array
        Control points at bind time.
    weights : (m, n) scipy.sparse.csr_matrix
        Each point's coordinates; rows sum to 1 and reproduce the point's bound position.
    domain : DomainMesh
        The mesh of the cage's interior the coordinates were computed on.
    domain_weights : (N, n) float array
        Coordinates at the domain's vertices.
    outside : (m,) bool array
        Points outside the cage, bound to the closest point of the domain.
    points : (m, d) float array
        The points at bind time; deformation is exact at the rest pose.
    scheme : str
        "lbc", or a baseline's name ("mvc", "harmonic", "bbw").
    options, timings : dict
        What the binding was computed with, and seconds per stage.
    iterations : int
    converged : bool
    objective : float
        The weighted total variation of ``domain_weights`` (NaN for baselines).
    """

    cage: Cage
    rest_cage_vertices: np.ndarray
    weights: sp.csr_matrix
    domain: DomainMesh
    domain_weights: np.ndarray
    outside: np.ndarray
    points: np.ndarray
    scheme: str = "lbc"
    options: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    iterations: int = 0
    converged: bool = True
    objective: float = float("nan")

    @property
    def outside_count(self):
        return int(np.count_nonzero(self.outside))

    @property
    def control_input_index(self):
        """(n,) int array: an input cage vertex for each control point (welded duplicates share one)."""
        first = np.full(self.cage.n_control_points, -1)
        for index in range(len(self.cage.vertex_map) - 1, -1, -1):
            first[self.cage.vertex_map[index]] = index
        return first

    def influence_counts(self, threshold=None):
        """Number of control points with a weight above ``threshold`` (default 1e-3 / n) per point; (m,) int array."""
        if threshold is None:
            threshold = 1e-3 / self.cage.n_control_points
        above = self.weights.copy()
        above.data = (above.data > threshold).astype(np.int64)
        return np.asarray(above.sum(axis=1)).ravel()

    def deform(self, new_cage_vertices):
        """Positions of the points for a moved cage.

        Displacement form, p + Σ w_i (c_i - c_i^rest), so the rest pose is exact and points outside the cage move
        with the point they are bound to.

        Parameters
        ----------
        new_cage_vertices : (n_input, d) float array
            The cage's vertices, in the order and number given to :func:`bind`.

        Returns
        -------
        (m, d) float array
        """
        displacement = self.cage.control_points_from_input(new_cage_vertices) - self.rest_cage_vertices
        moved = self.points.copy()

        def move(block):
            rows, weights = block
            moved[rows] += weights @ displacement

        thread_map(move, self._row_blocks)
        return moved

    @cached_property
    def _row_blocks(self):
        """The weights split into row blocks, one per thread for large meshes (CSR row slices copy: done once)."""
        m = self.weights.shape[0]
        count = worker_count() if m >= PARALLEL_MIN_POINTS else 1
        bounds = np.linspace(0, m, count + 1).astype(int)
        return [(slice(a, b), self.weights[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]

    def save(self, path):
        """Write the binding to a compressed .npz file (with the cage's fingerprint, the options and the version)."""
        weights = self.weights.tocsr()
        np.savez_compressed(
            path,
            format=np.array("lbc-binding-1"),
            version=np.array(__version__),
            scheme=np.array(self.scheme),
            fingerprint=np.array(self.cage.fingerprint()),
            cage_vertices=self.cage.vertices,
            cage_facets=self.cage.facets,
            cage_facet_face=self.cage.facet_face,
            cage_vertex_map=self.cage.vertex_map,
            rest_cage_vertices=self.rest_cage_vertices,
            weights_data=weights.data,
            weights_indices=weights.indices,
            weights_indptr=weights.indptr,
            weights_shape=np.array(weights.shape),
            points=self.points,
            outside=self.outside,
            domain_vertices=self.domain.vertices,
            domain_cells=self.domain.cells,
            domain_boundary_vertices=self.domain.boundary_vertices,
            domain_boundary_facet=self.domain.boundary_facet,
            domain_boundary_bary=self.domain.boundary_bary,
            domain_control_vertices=self.domain.control_vertices,
            domain_weights=self.domain_weights,
            options=np.array(json.dumps(self.options, default=str)),
            timings=np.array(json.dumps(self.timings)),
            iterations=np.array(self.iterations),
            converged=np.array(self.converged),
            objective=np.array(self.objective),
        )


def load_binding(path, cage_vertices=None, cage_faces=None):
    """Read a binding written by :meth:`Binding.save`.

    Parameters
    ----------
    path : str or path-like
    cage_vertices, cage_faces : optional
        The cage the binding will deform; if given, it must have the topology the binding was made for.

    Returns
    -------
    Binding

    Raises
    ------
    CageError
        If the file is not a binding, or the given cage differs from the bound one.
    """
    try:
        data = np.load(path, allow_pickle=False)
        if str(data["format"]) != "lbc-binding-1":
            raise KeyError("format")
    except (OSError, ValueError, KeyError) as error:
        raise CageError(f"{path} is not an lbc binding file ({error}): bind again to make one") from None
    cage = Cage(data["cage_vertices"], data["cage_facets"], data["cage_facet_face"], data["cage_vertex_map"])
    if str(data["fingerprint"]) != cage.fingerprint():
        raise CageError(f"{path} is damaged: its cage does not match its fingerprint; bind again")
    if cage_vertices is not None:
        given = make_cage(cage_vertices, cage_faces)
        if given.fingerprint() != cage.fingerprint():
            raise CageError(
                f"{path} was bound to another cage ({len(cage.vertex_map)} vertices, {len(cage.facets)} facets; "
                f"this one has {len(given.vertex_map)} vertices, {len(given.facets)} facets): bind this cage again"
            )
    domain = DomainMesh(
        data["domain_vertices"], data["domain_cells"], data["domain_boundary_vertices"],
        data["domain_boundary_facet"], data["domain_boundary_bary"], data["domain_control_vertices"],
    )
    weights = sp.csr_matrix(
        (data["weights_data"], data["weights_indices"], data["weights_indptr"]), shape=tuple(data["weights_shape"])
    )
    return Binding(
        cage=cage,
        rest_cage_vertices=data["rest_cage_vertices"],
        weights=weights,
        domain=domain,
        domain_weights=data["domain_weights"],
        outside=data["outside"],
        points=data["points"],
        scheme=str(data["scheme"]),
        options=json.loads(str(data["options"])),
        timings=json.loads(str(data["timings"])),
        iterations=int(data["iterations"]),
        converged=bool(data["converged"]),
        objective=float(data["objective"]),
    )


def bind(
    cage_vertices,
    cage_faces,
    points,
    *,
    cells=None,
    weighting=None,
    epsilon=None,
    threshold=None,
    method=None,
    tolerance=None,
    max_iterations=None,
    options=None,
    progress=None,
    cancel=None,
):
    """Local barycentric coordinates of ``points`` with respect to a cage.

    Parameters
    ----------
    cage_vertices : (n_input, 2) or (n_input, 3) float array
    cage_faces : None or sequence of index sequences
        None: a 2D polygon, vertices in boundary order. Else the faces of a closed 3D cage.
    points : (m, d) float array
        The points to bind (a mesh's vertices). 2D points may be given with a constant z.
    cells, weighting, epsilon, threshold, method, tolerance, max_iterations : optional
        The fields of :class:`lbc_core.options.BindOptions` (None: the default): about how many triangles /
        tetrahedra fill the cage (3000 in 2D, 8000 in 3D; more is finer and slower), ρ of the geodesic TV weights
        ("quadratic", the paper's default, "linear", "sqrt", "constant" or a function), the C¹ relaxation width
        (0: plain total variation), the reduction threshold (1e-3 / n), the domain mesher ("auto"), the ADMM
        stopping tolerance (the solver's) and its iteration limit (10000).
    options : BindOptions, optional
        The same options as one object; keywords given besides it override its fields.
    progress : callable(fraction, message), optional
    cancel : callable() -> bool, optional
        Returning True stops the bind with :class:`lbc_core.Cancelled`.

    Returns
    -------
    Binding

    Raises
    ------
    CageError
        For any bad option, cage or points, before any meshing or solving.
    """
    timings = {}
    clock = time.perf_counter()
    request = BindOptions.of(options, cells=cells, weighting=weighting, epsilon=epsilon, threshold=threshold,
                             method=method, tolerance=tolerance, max_iterations=max_iterations)
    cage, points = check_request(cage_vertices, cage_faces, points, request, progress)
    cells, weighting, epsilon, method = request.cells, request.weighting, request.epsilon, request.method
    tolerance, max_iterations = request.tolerance, request.max_iterations
    threshold = request.threshold_for(cage.n_control_points)

    domain = mesh_domain(cage, cells, method, progress=stage_progress(progress, *_STAGES["meshing"]), cancel=cancel)
    timings["meshing"] = time.perf_counter() - clock

    solver_options = {"weighting": weighting, "epsilon": epsilon, "max_iterations": max_iterations}
    if tolerance is not None:
        solver_options["tolerance"] = tolerance
    result = solve_on_mesh(
        domain.vertices, domain.cells, domain.boundary_vertices, boundary_weights(domain, cage), cage.vertices,
        progress=stage_progress(progress, *_STAGES["solve"]), cancel=cancel, **solver_options,
    )
    timings.update(result.seconds)

    clock = time.perf_counter()
    located, outside, _ = interpolation_matrix(
        domain.vertices, domain.cells, points, progress=stage_progress(progress, *_STAGES["interpolation"]),
        cancel=cancel,
    )
    timings["interpolation"] = time.perf_counter() - clock
    clock = time.perf_counter()
    weights = interpolate_and_reduce(located, result.weights, cage.vertices, domain.vertices, threshold,
                                     tolerance=1e-9 * cage.bbox_diagonal)
    timings["reduction"] = time.perf_counter() - clock
    if progress is not None:
        progress(1.0, "bound")
    options = dict(solver_options, cells=len(domain.cells), threshold=threshold, method=method)
    return Binding(
        cage=cage,
        rest_cage_vertices=cage.vertices.copy(),
        weights=weights,
        domain=domain,
        domain_weights=result.weights,
        outside=outside,
        points=points,
        scheme="lbc",
        options=options,
        timings=timings,
        iterations=result.iterations,
        converged=result.converged,
        objective=result.objective,
    )


def check_request(cage_vertices, cage_faces, points, options, progress=None):
    """Everything a bind is given, checked before any long work: options, cage, points and the memory it needs.

    Parameters
    ----------
    cage_vertices, cage_faces, points
        As for :func:`bind`.
    options : BindOptions
    progress : callable(fraction, message), optional
        Told, at 0, how much memory and (roughly) time the solve will take.

    Returns
    -------
    cage : Cage
    points : (m, d) float array

    Raises
    ------
    CageError
    """
    cage = make_cage(cage_vertices, cage_faces)
    options.check_for_cage(cage.n_control_points, cage.dim)
    plane_z = None
    if cage_faces is None and np.shape(cage_vertices)[1:] == (3,):
        plane_z = float(np.asarray(cage_vertices, dtype=float)[0, 2])
    points = check_points(cage, points, plane_z)
    n_cells = options.cells or DEFAULT_CELLS[cage.dim]
    # Refuse a resolution the machine cannot hold before meshing it, not after the OS kills the process.
    check_memory(cage.n_control_points, n_cells, cage.dim)
    if progress is not None:
        progress(0.0, solve_forecast(cage.n_control_points, n_cells, cage.dim))
    return cage, points


def check_points(cage, points, plane_z=None):
    """Points as an (m, d) float array for a d-dimensional cage.

    2D points may come as (m, 3) with a constant z (file data).

    Parameters
    ----------
    cage : Cage
    points : (m, 2) or (m, 3) array-like
    plane_z : float, optional
        The z of a 2D cage given with a constant z: 2D points given with a z must lie in that plane.

    Raises
    ------
    CageError
        Wrong shape, dimension mismatch, another plane than the cage's, or NaN/inf coordinates.
    """
    points = real_array(points, "points", "(m, 2) or (m, 3)")
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise CageError(f"points must be an (m, 2) or (m, 3) array, got shape {points.shape}")
    if cage.dim == 2 and points.shape[1] == 3:
        tolerance = 1e-9 * cage.bbox_diagonal
        if len(points) and np.ptp(points[:, 2]) > tolerance:
            raise CageError("the cage is 2D but the points' z varies: bind 2D points (or a z = constant plane)")
        if len(points) and plane_z is not None and abs(points[0, 2] - plane_z) > tolerance:
            raise CageError(
                f"the 2D cage lies in the plane z = {plane_z:g} but the points in z = {points[0, 2]:g}: move them "
                "into the cage's plane (or give both as 2D arrays)"
            )
        points = points[:, :2]
    if points.shape[1] != cage.dim:
        raise CageError(f"the cage is {cage.dim}D but the points are {points.shape[1]}D")
    if not np.all(np.isfinite(points)):
        raise CageError("some points have NaN or infinite coordinates: fix or delete them")
    return points


def stage_progress(progress, start, stop):
    """A progress callback mapping a stage's own [0, 1] onto [start, stop] of the whole (None stays None)."""
    if progress is None:
        return None
    return lambda fraction, message: progress(start + (stop - start) * fraction, message)
