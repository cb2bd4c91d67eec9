"""The 3D mesher's lattice: jittered body-centred cubic (BCC) points filling the inside of a cage, except a band along
its surface, and the inside tests they use (the distance to a convex cage's planes, the pieces of the lattice's graph
decided by one winding number each, the exact distance to a triangulated surface near it)."""

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import CageError
from ..kernel.geometry import circumspheres, closest_on_triangles, triangle_normals, unit, winding_numbers
from .surface import JITTER

# The lattice's axes (columns), turned away from the coordinate axes: the faces of boxes, cylinders and most cages
# made in Blender are parallel to those, and a lattice aligned with a face puts whole layers of points at one
# distance from it, where the band leaves slivers (the cube: 5 instead of 0, measured).
_LATTICE_AXES = np.linalg.qr(np.array([[3.0, 1.0, 2.0], [-1.0, 3.0, 1.0], [1.0, -2.0, 3.0]]))[0]
# Convex cages of at most this many facets test their lattice points by the facets' planes, cage vertices up to
# _CONVEX_SLACK (unit-diagonal frame) outside a plane still convex (bench/RESULTS.md, "Constants' notes").
_CONVEX_FACETS = 256
_CONVEX_SLACK = 1e-4
# Other cages with at most this many facets measure the lattice band against their facets directly, found plane by
# plane (see _surface_distance), instead of against the regions' small triangles through a search tree.
_FEW_FACETS = 32


def bcc_lattice(cage, side, band, surface_points, triangles, rng, steps):
    """Jittered body-centred cubic lattice points of cube side ``side`` inside the cage, except those closer than
    ``band`` to the cage surface.

    Returns
    -------
    (I, 3) float array
    """
    turned = cage.vertices @ _LATTICE_AXES  # the cage in the lattice's axes
    low = turned.min(axis=0) - side
    shape = np.ceil((turned.max(axis=0) + side - low) / side).astype(np.int64) + 1
    index = np.stack(np.meshgrid(*[np.arange(m) for m in shape], indexing="ij"), axis=-1).reshape(-1, 3)
    # Corners (i, j, k) then cube centres (i, j, k) + 1/2, numbered alike.
    points = (low + side * np.concatenate([index, index + 0.5])) @ _LATTICE_AXES.T
    points += JITTER * side * rng.uniform(-1.0, 1.0, points.shape)
    # The turned lattice's box is larger than the cage's: the points outside the cage's box are outside the cage.
    keep = np.all((points > cage.vertices.min(axis=0)) & (points < cage.vertices.max(axis=0)), axis=1)
    depth = _depth_in_convex(cage, points[keep])
    if depth is not None:  # small convex cages (boxes, cones, cylinders of few sides): no search needed
        keep[keep] = depth >= band
        return points[keep]
    if len(cage.facets) <= _FEW_FACETS:  # small cages: the distance to their few facets, found plane by plane
        keep[keep] = _surface_distance(cage.vertices[cage.facets], points[keep], band, steps) >= band
    else:
        # The nearest surface sample is at most one circumradius farther than the surface itself: only the points
        # in between need the exact distance.
        cover = circumspheres(surface_points, triangles)[1].max()
        nearest = np.full(len(points), np.inf)
        nearest[keep] = cKDTree(surface_points).query(points[keep], distance_upper_bound=band + cover)[0]  # inf beyond
        keep &= nearest >= band
        unsure = np.flatnonzero(keep & (nearest < band + cover))
        # The regions' triangles tile the surface the tetrahedra will follow; being small (about the spacing), each
        # unsure point meets only a few of them, where a cage's large facets would meet every point.
        keep[unsure] = _surface_distance(surface_points[triangles], points[unsure], band, steps) >= band
    # A lattice edge (centre to one of its cube's corners) between two kept points stays within its half length
    # (at most 0.52 side with the jitter; band = 0.7 side) of one of them, so it cannot cross the surface: the kept
    # points connected by lattice edges are all inside or all outside, which one winding number per piece decides.
    centre = np.flatnonzero(np.all(index < shape - 1, axis=1) & keep[len(index):])
    offsets = np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1).T
    corner = np.ravel_multi_index((index[centre][:, None, :] + offsets[None]).reshape(-1, 3).T, shape)
    centre = np.repeat(centre + len(index), len(offsets))
    linked = keep[centre] & keep[corner]
    inside = _inside_pieces(cage, points, keep, centre[linked], corner[linked], steps)
    return points[keep & inside]


def _depth_in_convex(cage, points):
    """Distance from each point to the surface of a convex cage, negative outside; None for a cage that is not
    convex (some cage vertex more than _CONVEX_SLACK outside a facet's plane) or has more than _CONVEX_FACETS facets.

    Inside a convex polyhedron the distance to its surface is the least distance to its facets' planes: a point
    that deep is inside, with no nearest-sample search, exact distances to the surface or winding numbers.

    Parameters
    ----------
    cage : Cage, in the meshing frame (unit diagonal)
    points : (P, 3) float array

    Returns
    -------
    (P,) float array or None
    """
    if len(cage.facets) > _CONVEX_FACETS:
        return None
    corners = cage.vertices[cage.facets]
    normals = unit(triangle_normals(corners))  # outward
    if not np.all(np.isfinite(normals)):
        return None
    offsets = np.einsum("ij,ij->i", normals, corners[:, 0])
    if np.max(cage.vertices @ normals.T - offsets) > _CONVEX_SLACK:
        return None
    # Facet by facet on coordinate rows: a (P, 3) x (3, F) product costs 3 to 7 times more at these sizes.
    x, y, z = np.ascontiguousarray(points.T)
    depth = np.full(len(points), np.inf)
    for (nx, ny, nz), offset in zip(normals, offsets):
        np.minimum(depth, offset - (nx * x + ny * y + nz * z), out=depth)
    return depth


def _inside_pieces(cage, points, keep, ends_a, ends_b, steps):
    """Whether each point lies inside the cage, for graphs whose connected pieces are all inside or all outside.

    Parameters
    ----------
    points : (P, 3) float array
    keep : (P,) bool array, the points to classify (the others come out False)
    ends_a, ends_b : (L,) int arrays, the graph's links between kept points

    Returns
    -------
    (P,) bool array
    """
    graph = sp.coo_matrix((np.ones(len(ends_a)), (ends_a, ends_b)), shape=(len(points),) * 2)
    _, piece = connected_components(graph, directed=False)
    candidates = np.flatnonzero(keep)
    pieces, first = np.unique(piece[candidates], return_index=True)
    winding = winding_numbers(cage.vertices, cage.facets, points[candidates[first]], steps.check)
    check_winding(winding)
    inside = np.zeros(piece.max() + 1, dtype=bool)
    inside[pieces] = winding > 0.5
    return keep & inside[piece]


def check_winding(winding):
    """Raise CageError unless every winding number (at points off the surface) is 0 or 1."""
    if np.any(np.abs(winding - np.round(winding)) > 0.1) or np.any((winding > 1.5) | (winding < -0.5)):
        raise CageError(
            "the cage surface overlaps itself (some space is enclosed twice or with the wrong orientation): "
            "make sure the cage does not pass through itself and that no part is inside-out"
        )


def _surface_distance(corners, points, reach, steps):
    """Distance from each point to a triangulated surface, where it is below ``reach`` (inf beyond).

    Only the (point, triangle) pairs within ``reach`` of the triangle's plane and of its bounding sphere get the
    exact closest point. A few triangles (up to _FEW_FACETS: a small cage's own facets) find them plane by plane;
    many (the regions' small triangles) through a search tree, where each large triangle would meet every point.

    Parameters
    ----------
    corners : (F, 3, 3) float array, the surface's triangles
    points : (P, 3) float array
    reach : float, length

    Returns
    -------
    (P,) float array
    """
    centres = corners.mean(axis=1)
    radii = np.linalg.norm(corners - centres[:, None], axis=2).max(axis=1)
    normals = unit(triangle_normals(corners))
    if len(corners) <= _FEW_FACETS:
        x, y, z = np.ascontiguousarray(points.T)
        point, facet = [], []
        for f, ((cx, cy, cz), (nx, ny, nz)) in enumerate(zip(centres, normals)):
            dx, dy, dz = x - cx, y - cy, z - cz
            near = np.flatnonzero((np.abs(nx * dx + ny * dy + nz * dz) < reach)
                                  & (dx * dx + dy * dy + dz * dz < (reach + radii[f]) ** 2))
            point.append(near)
            facet.append(np.full(len(near), f))
        point, facet = np.concatenate(point), np.concatenate(facet)
    else:
        pairs = cKDTree(points).sparse_distance_matrix(cKDTree(centres), reach + radii.max(), output_type="ndarray")
        point, facet = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64)
        height = np.einsum("ij,ij->i", points[point] - centres[facet], normals[facet])
        close = (pairs["v"] < reach + radii[facet]) & (np.abs(height) < reach)
        point, facet = point[close], facet[close]
    best = np.full(len(points), np.inf)
    for chunk in np.array_split(np.arange(len(point)), max(1, len(point) // 500_000)):
        steps.check()
        squared, _ = closest_on_triangles(points[point[chunk]], *corners[facet[chunk]].transpose(1, 0, 2))
        np.minimum.at(best, point[chunk], np.sqrt(squared))
    return best
