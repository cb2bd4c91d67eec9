"""The cage generator's stages in order, and the ladder of retries that keeps a failing cage from ever coming out.

voxels (the solid around the mesh) → extraction (its surface) → simplification (quadric, to the hull's start) →
hull (enclosing collapses to the vertex count) → check (lbc's cage checks, exact enclosure). A stage that cannot do
its part, or a cage that fails the check, sends the generator to its next attempt (a wider margin, a larger closing,
a larger start); when none is left it raises :class:`CageGenerationFailed` saying what to try."""

from dataclasses import dataclass

import numpy as np

from ..errors import CageError
from ..kernel.progress import Progress
from .check import checked_cage, enclosure
from .extraction import iso_surface, signed_volume
from .guard import MeshGuard
from .hull import ProgressiveHull
from .mesh_input import input_mesh
from .simplification import quadric_simplified
from .voxels import voxel_solid

# The margin between the mesh and its cage when none is asked, a share of the mesh's bounding-box diagonal
# (bench/RESULTS.md, "Cage generator").
DEFAULT_MARGIN = 0.01
# Voxels along the solid's longest side.
GRID_CELLS = 128
# The closing radius, in voxels: fills gaps a few voxels wide that no cage of this many vertices could follow.
CLOSING_VOXELS = 2.5
# The hull starts from this many times the vertices asked (at least START_LEAST), so that its collapses, which
# enclose, do the shaping (bench/RESULTS.md, "Cage generator").
START_FACTOR = 2.5
START_LEAST = 250
# A cage within this share of the vertices asked is accepted.
COUNT_SLACK = 0.15
# Vertex counts a cage may be asked for.
FEWEST_VERTICES, MOST_VERTICES = 8, 2000
# The attempts, in order: (margin factor, closing factor, start factor).
ATTEMPTS = ((1.0, 1.0, 1.0), (1.0, 2.0, 1.5), (1.5, 3.0, 2.0), (2.5, 5.0, 2.5))
# Each attempt's part of the progress bar: the first most of it, since it most often makes the cage.
ATTEMPT_SHARES = ((0.0, 0.7), (0.7, 0.8), (0.8, 0.9), (0.9, 1.0))


class CageGenerationFailed(CageError):
    """No attempt gave a cage that passes lbc's checks and encloses the mesh with the vertices asked."""


@dataclass(frozen=True)
class GeneratedCage:
    """A cage made for a mesh, checked by lbc's cage checks and for enclosure.

    vertices : (n, 3) float array, in the mesh's units
    faces : (F, 3) int array, outward triangles
    volume : float, what the cage encloses
    clearance : float, about the least distance from a mesh vertex to the cage
    mean_distance : float, about the mean distance from a cage vertex to the mesh
    margin : float, the margin it was made with, in the mesh's units
    asked_vertices : int, the vertex count asked (or chosen for the mesh)
    attempts : int, how many attempts it took (1: the first)
    warnings : tuple of str, what the artist should know
    """

    vertices: np.ndarray
    faces: np.ndarray
    volume: float
    clearance: float
    mean_distance: float
    margin: float
    asked_vertices: int
    attempts: int
    warnings: tuple = ()

    @property
    def vertex_count(self):
        return len(self.vertices)


@dataclass(frozen=True)
class Attempt:
    """One try's settings, in the mesh's units."""

    margin: float
    closing: float
    spacing: float
    start: int
    target: int


def generate_cage(vertices, faces, *, n_vertices=None, margin=None, progress=None, cancel=None):
    """A closed cage around a mesh, with about ``n_vertices`` vertices, that lbc binds.

    Parameters
    ----------
    vertices : (n, 3) float array
    faces : (F, k) int array or sequence of index sequences
        Any surface: several parts, holes, open clothing, self-intersections and non-manifold edges are fine.
    n_vertices : int, optional
        The cage's vertex count, met within 15 %; by default one chosen for the mesh's shape.
    margin : float, optional
        The space between the mesh and the cage, a share of the mesh's bounding-box diagonal (0.01 by default).
    progress : callable(fraction, message), optional
    cancel : callable() -> bool, optional
        Returning True stops the work with :class:`lbc_core.Cancelled`.

    Returns
    -------
    GeneratedCage

    Raises
    ------
    CageError
        The mesh cannot be caged (empty, points only, flat), the options are out of range, or no attempt gave a
        valid enclosing cage (:class:`CageGenerationFailed`); the message says what to do.

    Examples
    --------
    >>> import numpy as np
    >>> from lbc_core import generate_cage
    >>> from lbc_core.cage_generator.shapes import box
    >>> cage = generate_cage(*box(), n_vertices=20)
    >>> abs(cage.vertex_count - 20) <= 3
    True
    """
    steps = Progress.of(progress, cancel)
    margin_share = _checked_margin(margin)
    mesh = input_mesh(vertices, faces)
    target = None if n_vertices is None else _checked_count(n_vertices)
    failures = []
    for number, (margin_factor, closing_factor, start_factor) in enumerate(ATTEMPTS, start=1):
        part = steps.part(*ATTEMPT_SHARES[number - 1])
        attempt = _attempt(mesh, margin_share * margin_factor, closing_factor, start_factor, target)
        made, why = _try(mesh, attempt, part)
        if made is not None:
            vertices_out, triangles, report = made
            steps(1.0, "cage made")
            return GeneratedCage(vertices_out, triangles, signed_volume(vertices_out, triangles), report.clearance,
                                 report.mean_distance, attempt.margin, attempt.target, number, tuple(failures))
        failures.append(f"attempt {number} (margin {attempt.margin:.4g}): {why}")
    raise CageGenerationFailed(
        "no cage could be made that lbc accepts and that encloses the mesh (" + "; ".join(failures) + "): try more "
        "vertices, a wider margin, or cage the mesh's parts separately")


def _checked_margin(margin):
    if margin is None:
        return DEFAULT_MARGIN
    margin = float(margin)
    if not (0.0 < margin <= 0.2):
        raise CageError(f"the margin must be a share of the mesh's size between 0 and 0.2 (0.01 is 1 %), got {margin}")
    return margin


def _checked_count(n_vertices):
    count = int(n_vertices)
    if count != n_vertices or not (FEWEST_VERTICES <= count <= MOST_VERTICES):
        raise CageError(f"the cage's vertex count must be a whole number from {FEWEST_VERTICES} to {MOST_VERTICES}, "
                        f"got {n_vertices}")
    return count


def _attempt(mesh, margin_share, closing_factor, start_factor, target):
    sides = mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)
    spacing = float(sides.max()) / GRID_CELLS
    count = target if target is not None else default_vertex_count(mesh)
    start = int(max(START_LEAST, START_FACTOR * count) * start_factor)
    return Attempt(margin_share * mesh.diagonal, CLOSING_VOXELS * closing_factor * spacing, spacing, start, count)


def default_vertex_count(mesh):
    """A vertex count for the mesh's cage when none is asked: 100 for now."""
    return 100


def witness_points(vertices, spacing):
    """One mesh vertex per grid cell of ``spacing`` (the first in each), the points every collapse keeps inside."""
    keys = np.floor((vertices - vertices.min(axis=0)) / spacing).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return vertices[np.sort(first)]


def _try(mesh, attempt, steps):
    """((vertices, triangles, Enclosure), None) or (None, why) for one attempt."""
    zero = 1e-9 * mesh.diagonal
    steps(0.0, "voxelizing the mesh")
    solid = voxel_solid(mesh.vertices, mesh.triangles, attempt.spacing, attempt.margin, attempt.closing, steps.check)
    steps(0.25, "extracting the surface")
    surface = iso_surface(solid)
    steps(0.35, "simplifying the surface")
    witnesses = witness_points(mesh.vertices, attempt.spacing)
    start = quadric_simplified(*surface, attempt.start, mesh, 0.25 * attempt.margin, attempt.spacing, zero,
                               steps.check)
    if start is None:
        return None, "the simplified surface did not enclose the mesh"
    hull = ProgressiveHull(*start, zero, witnesses, guard=MeshGuard(mesh.vertices, mesh.triangles))
    collapses = max(1, len(hull.points) - attempt.target)
    hull_steps = steps.part(0.45, 0.9)
    left = hull.simplify(attempt.target, lambda: hull_steps(hull.collapses / collapses, "shaping the cage"))
    if left > attempt.target * (1.0 + COUNT_SLACK):
        return None, f"the cage kept {left} vertices, more than {attempt.target} asked"
    cage_vertices, cage_triangles = hull.result()
    steps(0.9, "checking the cage")
    try:
        checked_cage(cage_vertices, cage_triangles)
    except CageError as error:
        return None, f"lbc refused the cage ({error})"
    report = enclosure(mesh, cage_vertices, cage_triangles, attempt.spacing, steps.check)
    if not report.encloses:
        return None, f"the cage left {report.parts_outside} parts outside and crossed {report.crossings} edges"
    return (cage_vertices, cage_triangles, report), None
