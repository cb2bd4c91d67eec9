"""What a 3D cage's triangles must be as a surface: closed and manifold at every edge and vertex, one outward
orientation, one part (or an outer surface with cavities), and no two triangles crossing or touching except along
their shared edge or vertex.
"""

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, connected_components

from ..kernel.geometry import enclosed_measure, winding_numbers
from ..kernel.intersections import intersecting_triangles
from .messages import LISTED, NamesVertices, count_of, some_indices, some_items


def edge_pairing(triangles):
    """Directed edges and how they pair up across the mesh.

    Returns
    -------
    directed : (3T, 2) int array
        Edge k of triangle t is row k·T + t.
    order : (3T,) int array
        Directed edges sorted so that the copies of one undirected edge are consecutive.
    counts : (U,) int array
        Number of copies of each undirected edge, in ``order``.
    """
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    key = np.sort(directed, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    _, counts = np.unique(key[order], axis=0, return_counts=True)
    return directed, order, counts


def check_closed_manifold(triangles, names, defects, excused=()):
    """Report open or non-manifold edges and vertices in ``defects``, and several parts of such a surface (those of a
    closed one may be cavities: :func:`orient_outward` judges them); open edges in between corners of one set of
    ``excused`` are not reported.

    Returns
    -------
    (first, second, part) : two (3T / 2,) int arrays and a (T,) one, or None when the surface is not closed and
        manifold. The two directed edges (rows of the ``directed`` array of :func:`edge_pairing`) of each undirected
        edge, and each triangle's connected part.
    """
    if not len(triangles):
        return None
    found = len(defects)
    directed, order, counts = edge_pairing(triangles)
    edge_of = directed[order[np.cumsum(counts) - counts]]
    holes = counts == 1
    if excused:
        holes &= ~np.array([any(a in corners and b in corners for corners in excused) for a, b in edge_of.tolist()])
    if np.any(holes):
        where = some_items([f"{names[a]}-{names[b]}" for a, b in edge_of[holes]])
        open_edges = count_of(np.count_nonzero(holes), "boundary edge")
        defects.append(NamesVertices(
            f"the cage is not closed: it has {open_edges}, each in only one face (between vertices {where}); fill "
            "the holes (in Blender: select the boundary edges with Select > Select All by Trait > Non Manifold, and "
            "press F)"
        ))
    if np.any(counts > 2):
        where = some_items([f"{names[a]}-{names[b]}" for a, b in edge_of[counts > 2]])
        defects.append(NamesVertices(
            f"the cage has {count_of(np.count_nonzero(counts > 2), 'non-manifold edge')} shared by more than two faces "
            f"(between vertices {where}): make every edge belong to exactly two faces "
            "(in Blender: Select > Select All by Trait > Non Manifold)"
        ))
    n_tri = len(triangles)
    # Triangles sharing an edge are connected, whatever the edge's number of faces.
    group_head = order[np.repeat(np.cumsum(counts) - counts, counts)]
    adjacency = sp.coo_matrix((np.ones(len(order)), (order % n_tri, group_head % n_tri)), shape=(n_tri, n_tri))
    parts, label = connected_components(adjacency, directed=False)
    if np.any(counts != 2):
        if parts > 1:
            defects.append(_separate_parts(label))
        return None
    first, second = order[0::2], order[1::2]
    _check_manifold_vertices(triangles, directed, first, second, names, defects)
    return (first, second, label) if len(defects) == found else None


def _separate_parts(part):
    sizes = np.bincount(part)
    return (f"the cage has {len(sizes)} separate parts ({', '.join(str(s) for s in sizes[:LISTED])} triangles): LBC "
            "needs one closed surface around one region; make the parts one surface (Bridge Edge Loops), or separate "
            "them (Mesh > Separate > By Loose Parts) and bind each part's meshes to its own cage")


def _check_manifold_vertices(triangles, directed, first, second, names, defects):
    """Report in ``defects`` where the faces around a vertex form more than one fan (surfaces touching at a point)."""
    n_tri = len(triangles)
    # Corners are (triangle, vertex) pairs; two corners at one vertex are linked when their triangles share an edge
    # there. A manifold vertex has all its corners in one linked fan.
    corner = np.arange(3 * n_tri)
    corner_start, corner_end = corner, (corner + n_tri) % (3 * n_tri)  # the corners at directed edge's two ends
    same = directed[first, 0] == directed[second, 0]
    links_a = np.r_[corner_start[first], corner_end[first]]
    links_b = np.r_[np.where(same, corner_start[second], corner_end[second]),
                    np.where(same, corner_end[second], corner_start[second])]
    graph = sp.coo_matrix((np.ones(len(links_a)), (links_a, links_b)), shape=(3 * n_tri,) * 2)
    _, fan = connected_components(graph, directed=False)
    corner_vertex = directed[:, 0]
    fans_per_vertex = np.bincount(np.unique(np.c_[corner_vertex, fan], axis=0)[:, 0])
    pinched = np.flatnonzero(fans_per_vertex > 1)
    if len(pinched):
        defects.append(NamesVertices(
            f"the cage has {count_of(len(pinched), 'non-manifold vertex', 'non-manifold vertices')} where separate "
            f"sheets of the surface touch at a point (vertex {some_indices(names[pinched])}): pull the sheets apart or "
            "merge them along an edge"
        ))


def orient_outward(vertices, triangles, pairing, triangle_face, defects):
    """Make neighbouring triangles agree in orientation, then point the surface outward (from the region it bounds:
    into a cavity on an inner part).

    Parameters
    ----------
    vertices : (n, 3) float array
    triangles : (T, 3) int array
        A closed, edge-manifold surface of one or more connected parts.
    pairing : (first, second, part)
        From :func:`check_closed_manifold`.
    triangle_face : (T,) int array
        Named in the messages about parts.

    Returns
    -------
    (triangles (T, 3) int array, flipped (T,) bool array), or None
        The oriented triangles and which of them changed orientation; None, reported in ``defects``, when the
        surface is not orientable or its parts do not bound one region.
    """
    first, second, part = pairing
    n_tri = len(triangles)
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    a, b = first % n_tri, second % n_tri
    # Neighbours agree when they run their shared edge in opposite directions.
    disagree = np.all(directed[first] == directed[second], axis=1)
    relation = dict(zip(zip(a.tolist(), b.tolist()), disagree.tolist()))
    relation.update(zip(zip(b.tolist(), a.tolist()), disagree.tolist()))
    adjacency = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(n_tri, n_tri)).tocsr()
    flip = np.zeros(n_tri, dtype=bool)
    for root in np.unique(part, return_index=True)[1]:  # each part from its first triangle
        nodes, predecessors = breadth_first_order(adjacency, root, directed=False)
        for node in nodes[1:].tolist():  # breadth-first order: a parent's flip is known before its children's
            parent = predecessors[node]
            flip[node] = flip[parent] ^ relation[(parent, node)]
    if np.any((flip[a] ^ flip[b]) != disagree):
        defects.append("the cage surface is not orientable (like a Möbius strip): it cannot enclose a volume")
        return None
    oriented = np.where(flip[:, None], triangles[:, ::-1], triangles)
    outer = _outer_part(vertices, oriented, part, triangle_face, defects)
    if outer is None:
        return None
    if enclosed_measure(vertices, oriented[part == outer]) < 0:
        oriented, flip = oriented[:, ::-1], ~flip
    return oriented, flip


def _outer_part(vertices, triangles, part, triangle_face, defects):
    """The part that holds the others, each a cavity: inside it, in no other part, and oriented against it (so that
    the winding number is 1 in the region and 0 in the cavities and outside); None, reported in ``defects``, for
    parts side by side or nested deeper, and for an inner part facing the same way as the outer one."""
    parts = part.max() + 1
    if parts == 1:
        return 0
    surfaces = [triangles[part == k] for k in range(parts)]
    probes = vertices[[surface[0, 0] for surface in surfaces]]  # no two parts cross (else reported later)
    inside = np.array([np.abs(winding_numbers(vertices, surface, probes)) > 0.5 for surface in surfaces]).T
    np.fill_diagonal(inside, False)  # inside[k, j]: part k lies inside part j
    depth = inside.sum(axis=1)
    if np.count_nonzero(depth == 0) > 1 or np.any(depth > 1):
        defects.append(_separate_parts(part))
        return None
    outer = int(np.argmin(depth))
    volumes = np.array([enclosed_measure(vertices, surface) for surface in surfaces])
    same_way = np.flatnonzero(np.sign(volumes) == np.sign(volumes[outer]))
    same_way = same_way[same_way != outer]
    if len(same_way):
        faces = np.unique(triangle_face[np.isin(part, same_way)])
        defects.append(
            f"the cage has {count_of(len(same_way), 'inner surface')} inside its outer one facing the same way (face "
            f"{some_indices(faces)}): a cavity's faces point into it, away from the shell around it; flip the inner "
            "surface's normals (in Blender: select it with L, then Mesh > Normals > Flip) to bind the shell between "
            "them, or separate it (Mesh > Separate > By Loose Parts) and bind the meshes inside it to their own cage"
        )
        return None
    return outer


def check_self_intersection(vertices, triangles, triangle_face, zero, defects):
    """Report in ``defects`` the pairs of faces whose triangles cross or touch."""
    if len(triangles) < 2:
        return
    pairs = intersecting_triangles(vertices, triangles, zero)
    # The ear-clipped triangles of one n-gon tile its outline in the plane of its normal without overlapping, so they
    # cannot cross in 3D (a crossing point would project into both): a hit between them is rounding, as in a cap left
    # 6e-8 out of plane by Blender's float32 positions.
    in_ngon = np.bincount(triangle_face)[triangle_face] > 2
    same_ngon = (triangle_face[pairs[:, 0]] == triangle_face[pairs[:, 1]]) & in_ngon[pairs[:, 0]]
    pairs = pairs[~same_ngon]
    if len(pairs):
        faces = np.unique(np.sort(triangle_face[pairs], axis=1), axis=0)
        listed = some_items([f"{a} and {b}" if a != b else f"{a} with itself" for a, b in faces])
        defects.append(
            f"the cage intersects itself at {count_of(len(faces), 'pair')} of crossing or touching faces (faces "
            f"{listed}); move them apart so that the surface does not pass through itself (in Blender the 3D-Print "
            "Toolbox's Intersections check selects them)"
        )
