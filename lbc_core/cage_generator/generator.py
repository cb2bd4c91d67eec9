"""The cage generator's stages in order, and the ladder of retries that keeps a failing cage from ever coming out.

voxels (the solid around the mesh) → extraction (its surface) → simplification (quadric, to the hull's start) →
hull (enclosing collapses to the vertex count) → check (lbc's cage checks, exact enclosure). With a mirror plane
every stage keeps the cage exactly symmetric (:mod:`lbc_core.cage_generator.symmetry`). A stage that cannot do its
part, or a cage that fails the check, sends the generator to its next attempt (a wider margin, a larger closing, a
larger start); when none is left it raises :class:`CageGenerationFailed` saying what to try."""

from dataclasses import dataclass

import numpy as np

from ..errors import CageError
from ..kernel.progress import Progress
from .check import checked_cage, enclosure
from .clearance import cage_clearance, narrow_gaps
from .extraction import half_iso_surface, iso_surface, signed_volume
from .guard import MeshGuard
from .hull import ProgressiveHull
from .hull_tests import mirror_map
from .mesh_input import InputMesh, input_mesh
from .quads import quad_faces
from .simplification import quadric_simplified, symmetric_simplified
from .symmetry import SYMMETRY_TOLERANCE, asymmetry, checked_axis, mirror_error, mirror_frame, with_image
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
# With no vertex count asked, the hull stops when the cage would enclose more than this many times the volume of
# the surface it starts from: about the count hand-made cages of the same meshes have (bench/RESULTS.md,
# "Cage generator", the default vertex count). It then starts from DEFAULT_START vertices.
VOLUME_BUDGET = 2.0
DEFAULT_START = 300
# The hull runs again keeping its clearance only where the cage made without it has a gap narrower than this share
# of the clearance: hanyang_cactus and junyu_deer, which bind, have gaps under the clearance and took 1.5 times the
# time when every such cage ran again (bench/RESULTS.md, "Cage generator", the third round).
NARROW_SHARE = 0.5
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
    faces : list of tuples of int, the cage's faces facing out: quads where two triangles make a good one, else
        triangles (what to give Blender or :func:`lbc_core.bind`)
    triangles : (T, 3) int array, the faces split into triangles, as checked
    volume : float, what the cage encloses
    clearance : float, about the least distance from a mesh vertex to the cage
    mean_distance : float, about the mean distance from a cage vertex to the mesh
    margin : float, the margin it was made with, in the mesh's units
    asked_vertices : int or None, the vertex count asked; None when the generator chose it (see VOLUME_BUDGET)
    attempts : int, how many attempts it took (1: the first)
    symmetry : str or None, the axis normal to the mirror plane ("x", "y", "z"), or None
    mirror_error : float or None, with a mirror plane: the largest distance from a cage vertex's mirror image to the
        nearest cage vertex, in the mesh's units (rounding only)
    asymmetry : float or None, with a mirror plane: how far the mesh is from its own mirror image, a share of its
        bounding-box diagonal (see :func:`lbc_core.cage_generator.symmetry.asymmetry`)
    warnings : tuple of str, what the artist should know
    """

    vertices: np.ndarray
    faces: list
    triangles: np.ndarray
    volume: float
    clearance: float
    mean_distance: float
    margin: float
    asked_vertices: int
    attempts: int
    symmetry: str = None
    mirror_error: float = None
    asymmetry: float = None
    warnings: tuple = ()

    @property
    def vertex_count(self):
        return len(self.vertices)

    @property
    def quad_share(self):
        """The share of the faces that are quads."""
        return sum(len(face) == 4 for face in self.faces) / max(len(self.faces), 1)


@dataclass(frozen=True)
class Job:
    """What every attempt works on: the mesh in the frame the generator works in (its mirror plane through 0 when
    it has one), the mesh a cage must enclose there (with its mirror image when symmetric), the mirror frame."""

    mesh: InputMesh
    enclosed: InputMesh
    frame: object = None
    asymmetry: float = None

    @property
    def axis(self):
        return None if self.frame is None else self.frame.axis


@dataclass(frozen=True)
class Attempt:
    """One try's settings, in the mesh's units."""

    margin: float
    closing: float
    spacing: float
    start: int
    target: int


def generate_cage(vertices, faces, *, n_vertices=None, margin=None, symmetry=None, quads=True, progress=None,
                  cancel=None):
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
    symmetry : {None, "x", "y", "z"}, optional
        Make the cage exactly mirror-symmetric about the plane normal to this axis through the middle of the mesh's
        bounding box (for Blender's X-mirror editing). A mesh that is not symmetric about it gets a warning and a
        cage around it and its mirror image.
    quads : bool, optional
        Merge pairs of the cage's triangles into quads where they make good ones (True by default); lbc binds the
        same triangles either way.
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
    axis = checked_axis(symmetry)
    mesh = input_mesh(vertices, faces)
    target = None if n_vertices is None else _checked_count(n_vertices)
    job, warnings = _job(mesh, axis, symmetry)
    failures = []
    for number, (margin_factor, closing_factor, start_factor) in enumerate(ATTEMPTS, start=1):
        part = steps.part(*ATTEMPT_SHARES[number - 1])
        attempt = _attempt(mesh, margin_share * margin_factor, closing_factor, start_factor, target)
        made, why = _try(job, attempt, part)
        if made is not None:
            steps(1.0, "cage made")
            return _generated(job, attempt, made, number, warnings + tuple(failures), quads)
        failures.append(f"attempt {number} (margin {attempt.margin:.4g}): {why}")
    raise CageGenerationFailed(
        "no cage could be made that lbc accepts and that encloses the mesh (" + "; ".join(failures) + "): try more "
        "vertices, a wider margin, or cage the mesh's parts separately")


def _job(mesh, axis, symmetry):
    """(Job, warnings): the mesh in its mirror frame when symmetric, with its image; a warning when the mesh is not
    symmetric about the plane."""
    if axis is None:
        return Job(mesh, mesh), ()
    frame = mirror_frame(mesh, axis)
    moved = InputMesh(frame.into(mesh.vertices), mesh.triangles, mesh.diagonal)
    off = asymmetry(mesh, frame)
    warnings = ()
    if off > SYMMETRY_TOLERANCE:
        warnings = (f"the mesh is not symmetric about the {symmetry} plane through its middle: its mirror image lies "
                    f"up to {100 * off:.1f} % of its size away (2 % counts as symmetric); the cage is symmetric and "
                    "encloses the mesh and its mirror image, so it is looser where they differ",)
    return Job(moved, with_image(moved, axis), frame, off), warnings


def _generated(job, attempt, made, number, warnings, quads):
    """The GeneratedCage of an attempt's (vertices, triangles, Enclosure), back in the mesh's frame."""
    vertices, triangles, report = made
    symmetry, error, mirror = None, None, None
    if job.frame is not None:
        mirror = mirror_map(vertices, job.axis)
        vertices = job.frame.out_of(vertices)
        symmetry = "xyz"[job.axis]
        error = mirror_error(vertices, job.axis, job.frame.centre)
    faces = quad_faces(vertices, triangles, mirror) if quads else [tuple(face) for face in triangles.tolist()]
    return GeneratedCage(vertices, faces, triangles, signed_volume(vertices, triangles), report.clearance,
                         report.mean_distance, attempt.margin, attempt.target, number, symmetry, error, job.asymmetry,
                         warnings)


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
    start = DEFAULT_START if target is None else max(START_LEAST, START_FACTOR * target)
    return Attempt(margin_share * mesh.diagonal, CLOSING_VOXELS * closing_factor * spacing, spacing,
                   int(start * start_factor), target)


def witness_points(vertices, spacing):
    """One mesh vertex per grid cell of ``spacing`` (the first in each), the points every collapse keeps inside."""
    keys = np.floor((vertices - vertices.min(axis=0)) / spacing).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return vertices[np.sort(first)]


def _try(job, attempt, steps):
    """((vertices, triangles, Enclosure), None) or (None, why) for one attempt."""
    steps(0.0, "voxelizing the mesh")
    mesh = job.mesh
    solid = voxel_solid(mesh.vertices, mesh.triangles, attempt.spacing, attempt.margin, attempt.closing, steps.check,
                        job.axis)
    steps(0.25, "simplifying the surface")
    start = _start(job, solid, attempt, steps.check)
    if start is None:
        return None, "the simplified surface did not enclose the mesh"
    cage_vertices, cage_triangles, left = _hull_cage(job, attempt, start, steps.part(0.45, 0.9))
    if attempt.target is not None and left > attempt.target * (1.0 + COUNT_SLACK):
        return None, f"the cage kept {left} vertices, more than {attempt.target} asked"
    steps(0.9, "checking the cage")
    try:
        checked_cage(cage_vertices, cage_triangles)
    except CageError as error:
        return None, f"lbc refused the cage ({error})"
    report = enclosure(mesh, cage_vertices, cage_triangles, attempt.spacing, steps.check)
    if not report.encloses:
        return None, f"the cage left {report.parts_outside} parts outside and crossed {report.crossings} edges"
    return (cage_vertices, cage_triangles, report), None


def _hull_cage(job, attempt, start, steps):
    """(vertices, triangles, vertex count) of the hull from ``start``. Where parts of that cage face each other
    closer than NARROW_SHARE × the clearance lbc's mesher needs (:mod:`.clearance`), the hull runs again from the
    start keeping the clearance, and its cage is taken when it reaches the count too (a thin shell's cage, the clothing's, may not;
    its folds then stay, as before): cages that bound before stay the same (bench/RESULTS.md, "Cage generator",
    the third round)."""
    enclosed, zero = job.enclosed, 1e-9 * job.mesh.diagonal
    witnesses = witness_points(enclosed.vertices, attempt.spacing)
    guard = MeshGuard(enclosed.vertices, enclosed.triangles)
    hull = ProgressiveHull(*start, zero, witnesses, job.axis, guard)
    left = _shaped(hull, attempt, steps.part(0.0, 0.5))
    cage = hull.result()
    clearance = cage_clearance(signed_volume(*start))
    if not len(narrow_gaps(*cage, NARROW_SHARE * clearance)):
        return cage + (left,)
    kept = ProgressiveHull(*start, zero, witnesses, job.axis, guard, clearance)
    kept_left = _shaped(kept, attempt, steps.part(0.5, 1.0))
    if attempt.target is not None and kept_left > attempt.target * (1.0 + COUNT_SLACK):
        return cage + (left,)
    return kept.result() + (kept_left,)


def _shaped(hull, attempt, steps):
    """The hull brought down to the count asked, or with none asked until its volume reaches the budget; returns
    its vertex count."""
    if attempt.target is not None:
        collapses = max(1, len(hull.points) - attempt.target)
        return hull.simplify(attempt.target, lambda: steps(hull.collapses / collapses, "shaping the cage"))
    start = hull.volume
    limit = VOLUME_BUDGET * start
    return hull.simplify(FEWEST_VERTICES, lambda: steps(min(1.0, (hull.volume - start) / (limit - start)),
                                                        "shaping the cage"), limit)


def _start(job, solid, attempt, check):
    """The hull's start: the solid's surface simplified and pushed out of the mesh (its mirror image too), or None."""
    zero = 1e-9 * job.mesh.diagonal
    clearance = 0.25 * attempt.margin
    if job.axis is None:
        return quadric_simplified(*iso_surface(solid), attempt.start, job.enclosed, clearance, attempt.spacing,
                                  zero, check)
    return symmetric_simplified(*half_iso_surface(solid, job.axis), attempt.start, job.enclosed, clearance,
                                attempt.spacing, zero, job.axis, check)
