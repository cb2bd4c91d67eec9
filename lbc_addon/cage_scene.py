"""Make Cage's side of the scene (main thread): the selected meshes read into a
:class:`~lbc_addon.cage_job.CageRequest`, and the cage made for them written as a new object, or taken out again.

The cage is made in the first mesh's frame: the other meshes' vertices are brought into it from where they are in the
world, and the new object takes the first mesh's world transform (no parent). So the cage sits around the meshes
where they are, its origin and axes the first mesh's (Symmetry mirrors across the first mesh's own axes), and Bind
binds them to it at once. The meshes are read as Bind reads them: their own vertices, before modifiers and shape
keys.
"""

import hashlib

import bpy
import numpy as np
from mathutils import Matrix

from . import geometry
from .cage_job import CageOptions, CageRequest, face_lists
from .core import CageError

# The new object's name is the first mesh's with this after it ("SuzanneCage"; Blender adds ".001" to a taken name).
NAME_SUFFIX = "Cage"


def cage_targets(context):
    """The meshes Make Cage puts a cage around: the selected meshes, the active one first (the cage takes its frame,
    name and collections)."""
    meshes = [obj for obj in context.selected_objects if obj.type == "MESH"]
    active = context.active_object
    if active in meshes:
        meshes.remove(active)
        meshes.insert(0, active)
    return meshes


def snapshot(mesh_objs, options=CageOptions()):
    """Copy what making a cage around ``mesh_objs`` (the first gives the frame) with ``options`` needs; raises
    CageError for what can be seen already (not meshes, in Edit Mode, scaled to 0, a vertex group missing or empty)."""
    mesh_objs = _checked_meshes(mesh_objs)
    frame = np.array(mesh_objs[0].matrix_world, dtype=np.float64)
    to_frame = np.linalg.inv(frame)
    vertices, faces, offset = [], [], 0
    for number, obj in enumerate(mesh_objs):
        points = geometry.vertex_positions(obj.data)
        polygons = geometry.polygon_faces(obj.data)
        if options.vertex_group:
            points, polygons = group_part(obj, options.vertex_group, points, polygons)
        # The first mesh's own coordinates exactly; the others through the world.
        vertices.append(points if number == 0 else geometry.transform(to_frame @ np.array(obj.matrix_world), points))
        faces += [face + offset for face in polygons]
        offset += len(points)
    return CageRequest(
        mesh_uids=tuple(obj.session_uid for obj in mesh_objs),
        mesh_names=tuple(obj.name for obj in mesh_objs),
        vertices=np.concatenate(vertices),
        faces=faces,
        frame=frame,
        options=options,
        fingerprint=fingerprint(mesh_objs),
    )


def _checked_meshes(mesh_objs):
    """``mesh_objs`` (one object or several) as a list without repeats; refuses what cannot be caged here."""
    if isinstance(mesh_objs, bpy.types.Object):
        mesh_objs = [mesh_objs]
    mesh_objs = list(dict.fromkeys(mesh_objs))
    if not mesh_objs:
        raise CageError("no mesh to put a cage around: select the mesh(es) (in a script: api.make_cage([mesh]))")
    for obj in mesh_objs:
        if not isinstance(obj, bpy.types.Object):
            raise CageError(f"the mesh to cage is {obj!r}, not an object: pass it as e.g. bpy.data.objects['Name'] "
                            "(.get returns None for a name that is not there)")
        if obj.type != "MESH":
            raise CageError(geometry.not_a_mesh(obj, "only meshes can be caged",
                                                "select the mesh(es) to put a cage around"))
        if obj.data.is_editmode:
            raise CageError(f"'{obj.name}' is in Edit Mode, whose edits its mesh data does not hold yet: switch to "
                            "Object Mode first (Tab)")
    scales = np.linalg.svd(np.array(mesh_objs[0].matrix_world)[:3, :3], compute_uv=False)
    if not scales[-1] > 1e-9 * scales[0]:
        raise CageError(f"'{mesh_objs[0].name}' is scaled to 0 along an axis (Scale "
                        f"{tuple(round(value, 6) for value in mesh_objs[0].scale)}): a cage in its frame would enclose "
                        "nothing; give it a scale other than 0 on every axis (Object properties > Transform)")
    return mesh_objs


def group_part(mesh_obj, name, vertices, faces):
    """The part of a mesh in its vertex group ``name``: the faces with every corner in the group (with a weight above
    0), and their vertices, renumbered; (vertices (k, 3), faces). Refuses a group the mesh lacks or that holds no
    face."""
    group = mesh_obj.vertex_groups.get(name)
    if group is None:
        names = [f"'{other.name}'" for other in mesh_obj.vertex_groups]
        have = f"its groups: {', '.join(names[:8])}{' …' if len(names) > 8 else ''}" if names else "it has none"
        raise CageError(f"'{mesh_obj.name}' has no vertex group '{name}' ({have}): pick one of its groups, or leave "
                        "Vertex Group empty to cage the whole mesh")
    inside = geometry.vertex_group_mask(mesh_obj, name, False) > 0
    kept = [face for face in faces if inside[face].all()]
    if not kept:
        count = int(np.count_nonzero(inside))
        held = f"its {count} vertices make no whole face" if count else "it holds no vertex"
        raise CageError(f"the vertex group '{name}' of '{mesh_obj.name}' has nothing to cage ({held}): assign the part "
                        "to cage to it (Edit Mode: select it, then Object Data properties > Vertex Groups > Assign), "
                        "or leave Vertex Group empty to cage the whole mesh")
    used = np.unique(np.concatenate(kept))
    renumbered = np.full(len(vertices), -1, dtype=np.int64)
    renumbered[used] = np.arange(len(used))
    return vertices[used], [renumbered[face] for face in kept]


def fingerprint(mesh_objs):
    """16 hex digits of a hash of the meshes' world transforms, vertex positions and topology: what the cage was
    made around, to tell that one was moved or edited while it was made."""
    digest = hashlib.sha256()
    for obj in mesh_objs:
        digest.update(np.array(obj.matrix_world, dtype=np.float64).tobytes())
        digest.update(np.float32(geometry.vertex_positions(obj.data)).tobytes())
        digest.update(geometry.topology_fingerprint(obj.data).encode())
    return digest.hexdigest()[:16]


def write(request, result, select=True):
    """Add the cage of ``result`` (a :class:`~lbc_addon.cage_job.CageResult`) for ``request`` to the scene: a new mesh
    object "<first mesh>Cage" drawn as a wire and hidden in renders, with the first mesh's world transform, in its
    collections; with ``select``, the meshes selected and the cage active (ready for Bind). Raises CageError, changing
    nothing, when a mesh was deleted, moved or edited since the snapshot. Returns the new object."""
    meshes = [geometry.find_object(uid) for uid in request.mesh_uids]
    names = ", ".join(f"'{name}'" for name in request.mesh_names)
    if any(obj is None for obj in meshes):
        raise CageError(f"{names} was deleted while its cage was made: nothing was made")
    if fingerprint(meshes) != request.fingerprint:
        raise CageError(f"{names} was moved or edited while its cage was made: nothing was made; make the cage again")
    first = meshes[0]
    data = bpy.data.meshes.new(first.name + NAME_SUFFIX)
    data.from_pydata(result.cage.vertices.tolist(), [], face_lists(result.cage.faces))
    data.update()
    cage = bpy.data.objects.new(first.name + NAME_SUFFIX, data)
    cage.matrix_world = Matrix(request.frame.tolist())
    cage.display_type = "WIRE"
    cage.hide_render = True  # a control object, as a Mesh Deform cage: the meshes render, not the cage
    editable = [collection for collection in first.users_collection if collection.library is None]
    for collection in editable or [bpy.context.scene.collection]:
        collection.objects.link(cage)
    if select:
        select_for_bind(meshes, cage)
    return cage


def select_for_bind(meshes, cage):
    """Select ``meshes`` and ``cage`` alone, the cage active: what Bind binds (in this view layer)."""
    layer = bpy.context.view_layer
    # An object a script removed keeps its base in the layer until the layer is synced: reading that base reads freed
    # memory (a crash in one run of three), so sync first.
    layer.update()
    for obj in layer.objects:
        if obj.select_get():
            obj.select_set(False)
    for obj in list(meshes) + [cage]:
        if obj.name in layer.objects:
            obj.select_set(True)
    if cage.name in layer.objects:
        layer.objects.active = cage


def remove(cage):
    """Take a cage :func:`write` added out of the file again, its mesh data too."""
    data = cage.data
    bpy.data.objects.remove(cage)
    if data.users == 0:
        bpy.data.meshes.remove(data)
