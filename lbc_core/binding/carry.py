"""The previous binding's domain mesh carried onto an edited cage, in place of meshing it again: split along the cage
edges the edit bends (:func:`following_bent_edges`), moved by its own coordinates (:func:`carry_domain`), and
checked (no folded or squashed cell, every boundary face on the cage); None where it would fold, so that the
re-bind binds from scratch.
"""

from dataclasses import replace

import numpy as np
import scipy.sparse as sp

from ..cage import ZERO_LENGTH, edge_pairing
from ..evaluate.smoothing import median_edge
from ..kernel.constraints import padded_rows
from ..kernel.fem import boundary_facets
from ..kernel.geometry import (
    bary_positions,
    closest_on_facets,
    orient_positive,
    radius_ratios,
    row_keys,
    signed_measures,
    triangle_normals,
    unit,
)
from ..kernel.progress import Progress
from ..meshing import COPLANAR_ANGLE
from ..meshing.common import cell_edges
from ..meshing.tetrahedra import polish

# Share of its radius ratio a carried cell with a corner off the cage must keep (bench/RESULTS.md, "The warm re-bind
# keeps a carried mesh whose squashed cells lie wholly on the cage").
QUALITY_KEPT = 0.25
# A carried boundary face may cross a cage face that the edit bent (a quad's diagonal, an n-gon's split) as a chord:
# its corners stay on the cage, its inside leaves it. Up to this share of the median cell edge, the carried mesh is
# kept: binds were measured as close to a bind from scratch as two binds from scratch are to each other.
CHORD_KEPT = 0.5
# A cage edge the edit bends is followed by splitting the mesh edges it crosses (following_bent_edges), except within
# this share of a mesh edge's length from its ends: a split so near a corner would make a sliver, and the mesh
# follows the cage edge there within that share already.
CROSSING_END = 0.05


def following_bent_edges(previous, cage):
    """``previous`` with its mesh's surface split along the cage edges the edit bends, where its faces cross them.

    Where coplanar facets meet (a quad's diagonal, an n-gon's split lines, a loop cut across a flat side), the mesher
    needs no mesh edge along the cage edge, and mesh faces cross it. The edit bends such an edge into a crease of the
    boundary values; carried, those faces would cut across it as chords, and a mesh that does not follow the crease
    holds on to the flat cage's coordinates: the loop-cut Cylinder's side vertex moved out by 0.25-2 % came out 2.3-3.2
    times as far from a fine bind as a bind from scratch under a pose of that vertex (bench/RESULTS.md). Each mesh
    edge on the cage that the bent edge crosses is split where it crosses, the cells around it in two, in the previous
    (flat) geometry; the segment between two crossings then is a mesh edge, so the carried surface follows the crease.
    A new vertex lies on the cage, with the exact boundary values there; the previous solution and state are kept
    elsewhere (a split cell's state is its parent's), and the cells around the new vertices are solved again.

    Parameters
    ----------
    previous : Binding (3D: else returned as it is)
    cage : Cage
        The edited cage, split into the previous cage's facets (:func:`split_as_before`).

    Returns
    -------
    previous : Binding
        On the split mesh (the same object when nothing was split).
    touched : (N,) bool array or None
        The vertices of the cells around the new vertices; None when nothing was split.
    """
    if cage.dim != 3:
        return previous, None
    old_cage, mesh = previous.cage, previous.domain
    bent = _bent_edges(old_cage, cage)
    if not len(bent):
        return previous, None
    vertices, cells = mesh.vertices, mesh.cells
    weights, stale = previous.domain_weights, previous.stale
    boundary = [mesh.boundary_vertices, mesh.boundary_facet, mesh.boundary_bary]
    source = np.arange(len(cells))
    first_new = len(vertices)
    carried = weights @ cage.vertices  # where the carry will put each vertex
    zero = ZERO_LENGTH * old_cage.bbox_diagonal
    values = cage.surface_values.toarray()
    for a, b, facet in bent:
        ends = old_cage.surface_vertices[[a, b]]
        for p, q, at in _crossings(ends, vertices, cells, zero):
            x = len(vertices)
            row = (1.0 - at) * values[[a]] + at * values[[b]]  # the boundary values on the cage edge
            around = np.flatnonzero(np.any(cells == p, axis=1) & np.any(cells == q, axis=1))
            towards_p, towards_q = cells[around].copy(), cells[around].copy()
            towards_p[towards_p == q] = x
            towards_q[towards_q == p] = x
            halves = np.concatenate([towards_p, towards_q])
            # Where the edit bends the edge inwards, halves thin across it fold once carried: left as a chord.
            after = np.vstack([carried, row @ cage.vertices])
            before = np.vstack([vertices, (1.0 - at) * ends[0] + at * ends[1]])
            if np.any(signed_measures(after, halves) <= 0) or np.any(
                    radius_ratios(after, halves) < QUALITY_KEPT * radius_ratios(before, halves)):
                continue
            vertices, carried = before, after
            weights = np.vstack([weights, row])
            if stale is not None:
                stale = np.append(stale, max(stale[p], stale[q]))
            corners = list(old_cage.facets[facet])
            bary = np.zeros((1, 3))
            bary[0, corners.index(a)], bary[0, corners.index(b)] = 1.0 - at, at
            boundary = [np.append(boundary[0], x), np.append(boundary[1], facet), np.vstack([boundary[2], bary])]
            cells = np.vstack([cells, towards_q])
            cells[around] = towards_p
            source = np.append(source, source[around])
    if len(vertices) == first_new:
        return previous, None
    touched = np.zeros(len(vertices), dtype=bool)
    touched[cells[np.any(cells >= first_new, axis=1)].ravel()] = True
    domain = replace(mesh, vertices=vertices, cells=cells, boundary_vertices=boundary[0], boundary_facet=boundary[1],
                     boundary_bary=boundary[2])
    state = None if previous.solver_state is None else previous.solver_state.for_cells(source)
    return replace(previous, domain=domain, domain_weights=weights, stale=stale, solver_state=state), touched


def _bent_edges(old_cage, cage):
    """(K, 3) int array: the cage edges (a, b) whose two facets were coplanar in ``old_cage`` and are not in ``cage``
    (same facets), with one of those facets."""
    facets = old_cage.facets
    directed, order, _ = edge_pairing(facets)  # a closed manifold cage: each edge twice, its two facets side by side
    edges = np.sort(directed[order[::2]], axis=1)
    first, second = order[::2] % len(facets), order[1::2] % len(facets)
    old_normals, normals = (unit(triangle_normals(c.surface_vertices[facets])) for c in (old_cage, cage))
    bent = _coplanar(old_normals, first, second) & ~_coplanar(normals, first, second)
    return np.column_stack([edges[bent], first[bent]])


def _crossings(ends, vertices, cells, zero):
    """The mesh edges on the cage that the segment ``ends`` (2, 3) crosses, in the flat geometry where both lie in
    one plane (within COPLANAR_ANGLE): a list of (p, q, t), the crossing at (1 - t) ends[0] + t ends[1]. Crossings
    within CROSSING_END of an edge's length from its ends are left out: the mesh there follows the cage edge within
    that share already, and splitting so near a corner would make slivers."""
    edges = cell_edges(boundary_facets(cells))
    start, direction = ends[0], ends[1] - ends[0]
    p, along = vertices[edges[:, 0]], vertices[edges[:, 1]] - vertices[edges[:, 0]]
    normal = np.cross(direction, along)
    area = np.einsum("ij,ij->i", normal, normal)
    apart = p - start
    with np.errstate(divide="ignore", invalid="ignore"):  # parallel edges: nan, never a crossing
        on_segment = np.einsum("ij,ij->i", np.cross(apart, along), normal) / area
        on_edge = np.einsum("ij,ij->i", np.cross(apart, direction), normal) / area
        lengths = np.linalg.norm(along, axis=1)
        gap = np.linalg.norm(start + on_segment[:, None] * direction - (p + on_edge[:, None] * along), axis=1)
        end = CROSSING_END * lengths / np.linalg.norm(direction)
        hit = np.flatnonzero((gap <= zero + np.sin(COPLANAR_ANGLE) * lengths)
                            & (CROSSING_END < on_edge) & (on_edge < 1 - CROSSING_END)
                            & (end < on_segment) & (on_segment < 1 - end))
    return [(int(edges[k, 0]), int(edges[k, 1]), float(on_segment[k])) for k in hit]


def carry_domain(previous, unit_cage):
    """The previous binding's domain mesh carried onto an edited cage by its own coordinates, if still valid.

    Parameters
    ----------
    previous : Binding
    unit_cage : Cage
        The edited cage (same topology as ``previous.cage``), in its unit frame.

    Returns
    -------
    mesh : DomainMesh or None
        In the unit frame of ``unit_cage``; None when the carried mesh is not a valid domain.
    reason : str or None
        Why not, for the user.
    """
    old = previous.domain
    vertices = previous.domain_weights @ unit_cage.vertices
    vertices[old.boundary_vertices] = bary_positions(unit_cage, old.boundary_facet, old.boundary_bary)
    vertices[old.control_vertices] = unit_cage.vertices
    folded = signed_measures(vertices, old.cells) <= 0
    cells = old.cells
    if folded.any() and vertices.shape[1] == 3:
        cells = flipped_slivers(vertices, old.cells, old.boundary_vertices, folded)
        folded = signed_measures(vertices, cells) <= 0
    if folded.any():
        return None, _near(previous, cells[folded],
                           "the edit would turn inside out some of the cells the last bind filled the cage with")
    # Each flip trades three cells for two, put last: the cells before them are old ones, with an old shape to keep.
    kept = np.arange(len(cells)) < len(cells) - 2 * (len(old.cells) - len(cells))
    kept_mesh = replace(old, cells=cells[kept])
    squashed = np.zeros(len(cells), dtype=bool)
    squashed[kept] = _squashed(kept_mesh, vertices)
    if squashed.any() and vertices.shape[1] == 3:
        vertices = polished(replace(old, cells=cells), vertices, squashed)  # every cell kept positive
        squashed[kept] = _squashed(kept_mesh, vertices)
    if squashed.any():
        return None, _near(previous, cells[squashed],
                           "the edit would squash some of the cells the last bind filled the cage with, to less "
                           f"than {QUALITY_KEPT:.0%} of their shape")
    bent = _faces_off_cage(old, vertices, previous.cage, unit_cage)
    if len(bent):
        one = len(bent) == 1
        return None, (f"{_named_faces(bent)} bent too far: the cells the last bind filled the cage with cross "
                      f"{'it' if one else 'them'} and would leave the cage by more than {CHORD_KEPT:.0%} of a cell's "
                      "size")
    return replace(old, vertices=vertices, cells=cells), None


def flipped_slivers(vertices, cells, boundary_vertices, folded):
    """The cells with folded slivers on the cage mended by a 3-2 flip where one applies.

    A sliver with every corner on the cage, two of its faces on the cage either side of a cage edge (e1, e2), is
    turned inside out when an edit turns that edge past flat. When its two other faces (sharing the edge a-b) lead to
    two cells with one apex p, and these three cells are all that surround a-b, the three are replaced by the two
    cells (e1, e2, p, a) and (e1, e2, p, b): the same faces bound the same region, and the cage faces stay faces.
    Applied only where both new cells are positively oriented at ``vertices``.

    Parameters
    ----------
    vertices : (N, 3) float array, the carried positions
    cells : (F, 4) int array
    boundary_vertices : (B,) int array
    folded : (F,) bool array

    Returns
    -------
    (F', 4) int array, F' <= F: cells whose rows a flip replaced come last
    """
    on_cage = np.zeros(len(vertices), dtype=bool)
    on_cage[boundary_vertices] = True
    cells = cells.copy()
    removed, added = [], []
    for sliver in np.flatnonzero(folded & np.all(on_cage[cells], axis=1)):
        corners = cells[sliver]
        # Cells sharing a face with the sliver: three of its corners each.
        sharing = np.count_nonzero(np.isin(cells, corners), axis=1) == 3
        sharing[sliver] = False
        neighbours = np.flatnonzero(sharing)
        if len(neighbours) != 2 or np.isin(neighbours, removed).any():
            continue
        apexes = [np.setdiff1d(cells[n], corners) for n in neighbours]
        inner = np.intersect1d(*[np.intersect1d(cells[n], corners) for n in neighbours])  # the edge a-b
        if apexes[0][0] != apexes[1][0] or len(inner) != 2:
            continue
        around = np.flatnonzero(np.count_nonzero(np.isin(cells, inner), axis=1) == 2)
        if len(around) != 3:  # a-b has more cells around it than the sliver and its two neighbours
            continue
        apex, (e1, e2) = apexes[0][0], np.setdiff1d(corners, inner)
        flipped = orient_positive(vertices, np.array([[e1, e2, apex, inner[0]], [e1, e2, apex, inner[1]]]))
        if np.any(signed_measures(vertices, flipped) <= 0):
            continue
        removed += [sliver, *neighbours]
        added.append(flipped)
    if not removed:
        return cells
    return np.concatenate([np.delete(cells, removed, axis=0), *added])


def split_as_before(old, new):
    """The edited cage split into the previous cage's facets, and why a carried mesh cannot serve it (or None).

    How a quad or an n-gon is split into triangles follows the positions (a quad's shorter diagonal), so a small edit
    can change the split alone; the carried mesh lies on the previous facets, which stay a valid surface of the same
    faces as long as none of them folds against its face or flattens, and as long as the faces split otherwise stay
    flat: a bent face's surface is its split, and a cold bind would bind the other one.
    """
    if old.fingerprint() == new.fingerprint():
        return new, None
    if not np.array_equal(old.vertex_map, new.vertex_map) or old.face_corners() != new.face_corners():
        return new, "the cage's vertices, faces or welding changed"
    # The same faces (so the same face numbers), triangles per face differing: an n-gon split otherwise, its middle
    # now too near a side (or no longer) to split it from there.
    old_counts, new_counts = np.bincount(old.facet_face), np.bincount(new.facet_face)
    if not np.array_equal(old_counts, new_counts):
        faces = np.flatnonzero(old_counts != new_counts)
        its = "its" if len(faces) == 1 else "their"
        return new, (f"{_named_faces(faces)} changed shape so far that {its} split into triangles changed (from the "
                     "middle to one of the vertices, or back), which the cells the last bind filled the cage with do "
                     "not follow")
    if new.dim == 3:
        normals = triangle_normals(new.surface_vertices[old.facets])
        face_normals = np.zeros((int(new.facet_face.max()) + 1, 3))
        np.add.at(face_normals, new.facet_face, triangle_normals(new.surface_vertices[new.facets]))
        facing = np.einsum("ij,ij->i", normals, face_normals[old.facet_face])
        face_sizes = np.linalg.norm(face_normals[old.facet_face], axis=1)
        if np.any(facing <= ZERO_LENGTH * new.bbox_diagonal ** 2 * face_sizes):
            return new, "a cage face bent so far that its previous split into triangles folds"
        # A bent face's surface is its split: keeping the previous one would bind another cage than a cold bind.
        size = len(new.surface_vertices)
        resplit = np.unique(old.facet_face[~np.isin(row_keys(np.sort(old.facets, axis=1), size),
                                                    row_keys(np.sort(new.facets, axis=1), size))])
        bent = _bent(normals, old.facet_face, resplit)
        if len(bent):
            return new, (f"{_named_faces(bent)} bent and now split into other triangles (the edit changed which "
                         "diagonal a bind splits it along), which the cells the last bind filled the cage with do "
                         "not follow")
    return replace(new, facets=old.facets, facet_face=old.facet_face), None


def _named_faces(faces):
    """ "cage face 3", "cage faces 1, 4" or "cage faces 0, 1, 2, 3, 4 and 2 more": the first five of ``faces``."""
    listed = ", ".join(map(str, faces[:5])) + (f" and {len(faces) - 5} more" if len(faces) > 5 else "")
    return f"cage face{'s' if len(faces) > 1 else ''} {listed}"


def _bent(normals, facet_face, faces):
    """The faces among ``faces`` whose facets (normals (E, 3), any length) are not all coplanar within
    COPLANAR_ANGLE."""
    directions = unit(normals)
    mean = np.zeros((int(facet_face.max()) + 1, 3))
    np.add.at(mean, facet_face, normals)
    off = np.einsum("ij,ij->i", directions, unit(mean)[facet_face]) < np.cos(COPLANAR_ANGLE)
    return faces[np.isin(faces, facet_face[off])]


def polished(mesh, vertices, squashed):
    """The carried ``vertices`` (N, 3) with the free corners of the ``squashed`` cells (F,) moved, as the mesher
    polishes its own, where that raises the least quality around them; the re-bind solves them again."""
    movable = np.zeros(len(vertices), dtype=bool)
    movable[mesh.cells[squashed].ravel()] = True
    movable[mesh.boundary_vertices] = False
    poor_below = np.where(squashed, QUALITY_KEPT * radius_ratios(mesh.vertices, mesh.cells), -np.inf)
    return polish(vertices, mesh.cells, movable, median_edge(vertices, mesh.cells), np.random.default_rng(0),
                  Progress.of(None, None), poor_below)


def _squashed(mesh, vertices):
    """(F,) bool array: the cells of ``mesh`` that, at the carried ``vertices`` (N, d), keep less than QUALITY_KEPT
    of their shape quality and have a corner off the cage."""
    on_cage = np.zeros(len(vertices), dtype=bool)
    on_cage[mesh.boundary_vertices] = True
    kept = radius_ratios(vertices, mesh.cells) >= QUALITY_KEPT * radius_ratios(mesh.vertices, mesh.cells)
    return ~kept & ~np.all(on_cage[mesh.cells], axis=1)


def _faces_off_cage(mesh, vertices, old_cage, cage):
    """Input faces (3D) that some carried mesh boundary face crosses as a chord leaving the cage by more than
    CHORD_KEPT of the median cell edge.

    A mesh boundary face may straddle the split lines of a planar cage face (a quad's diagonal, the edge between two
    coplanar faces); carried, its corners stay on their facets but its inside stays on the cage only if those facets
    stay coplanar. (A face vertex on a sharp cage edge may be recorded on the facet beyond it; such pairs were not
    coplanar before either, and the vertex stays on the edge.)

    Parameters
    ----------
    mesh : DomainMesh, before the edit (in the frame of ``old_cage``)
    vertices : (N, 3) float array, the mesh's vertices carried onto ``cage`` (in its unit frame)
    old_cage, cage : Cage, before and after the edit, with the same facets
    """
    if cage.dim == 2:
        return np.zeros(0, dtype=np.int64)
    facet_of = np.full(len(mesh.vertices), -1)
    facet_of[mesh.boundary_vertices] = mesh.boundary_facet
    triangles = boundary_facets(mesh.cells)
    facets = facet_of[triangles]  # (K, 3): the cage facet of each corner
    mixed = np.any(facets != facets[:, :1], axis=1)
    triangles, facets = triangles[mixed], facets[mixed]
    # A corner on an edge or at a corner of a facet is recorded on any facet there: a face lying within one facet
    # is no face across a split line, whatever its corners' records say. That facet holds the first corner, so it
    # shares a vertex with the facet the first corner is recorded on.
    within = np.zeros(len(triangles), dtype=bool)
    tolerance = (1e-9 * old_cage.bbox_diagonal) ** 2
    old_surface = old_cage.surface_vertices
    for candidates in _facets_around(old_cage.facets, facets[:, 0]).T:
        corners = old_surface[old_cage.facets[np.maximum(candidates, 0)]]
        inside = candidates >= 0
        for k in range(3):
            inside &= closest_on_facets(mesh.vertices[triangles[:, k]], corners)[0] <= tolerance
        within |= inside
    triangles, facets = triangles[~within], facets[~within]
    old_normals, normals = (unit(triangle_normals(c.surface_vertices[c.facets])) for c in (old_cage, cage))
    off = np.zeros(len(facets), dtype=bool)
    for k in (1, 2):
        off |= _coplanar(old_normals, facets[:, 0], facets[:, k]) & ~_coplanar(normals, facets[:, 0], facets[:, k])
    triangles, facets = triangles[off], facets[off]
    far = _chord_distances(vertices[triangles], facets, cage) > CHORD_KEPT * median_edge(vertices, mesh.cells)
    faces = np.unique(cage.facet_face[facets[far]])
    bent = _bent(triangle_normals(cage.surface_vertices[cage.facets]), cage.facet_face, faces)
    return bent if len(bent) else faces  # the faces that bent, not their flat neighbours the mesh spans with them


def _chord_distances(corners, facets, cage):
    """(K,) float array: how far each triangle (corners (K, 3, 3), on the cage) leaves the surface of ``cage``, taken
    at its centroid and edge midpoints, against the facets around its corners' facets ``facets`` (K, 3)."""
    samples = np.stack([corners.mean(axis=1), *((corners[:, k] + corners[:, k - 1]) / 2 for k in range(3))], axis=1)
    nearest = np.full(samples.shape[:2], np.inf)
    surface = cage.surface_vertices
    for k in range(3):
        for candidates in _facets_around(cage.facets, facets[:, k]).T:
            facet_corners = surface[cage.facets[np.maximum(candidates, 0)]]
            for s in range(samples.shape[1]):
                squared = closest_on_facets(samples[:, s], facet_corners)[0]
                nearest[:, s] = np.minimum(nearest[:, s], np.where(candidates >= 0, squared, np.inf))
    return np.sqrt(nearest.max(axis=1))


def _facets_around(facets, which):
    """(len(which), D) int array: for each facet of ``which``, the facets sharing a vertex with it (itself included),
    padded with -1."""
    count = len(facets)
    incidence = sp.csr_matrix((np.ones(facets.size), (np.repeat(np.arange(count), facets.shape[1]), facets.ravel())))
    shared, around = padded_rows(incidence[which] @ incidence.T)  # shared vertices, 0 in the padding
    return np.where(shared > 0, around, -1)


def _coplanar(normals, first, second):
    """Whether facets ``first`` and ``second`` (arrays of indices) have unit normals within COPLANAR_ANGLE."""
    return np.einsum("kd,kd->k", normals[first], normals[second]) >= np.cos(COPLANAR_ANGLE)


def _near(previous, cells, what):
    """``what``, and the cage vertices nearest the offending cells, for the user."""
    centroid = previous.domain.vertices[np.unique(cells)].mean(axis=0)
    nearest = np.argsort(np.linalg.norm(previous.cage.vertices - centroid, axis=1))[:3]
    inputs = previous.cage.first_inputs[nearest]
    count = f"{len(cells)} cell" if len(cells) == 1 else f"{len(cells)} cells"
    return f"{what} ({count}, near cage vertices {', '.join(map(str, inputs))})"
