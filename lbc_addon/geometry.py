"""Reading the scene out of Blender into numpy arrays, on the main thread: a bind's request, and meshes' topology.

Everything the solve needs is copied here (:func:`snapshot`), so the worker thread never touches ``bpy``. Positions
are expressed in the bound mesh's local space, the space the Geometry Nodes deformer works in (Object Info in
relative mode).
"""

import hashlib

import bpy
import numpy as np

from . import storage
from .core import MAX_CONTROL_POINTS, CageError, flatten, some_indices
from .jobs import BindRequest, verb_for
from .options import AddonOptions
from .properties import is_bound


def vertex_positions(mesh):
    """The vertex positions of a ``bpy.types.Mesh`` as an (m, 3) float64 array."""
    positions = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", positions)
    return positions.reshape(-1, 3).astype(np.float64)


def shape_key_positions(key):
    """The positions a shape key (``bpy.types.ShapeKey``) holds, as an (m, 3) float64 array."""
    positions = np.empty(len(key.data) * 3, dtype=np.float32)
    key.data.foreach_get("co", positions)
    return positions.reshape(-1, 3).astype(np.float64)


def shape_keys_on(obj):
    """The relative shape keys that change ``obj``'s shape now: not muted, at a value other than 0, and moving some
    vertex from the key they are relative to (a new key is a copy of it, at value 1 in Blender 5)."""
    keys = obj.data.shape_keys
    return [key for key in (keys.key_blocks[1:] if keys is not None else ())
            if not key.mute and key.value != 0 and not np.array_equal(shape_key_positions(key),
                                                                      shape_key_positions(key.relative_key))]


def polygon_faces(mesh):
    """The faces of a ``bpy.types.Mesh`` as a list of vertex index arrays."""
    corners = np.empty(len(mesh.loops), dtype=np.int64)
    mesh.loops.foreach_get("vertex_index", corners)
    sizes = np.empty(len(mesh.polygons), dtype=np.int64)
    mesh.polygons.foreach_get("loop_total", sizes)
    return np.split(corners, np.cumsum(sizes)[:-1]) if len(sizes) else []


def edge_pairs(mesh):
    """The edges of a ``bpy.types.Mesh`` as an (E, 2) int array."""
    edges = np.empty(len(mesh.edges) * 2, dtype=np.int64)
    mesh.edges.foreach_get("vertices", edges)
    return edges.reshape(-1, 2)


# The prefix of the fingerprints this version makes (those of earlier versions, kept in files, have none).
FINGERPRINT_VERSION = "2:"


def topology_fingerprint(mesh):
    """A hash of a mesh's vertex count, edges (each an unordered pair, in the mesh's order) and face sizes: what
    the weights depend on. Positions do not enter it, nor the faces' winding (Blender 5.2 reverses it when a
    negative scale is applied, the cage unchanged); vertices added, removed or reordered change it.

    Returns
    -------
    str
        :data:`FINGERPRINT_VERSION` and 16 hex digits.
    """
    return _fingerprint(len(mesh.vertices), edge_pairs(mesh), _face_sizes(mesh))


def shape_fingerprint(mesh):
    """16 hex digits of a hash of a mesh's own vertex positions (its data, before modifiers), or "" for a mesh in
    Edit Mode, whose data lags its edits: what tells that a cage was edited at rest since a bind."""
    if mesh.is_editmode:
        return ""
    return hashlib.sha256(np.float32(vertex_positions(mesh)).tobytes()).hexdigest()[:16]


def topology_fingerprints(mesh):
    """The mesh's :func:`topology_fingerprint` and the one the version before made (which hashed the faces' corners
    as well), for bindings stored by it: a set of two strings."""
    count, edges, sizes = len(mesh.vertices), edge_pairs(mesh), _face_sizes(mesh)
    corners = np.empty(len(mesh.loops), dtype=np.int64)
    mesh.loops.foreach_get("vertex_index", corners)
    return {_fingerprint(count, edges, sizes), _digest(count, edges, corners, sizes)}


def _fingerprint(vertex_count, edges, face_sizes):
    """:func:`topology_fingerprint` from the mesh's vertex count, (E, 2) edges and face sizes."""
    return FINGERPRINT_VERSION + _digest(vertex_count, np.sort(edges, axis=1), face_sizes)


def _face_sizes(mesh):
    sizes = np.empty(len(mesh.polygons), dtype=np.int64)
    mesh.polygons.foreach_get("loop_total", sizes)
    return sizes


def _digest(vertex_count, *arrays):
    """16 hex digits of the SHA-256 of a count and int64 arrays."""
    digest = hashlib.sha256()
    digest.update(np.int64(vertex_count).tobytes())
    for array in arrays:
        digest.update(np.ascontiguousarray(array, dtype=np.int64).tobytes())
    return digest.hexdigest()[:16]


# Modifier types that can change a mesh's vertex count (Geometry Nodes too: a tree may).
VERTEX_COUNT_MODIFIERS = frozenset({
    "ARRAY", "BEVEL", "BOOLEAN", "BUILD", "DECIMATE", "EDGE_SPLIT", "EXPLODE", "MASK", "MESH_SEQUENCE_CACHE",
    "MIRROR", "MULTIRES", "NODES", "OCEAN", "PARTICLE_INSTANCE", "REMESH", "SCREW", "SKIN", "SOLIDIFY", "SUBSURF",
    "WELD", "WIREFRAME",
})


def may_change_vertex_count(modifier):
    """Whether a modifier shown in the viewport is of a type that can change the mesh's vertex count."""
    return modifier.show_viewport and modifier.type in VERTEX_COUNT_MODIFIERS


def render_difference(obj):
    """Why ``obj``'s evaluated mesh may have other vertices in renders than in the viewport, or None.

    A deformer bound to a cage's evaluated vertices stops where their count differs, and the viewport and renders
    each evaluate their own: a Subdivision at Blender's defaults (1 level in the viewport, 2 in renders) leaves the
    mesh undeformed in every render.
    """
    for modifier in obj.modifiers:
        if modifier.type not in VERTEX_COUNT_MODIFIERS:
            continue
        if modifier.show_viewport != modifier.show_render:
            return f"modifier '{modifier.name}' is shown in {'renders' if modifier.show_render else 'the viewport'} only"
        render_levels = getattr(modifier, "render_levels", None)
        if modifier.show_render and render_levels is not None and render_levels != modifier.levels:
            return (f"modifier '{modifier.name}' has {render_levels} levels in renders and {modifier.levels} in the "
                    "viewport")
    return None


def mirror_warning(mesh_obj):
    """The warning for a mesh with a Mirror modifier, or None: the deformer goes above modifiers that change the
    vertex count, so the Mirror copies the deformed half, where Mesh Deform, below it, deforms both halves."""
    mirrors = [modifier.name for modifier in mesh_obj.modifiers
               if modifier.type == "MIRROR" and (modifier.show_viewport or modifier.show_render)]
    if not mirrors:
        return None
    # Blender applies no modifier to a mesh with shape keys.
    shape_keys = (" (Blender applies no modifier to a mesh with shape keys: there, Mesh Deform below the Mirror "
                  "deforms both halves)" if mesh_obj.data.shape_keys is not None else "")
    return (f"the mesh's Mirror modifier '{mirrors[0]}' comes after the deformer: the mirrored half copies this half's "
            f"deformation instead of following its own side of the cage. Apply the Mirror (Ctrl+A) and Rebind for "
            f"each half to follow its own side{shape_keys}")


def cage_pose_warning(cage_obj, depsgraph):
    """The warning for a cage bound in a pose, or None: an armature whose bones are not at rest (by their own
    transforms, IK or other constraints) deforming it, or a shape key of its own at a value other than 0. The bind
    takes the cage as it is as the rest, so that pose would be undone when the bones or keys go back."""
    for modifier in cage_obj.modifiers:
        armature = getattr(modifier, "object", None) if modifier.type == "ARMATURE" else None
        if (not modifier.show_viewport or armature is None or armature.type != "ARMATURE"
                or armature.data.pose_position != "POSE"):
            continue
        bones = armature.evaluated_get(depsgraph).pose.bones
        posed = [bone.name for bone in bones
                 if not np.allclose(np.array(bone.matrix), np.array(bone.bone.matrix_local), atol=1e-5)]
        if posed:
            return (f"the cage is bound as the armature '{armature.name}' poses it now (bone '{posed[0]}' "
                    f"{'and others ' if len(posed) > 1 else ''}out of its rest pose): that pose is the rest the mesh "
                    "follows from. If it is not, set the armature to Rest Position (Armature properties > Pose "
                    "Position) and Rebind")
    shaped = [] if cage_obj.show_only_shape_key else shape_keys_on(cage_obj)
    if shaped:
        return (f"the cage is bound with its shape key '{shaped[0].name}' at {shaped[0].value:g}: that shape is the "
                "rest the mesh follows from. If it is not, set the key to 0 and Rebind")
    return None


def render_warning(mesh_obj, cage_obj):
    """The warning for a binding whose cage has other vertices in renders (:func:`render_difference`), or None."""
    difference = render_difference(cage_obj)
    if difference is None:
        return None
    return (f"renders leave '{mesh_obj.name}' undeformed: the cage's {difference}; make the viewport and render "
            "settings the same (or apply the modifier) and Rebind")


def transform(matrix, positions):
    """Apply a 4×4 ``mathutils.Matrix`` (or array) to (k, 3) positions."""
    matrix = np.array(matrix, dtype=np.float64)
    return positions @ matrix[:3, :3].T + matrix[:3, 3]


def vertex_group_mask(mesh_obj, name, invert):
    """(m,) float array: the factor the deformer's Vertex Group input gives each vertex: its weight in the group named
    ``name`` (0 outside it), 1 minus that when ``invert``; 1 everywhere when no group has that name, as in Mesh
    Deform."""
    group = mesh_obj.vertex_groups.get(name) if name else None
    if group is None:
        return np.ones(len(mesh_obj.data.vertices))
    weights = np.zeros(len(mesh_obj.data.vertices))
    for vertex in mesh_obj.data.vertices:
        for element in vertex.groups:
            if element.group == group.index:
                weights[vertex.index] = element.weight
    return 1.0 - weights if invert else weights


def cage_to_mesh_matrix(cage_obj, mesh_obj):
    """The matrix taking the cage's local coordinates to the mesh's: what Object Info (relative) applies."""
    return mesh_obj.matrix_world.inverted_safe() @ cage_obj.matrix_world


def _evaluation_changes(obj):
    """What evaluating a mesh object applies that can change its vertices, for a message: "its modifiers", "its shape
    keys", both joined by "and", or "" (a shape key at value 0, muted, or a copy of its basis changes nothing)."""
    keys = obj.data.shape_keys
    keyed = keys is not None and (not keys.use_relative and len(keys.key_blocks) > 1 or bool(shape_keys_on(obj)))
    changes = (["its modifiers"] if any(modifier.show_viewport for modifier in obj.modifiers) else []) + (
        ["its shape keys"] if keyed else [])
    return " and ".join(changes)


def _why_not_evaluated(obj, scene):
    """Why Blender does not evaluate ``obj`` in the scene's view layer, and what makes it evaluated."""
    if obj.name not in scene.objects:
        return ("it is not in this scene",
                "link it into this scene (Object > Link/Transfer Data > Link Objects to Scene)")
    if obj.hide_viewport:
        return "it is disabled in viewports", "enable it in viewports (the screen icon; H still hides it)"
    disabled = [collection.name for collection in scene.collection.children_recursive
                if collection.hide_viewport and obj.name in collection.all_objects]
    if disabled:
        return (f"its collection '{disabled[0]}' is disabled in viewports",
                "enable the collection in viewports (its screen icon, shown by the Outliner's filter menu)")
    return "it is in an excluded collection", "include its collection in the view layer (its checkbox in the Outliner)"


def not_editable_here(mesh_obj):
    """Why the binding of ``mesh_obj`` cannot be changed in this file (the object or its mesh data is linked from a
    library, as a library override's mesh data stays), or None. Changes there would be lost on saving."""
    for what, block in ((f"'{mesh_obj.name}'", mesh_obj), (f"the mesh data of '{mesh_obj.name}'", mesh_obj.data)):
        if block is not None and block.library is not None:
            # An object that came in a linked collection stays there: Make Local > Selected makes an orphan copy.
            linked = [collection.name for collection in mesh_obj.users_collection if collection.library is not None]
            local = (f"make its collection '{linked[0]}' local first (Outliner: right-click it > Make Local), or "
                     "Object > Relations > Make Local > All" if linked else
                     "Object > Relations > Make Local > Selected Objects and Data")
            return (f"{what} is linked from the library '{block.library.filepath}': its binding is saved in that file "
                    f"(change it there), or make it local here first ({local})")
    return None


# Object types Object > Convert > Mesh turns into a mesh, by the names Blender's menus give them.
CONVERTIBLE_TO_MESH = {"CURVE": "Curve", "SURFACE": "Surface", "META": "Metaball", "FONT": "Text"}


def not_a_mesh(obj, need, remedy):
    """Why ``obj``, not a mesh, cannot take the role it was given: "'Name' (Kind) is not a mesh, and ``need``: ",
    how to convert it where Object > Convert > Mesh can, then ``remedy``; its type named as Blender's menus do."""
    kind = CONVERTIBLE_TO_MESH.get(obj.type, obj.type.title())
    convert = "convert it (Object > Convert > Mesh), or " if obj.type in CONVERTIBLE_TO_MESH else ""
    return f"'{obj.name}' ({kind}) is not a mesh, and {need}: {convert}{remedy}"


def swapped_selection(cage_obj, mesh_objs):
    """What to say when the would-be cage is most likely a mesh to bind, made active by clicking it last, or None: it
    has more vertices than any cage can have control points and than every selected mesh. Vertex counts alone, so the
    panel and Bind's poll can say it before any long work (lbc_core's own refusal comes after the snapshot)."""
    if cage_obj.type != "MESH":
        return None
    count = len(cage_obj.data.vertices)
    if count <= MAX_CONTROL_POINTS or any(count <= len(obj.data.vertices) for obj in mesh_objs):
        return None
    return (f"'{cage_obj.name}' is active and would be the cage; make the cage active (click it last) and select the "
            "meshes to bind")


def snapshot(mesh_obj, cage_obj, depsgraph, options=AddonOptions()):
    """Copy what binding ``mesh_obj`` to ``cage_obj`` with ``options`` (:class:`AddonOptions`) needs; raises
    CageError for what can be seen already."""
    _check_roles(mesh_obj, cage_obj)
    swapped = swapped_selection(cage_obj, [mesh_obj])
    if swapped:  # at once, in the Bind button's words: the cage's checks would take seconds on a dense mesh
        raise CageError(f"{swapped} (in a script: api.bind(mesh, cage), the mesh first)")
    _check_bindable(mesh_obj, cage_obj)
    points = _mesh_points(mesh_obj)
    cage_points, cage_faces, flat, cage_topology, world = _cage_geometry(mesh_obj, cage_obj, depsgraph, points,
                                                                         options.mode)
    return BindRequest(
        mesh_uid=mesh_obj.session_uid,
        cage_uid=cage_obj.session_uid,
        mesh_name=mesh_obj.name,
        cage_name=cage_obj.name,
        bound_to_cage=is_bound(mesh_obj) and mesh_obj.lbc.cage == cage_obj,
        points=points,
        cage_points=cage_points,
        cage_faces=cage_faces,
        flat=flat,
        options=options,
        cage_topology=cage_topology,
        cage_shape=shape_fingerprint(cage_obj.data),
        mesh_topology=topology_fingerprint(mesh_obj.data),
        warnings=[warning for warning in (render_warning(mesh_obj, cage_obj), mirror_warning(mesh_obj),
                                          cage_pose_warning(cage_obj, depsgraph)) if warning],
        cage_modifiers=_named_modifiers(list(filter(may_change_vertex_count, cage_obj.modifiers))),
        cage_modifiers_off=_named_modifiers(_modifiers_off(cage_obj)),
        world=world,
    )


def _check_roles(mesh_obj, cage_obj):
    """Refuse what cannot be a mesh and its cage: not objects, not meshes, one object in both roles, or a cage scaled
    to 0."""
    for role, obj in (("mesh", mesh_obj), ("cage", cage_obj)):
        if not isinstance(obj, bpy.types.Object):
            raise CageError(f"the {role} to bind is {obj!r}, not an object: pass it as e.g. bpy.data.objects['Name'] "
                            "(.get returns None for a name that is not there)")
    if mesh_obj.type != "MESH":
        raise CageError(not_a_mesh(mesh_obj, "only meshes can be bound", "bind a mesh"))
    if cage_obj.type != "MESH":
        raise CageError(f"the cage {not_a_mesh(cage_obj, 'the cage must be one', 'use a mesh as the cage')}")
    if mesh_obj == cage_obj:
        raise CageError(f"'{mesh_obj.name}' cannot be its own cage: bind it to a closed mesh around it (select "
                        "the mesh, then the cage last, so that it is active; in a script, api.bind(mesh, cage))")
    scales = np.linalg.svd(np.array(cage_obj.matrix_world)[:3, :3], compute_uv=False)
    if not scales[-1] > 1e-9 * scales[0]:
        raise CageError(f"the cage object '{cage_obj.name}' is scaled to 0 along an axis (Scale "
                        f"{tuple(round(value, 6) for value in cage_obj.scale)}), so it encloses nothing: give it a "
                        "scale other than 0 on every axis (Object properties > Transform)")


def _check_bindable(mesh_obj, cage_obj):
    """Refuse a mesh whose binding cannot be written here and now: linked from a library, its data shared, in Edit
    Mode, or the cage bound to it."""
    linked = not_editable_here(mesh_obj)
    if linked:
        raise CageError(linked)
    if mesh_obj.data.users > 1:
        raise CageError(
            f"the mesh data of '{mesh_obj.name}' is shared by {mesh_obj.data.users} objects and the weights are "
            "stored in it: make it single user first (Object > Relations > Make Single User)"
        )
    if mesh_obj.data.is_editmode:
        # Edit Mode keeps the mesh's vertices out of its data until it is left, and would overwrite the weights then.
        raise CageError(f"'{mesh_obj.name}' is in Edit Mode: switch to Object Mode first (Tab, or "
                        "bpy.ops.object.mode_set(mode='OBJECT'))")
    deformed_by = _binding_chain(cage_obj)
    if mesh_obj in deformed_by:
        raise CageError(f"the cage '{cage_obj.name}' is itself deformed by '{mesh_obj.name}' (bound to it): binding "
                        f"'{mesh_obj.name}' to it would make each follow the other. Unbind '{cage_obj.name}' first")


def _mesh_points(mesh_obj):
    """The mesh's vertex positions (m, 3); refuses a mesh without vertices, or with NaN or infinite ones."""
    if not len(mesh_obj.data.vertices):
        raise CageError(f"'{mesh_obj.name}' has no vertices: there is nothing to bind")
    points = vertex_positions(mesh_obj.data)
    bad = np.flatnonzero(~np.all(np.isfinite(points), axis=1))
    if len(bad):  # named here: lbc_core's message counts points, not which of the selected meshes holds them
        raise CageError(f"'{mesh_obj.name}' has {len(bad)} {'vertex' if len(bad) == 1 else 'vertices'} with NaN or "
                        f"infinite coordinates ({some_indices(bad)}): fix or delete them")
    return points


def _cage_geometry(mesh_obj, cage_obj, depsgraph, points, mode):
    """The evaluated cage in the mesh's space: (cage points, outward faces, its flat outline or None, its topology
    fingerprint, the world-space geometry of the solve); refuses a cage the bind would see otherwise than the
    deformer, one without faces, and one not flat where ``mode`` is "2D"."""
    cage_eval, mesh_eval = cage_obj.evaluated_get(depsgraph), mesh_obj.evaluated_get(depsgraph)
    changes = _evaluation_changes(cage_obj)
    if not cage_eval.is_evaluated and changes:
        # The deformer evaluates the cage (its modifier makes the cage part of the depsgraph): the bind must too.
        why, fix = _why_not_evaluated(cage_obj, depsgraph.scene)
        raise CageError(f"the cage '{cage_obj.name}' is not evaluated in this view layer ({why}), so {changes} would "
                        f"not be applied and the bind would see another cage than the deformer: {fix} for the bind, "
                        f"or apply {changes}")
    cage_mesh = cage_eval.to_mesh()
    try:
        matrix = cage_to_mesh_matrix(cage_eval, mesh_eval)
        cage_local = vertex_positions(cage_mesh)
        cage_points = transform(matrix, cage_local)
        faces = polygon_faces(cage_mesh)
        # A mirroring transform (a negative scale) turns outward faces inward; turned back, so that lbc_core does not
        # report faces the artist sees pointing outward as reversed.
        cage_faces = _outward(faces, matrix)
        # The solve's frame: world space, the same cage for every mesh bound to it (jobs.BindRequest.solve_geometry).
        world = (transform(cage_eval.matrix_world, cage_local), _outward(faces, cage_eval.matrix_world),
                 transform(mesh_eval.matrix_world, points))
        cage_topology = topology_fingerprint(cage_mesh)
        flat = None if mode == "3D" else flatten(cage_points, cage_faces, points, edge_pairs(cage_mesh))
        if flat is None and not cage_faces:
            raise CageError(f"the cage '{cage_obj.name}' has no faces: a cage is a closed surface around the mesh "
                            "(fill its holes: Edit Mode, Select All, F)")
        if mode == "2D" and flat is None:
            raise CageError(
                "2D binding needs a flat cage with the mesh lying in its plane: flatten them, or bind in 3D"
            )
    finally:
        cage_eval.to_mesh_clear()
    return cage_points, cage_faces, flat, cage_topology, world


def changed_since(request, mesh_obj, cage_obj, depsgraph):
    """What changed in the mesh or the cage since ``request`` was made (e.g. during a modal bind), or None.

    The weights reproduce the mesh as it was from the cage as it was, both in the mesh's space: a vertex or object
    moved since would make the deformer add that move to the mesh."""
    if (topology_fingerprint(mesh_obj.data) != request.mesh_topology
            or not np.array_equal(vertex_positions(mesh_obj.data), request.points)):
        return f"'{mesh_obj.name}' was edited during the bind"
    cage_eval = cage_obj.evaluated_get(depsgraph)
    cage_mesh = cage_eval.to_mesh()
    try:
        if topology_fingerprint(cage_mesh) != request.cage_topology:
            return f"the cage '{cage_obj.name}' was edited during the bind"
        matrix = cage_to_mesh_matrix(cage_eval, mesh_obj.evaluated_get(depsgraph))
        if not np.array_equal(transform(matrix, vertex_positions(cage_mesh)), request.cage_points):
            return f"the cage '{cage_obj.name}' or '{mesh_obj.name}' was moved or edited during the bind"
    finally:
        cage_eval.to_mesh_clear()
    return None


def _outward(faces, matrix):
    """``faces`` as they point after ``matrix`` (4×4): reversed where it mirrors."""
    return [face[::-1] for face in faces] if np.linalg.det(np.array(matrix)[:3, :3]) < 0 else faces


def _binding_chain(obj):
    """The cages ``obj`` follows: its binding's cage, that cage's cage, and so on (a cycle ends the walk)."""
    chain = []
    while is_bound(obj) and obj.lbc.cage is not None and obj.lbc.cage not in chain:
        obj = obj.lbc.cage
        chain.append(obj)
    return chain


def snapshots(targets, depsgraph, skip_refused=False, left_out=()):
    """:func:`snapshot` of each (mesh, cage, options) triple of ``targets``.

    Returns (requests, refused): with ``skip_refused``, a mesh :func:`snapshot` refuses (e.g. its data shared by a
    linked duplicate) is left out and ``refused`` says why ("'Name' left as it was: …"), after the messages
    ``left_out`` of meshes the caller left out already, unless every mesh is refused, which raises CageError with all
    the reasons; without it, the first refusal raises.
    """
    requests, refused = [], list(left_out)
    for mesh_obj, cage_obj, options in targets:
        try:
            requests.append(snapshot(mesh_obj, cage_obj, depsgraph, options))
        except CageError as error:
            if not skip_refused:
                raise
            refused.append(f"'{mesh_obj.name}' left as it was: {error}")
    if refused and not requests:
        raise CageError("; ".join(refused))
    return requests, refused


def _modifiers_off(obj):
    """``obj``'s modifiers of a type that can change the vertex count, off in viewports."""
    return [modifier for modifier in obj.modifiers
            if not modifier.show_viewport and modifier.type in VERTEX_COUNT_MODIFIERS]


def cage_modifiers_note(cage_obj):
    """Which of the cage's modifiers make its vertices other than its mesh data's, for messages: "its modifier
    'Subdivision' makes them", "its modifier 'Mirror' is off in viewports", both, or ""."""
    notes = []
    on = _named_modifiers(list(filter(may_change_vertex_count, cage_obj.modifiers)))
    if on:
        notes.append(f"its {on} {verb_for(on, 'makes', 'make')} them")
    off = _named_modifiers(_modifiers_off(cage_obj))
    if off:
        notes.append(f"its {off} {verb_for(off, 'is', 'are')} off in viewports")
    return "; ".join(notes)


def _named_modifiers(modifiers):
    """ "modifier 'Mirror'" or "modifiers 'Mirror', 'Subdivision'", "" for none."""
    if not modifiers:
        return ""
    return ("modifiers " if len(modifiers) > 1 else "modifier ") + ", ".join(f"'{m.name}'" for m in modifiers)


def find_object(uid):
    """The object with this ``session_uid``, or None once it was deleted."""
    for obj in bpy.data.objects:
        if obj.session_uid == uid:
            return obj
    return None


def leftover_weights(obj):
    """The names of the LBC attributes an unbound mesh carries for no binding: a bound mesh joined into it (Ctrl+J)
    brings its weights along, but not its binding. Dead weight in the .blend, which Unbind removes. Empty for a
    bound mesh, and for mesh data a bound object shares (a linked duplicate's weights are in use)."""
    if obj.type != "MESH" or is_bound(obj) or shared_with(obj):
        return []
    return storage.binding_names(obj.data)


def shared_with(mesh_obj):
    """The other bound objects using ``mesh_obj``'s mesh data (linked duplicates)."""
    if mesh_obj.data.users < 2:
        return []
    return [obj for obj in bpy.data.objects if obj != mesh_obj and obj.data == mesh_obj.data and is_bound(obj)]


def evaluated_cage(cage_obj, depsgraph):
    """Topology fingerprints (:func:`topology_fingerprints`) and (n, 3) vertex positions of the cage as the
    deformer sees it (modifiers applied)."""
    cage_eval = cage_obj.evaluated_get(depsgraph)
    mesh = cage_eval.to_mesh()
    try:
        return topology_fingerprints(mesh), vertex_positions(mesh)
    finally:
        cage_eval.to_mesh_clear()


def evaluated_cage_once(cage_obj, depsgraph, cages):
    """:func:`evaluated_cage`, kept in ``cages`` (a dict by cage name, or None to keep nothing) for the next call."""
    if cages is None:
        return evaluated_cage(cage_obj, depsgraph)
    if cage_obj.name_full not in cages:
        cages[cage_obj.name_full] = evaluated_cage(cage_obj, depsgraph)
    return cages[cage_obj.name_full]
