"""The first, fast simplification: the marching-cubes surface (tens of thousands of vertices) down to the progressive
hull's start (hundreds to a few thousand) by quadric error collapses (fast-simplification, MIT). It may return a
non-manifold, self-intersecting or short surface, and does not promise to enclose the mesh: each result is checked,
its vertices pushed out along their normals past the mesh's witness points it left outside, and a few nearby targets
are tried before giving up (None), so the caller can start from a larger surface."""

import numpy as np
from scipy.spatial import cKDTree

from ..cage import edge_pairing
from ..kernel.geometry import closest_on_triangles
from ..kernel.intersections import intersecting_triangles
from .extraction import compact, mirrored_whole, signed_volume
from .hull_tests import mirror_map
from .check import CageSamples, edges_crossing, mesh_edges
from .decimation import decimated
from .inside import inside_surface

# Targets tried, as factors of the vertex count asked, when a result fails its checks: a thin shell (clothing) needs
# more vertices than the hull's start asks for its surface to be pushed out of the mesh (bench/RESULTS.md,
# "Cage generator").
TARGET_FACTORS = (1.0, 1.5, 2.25)
# Rounds of pushing vertices out past the mesh's vertices and edges the simplification left outside, at most; it
# stops sooner when two rounds in a row leave no fewer.
PUSH_ROUNDS = 8
# Where fast-simplification's surface at a target pinches, its surface at this many times the target (which pinches
# far less often) is brought down by manifold-keeping collapses (bench/RESULTS.md, "Cage generator", the third round).
WIDER_FACTOR = 4
# Sweeps that reconcile the pushes several triangles ask of one vertex.
PUSH_SWEEPS = 4


def is_closed_manifold(triangles):
    """Every edge in exactly two triangles, each way once, and one fan of triangles around every vertex."""
    directed, order, counts = edge_pairing(triangles)
    if not np.all(counts == 2):
        return False
    # Each directed edge once: the two copies of an edge run opposite ways (consistently oriented).
    pairs = directed[order].reshape(-1, 2, 2)
    if not np.all(pairs[:, 0, 0] == pairs[:, 1, 1]):
        return False
    # One fan per vertex: on a closed oriented manifold, Euler counts agree vertex by vertex through corners = edges.
    n = triangles.max() + 1
    corners = np.bincount(triangles.ravel(), minlength=n)
    out_edges = np.bincount(directed[:, 0], minlength=n)
    return bool(np.all(corners == out_edges)) and _fans_single(triangles, directed, n)


def _fans_single(triangles, directed, n):
    """Each vertex's outgoing edges form one cycle (next edge around the vertex by the triangle before it)."""
    t = len(triangles)
    # The directed edge (v -> w) of triangle f is followed around v by the edge (v -> u) where (u -> v) is f's edge
    # before it; the opposite triangle's copy of (v -> u) continues the fan.
    key = directed[:, 0] * n + directed[:, 1]
    position = np.argsort(key)
    previous = (np.arange(3 * t) + 2 * t) % (3 * t)  # the edge before, in the same triangle: (u -> v)
    reverse_key = directed[previous, 1] * n + directed[previous, 0]  # (v -> u)
    following = position[np.searchsorted(key[position], reverse_key)]
    seen = np.zeros(3 * t, dtype=bool)
    cycles = np.zeros(n, dtype=np.int64)
    for start in range(3 * t):
        if seen[start]:
            continue
        cycles[directed[start, 0]] += 1
        edge = start
        while not seen[edge]:
            seen[edge] = True
            edge = following[edge]
    return bool(np.all(cycles[np.unique(triangles)] == 1))


def quadric_simplified(vertices, triangles, target, mesh, clearance, spacing, zero, check=None):
    """(vertices, triangles) of about ``target`` vertices: closed, manifold, outward, not self-intersecting, with
    every vertex of the InputMesh ``mesh`` inside and none of its edges crossing (vertices pushed out where the
    simplification cut into the mesh); or None when no target tried gives one. The targets are tried with
    fast-simplification first, then (where none gave a start: a thin part pinched at every one) with
    manifold-keeping collapses (:func:`_simplified_surface`)."""
    for decimate in (False, True):
        for factor in TARGET_FACTORS:
            count = int(round(2 * target * factor))
            if count >= len(triangles):
                return vertices, triangles
            found = _simplified_surface(vertices, triangles, count, zero, decimate, check)
            if found is None:
                continue
            points = pushed_out(*found, mesh, clearance, spacing, check)
            if points is not None and is_surface(points, found[1], zero):
                return points, found[1]
    return None


def _fast_simplified(vertices, triangles, count):
    """fast-simplification's result at ``count`` triangles, without doubled faces and unused vertices."""
    import fast_simplification

    points, faces = fast_simplification.simplify(vertices.astype(np.float64), triangles.astype(np.int64),
                                                 target_count=count)
    return compact(*without_doubled_faces(np.asarray(points, dtype=float), np.asarray(faces, dtype=np.int64)))


def _simplified_surface(vertices, triangles, count, zero, decimate=False, check=None):
    """A surface (:func:`is_surface`) of about ``count`` triangles, or None: fast-simplification's; or, to
    ``decimate``, fast-simplification's at WIDER_FACTOR × the count (which pinches far less often) brought down by
    manifold-keeping collapses (:mod:`.decimation`). Decimation comes second: where both give a start, the hull
    from fast-simplification's is tighter (bench/RESULTS.md, "Cage generator", the third round)."""
    if not decimate:
        points, faces = _fast_simplified(vertices, triangles, count)
        return (points, faces) if is_surface(points, faces, zero) else None
    wider = WIDER_FACTOR * count
    points, faces = (vertices, triangles) if wider >= len(triangles) else _fast_simplified(vertices, triangles, wider)
    if not is_surface(points, faces, zero):
        return None
    points, faces = decimated(points, faces, count // 2, check)
    return (points, faces) if is_surface(points, faces, zero) else None


def symmetric_simplified(half_vertices, half_triangles, target, mesh, clearance, spacing, zero, axis, check=None):
    """As :func:`quadric_simplified`, exactly symmetric about the plane through 0 normal to ``axis``: the half
    surface beyond the plane (its boundary in the plane) simplified, welded to its mirror image and pushed out
    symmetrically. Quadric collapses along an open boundary keep its vertices on it (its ends or its middle) but may
    leave it a handful of vertices, or one; then the boundary is kept whole, and the hull brings its vertices down.
    ``mesh`` holds the mesh and its mirror image."""
    for keep_boundary in (False, True):
        for factor in TARGET_FACTORS:
            count = int(round(target * factor))  # the half's triangles: about twice its vertices, half the whole's
            found = _symmetric_start(half_vertices, half_triangles, count, keep_boundary, axis, zero)
            if found is None:
                continue
            points = pushed_out(*found, mesh, clearance, spacing, check, axis=axis)
            if points is not None and is_surface(points, found[1], zero):
                return points, found[1]
    return None


def _symmetric_start(half_vertices, half_triangles, count, keep_boundary, axis, zero):
    """The half simplified to ``count`` triangles and welded to its image, or None when that is no surface."""
    import fast_simplification

    if count >= len(half_triangles):
        points, faces = half_vertices, half_triangles
    else:
        points, faces = fast_simplification.simplify(half_vertices.astype(np.float64), half_triangles.astype(np.int64),
                                                     target_count=count, preserve_border=keep_boundary)
        points, faces = compact(*without_doubled_faces(np.asarray(points, dtype=float),
                                                       np.asarray(faces, dtype=np.int64)))
    if np.any(points[:, axis] < 0.0) or np.any((points[:, axis] == 0.0) & ~_on_boundary(faces, len(points))):
        return None
    points, faces = mirrored_whole(points, faces, axis)
    return (points, faces) if is_surface(points, faces, zero) else None


def _on_boundary(triangles, count):
    """(count,) bool: the vertices on an open surface's boundary (an edge of one triangle only)."""
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    keys, counts = np.unique(edges[:, 0] * count + edges[:, 1], return_counts=True)
    found = np.zeros(count, dtype=bool)
    found[keys[counts == 1] // count] = True
    found[keys[counts == 1] % count] = True
    return found


def without_doubled_faces(vertices, triangles):
    """The triangles without those whose three corners another triangle has too (both copies): quadric collapses
    flatten a thin pocket into two such triangles back to back, whose edges then have four triangles each."""
    keys = np.sort(triangles, axis=1)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    return vertices, triangles[counts[inverse.ravel()] == 1]


def is_surface(vertices, triangles, zero):
    """Whether the surface is closed, manifold, outward and without self-intersection."""
    if len(triangles) < 4 or not is_closed_manifold(triangles) or signed_volume(vertices, triangles) <= 0:
        return False
    return not len(intersecting_triangles(vertices, triangles, zero))


def vertex_normals(vertices, triangles):
    """(n, 3) unit normals: each vertex's triangles' area-weighted normals summed."""
    corners = vertices[triangles]
    face = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, triangles[:, k], face)
    return normals / np.maximum(np.linalg.norm(normals, axis=1), 1e-300)[:, None]


def pushed_out(vertices, triangles, mesh, clearance, spacing, check=None, rounds=PUSH_ROUNDS, axis=None):
    """The vertices moved out until every vertex of the InputMesh ``mesh`` is inside and none of its edges crosses
    the surface: the corners of the triangle nearest a vertex outside, or of a triangle an edge crosses, go out along
    that triangle's normal past the vertex (the edge's ends) by ``clearance`` (the nearest vertex may lie on another
    sheet of a thin part); None after ``rounds`` tries. The surface is sampled ``spacing`` apart to find the mesh's
    edges near it; after the first round only the mesh near the triangles that moved is tested again. With a mirror
    ``axis`` (a surface and mesh symmetric about the plane through 0 normal to it) the pushes are made symmetric:
    of each vertex and its image the longer push, mirrored, and none across the plane for a vertex on it."""
    check = check or (lambda: None)
    vertices = vertices.copy()
    inside = inside_surface(vertices, triangles, mesh.vertices)
    samples = CageSamples(vertices, triangles, spacing)
    edges = mesh_edges(mesh.triangles)
    crossing, crossed = edges_crossing(mesh.vertices, edges, vertices, triangles, samples,
                                       samples.lower(mesh.vertices)[0])
    tree = cKDTree(mesh.vertices)
    mirror = None if axis is None else mirror_map(vertices, axis)
    reach = float(np.linalg.norm(mesh.vertices[edges[:, 1]] - mesh.vertices[edges[:, 0]], axis=1).max())
    left = []
    for _ in range(rounds):
        check()
        if inside.all() and not len(crossing):
            return vertices
        left.append(np.count_nonzero(~inside) + len(crossing))
        if len(left) >= 3 and left[-1] >= left[-3]:
            return None
        before = vertices.copy()
        push = _pushes(vertices, triangles, mesh.vertices[~inside], mesh.vertices[edges[crossing]], crossed, clearance)
        vertices += push if axis is None else _symmetric(push, mirror, axis)
        moved = np.flatnonzero(np.any(np.any(vertices != before, axis=1)[triangles], axis=1))
        near = _near_moved(tree, before[triangles[moved]], vertices[triangles[moved]], reach)
        inside[near] = inside_surface(vertices, triangles, mesh.vertices[near])
        moved_samples = CageSamples(vertices, triangles[moved], spacing)
        lower = np.full(len(mesh.vertices), np.inf)
        lower[near] = moved_samples.lower(mesh.vertices[near])[0]
        crossing, crossed = edges_crossing(mesh.vertices, edges, vertices, triangles[moved], moved_samples, lower)
        crossed = moved[crossed]
    return None


def _symmetric(push, mirror, axis):
    """The pushes (n, 3) made exactly symmetric: each vertex takes the longer of its own and its image's mirrored."""
    image = push[mirror].copy()
    image[:, axis] = -image[:, axis]
    own = np.einsum("ij,ij->i", push, push) >= np.einsum("ij,ij->i", image, image)
    chosen = np.where(own[:, None], push, image)
    on_plane = mirror == np.arange(len(mirror))
    chosen[on_plane, axis] = 0.0
    # A tie between a vertex and its image must resolve the same way for both: the lower index's choice wins.
    first = np.arange(len(mirror)) < mirror
    result = chosen.copy()
    result[mirror[first]] = chosen[first]
    result[mirror[first], axis] = -chosen[first, axis]
    return result


def _near_moved(tree, old, new, reach):
    """The mesh vertices (by index) within ``reach`` of the space the moved triangles (old and new corners (k, 3, 3))
    swept: those whose inside status or edges can have changed."""
    corners = np.concatenate([old, new], axis=1)
    centre = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centre[:, None], axis=2).max(axis=1) + reach
    found = tree.query_ball_point(centre, radius)
    return np.unique(np.concatenate([np.asarray(items, dtype=np.int64) for items in found] + [np.empty(0, np.int64)]))


def _pushes(vertices, triangles, outside, crossing, crossed, clearance):
    """(n, 3): each vertex's push out: the triangle nearest each ``outside`` point, and each ``crossed`` triangle of
    a crossing edge (its ends (k, 2, 3)), go out along their normals past the point (the edge's ends) by
    ``clearance``. A vertex several pushes ask to move goes far enough along each of their normals: each round adds,
    per vertex, the largest push still missing (a vertex moved along one normal only left the other triangles cut,
    and the rounds of pushing out did not settle)."""
    corners = vertices[triangles]
    pushed = np.concatenate([_nearest_triangles(outside, corners), crossed, crossed])
    points = np.concatenate([outside, crossing[:, 0], crossing[:, 1]])
    normal = np.cross(corners[pushed, 1] - corners[pushed, 0], corners[pushed, 2] - corners[pushed, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    lift = np.maximum(np.einsum("ij,ij->i", points - corners[pushed, 0], normal), 0.0) + clearance
    owner = triangles[pushed].ravel()  # one request per corner of each push
    normal, lift = np.repeat(normal, 3, axis=0), np.repeat(lift, 3)
    push = np.zeros((len(vertices), 3))
    for _ in range(PUSH_SWEEPS):
        missing = lift - np.einsum("ij,ij->i", push[owner], normal)
        order = np.argsort(missing, kind="stable")
        step = np.zeros((len(vertices), 3))
        step[owner[order]] = np.maximum(missing[order], 0.0)[:, None] * normal[order]
        push += step
    return push


def _nearest_triangles(points, corners):
    """(P,) index of the triangle nearest each point, the first of those as near (as over all pairs): only the
    triangles whose centres lie within the distance to the triangle of the nearest centre plus their own radius can
    be nearer (a k-d tree over the centres finds them; all pairs took 4 of the 64k gargoyle's 14 s)."""
    if not len(points):
        return np.zeros(0, dtype=np.int64)
    centres = corners.mean(axis=1)
    radii = np.linalg.norm(corners - centres[:, None], axis=2).max(axis=1)
    tree = cKDTree(centres)
    _, first = tree.query(points)
    bound = np.sqrt(closest_on_triangles(points, *corners[first].transpose(1, 0, 2))[0])
    found = tree.query_ball_point(points, bound + radii.max() * (1.0 + 1e-9) + 1e-12)
    counts = np.array([len(items) for items in found])
    owner = np.repeat(np.arange(len(points)), counts)
    candidate = np.concatenate([np.sort(np.asarray(items, dtype=np.int64)) for items in found])
    squared, _ = closest_on_triangles(points[owner], *corners[candidate].transpose(1, 0, 2))
    # The least distance per point, and of the triangles at it the first: sort by (point, distance, index).
    order = np.lexsort((candidate, squared, owner))
    starts = np.cumsum(counts) - counts
    return candidate[order[starts]]
