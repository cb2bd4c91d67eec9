"""The capsule scene: a smooth capsule in an 8-sided, 9-ring cylinder cage, bent 90° (or twisted,
stretched: :data:`POSES`), and its kinks.

A deformed smooth surface creases where the coordinates are not smooth; the "kink" of an edge of the mesh is the
change of the dihedral angle between its two faces against the rest shape (degrees). The bend itself changes the
dihedral angles a little everywhere, so a perfectly smooth deformer does not score 0 (mean value coordinates: about
0.2°); creases show in the tail: p99, max and the share of edges changed by more than 2°.

Used by the benchmark (bench/smoothness.py) and the tests (tests/test_smoothing.py, on a smaller version).
"""

import numpy as np

RADIUS = 0.5  # the capsule's radius
HALF_LENGTH = 1.5  # half the length of its cylindrical part (its axis is z)
CAGE_RADIUS = 0.75  # the cage rings' circumradius
CAGE_HALF_HEIGHT = 2.2  # the cage runs from z = -2.2 to 2.2 (the capsule from -2 to 2)


def capsule(around=96, rows=125):
    """A capsule along z, triangulated: ``around`` vertices per row, ``rows`` rows spaced evenly along its profile.

    Parameters
    ----------
    around, rows : int
        96 × 125 gives 12,002 vertices (the scene of docs/benchmarks.md, "Smoothness").

    Returns
    -------
    vertices : (around * rows + 2, 3) float array
    faces : (F, 3) int array, outward
    """
    profile_length = np.pi * RADIUS + 2 * HALF_LENGTH
    s = np.linspace(0.0, profile_length, rows + 2)[1:-1]  # arc length from the bottom pole, poles excluded
    quarter = np.pi * RADIUS / 2
    polar = np.where(s < quarter, s / RADIUS, np.where(s > profile_length - quarter,
                                                       (s - profile_length) / RADIUS + np.pi, np.pi / 2))
    ring_radius = RADIUS * np.sin(polar)
    z = np.where(s < quarter, -HALF_LENGTH - RADIUS * np.cos(polar),
                 np.where(s > profile_length - quarter, HALF_LENGTH - RADIUS * np.cos(polar),
                          s - quarter - HALF_LENGTH))
    angle = 2 * np.pi * np.arange(around) / around
    rings = np.stack([ring_radius[:, None] * np.cos(angle), ring_radius[:, None] * np.sin(angle),
                      np.broadcast_to(z[:, None], (rows, around))], axis=2).reshape(-1, 3)
    bottom, top = rows * around, rows * around + 1
    vertices = np.vstack([rings, [[0, 0, -HALF_LENGTH - RADIUS], [0, 0, HALF_LENGTH + RADIUS]]])
    return vertices, _tube_faces(around, rows, bottom, top)


def cage(sides=8, rings=9):
    """The cylinder cage around :func:`capsule`: ``rings`` rings of ``sides`` vertices, triangle-fan caps.

    Returns
    -------
    vertices : (sides * rings + 2, 3) float array (74 by default)
    faces : list of vertex index lists (quads on the side, triangles on the caps), outward
    """
    angle = 2 * np.pi * np.arange(sides) / sides
    z = np.linspace(-CAGE_HALF_HEIGHT, CAGE_HALF_HEIGHT, rings)
    ring_vertices = np.stack([CAGE_RADIUS * np.cos(angle)[None].repeat(rings, 0),
                              CAGE_RADIUS * np.sin(angle)[None].repeat(rings, 0),
                              z[:, None].repeat(sides, 1)], axis=2).reshape(-1, 3)
    bottom, top = sides * rings, sides * rings + 1
    vertices = np.vstack([ring_vertices, [[0, 0, -CAGE_HALF_HEIGHT], [0, 0, CAGE_HALF_HEIGHT]]])
    faces = []
    for ring in range(rings - 1):
        for k in range(sides):
            a, b = ring * sides + k, ring * sides + (k + 1) % sides
            faces.append([a, b, b + sides, a + sides])
    faces += [[bottom, (k + 1) % sides, k] for k in range(sides)]
    last = (rings - 1) * sides
    faces += [[top, last + k, last + (k + 1) % sides] for k in range(sides)]
    return vertices, faces


def bend(vertices, degrees=90.0):
    """Bend about an axis parallel to y: z = -CAGE_HALF_HEIGHT stays, z = +CAGE_HALF_HEIGHT turns by ``degrees``.

    Each height z is rotated by an angle growing linearly with z about the axis x = R, z = -CAGE_HALF_HEIGHT, where
    R is the arc radius that keeps the axis' length: lengths along x = 0 are kept, the outside stretches.

    Parameters
    ----------
    vertices : (n, 3) float array
    degrees : float

    Returns
    -------
    (n, 3) float array
    """
    total = np.radians(degrees)
    height = 2 * CAGE_HALF_HEIGHT
    arc_radius = height / total
    theta = (vertices[:, 2] + CAGE_HALF_HEIGHT) / arc_radius
    lever = arc_radius - vertices[:, 0]
    return np.stack([arc_radius - lever * np.cos(theta), vertices[:, 1],
                     -CAGE_HALF_HEIGHT + lever * np.sin(theta)], axis=1)


def twist(vertices, degrees=90.0):
    """Twist about the z axis: z = -CAGE_HALF_HEIGHT stays, z = +CAGE_HALF_HEIGHT turns by ``degrees``, the angle
    linear in z.

    Parameters
    ----------
    vertices : (n, 3) float array
    degrees : float

    Returns
    -------
    (n, 3) float array
    """
    angle = np.radians(degrees) * (vertices[:, 2] + CAGE_HALF_HEIGHT) / (2 * CAGE_HALF_HEIGHT)
    cosine, sine = np.cos(angle), np.sin(angle)
    return np.stack([cosine * vertices[:, 0] - sine * vertices[:, 1], sine * vertices[:, 0] + cosine * vertices[:, 1],
                     vertices[:, 2]], axis=1)


def stretch(vertices, factor=1.5):
    """Stretch along z by ``factor`` from z = -CAGE_HALF_HEIGHT, thinning towards the top (x and y scaled by
    1 / sqrt(factor) there, linearly in z): a taper, smooth but not affine."""
    share = (vertices[:, 2] + CAGE_HALF_HEIGHT) / (2 * CAGE_HALF_HEIGHT)
    across = 1.0 + (1.0 / np.sqrt(factor) - 1.0) * share
    return np.stack([vertices[:, 0] * across, vertices[:, 1] * across,
                     -CAGE_HALF_HEIGHT + (vertices[:, 2] + CAGE_HALF_HEIGHT) * factor], axis=1)


# The capsule's poses in the benchmarks: name → function of the cage's vertices.
POSES = {
    "bend 90°": bend,
    "twist 90°": twist,
    "bend 45° + twist 45°": lambda vertices: bend(twist(vertices, 45.0), 45.0),
    "stretch 1.5, tapered": stretch,
}


def kinks(rest, posed, faces):
    """Change of the dihedral angle at every interior edge of a triangle mesh, in degrees.

    Parameters
    ----------
    rest, posed : (m, 3) float array
        The mesh's vertices at rest and deformed.
    faces : (F, 3) int array
        Consistently oriented triangles.

    Returns
    -------
    (E,) float array, one per edge shared by two faces
    """
    faces = np.asarray(faces)
    first, second = _edge_neighbours(faces)

    def angles(vertices):
        corners = vertices[faces]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        cosine = np.einsum("ij,ij->i", normals[first], normals[second])
        return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))

    return np.abs(angles(posed) - angles(rest))


def kink_figures(rest, posed, faces):
    """mean, p99, max (degrees) and % of edges creased by more than 2° of :func:`kinks`, as a dict; also the number
    of edges whose angle changed by more than 30° ("folded") and of triangles turned over (:func:`flipped`)."""
    values = kinks(rest, posed, faces)
    return {"mean": float(values.mean()), "p99": float(np.percentile(values, 99)), "max": float(values.max()),
            "creased": float(100 * np.mean(values > 2.0)), "folded": int(np.count_nonzero(values > 30.0)),
            "flipped": flipped(rest, posed, faces)}


def flipped(rest, posed, faces):
    """Triangles turned over: facing the same way as their edge neighbours at rest (positive dot product of the unit
    normal with the sum of theirs), against them when posed.

    Parameters
    ----------
    rest, posed : (m, 3) float array
    faces : (F, 3) int array, consistently oriented

    Returns
    -------
    int
    """
    faces = np.asarray(faces)
    first, second = _edge_neighbours(faces)

    def agreement(vertices):
        corners = vertices[faces]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
        around = np.zeros_like(normals)
        np.add.at(around, first, normals[second])
        np.add.at(around, second, normals[first])
        return np.einsum("ij,ij->i", normals, around)

    return int(np.count_nonzero((agreement(rest) > 0) & (agreement(posed) <= 0)))


def _edge_neighbours(faces):
    """The two faces of every edge shared by two faces: (first, second) int arrays."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(len(faces)), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, owner = edges[order], owner[order]
    pair = np.flatnonzero(np.all(edges[1:] == edges[:-1], axis=1))
    return owner[pair], owner[pair + 1]


def mesh_deform(mesh_vertices, mesh_faces, cage_vertices, cage_faces, posed_cage, precision=5):
    """Blender's Mesh Deform on the scene through the bpy module: bind seconds and the deformed vertices.

    Parameters
    ----------
    mesh_vertices : (m, 3) float array
    mesh_faces : (F, 3) int array
    cage_vertices, posed_cage : (n, 3) float array
    cage_faces : list of index lists
    precision : int
        Mesh Deform's precision (Blender's default: 5).

    Returns
    -------
    bind_seconds : float
    posed : (m, 3) float array
    """
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = blender_object(bpy, "Capsule", mesh_vertices, mesh_faces)
    cage_object = blender_object(bpy, "Cage", cage_vertices, cage_faces)
    seconds = bind_mesh_deform(bpy, mesh, cage_object, precision)
    cage_object.data.vertices.foreach_set("co", np.asarray(posed_cage, dtype=np.float32).ravel())
    cage_object.data.update()
    evaluated = mesh.evaluated_get(bpy.context.evaluated_depsgraph_get())
    deformed = evaluated.to_mesh()
    try:
        values = np.empty(len(deformed.vertices) * 3, dtype=np.float32)
        deformed.vertices.foreach_get("co", values)
    finally:
        evaluated.to_mesh_clear()
    return seconds, values.reshape(-1, 3).astype(float)


def bind_mesh_deform(bpy, mesh_object, cage_object, precision=5):
    """Add a Mesh Deform modifier to ``mesh_object`` following ``cage_object`` and bind it; returns the seconds."""
    import time

    modifier = mesh_object.modifiers.new("Mesh Deform", "MESH_DEFORM")
    modifier.object = cage_object
    modifier.precision = precision
    bpy.context.view_layer.update()
    start = time.perf_counter()
    with bpy.context.temp_override(object=mesh_object, active_object=mesh_object):
        bpy.ops.object.meshdeform_bind(modifier=modifier.name)
    return time.perf_counter() - start


def blender_object(bpy, name, vertices, faces):
    """A Blender mesh object from arrays, linked to the scene."""
    data = bpy.data.meshes.new(name)
    data.from_pydata(np.asarray(vertices, dtype=float).tolist(), [], [[int(i) for i in f] for f in faces])
    data.update()
    obj = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _tube_faces(around, rows, bottom, top):
    """Triangles of a tube of ``rows`` rings closed by fans to the ``bottom`` and ``top`` poles, outward (z up)."""
    k = np.arange(around)
    following = (k + 1) % around
    faces = [np.stack([np.full(around, bottom), following, k], axis=1)]
    for row in range(rows - 1):
        a, b = row * around + k, row * around + following
        faces += [np.stack([a, b, b + around], axis=1), np.stack([a, b + around, a + around], axis=1)]
    last = (rows - 1) * around
    faces.append(np.stack([np.full(around, top), last + k, last + following], axis=1))
    return np.concatenate(faces)
