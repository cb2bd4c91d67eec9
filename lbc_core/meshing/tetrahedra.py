"""3D backend: a conforming Delaunay tetrahedralisation of the cage, on scipy's qhull.

Samples on the cage's planar regions and feature edges (:mod:`.surface`) are triangulated region by region (regions
facing another part of the cage across a gap narrower than the spacing are sampled finer from the start); a
body-centred cubic (BCC) lattice fills space, except for a band along the surface and the protecting spheres of the
surface triangles (the sphere centred in the triangle's plane through its corners: if it holds no other sample, that
triangle is a face of the 3D Delaunay tetrahedralisation). Surface triangles missing from the tetrahedralisation are
refined (circumcentre insertion, or the split of the feature-edge piece it encroaches, as in Ruppert's algorithm)
until every one is present. The surface then separates the tetrahedra into connected pieces; a piece is kept when
the cage's winding number around it is 1. The lattice corners of poor tetrahedra are then moved, the tetrahedra
kept, where that raises the least radius ratio around them (:func:`polish`): one tetrahedralisation in all, where
smoothing and sliver perturbation by new tetrahedralisations took four. The lattice side is chosen before the
tetrahedralisation, by counting the samples and lattice points it makes (:mod:`.sizing`); when the cell count still
misses the target by more than 15 %, everything is done once more with the count model corrected.

Every loop is bounded by counts, never by the clock, so the same cage takes the same path on any machine under any
load: recovery rounds, a surface-sample budget, a work budget (the points handed to the tetrahedraliser in all, the
last guard), and a cancel check in each round. Refinement whose missing triangles keep growing, on course to
pass the sample budget (parts of the cage nearly touching, far closer than the sampling), is refused at once,
naming the faces. When recovery runs out of its budget (feature edges meeting at very small angles can make
Ruppert-style refinement cascade), the mesh is made again with fresh jitter and a coarser surface, and only then is
the cage refused, naming the faces where it failed.
"""

import itertools
from dataclasses import replace
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Delaunay, cKDTree

from ..errors import CageError, GapTooNarrow
from ..kernel.geometry import (circumspheres, orient_positive, radius_ratios, row_keys, signed_measures,
                               signed_radius_ratios_by_coordinate, triangle_normals, winding_numbers)
from .common import far_points, on_common, raw_mesh, rows_in
from .lattice import bcc_lattice, check_winding
from .sizing import Sizing, WorkBudget
from .surface import OutOfBudget, Surface, split_facets

# Sizing: the Delaunay tetrahedra of a body-centred cubic lattice of cube side a are 12 per a^3; with the band
# along the surface, the corpus's meshes have 8.2 to 10.8 per a^3 at 8000 cells (7.1 to 13.9 at 2000).
_TETS_PER_CUBE = 9.5
_COUNT_TOLERANCE = 0.15  # beyond this relative miss of the target cell count, mesh again with a corrected size
_SURFACE_SPACING = 1.0  # surface sample spacing, × the lattice cube side
_BAND = 0.7  # lattice points stay this far (× surface spacing) from the cage surface
# Lattice corners of tetrahedra below this radius ratio are moved to raise the least ratio around them, in
# _POLISH_ROUNDS rounds of _POLISH_TRIES tries up to _POLISH_STEP cube sides away (bench/RESULTS.md, "Constants' notes").
_POLISH_RATIO = 0.2
_FLAT = 1e-9  # a tetrahedron of at most this share of the median volume is flat (see _flip_flat)
_POLISH_ROUNDS = 3
_POLISH_TRIES = 8
_POLISH_STEP = 0.3
# qhull joggles its input (QJ) instead of merging degenerate facets; Q3 Q5 Q8 skip work on merged output; the
# tetrahedra are checked as before (bench/RESULTS.md, "Constants' notes").
_QHULL_OPTIONS = "QJ Qbb Q3 Q5 Q8"
_RECOVERY_ROUNDS = 40  # rounds of surface refinement per tetrahedralisation
# Refinement may make at most this many times the initial surface samples (plus a few thousand for small cages).
_SAMPLE_BUDGET = 6
# Refinement whose missing triangles grew this many rounds in a row, on course to pass the sample budget, is
# running away. A 1e-3 slot (valid, it meshes) grows 3 rounds in a row and stays within budget by a factor 1.5;
# a 1e-4 slot passes it after 2 (measured at 2000 and 8000 cells).
_GROWING_ROUNDS = 2
_ATTEMPTS = 3  # fresh jitter and a coarser surface (× 1.5 spacing each time) before a cage is refused


class _Made(NamedTuple):
    """One conforming tetrahedralisation: its Surface (whose ``last`` samples are its first vertices), vertices (N, 3),
    positively oriented tetrahedra (T, 4), the lattice side, the cell count predicted for it and whether that
    prediction came near the target."""

    surface: Surface
    vertices: np.ndarray
    tets: np.ndarray
    side: float
    predicted: float
    sized: bool


class _NotConforming(Exception):
    """The tetrahedralisation could not be made to follow the surface; carries the cage facets where it failed (and
    the lattice side it tried, once known)."""

    def __init__(self, facets):
        super().__init__(facets)
        self.facets, self.side = facets, None


class _RunsAway(_NotConforming):
    """Refinement near some facets grows without converging (parts of the cage nearly touch there): no retry with
    another jitter or a coarser surface can help."""

    def __init__(self, facets, spacing):
        super().__init__(facets)
        self.spacing = spacing


def mesh(cage, cells, steps):
    """Tetrahedra filling the cage (in the meshing frame): a DomainMesh before the final check."""
    side = (_TETS_PER_CUBE * cage.measure / cells) ** (1.0 / 3.0)
    work = WorkBudget(cells)
    # Chosen at the first spacing and kept: regions that changed with a retry's spacing would undo its correction.
    split = split_facets(cage, _SURFACE_SPACING * side)
    made = _attempts(cage, side, split, Sizing(cells, side), work, steps.part(0.0, 0.8))
    # The count model missed (thin or small cages): once more with the model corrected, unless the sizing could not
    # reach the target anyway (the samples along narrow gaps alone make more cells than asked for).
    if abs(len(made.tets) / cells - 1.0) > _COUNT_TOLERANCE and made.sized:
        try:
            again = f"meshing again, {len(made.tets)} cells made for about {cells}: "
            sizing = Sizing(cells, side, scale=len(made.tets) / made.predicted)
            made = _attempts(cage, made.side, split, sizing, work, steps.part(0.8, 0.95, again))
        except CageError:
            pass  # the first mesh conforms: keep it, with its cell count off target
    steps(0.95, "checking the tetrahedralisation")
    samples = made.surface.last
    return raw_mesh(made.vertices, made.tets, np.arange(len(samples.points)), samples.facet, samples.bary)


def _attempts(cage, side, split, sizing, work, steps):
    """The smoothed conforming tetrahedralisation sized for ``sizing`` from lattice side ``side`` on (``split``: see
    :class:`Surface`), retried with fresh jitter and a coarser surface when refinement runs out of samples; CageError
    after the last attempt or once the work budget is spent.

    A sized attempt that fails at another side is tried again at ``side`` itself first: the sample budget and the
    run-away test were measured there (a 1e-4 slot at 2000 cells, counted to a coarser side, ran out of samples
    before the test saw the refinement grow).
    """
    plans = [(sizing, 1.0, 0)] + [(replace(sizing, rounds=1), 1.5**attempt, attempt) for attempt in range(_ATTEMPTS)]
    tried_side = None  # the side the sized attempt failed at
    for number, (plan, coarsening, seed) in enumerate(plans):
        if number == 1 and tried_side == side:
            continue  # the sized attempt failed at this side already
        try:
            return _tetrahedralise(cage, side, split, coarsening, seed, plan, work,
                                   steps.part(number / len(plans), (number + 1) / len(plans)))
        except _RunsAway as failure:
            raise GapTooNarrow(_diagnose_gap(cage, failure.facets, failure.spacing)) from None
        except _NotConforming as failure:
            facets, tried_side = failure.facets, failure.side
        if work.exhausted:
            break
    raise CageError(_diagnose(cage, facets))


def _tetrahedralise(cage, side, split, coarsening, seed, sizing, work, steps):
    """The conforming Delaunay tetrahedralisation sized for ``sizing`` (from lattice side ``side`` on), smoothed
    (``split``: the facets that are surface regions of their own, see :class:`Surface`).

    Returns
    -------
    _Made: its surface's ``last`` samples are the mesh's first vertices
    """
    rng = np.random.default_rng(seed)  # fixed: the same cage always gives the same mesh
    chosen = None
    try:
        surface, samples, lattice, chosen = _sized_start(cage, side, split, coarsening, sizing, rng, steps)
        steps(0.5, "filling the cage with tetrahedra")
        far = far_points(cage.vertices)
        samples, lattice, delaunay = _conforming_delaunay(surface, lattice, far, work, steps)
    except _NotConforming as failure:
        failure.side = side if chosen is None else chosen.side
        raise
    n_surface = len(samples.points)
    vertices = np.concatenate([samples.points, lattice, far])
    vertex_side = np.repeat([-1, 1, 0], [n_surface, len(lattice), len(far)])
    inside = _inside_tetrahedra(cage, vertices, delaunay.simplices, delaunay.neighbors, samples, vertex_side, steps)
    tets = delaunay.simplices[inside]
    used = np.flatnonzero(np.bincount(tets.ravel(), minlength=len(vertices)))
    if (len(used) < n_surface or used[n_surface - 1] != n_surface - 1
            or not _conforms(tets, delaunay.neighbors[inside], inside, samples.triangles, samples.incidence)):
        raise _NotConforming(np.arange(len(cage.facets)))
    renumber = np.full(len(vertices), -1)
    renumber[used] = np.arange(len(used))  # the surface samples keep their numbers
    surface.last = samples
    vertices, tets = vertices[used], orient_positive(vertices[used], renumber[tets])
    tets = _flip_flat(vertices, tets, n_surface)
    steps(0.9, "improving the tetrahedra")
    vertices = polish(vertices, tets, np.arange(len(vertices)) >= n_surface, chosen.side, rng, steps)
    return _Made(surface, vertices, tets, chosen.side, chosen.predicted, sizing.near(chosen))


def _sized_start(cage, side, split, coarsening, sizing, rng, steps):
    """The surface samples and the lattice at the side whose predicted cell count comes nearest ``sizing``'s target,
    of at most ``sizing.rounds`` sides counted from ``side`` on (see :mod:`.sizing`).

    Returns
    -------
    surface : Surface
    samples : surface.Samples, its first
    lattice : (I, 3) float array
    chosen : sizing.Candidate
    """
    best = None
    tried = []
    for _ in range(sizing.rounds):
        steps(0.05 * len(tried), "sampling the cage surface" + (" again, at a size counted for about "
                                                                 f"{sizing.target} cells" if tried else ""))
        spacing = _SURFACE_SPACING * side * coarsening
        # The sample budget at the volume's side whatever the side counted: a coarser one must not stop refinement
        # before the run-away test has seen its rounds (a 1e-4 slot, refused as a gap).
        budget = int(_SAMPLE_BUDGET * _initial_count(cage, _SURFACE_SPACING * sizing.volume_side * coarsening) + 5000)
        surface, samples = _sampled_surface(cage, spacing, split, budget, rng, steps)
        lattice = bcc_lattice(cage, side, _BAND * spacing, samples.points, samples.triangles, rng, steps)
        tried.append(sizing.candidate(side, len(lattice), len(samples.points)))
        if best is None or sizing.miss(tried[-1]) < sizing.miss(best[3]):
            best = surface, samples, lattice, tried[-1]
        side = None if sizing.near(tried[-1]) else sizing.next_side(tried)
        if side is None:
            break
    return best


def _sampled_surface(cage, spacing, split, budget, rng, steps):
    """The Surface at ``spacing`` (regions facing a narrow gap sampled finer, unless that passes the sample
    ``budget``) and its first samples; _NotConforming when its region boundaries cannot be recovered within it."""
    try:
        surface = Surface(cage, spacing, rng, budget, split, band=_BAND * spacing)
    except OutOfBudget:  # gaps too narrow to sample finely from the start: leave them to refinement
        surface = Surface(cage, spacing, rng, budget, split)
    try:
        return surface, surface.samples(steps)
    except OutOfBudget:
        raise _NotConforming(np.flatnonzero(np.isin(surface.region, surface.trouble))) from None


def _initial_count(cage, spacing):
    """About how many surface samples a spacing gives: area over the area per sample of a hexagonal lattice."""
    corners = cage.vertices[cage.facets]
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1).sum()
    return area / (np.sqrt(3.0) / 2.0 * spacing**2) + cage.n_control_points


def _conforming_delaunay(surface, lattice, far, work, steps):
    """Refine the surface samples until every surface triangle is a face of the Delaunay tetrahedralisation, or the
    rounds or the ``work`` budget (a :class:`WorkBudget`) run out.

    Returns
    -------
    samples : surface.Samples
    lattice : (I, 3) float array, the lattice points kept (outside the protecting spheres)
    delaunay : scipy.spatial.Delaunay of the samples' points, lattice and far, in that order
    """
    missing = []  # missing triangles per round
    try:
        for _ in range(_RECOVERY_ROUNDS):
            samples = surface.samples(steps)
            lattice = _outside_protecting_spheres(lattice, samples.points, samples.triangles)
            steps.check()
            points = np.concatenate([samples.points, lattice, far])
            if not work.spend(len(points)):
                break
            delaunay = Delaunay(points, qhull_options=_QHULL_OPTIONS)
            # Only the tetrahedra with three corners or more on the surface have faces with all three there.
            touching = delaunay.simplices[np.count_nonzero(delaunay.simplices < len(samples.points), axis=1) >= 3]
            faces = _cell_faces(touching)
            is_face = rows_in(np.sort(samples.triangles, axis=1), faces)
            if not is_face.all():
                samples = samples._replace(triangles=_take_tied_splits(samples, ~is_face, faces))
                is_face = rows_in(np.sort(samples.triangles, axis=1), faces)
            if is_face.all():
                return samples, lattice, delaunay
            missing.append(np.count_nonzero(~is_face))
            # A report each round: refinement along a narrow gap ran 12 to 30 rounds with the bar standing still.
            steps(0.5 + 0.35 * (1.0 - 0.8 ** len(missing)),
                  f"fitting the tetrahedra to the cage's surface: {missing[-1]} triangles left (round {len(missing)})")
            regions = np.unique(samples.triangle_region[~is_face])
            if _runs_away(missing, len(samples.points), surface.budget):
                raise _RunsAway(np.flatnonzero(np.isin(surface.region, regions)), surface.spacing)
            surface.refine(np.flatnonzero(~is_face), steps)
    except OutOfBudget:
        if _growing(missing):  # out of samples while the missing triangles kept growing: running away too
            raise _RunsAway(np.flatnonzero(np.isin(surface.region, regions)), surface.spacing) from None
    raise _NotConforming(np.flatnonzero(np.isin(surface.region, surface.trouble)))


def _take_tied_splits(samples, missing, faces):
    """The surface triangles with each pair of missing ones that splits a quad replaced by the quad's other split
    where the tetrahedralisation has that one.

    Four samples of one planar region on a circle (a regular grid of cage vertices, as Blender's subdivided cube gives
    many) tie: the region's 2D triangulation and the tetrahedralisation may split their quad along different
    diagonals. Either split is the same piece of surface; refining it instead puts circumcentres on the same circle
    and cascades (the cube subdivided 12 times ran out of its sample budget twice).

    Parameters
    ----------
    samples : surface.Samples
    missing : (S,) bool array, which of ``samples.triangles`` are no face of the tetrahedralisation
    faces : (K, 3) int array, sorted rows: the tetrahedralisation's faces with their three corners on the surface

    Returns
    -------
    (S, 3) int array, oriented as the surface triangles
    """
    triangles = samples.triangles.copy()
    lost = np.flatnonzero(missing)
    # Each directed edge (a, b) of a missing triangle; its twin (b, a) in another missing one of the same region.
    edges = np.concatenate([triangles[lost][:, [k, (k + 1) % 3]] for k in range(3)])
    owner = np.tile(lost, 3)
    apex = np.concatenate([triangles[lost][:, (k + 2) % 3] for k in range(3)])
    # Found by sorted keys, not in Python sets and loops: those cost 0.25 s a round of refinement along a narrow slot.
    base = len(samples.points)
    keys = row_keys(edges, base)
    order = np.argsort(keys, kind="stable")
    at = np.searchsorted(keys[order], row_keys(edges[:, ::-1], base), side="right") - 1  # the last of equal edges
    twin = order[np.maximum(at, 0)]
    candidate = np.flatnonzero((at >= 0) & (keys[twin] == row_keys(edges[:, ::-1], base)))
    twin = twin[candidate]
    first, second = owner[candidate], owner[twin]
    same = samples.triangle_region[first] == samples.triangle_region[second]
    candidate, twin, first, second = candidate[same], twin[same], first[same], second[same]
    # The quad a, q, b, p (p = this triangle's apex, q = the twin's): split along p-q instead of a-b.
    a, b, p, q = edges[candidate, 0], edges[candidate, 1], apex[candidate], apex[twin]
    split = np.stack([np.stack([a, q, p], axis=1), np.stack([q, b, p], axis=1)], axis=1)  # (C, 2, 3)
    present = rows_in(np.sort(split.reshape(-1, 3), axis=1), faces).reshape(-1, 2).all(axis=1)
    candidate, first, second, split = candidate[present], first[present], second[present], split[present]
    normal = triangle_normals(samples.points[triangles[first]])
    halves = triangle_normals(samples.points[split.reshape(-1, 3)]).reshape(-1, 2, 3)
    convex = np.all(np.einsum("ckd,cd->ck", halves, normal) > 0, axis=1)  # a convex quad: neither folds over
    used = np.zeros(len(triangles), dtype=bool)
    for i in np.flatnonzero(convex):  # in edge order, each triangle in one pair at most
        if not used[first[i]] and not used[second[i]]:
            triangles[[first[i], second[i]]] = split[i]
            used[[first[i], second[i]]] = True
    return triangles


def _runs_away(missing, n_samples, budget):
    """Whether refinement is running away: the missing triangles grew _GROWING_ROUNDS rounds in a row, and two more
    rounds growing alike (each missing triangle costing about one sample) would pass the sample budget.

    Parameters
    ----------
    missing : list of int, missing surface triangles per round so far
    n_samples : int, surface samples in the last round
    budget : int, the most samples refinement may make
    """
    if not _growing(missing):
        return False
    growth = missing[-1] / missing[-2]
    return n_samples + missing[-1] * (1.0 + growth) > budget


def _growing(missing):
    """Whether the missing surface triangles per round (list of int) grew _GROWING_ROUNDS rounds in a row."""
    recent = missing[-_GROWING_ROUNDS - 1:]
    return len(recent) > _GROWING_ROUNDS and all(b > a for a, b in zip(recent, recent[1:]))


def _conforms(tets, across, inside, triangles, incidence):
    """Whether the tetrahedra's boundary triangles are the surface triangles, up to ties.

    Four samples on one planar region that lie on a circle (a regular grid of cage vertices, as Blender's subdivided
    cube gives, makes many) tie: the tetrahedralisation may hold both splits of their quad, around a flat cell that
    belongs to neither side, and the kept tetrahedra then end on the other diagonal. A boundary triangle that is not a
    surface triangle is accepted when its corners lie on one common region: it is then part of the surface as well.

    Parameters
    ----------
    tets, across : (T, 4) int arrays, the tetrahedra kept and their neighbours (-1: none) in the tetrahedralisation
    inside : (T_all,) bool array, which tetrahedra of the tetrahedralisation are kept
    triangles : (S, 3) int array
    incidence : (P, R) sparse 0/1 matrix, the regions each surface sample lies on
    """
    # Face k, opposite corner k, is on the boundary when the tetrahedron across it is not kept.
    open_face = ~np.r_[inside, False][across]
    boundary = np.sort(np.concatenate([np.delete(tets[open_face[:, k]], k, axis=1) for k in range(4)]), axis=1)
    if len(boundary) != len(triangles):
        return False
    other = ~rows_in(boundary, np.sort(triangles, axis=1))
    return bool(on_common(incidence, boundary[other]).all())


def _flip_flat(vertices, tets, n_surface):
    """The tetrahedra with their flat cells among surface samples flipped away.

    Four surface samples on one plane and one circle tie in a Delaunay tetrahedralisation: grid cage vertices on two
    faces either side of a cube's edge make such rectangles (Blender's cube subdivided 9 times: 1 at 8000 cells, 20
    with 11 cuts). The tetrahedralisation may then keep a flat cell between the quad's two splits, one on each side.
    Where the two cells on one side of it share their apex (a pyramid over the quad), that pyramid is split along the
    other diagonal, and the flat cell goes: the same region, tiled conformingly. Flat cells with a lattice corner
    (:func:`polish` moves those) or with no such side are left to the final check.

    Parameters
    ----------
    vertices : (N, 3) float array
    tets : (T, 4) int array, positively oriented but for flat cells
    n_surface : int, the surface samples are the first vertices

    Returns
    -------
    (T', 4) int array, T' <= T
    """
    volume = signed_measures(vertices, tets)
    flat = np.flatnonzero(np.all(tets < n_surface, axis=1) & (volume <= _FLAT * np.median(volume)))
    if len(flat) == 0:
        return tets
    tets = tets.copy()
    face_keys = _face_keys(tets, len(vertices))
    flipped = []
    for cell in flat:
        corners = vertices[tets[cell]]
        # The quad's diagonals: of the three ways to pair its corners, the one of longest total length (convex quad).
        pairings = [((0, 1), (2, 3)), ((0, 2), (1, 3)), ((0, 3), (1, 2))]
        diagonals = max(pairings, key=lambda pair: sum(np.linalg.norm(np.subtract(*corners[list(p)])) for p in pair))
        for ends, other in (diagonals, diagonals[::-1]):
            # The side split along `other` holds the faces opposite the ends of `ends`.
            side = [np.flatnonzero(np.any(face_keys == face_keys[cell, k], axis=1)) for k in ends]
            side = [held[held != cell] for held in side]
            if not all(len(held) == 1 for held in side):
                continue  # the quad's side is on the cage surface
            (first,), (second,) = side
            apexes = [np.setdiff1d(tets[t], tets[cell]) for t in (first, second)]
            if len(apexes[0]) != 1 or apexes[0][0] != apexes[1][0]:
                continue
            apex, (i, j), (k, l) = apexes[0][0], tets[cell][list(ends)], tets[cell][list(other)]
            tets[[first, second]] = orient_positive(vertices, np.array([[apex, i, j, k], [apex, i, j, l]]))
            face_keys[[first, second]] = _face_keys(tets[[first, second]], len(vertices))
            face_keys[cell] = -1
            flipped.append(cell)
            break
    return np.delete(tets, flipped, axis=0)


def _face_keys(tets, n_vertices):
    """A number for each face of each tetrahedron (T, 4), face k opposite corner k; equal faces get equal numbers."""
    return row_keys(np.sort(np.stack([np.delete(tets, k, axis=1) for k in range(4)], axis=1), axis=2), n_vertices)


def polish(vertices, tets, movable, side, rng, steps, poor_below=_POLISH_RATIO):
    """Move the movable corners of poor tetrahedra where that raises the least radius ratio around them.

    The tetrahedra stay as they are and the surface samples do not move, so the mesh still follows the surface; a
    move is kept only when every tetrahedron around the vertex stays positively oriented (with the boundary fixed,
    the mesh then stays a valid filling of the cage) and their least radius ratio rises. This does what a round of
    sliver perturbation followed by a new Delaunay tetrahedralisation did, for a fraction of its cost. The warm
    re-bind uses it too, on the cells an edit of the cage squashed (:mod:`lbc_core.binding.rebinding`).

    Parameters
    ----------
    vertices : (N, 3) float array
    tets : (T, 4) int array, positively oriented
    movable : (N,) bool array, the vertices that may move (never the surface samples)
    side : float, the lattice cube side (length): the scale of the moves tried
    poor_below : float or (T,) float array, the radius ratio below which a tetrahedron is poor

    Returns
    -------
    (N, 3) float array
    """
    vertices = vertices.copy()
    owner = np.repeat(np.arange(len(tets)), 4)
    star = sp.csr_matrix((np.ones(tets.size), (tets.ravel(), owner)), shape=(len(vertices), len(tets)))
    scale = _POLISH_STEP * side * 0.5 ** (np.arange(_POLISH_TRIES) % 4)  # large and small moves alike
    ratio = radius_ratios(vertices, tets)
    for _ in range(_POLISH_ROUNDS):
        steps.check()
        poor = np.flatnonzero(ratio < poor_below)
        # Worst first; no two vertices moved together share a tetrahedron, so each move is judged on its own.
        corners = tets[poor[np.argsort(ratio[poor])]].ravel()
        candidates = corners[movable[corners]]
        candidates = candidates[np.sort(np.unique(candidates, return_index=True)[1])]
        taken = np.zeros(len(tets), dtype=bool)
        chosen = []
        for v in candidates:
            around = star.indices[star.indptr[v]:star.indptr[v + 1]]
            if not taken[around].any():
                chosen.append(v)
                taken[around] = True
        if not chosen:
            break
        chosen = np.array(chosen)
        # The tetrahedra around each chosen vertex, vertex by vertex (the star's rows, gathered without scipy's
        # row indexing, which costs more on these few rows); starts[i] is where vertex i's begin.
        counts = star.indptr[chosen + 1] - star.indptr[chosen]
        starts = np.r_[0, np.cumsum(counts)[:-1]]
        vertex_of = np.repeat(np.arange(len(chosen)), counts)
        around = star.indices[np.arange(len(vertex_of)) - starts[vertex_of] + star.indptr[chosen][vertex_of]]
        slot = np.argmax(tets[around] == chosen[vertex_of, None], axis=1)
        moves = scale[:, None, None] * rng.uniform(-1.0, 1.0, (_POLISH_TRIES, len(chosen), 3))
        moves[0] = 0.0  # the current position
        # and the centroid of the star's other corners (a Laplacian smoothing step)
        others = vertices[tets[around]].sum(axis=1) - vertices[chosen][vertex_of]
        centroid = np.stack([np.bincount(vertex_of, others[:, d]) for d in range(3)], axis=1)
        moves[1] = centroid / (3.0 * counts)[:, None] - vertices[chosen]
        # Coordinate d of corner k of tetrahedron a in try t at [d, k, t, a]: the layout the ratios are fastest on.
        # Try 0, the current position, has the ratios already known.
        tries = _POLISH_TRIES - 1
        coordinates = np.broadcast_to(vertices.T[:, tets[around].T, None], (3, 4, len(around), tries))
        coordinates = np.ascontiguousarray(coordinates.transpose(0, 1, 3, 2))
        tried = vertices[chosen][None, vertex_of] + moves[1:, vertex_of]  # (tries, A, 3)
        coordinates[:, slot, :, np.arange(len(around))] = tried.transpose(1, 2, 0)
        quality = signed_radius_ratios_by_coordinate(coordinates.reshape(3, 4, -1)).reshape(tries, -1)
        quality = np.concatenate([ratio[None, around], np.maximum(quality, -1.0)])
        least = np.minimum.reduceat(quality, starts, axis=1)
        best = np.argmax(least, axis=0)
        better = least[best, np.arange(len(chosen))] > least[0]
        vertices[chosen[better]] += moves[best[better], np.flatnonzero(better)]
        ratio[around] = quality[best[vertex_of], np.arange(len(around))]
    return vertices


def _outside_protecting_spheres(lattice, points, triangles):
    """Drop the lattice points inside (or on) the protecting sphere of any surface triangle."""
    if len(lattice) == 0:
        return lattice
    centres, radii = circumspheres(points, triangles)
    near = cKDTree(lattice).query_ball_point(centres, radii * (1.0 + 1e-6))
    drop = np.unique(np.fromiter(itertools.chain.from_iterable(near), dtype=np.int64))
    return np.delete(lattice, drop, axis=0)


def _cell_faces(tets):
    """The four faces of each tetrahedron, each sorted, face k opposite corner k of every tetrahedron in turn.

    Returns
    -------
    (4 T, 3) int array
    """
    return np.sort(np.concatenate([np.delete(tets, k, axis=1) for k in range(4)]), axis=1)


def _inside_tetrahedra(cage, vertices, tets, neighbours, samples, vertex_side, steps):
    """The tetrahedra inside the cage, once every surface triangle is a face of the tetrahedralisation.

    No tetrahedron then crosses the surface: one with a corner strictly inside (a lattice point) is inside, one with
    a corner outside (a far point) is outside. The rest, all four corners on the surface, are classified by
    connection: the surface triangles cut them into connected pieces, each inside or outside as a whole, as the
    tetrahedra with a corner off the surface next to it say (the winding number where none does). Tetrahedra with
    all four corners on one planar region are flat and belong to neither.

    Parameters
    ----------
    vertices : (N, 3) float array, the surface samples first
    tets, neighbours : (T, 4) int arrays, as scipy.spatial.Delaunay's simplices and neighbors
    samples : surface.Samples
    vertex_side : (N,) int array, 1 for a vertex inside the cage, 0 outside, -1 on its surface

    Returns
    -------
    (T,) bool array
    """
    side = vertex_side[tets].max(axis=1)  # 1 or 0 from a corner off the surface, -1 for none
    on_surface = np.flatnonzero(side < 0)
    flat = np.zeros(len(tets), dtype=bool)
    flat[on_surface] = on_common(samples.incidence, tets[on_surface])
    cut = rows_in(_cell_faces(tets[on_surface]), np.sort(samples.triangles, axis=1)).reshape(4, -1).T
    across = neighbours[on_surface]
    link = (across >= 0) & ~cut & ~flat[on_surface, None]
    link[link] = ~flat[across[link]]
    ends = np.repeat(on_surface[:, None], 4, axis=1)[link]
    graph = sp.coo_matrix((np.ones(len(ends)), (ends, across[link])), shape=(len(tets),) * 2)
    _, piece = connected_components(graph, directed=False)
    off = side >= 0
    low, high = np.full(piece.max() + 1, 2), np.full(piece.max() + 1, -1)
    np.minimum.at(low, piece[off], side[off])
    np.maximum.at(high, piece[off], side[off])
    if np.any(low[high >= 0] != high[high >= 0]):  # a piece both inside and outside: some triangle leaks
        raise _NotConforming(np.arange(len(cage.facets)))
    # Pieces of tetrahedra on the surface alone: the winding number at the centroid of each one's largest.
    alone = on_surface[~flat[on_surface] & (high[piece[on_surface]] < 0)]
    if len(alone):
        alone = alone[np.argsort(-np.abs(signed_measures(vertices, tets[alone])), kind="stable")]
        pieces, first = np.unique(piece[alone], return_index=True)
        winding = winding_numbers(cage.vertices, cage.facets, vertices[tets[alone[first]]].mean(axis=1), steps.check)
        check_winding(winding)
        high[pieces] = winding > 0.5
    return (high[piece] == 1) & ~flat


def _diagnose(cage, facets):
    """The error message when the tetrahedra cannot be made to follow the cage near the given facets."""
    listed = _listed_faces(cage, facets)
    return (f"could not make the tetrahedra follow the cage surface near its faces {listed} (numbered from 0 in "
            "input order): faces meeting at very sharp angles or nearly touching parts there are the usual cause; "
            "widen those angles or move the parts apart, or try a different cell count")


def _diagnose_gap(cage, facets, spacing):
    """The error message when refinement near the given facets runs away: a gap far below the sample spacing."""
    listed = _listed_faces(cage, facets)
    return (f"parts of the cage nearly touch near its faces {listed} (numbered from 0 in input order): the gap "
            f"there is far narrower than the cells (about {spacing:.3g} across in the cage's unit-diagonal frame), "
            "so the tetrahedra cannot follow the surface; widen the gap, close it (merge the parts), or raise the "
            "cell count a lot")


def _listed_faces(cage, facets):
    """The input faces holding the given facets, as a short list for a message."""
    faces = np.unique(cage.facet_face[facets])
    return ", ".join(str(f) for f in faces[:10]) + (" ..." if len(faces) > 10 else "")
