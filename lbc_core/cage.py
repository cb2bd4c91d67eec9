"""Cages: closed 2D polygons and closed 3D polygon meshes, checked and put into one form.

A :class:`Cage` always has its control points (``vertices``, welded) and its boundary ``facets``: the polygon's edges
in 2D, an outward-oriented triangulation of the faces in 3D. Boundary values are linear on each facet, so a quad or
n-gon face is linear on each triangle of its triangulation (quads are split along the shorter diagonal, n-gons by
ear clipping in the face's best-fit plane): a documented, consistent choice that keeps the Lagrange and linearity
properties on every edge of the input.
"""

import hashlib
from dataclasses import dataclass, field

import numpy as np

from .errors import CageError

DEFAULT_WELD_TOLERANCE = 1e-9  # relative to the bounding-box diagonal


@dataclass
class Cage:
    """A checked cage.

    Attributes
    ----------
    vertices : (n, d) float array
        Control points after welding, d = 2 or 3.
    facets : (E, d) int array
        2D: polygon edges (i, i+1), counter-clockwise. 3D: triangles, outward-oriented.
    facet_face : (E,) int array
        Index of the input face each facet comes from (2D: the edge index).
    vertex_map : (n_input,) int array
        Index in ``vertices`` of each input vertex (welding merges some).
    warnings : list of str
        What was repaired (welded vertices, flipped faces), for the user to read.
    """

    vertices: np.ndarray
    facets: np.ndarray
    facet_face: np.ndarray
    vertex_map: np.ndarray
    warnings: list = field(default_factory=list)

    @property
    def dim(self):
        return self.vertices.shape[1]

    @property
    def n_control_points(self):
        return len(self.vertices)

    @property
    def bbox_diagonal(self):
        return float(np.linalg.norm(self.vertices.max(axis=0) - self.vertices.min(axis=0)))

    @property
    def measure(self):
        """Signed area (2D) or volume (3D) enclosed; positive for the stored orientation."""
        return float(_enclosed_measure(self.vertices, self.facets))

    def fingerprint(self):
        """A hash of the topology (vertex count and facets); positions do not enter it.

        Returns
        -------
        str, 16 hex digits
        """
        digest = hashlib.sha256()
        digest.update(np.int64(len(self.vertex_map)).tobytes())
        digest.update(np.ascontiguousarray(self.vertex_map, dtype=np.int64).tobytes())
        digest.update(np.ascontiguousarray(self.facets, dtype=np.int64).tobytes())
        return digest.hexdigest()[:16]

    def control_points_from_input(self, input_vertices):
        """Map positions given per input vertex (e.g. a posed cage) to the welded control points.

        Parameters
        ----------
        input_vertices : (n_input, d) float array

        Returns
        -------
        (n, d) float array
        """
        input_vertices = np.asarray(input_vertices, dtype=float)
        if input_vertices.shape != (len(self.vertex_map), self.dim):
            raise CageError(
                f"the cage has {len(self.vertex_map)} vertices in {self.dim}D, got positions of shape "
                f"{input_vertices.shape}: deform with the cage the binding was made for, or bind again"
            )
        points = np.zeros((self.n_control_points, self.dim))
        points[self.vertex_map] = input_vertices
        return points


def make_cage(vertices, faces=None, weld_tolerance=DEFAULT_WELD_TOLERANCE):
    """Check and normalise a cage.

    Parameters
    ----------
    vertices : (n, 2) or (n, 3) float array
        2D polygon vertices in boundary order (either orientation), or 3D mesh vertices. A 2D polygon may also be
        given as (n, 3) with a constant z when ``faces`` is None.
    faces : None or sequence of index sequences
        None for a 2D polygon; else the 3D faces (triangles, quads, n-gons).
    weld_tolerance : float
        Vertices closer than this fraction of the bounding-box diagonal are merged (and reported).

    Returns
    -------
    Cage

    Raises
    ------
    CageError
        With a message that names the problem and what to do.
    """
    vertices = np.asarray(vertices, dtype=float)
    if vertices.ndim != 2 or vertices.shape[1] not in (2, 3):
        raise CageError(f"cage vertices must be an (n, 2) or (n, 3) array, got shape {vertices.shape}")
    if not np.all(np.isfinite(vertices)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(vertices), axis=1)))
        raise CageError(f"{bad} cage vertices have NaN or infinite coordinates: fix or delete them")
    if faces is None:
        return _make_polygon_cage(vertices, weld_tolerance)
    return _make_mesh_cage(vertices, faces, weld_tolerance)


def _weld(vertices, weld_tolerance):
    """Merge vertices closer than ``weld_tolerance`` × diagonal; returns (welded, vertex_map, n_merged)."""
    from scipy.spatial import cKDTree

    diagonal = np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))
    pairs = cKDTree(vertices).query_pairs(weld_tolerance * diagonal, output_type="ndarray")
    vertex_map = np.arange(len(vertices))
    if len(pairs):
        import scipy.sparse as sp
        from scipy.sparse.csgraph import connected_components

        graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(vertices),) * 2)
        _, labels = connected_components(graph, directed=False)
        _, first, vertex_map = np.unique(labels, return_index=True, return_inverse=True)
        # Keep the input order of the first vertex of each group.
        order = np.argsort(first)
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        vertex_map = rank[vertex_map]
        welded = vertices[np.sort(first)]
        return welded, vertex_map, len(vertices) - len(welded)
    return vertices.copy(), vertex_map, 0


def _make_polygon_cage(vertices, weld_tolerance):
    if vertices.shape[1] == 3:
        if np.ptp(vertices[:, 2]) > 1e-9 * max(np.ptp(vertices[:, :2]), 1e-300):
            raise CageError("a 2D polygon cage must lie in a plane z = constant; pass faces for a 3D cage")
        vertices = vertices[:, :2]
    if len(vertices) < 3:
        raise CageError(f"a polygon cage needs at least 3 vertices, got {len(vertices)}")
    warnings = []
    welded, vertex_map, merged = _weld(vertices, weld_tolerance)
    if merged:
        warnings.append(f"welded {merged} duplicate cage vertices")
        # Consecutive duplicates collapse; the polygon order follows the first occurrences.
        order = vertex_map[np.r_[True, vertex_map[1:] != vertex_map[:-1]]]
        if len(order) > 1 and order[0] == order[-1]:
            order = order[:-1]
        if len(np.unique(order)) != len(order):
            raise CageError("the polygon visits a vertex twice: it touches itself; separate the touching parts")
        welded, vertex_map = welded[order], np.argsort(order)[vertex_map]
    if len(welded) < 3:
        raise CageError(f"a polygon cage needs at least 3 distinct vertices, got {len(welded)}")
    n = len(welded)
    edges = np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1)
    area = _enclosed_measure(welded, edges)
    if abs(area) <= 1e-12 * np.linalg.norm(np.ptp(welded, axis=0)) ** 2:
        raise CageError("the polygon cage encloses zero area: its vertices are collinear")
    _check_polygon_simple(welded)
    if area < 0:
        edges = edges[:, ::-1]
    return Cage(welded, edges, np.arange(n), vertex_map, warnings)


def _check_polygon_simple(vertices):
    """Raise CageError if two non-adjacent edges of the closed polygon intersect."""
    n = len(vertices)
    a = vertices
    b = np.roll(vertices, -1, axis=0)
    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))
    i, j = i[keep], j[keep]

    def orient(p, q, r):
        return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])

    d1 = orient(a[i], b[i], a[j])
    d2 = orient(a[i], b[i], b[j])
    d3 = orient(a[j], b[j], a[i])
    d4 = orient(a[j], b[j], b[i])
    crossing = (d1 * d2 <= 0) & (d3 * d4 <= 0)
    if np.any(crossing):
        k = int(np.argmax(crossing))
        raise CageError(
            f"the polygon cage intersects itself (edge {i[k]}-{(i[k] + 1) % n} crosses edge {j[k]}-{(j[k] + 1) % n}): "
            "move its vertices so that the outline does not cross itself"
        )


def _make_mesh_cage(vertices, faces, weld_tolerance):
    if vertices.shape[1] != 3:
        raise CageError("a cage with faces must have 3D vertices")
    faces = [np.asarray(f, dtype=np.int64) for f in faces]
    if len(vertices) < 4:
        raise CageError(f"a 3D cage needs at least 4 vertices, got {len(vertices)}")
    if not faces:
        raise CageError("the 3D cage has no faces")
    for f in faces:
        if len(f) < 3 or f.min() < 0 or f.max() >= len(vertices):
            raise CageError(f"cage face {f.tolist()} is invalid: faces need 3 or more valid vertex indices")
    warnings = []
    welded, vertex_map, merged = _weld(vertices, weld_tolerance)
    if merged:
        warnings.append(f"welded {merged} duplicate cage vertices")
    triangles, triangle_face = [], []
    for index, face in enumerate(faces):
        face = vertex_map[face]
        face = face[np.r_[True, face[1:] != face[:-1]]]
        if len(face) > 1 and face[0] == face[-1]:
            face = face[:-1]
        if len(face) < 3:
            continue
        for tri in _triangulate_face(welded, face):
            triangles.append(tri)
            triangle_face.append(index)
    triangles = np.array(triangles, dtype=np.int64).reshape(-1, 3)
    triangle_face = np.array(triangle_face, dtype=np.int64)
    used = np.unique(triangles)
    if len(used) < len(welded):
        raise CageError(
            f"{len(welded) - len(used)} cage vertices belong to no face: delete loose vertices from the cage"
        )
    _check_closed_manifold(triangles)
    triangles, flipped = _orient_outward(welded, triangles)
    if flipped:
        warnings.append(f"flipped {flipped} cage faces to make the orientation consistent and outward")
    volume = _enclosed_measure(welded, triangles)
    if volume <= 1e-12 * np.linalg.norm(np.ptp(welded, axis=0)) ** 3:
        raise CageError("the cage encloses zero volume: it is flat; give it thickness or bind in 2D")
    return Cage(welded, triangles, triangle_face, vertex_map, warnings)


def _triangulate_face(vertices, face):
    """Triangles of one planar-ish face: as is, a quad on its shorter diagonal, or ear clipping."""
    if len(face) == 3:
        return [face]
    if len(face) == 4:
        p = vertices[face]
        if np.linalg.norm(p[0] - p[2]) <= np.linalg.norm(p[1] - p[3]):
            return [face[[0, 1, 2]], face[[0, 2, 3]]]
        return [face[[0, 1, 3]], face[[1, 2, 3]]]
    return _ear_clip(vertices, face)


def _ear_clip(vertices, face):
    points = vertices[face]
    normal = np.zeros(3)
    for k in range(len(points)):  # Newell's normal
        p, q = points[k], points[(k + 1) % len(points)]
        normal += np.cross(p, q)
    axis_u = np.cross(normal, [1.0, 0, 0] if abs(normal[0]) < 0.9 * np.linalg.norm(normal) else [0, 1.0, 0])
    axis_u /= np.linalg.norm(axis_u)
    axis_v = np.cross(normal / np.linalg.norm(normal), axis_u)
    flat = np.stack([points @ axis_u, points @ axis_v], axis=1)
    remaining = list(range(len(face)))
    triangles = []
    while len(remaining) > 3:
        for k in range(len(remaining)):
            a, b, c = remaining[k - 1], remaining[k], remaining[(k + 1) % len(remaining)]
            pa, pb, pc = flat[a], flat[b], flat[c]
            cross = (pb[0] - pa[0]) * (pc[1] - pa[1]) - (pb[1] - pa[1]) * (pc[0] - pa[0])
            if cross <= 0:
                continue
            others = [flat[m] for m in remaining if m not in (a, b, c)]
            if any(_in_triangle(p, pa, pb, pc) for p in others):
                continue
            triangles.append(face[[a, b, c]])
            remaining.pop(k)
            break
        else:  # no ear found (degenerate face): fall back to a fan
            triangles.extend(face[[remaining[0], remaining[m], remaining[m + 1]]] for m in range(1, len(remaining) - 1))
            return triangles
    triangles.append(face[remaining])
    return triangles


def _in_triangle(p, a, b, c):
    def side(p, q, r):
        return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])

    return side(a, b, p) >= 0 and side(b, c, p) >= 0 and side(c, a, p) >= 0


def _check_closed_manifold(triangles):
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    open_edges = int(np.count_nonzero(counts == 1))
    if open_edges:
        raise CageError(
            f"the cage is not closed: {open_edges} edges belong to only one face; fill the holes "
            "(in Blender: select the boundary edges and press F)"
        )
    nonmanifold = int(np.count_nonzero(counts > 2))
    if nonmanifold:
        raise CageError(
            f"the cage has {nonmanifold} non-manifold edges (shared by more than two faces): "
            "make every edge belong to exactly two faces"
        )


def _orient_outward(vertices, triangles):
    """Make neighbouring triangles agree in orientation, then point the whole surface outward."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import breadth_first_order

    n_tri = len(triangles)
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    owner = np.tile(np.arange(n_tri), 3)
    key = np.sort(directed, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    first, second = order[0::2], order[1::2]  # closed manifold: every edge appears exactly twice
    same_direction = np.all(directed[first] == directed[second], axis=1)
    a, b = owner[first], owner[second]
    adjacency = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(n_tri, n_tri)).tocsr()
    adjacency = adjacency + adjacency.T
    flip = np.zeros(n_tri, dtype=bool)
    visited = np.zeros(n_tri, dtype=bool)
    relation = {}
    for x, y, s in zip(a, b, same_direction):
        relation[(x, y)] = relation[(y, x)] = s
    for start in range(n_tri):
        if visited[start]:
            continue
        nodes, predecessors = breadth_first_order(adjacency, start, directed=False)
        visited[nodes] = True
        for node in nodes[1:]:
            parent = predecessors[node]
            flip[node] = flip[parent] ^ relation[(parent, node)]
    for (x, y), s in relation.items():
        if (flip[x] ^ flip[y]) != s:
            raise CageError("the cage surface is not orientable (like a Möbius strip): it cannot enclose a volume")
    oriented = np.where(flip[:, None], triangles[:, ::-1], triangles)
    # Each connected shell points outward on its own.
    _, shell = sp.csgraph.connected_components(adjacency, directed=False)
    for label in np.unique(shell):
        members = shell == label
        if _enclosed_measure(vertices, oriented[members]) < 0:
            oriented[members] = oriented[members][:, ::-1]
            flip[members] = ~flip[members]
    return oriented, int(min(np.count_nonzero(flip), np.count_nonzero(~flip)))


def _enclosed_measure(vertices, facets):
    if vertices.shape[1] == 2:
        p, q = vertices[facets[:, 0]], vertices[facets[:, 1]]
        return 0.5 * np.sum(p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0])
    p, q, r = (vertices[facets[:, k]] for k in range(3))
    return np.sum(np.einsum("ij,ij->i", p, np.cross(q, r))) / 6.0
