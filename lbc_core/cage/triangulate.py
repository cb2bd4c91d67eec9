"""A cage's faces as triangles, the documented, consistent split that keeps the Lagrange and linearity properties
on every input edge (the rules are in :mod:`lbc_core.cage.make`'s docstring): quads on their shorter diagonal, n-gons
poked at their mean or ear-clipped; faces that welding collapsed dropped; degenerate triangles reported.
"""

import operator

import numpy as np

from ..errors import CageError
from ..kernel.geometry import (
    cross2,
    in_triangle_2d,
    is_convex_polygon,
    newell_normal,
    plane_axes,
    triangle_normals,
    unit,
)
from .messages import NamesVertices, count_of, some_indices, some_items

# n-gons from this many sides are poked at their vertices' mean (the module docstring). Ear-clipped, Blender's
# Cylinder's 32-gon caps fanned out from one vertex, whose coordinate summed to 466 over the points inside against
# 18-166 for the others (bench/RESULTS.md).
POKE_SIDES = 5
# Least distance of an n-gon's centre inside each side's line to poke it, a share of its largest distance to a vertex
# (bench/RESULTS.md, "n-gons poked at their vertices' mean"); a convex n-gon's, less (bench/RESULTS.md, "A convex
# poked n-gon's values").
POKE_HEIGHT = 0.1
POKE_HEIGHT_CONVEX = 0.02
# n-gons from this many sides that could not be poked and whose ear clipping fans out from one vertex are named in the
# cage's warnings.
FAN_NOTICE_SIDES = 8
# Share by which a quad's diagonals may differ and still split it from its first vertex, so that a small edit keeps
# its split (bench/RESULTS.md, "Warm re-bind of Blender's quad cages").
QUAD_SPLIT_TIE = 0.25


def poke(vertices, triangles, triangle_face, clean, faces):
    """The n-gons of :data:`POKE_SIDES` sides or more whose mean sees every side (:data:`POKE_HEIGHT`) split into
    triangles from it instead of their ear clipping, in the orientation their ear clipping was given.

    Returns
    -------
    triangles (T', 3) int array, triangle_face (T',) int array, clean (T',) bool array
        As given, the poked faces' triangles replaced (centre c is vertex n + c), in input face order.
    centres : list of (k,) int arrays
        The vertices of each poked face, in its outward order.
    """
    n = len(vertices)
    centres, replaced, added = [], [], []
    for index, face in faces:
        low, high = np.searchsorted(triangle_face, [index, index + 1])  # triangles come in input face order
        if len(face) < POKE_SIDES or not clean[low:high].all():
            continue
        ring = np.array(face)
        if _reversed(triangles[low], face):
            ring = ring[::-1]
        if _sees_every_side(vertices[ring]):
            replaced.append(np.arange(low, high))
            added.append((index, np.column_stack([np.full(len(ring), n + len(centres)), ring, np.roll(ring, -1)])))
            centres.append(ring)
    if not centres:
        return triangles, triangle_face, clean, centres
    kept = np.ones(len(triangles), dtype=bool)
    kept[np.concatenate(replaced)] = False
    triangles = np.vstack([triangles[kept]] + [pieces for _, pieces in added])
    triangle_face = np.concatenate([triangle_face[kept]] + [np.full(len(pieces), index) for index, pieces in added])
    clean = np.r_[clean[kept], np.ones(len(triangles) - np.count_nonzero(kept), dtype=bool)]
    order = np.argsort(triangle_face, kind="stable")
    return triangles[order], triangle_face[order], clean[order], centres


def _reversed(triangle, face):
    """Whether a triangle cut from ``face`` (its corners in the face's cyclic order or against it) runs against it."""
    position = {corner: k for k, corner in enumerate(face)}
    a, b, c = (position[corner] for corner in triangle.tolist())
    return (b - a) % len(face) + (c - b) % len(face) + (a - c) % len(face) > len(face)


def _sees_every_side(points):
    """Whether the mean of an n-gon's points (k, 3), in outward order, stands at least POKE_HEIGHT (a convex n-gon:
    POKE_HEIGHT_CONVEX) of its largest distance to them inside the line of each side, in the plane of the n-gon's
    Newell normal."""
    normal = newell_normal(points)
    centre = points.mean(axis=0)
    if not np.linalg.norm(normal) > 0:
        return False
    normal /= np.linalg.norm(normal)
    sides = np.roll(points, -1, axis=0) - points
    lengths = np.linalg.norm(sides, axis=1)
    heights = np.einsum("ij,j->i", np.cross(sides, centre - points), normal) / np.maximum(lengths, np.finfo(float).tiny)
    reach = np.max(np.linalg.norm(points - centre, axis=1))
    least = POKE_HEIGHT_CONVEX if is_convex_polygon(points @ plane_axes(normal).T) else POKE_HEIGHT
    return bool(np.all(lengths > 0) and np.all(heights >= least * reach))


def fans(triangles, triangle_face, faces, names):
    """A notice (a list of at most one string) naming the n-gons of :data:`FAN_NOTICE_SIDES` sides or more, not
    poked, whose triangles fan out from one vertex: its boundary values span the whole face, the others' slivers."""
    fans = []
    for index, face in faces:
        own = triangles[triangle_face == index]
        if len(face) >= FAN_NOTICE_SIDES and np.all(own < len(names)):  # not poked: no centre among its corners
            counts = np.bincount(own.ravel())
            apex = int(np.argmax(counts))
            if counts[apex] > (len(face) - 2) / 2:
                fans.append((index, len(face), int(names[apex])))
    if not fans:
        return []
    sides = sorted({count for _, count, _ in fans})
    size = f"{sides[0]} sides" if len(sides) == 1 else f"{sides[0]} to {sides[-1]} sides"
    which = " and ".join(some_indices([index for index, _, _ in fans]).rsplit(", ", 1))
    apexes = " and ".join(some_indices([apex for _, _, apex in fans]).rsplit(", ", 1))
    if len(fans) == 1:
        said = (f"cage face {which} (an n-gon of {size}) is split into a fan of triangles from vertex {apexes}, which "
                "moves most of the face while its other vertices barely do")
    else:
        said = (f"cage faces {which} (n-gons of {size}) are split into fans of triangles from vertices {apexes}, "
                "which move most of their faces while the other vertices barely do")
    # Triangulating in Blender does not help: its Beauty split of such a face is a fan as well (a new user's check).
    them, whose = ("it", "its") if len(fans) == 1 else ("them", "their")
    return [f"{said}, and {whose} middle lies outside {them} or too near a side to split {them} from there: split "
            f"{them} into rounder faces (in Blender, Select > Select All by Trait > Faces by Sides, greater than "
            f"{FAN_NOTICE_SIDES - 1}, finds {them}; select two vertices across such a face and press J, Connect Vertex "
            "Path)"]


def face_list(faces, n_vertices):
    """The faces as lists of Python ints, checked against the vertex count."""
    if isinstance(faces, np.ndarray):
        faces = faces.tolist()
    try:
        faces = [[operator.index(corner) for corner in face] for face in faces]
    except TypeError:
        raise CageError("cage faces must be sequences of integer vertex indices") from None
    if not faces:
        raise CageError("the 3D cage has no faces: pass its faces, or faces=None for a 2D polygon")
    invalid = [index for index, face in enumerate(faces) if len(face) < 3 or min(face) < 0 or max(face) >= n_vertices]
    if invalid:
        listed = some_items([f"{index} ({faces[index]})" for index in invalid])
        raise CageError(
            f"cage face{'s' if len(invalid) > 1 else ''} {listed} {'are' if len(invalid) > 1 else 'is'} invalid: a "
            f"face needs 3 or more indices of the cage's {n_vertices} vertices"
        )
    return faces


def collapse_welded(faces, vertex_map, names, defects):
    """Faces in welded indices without the corners welding merged; faces reduced below 3 corners are dropped;
    faces passing twice through a vertex and duplicated faces (the same corners, in any order) are reported in
    ``defects`` and left out (duplicates: all copies but the first).

    Returns
    -------
    faces : list of (index, list of int)
        Input face index and corners of each kept face.
    dropped : int
    excused : list of sets of int
        The corners of each face passing twice through a vertex: edges between them, left open by leaving those
        faces out, close when the faces are split as advised, so they are not reported as holes.
    """
    vertex_map = vertex_map.tolist()
    kept, dropped, seen, twice, copies = [], 0, {}, [], []
    for index, face in enumerate(faces):
        face = [vertex_map[corner] for corner in face]
        face = [corner for k, corner in enumerate(face) if corner != face[k - 1]]
        if len(face) < 3:
            dropped += 1
            continue
        if len(set(face)) != len(face):
            twice.append((index, sorted({corner for corner in face if face.count(corner) > 1})))
            continue
        copy = seen.setdefault(tuple(sorted(face)), index)
        if copy != index:
            copies.append((copy, index))
            continue
        kept.append((index, face))
    if twice:
        listed = some_items([f"face {index} twice through vertex {some_indices(names[corners])}"
                          for index, corners in twice])
        defects.append(NamesVertices(
            f"{count_of(len(twice), 'cage face passes', 'cage faces pass')} through a vertex twice ({listed}): split "
            "each into faces that visit a vertex once"
        ))
    if copies:
        listed = some_items([f"{a} and {b}" for a, b in copies])
        defects.append(
            f"the cage has {count_of(len(copies), 'duplicated face')} (faces using the same vertices as another: "
            f"{listed}): delete one face of each pair, not both (deleting both opens the cage; in Blender, Select "
            "All by Trait > Interior Faces selects both)"
        )
    excused = [{vertex_map[corner] for corner in faces[index]} for index, _ in twice]
    return kept, dropped, excused


def triangulate_faces(vertices, faces, zero, defects):
    """Triangles of all faces (see the module docstring for the choice).

    An n-gon that cannot be triangulated is reported in ``defects`` and split as a fan, so that the checks of the
    surface's topology still see it.

    Returns
    -------
    triangles : (T, 3) int array
        In the faces' own orientation, in input face order.
    triangle_face : (T,) int array
        Input face index of each triangle.
    clean : (T,) bool array
        False for the fans of the n-gons that could not be triangulated.
    """
    if not faces and not defects:
        raise CageError("every face of the cage collapsed when welding its vertices: the cage has no faces left")
    triangles = [(index, [face]) for index, face in faces if len(face) == 3]
    fans = set()
    for index, face in faces:
        if len(face) == 4:
            triangles.append((index, _split_quad(vertices, np.array(face), zero)))
        elif len(face) > 4:
            try:
                triangles.append((index, _ear_clip(vertices, np.array(face), index, zero)))
            except CageError as error:
                defects.append(str(error))
                triangles.append((index, [[face[0], face[k], face[k + 1]] for k in range(1, len(face) - 1)]))
                fans.add(index)
    triangles.sort(key=lambda item: item[0])
    triangle_face = np.array([index for index, pieces in triangles for _ in pieces], dtype=np.int64)
    triangles = np.array([list(t) for _, pieces in triangles for t in pieces], dtype=np.int64).reshape(-1, 3)
    return triangles, triangle_face, ~np.isin(triangle_face, list(fans))


def _split_quad(vertices, quad, zero):
    """(2, 3) int array: the quad's two triangles along the shorter diagonal that stays inside it (the one from its
    first vertex when the two tie within QUAD_SPLIT_TIE)."""
    points = vertices[quad]
    options = (quad[[[0, 1, 2], [0, 2, 3]]], quad[[[0, 1, 3], [1, 2, 3]]])
    lengths = np.array([np.linalg.norm(points[0] - points[2]), np.linalg.norm(points[1] - points[3])])
    tie = abs(lengths[0] - lengths[1]) <= QUAD_SPLIT_TIE * lengths.max()
    preference = (0, 1) if tie else np.argsort(lengths, kind="stable")
    for choice in preference:
        normals = triangle_normals(vertices[options[choice]])
        if normals[0] @ normals[1] > 0 and not np.any(_degenerate(vertices[options[choice]], zero)):
            return options[choice]
    # A zero-area or bow-tie quad: the degenerate-face or self-intersection check names it.
    return options[preference[0]]


def _ear_clip(vertices, face, index, zero):
    """(k - 2, 3) int array: ear clipping of an n-gon in the plane of its Newell normal, first ear in face order."""
    points = vertices[face]
    normal = newell_normal(points)
    if np.linalg.norm(normal) <= zero * np.max(np.linalg.norm(points - points[0], axis=1)):
        raise CageError(f"cage face {index} has zero area: delete it or dissolve it into its neighbours")
    flat = points @ plane_axes(unit(normal)).T  # the face counter-clockwise
    remaining = np.arange(len(face))
    triangles = []
    while len(remaining) > 3:
        corner = flat[remaining]
        before, after = np.roll(corner, 1, axis=0), np.roll(corner, -1, axis=0)
        # Convex corners standing clear of the line through their neighbours (collinear ones make no ear).
        convex = cross2(corner - before, after - corner) > zero * np.linalg.norm(after - before, axis=1)
        ears = np.flatnonzero(convex)
        others = np.flatnonzero(~convex)  # only non-convex corners can lie inside a convex ear
        if len(others):
            count = len(remaining)
            blocked = in_triangle_2d(corner[others][None], before[ears][:, None], corner[ears][:, None],
                                     after[ears][:, None], zero)
            own = (others[None] == (ears[:, None] - 1) % count) | (others[None] == (ears[:, None] + 1) % count)
            ears = ears[~np.any(blocked & ~own, axis=1)]
        if not len(ears):
            raise CageError(
                f"cage face {index} cannot be triangulated: its outline crosses itself or is badly non-planar; "
                "split it into simpler faces (in Blender: Face > Triangulate Faces, then fix the result)"
            )
        ear = ears[0]
        triangles.append(face[remaining[[ear - 1, ear, (ear + 1) % len(remaining)]]])
        remaining = np.delete(remaining, ear)
    triangles.append(face[remaining])
    return np.array(triangles)


def report_degenerate(vertices, triangles, triangle_face, zero, defects):
    """(T,) bool: the triangles of zero area; their input faces are reported in ``defects``."""
    bad = _degenerate(vertices[triangles], zero)
    if np.any(bad):
        faces = np.unique(triangle_face[bad])
        defects.append(
            f"the cage has {count_of(len(faces), 'face')} of zero area (face {some_indices(faces)}): delete or "
            "dissolve "
            "them (in Blender: Mesh > Clean Up > Degenerate Dissolve)"
        )
    return bad


def _degenerate(corners, zero):
    """(T,) bool: triangles whose height over their longest edge is at most ``zero``.

    Parameters
    ----------
    corners : (T, 3, d) float array
    zero : float
        Length that counts as zero.
    """
    edges = np.roll(corners, -1, axis=1) - corners
    longest = np.max(np.linalg.norm(edges, axis=2), axis=1)
    if corners.shape[2] == 2:
        twice_area = np.abs(cross2(edges[:, 0], edges[:, 1]))
    else:
        twice_area = np.linalg.norm(np.cross(edges[:, 0], edges[:, 1]), axis=1)
    return twice_area <= zero * longest
