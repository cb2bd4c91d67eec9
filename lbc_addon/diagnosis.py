"""Why a bound mesh's deformer cannot work: the twelve causes :func:`diagnose` tells apart, each with its message,
and the checks behind them (the mesh moved as a whole, welded cage vertices posed apart); and what the panels and
``api.status`` add of a mesh that follows (:func:`notes`).
"""

import enum
from dataclasses import dataclass

import bpy
import numpy as np

from . import deformer, geometry, node_group, storage
from .core import POSED_APART
from .jobs import cage_too_small, few_cells_warning, read_welded


class NoteKind(enum.Enum):
    """What a note on a bound mesh that follows is about (:func:`notes`)."""

    CAGE_TOO_SMALL = "cage too small"  # much of the mesh outside its cage: it follows by extrapolation
    OUTSIDE_ITS_CAGE = "outside its cage"  # moved as an object out of its cage, which still places it
    FEW_CELLS = "few cells"  # few cells for the cage's vertices: coarse weights
    EDITED_SINCE_BIND = "edited since bind"  # the cage edited at rest: the mesh follows the edit as a pose
    MOVED_AS_AN_OBJECT = "moved as an object"  # which shows nothing: the cage alone places the mesh


# The notes that are lasting problems of the binding rather than advice: ``api.status(...).ok`` is false with one.
PROBLEMS = frozenset({NoteKind.CAGE_TOO_SMALL, NoteKind.OUTSIDE_ITS_CAGE})


@dataclass(frozen=True)
class Note:
    """One note on a bound mesh that follows: its ``kind`` and the ``text`` the panels and ``api.status`` show."""

    kind: NoteKind
    text: str

    @property
    def problem(self):
        """Whether the note is a lasting problem of the binding (:data:`PROBLEMS`), not advice."""
        return self.kind in PROBLEMS


@dataclass(frozen=True)
class RebindWords:
    """How the notes tell to bind again where they are read: one mesh (``one``) and every mesh of a cage (``all``)."""

    one: str
    all: str


PANEL_WORDS = RebindWords("Rebind", "Rebind")
SCRIPT_WORDS = RebindWords("rebind (api.bind)", "rebind (api.rebind_all(cage))")


def notes(mesh_obj, words=PANEL_WORDS):
    """What the panels and ``api.status`` add of a bound mesh that follows its cage, as :class:`Note` records in the
    order shown: much of it outside a cage too small, few cells for the cage, the cage edited since the bind, the mesh
    moved as an object (out of its cage, or not). ``words``: how to rebind there."""
    settings = mesh_obj.lbc
    found = []
    too_small = cage_too_small(settings, len(mesh_obj.data.vertices))
    if too_small:
        found.append(Note(NoteKind.CAGE_TOO_SMALL, too_small))
    few = few_cells_warning(settings.dimension, settings.control_points, settings.domain_cells)
    if few:
        found.append(Note(NoteKind.FEW_CELLS, few))
    if edited_since_bind(settings):
        found.append(Note(NoteKind.EDITED_SINCE_BIND, edited_since_bind_note(words.all)))
    if moved_as_an_object(mesh_obj):
        found.append(Note(NoteKind.OUTSIDE_ITS_CAGE, outside_its_cage_note(mesh_obj)) if outside_its_cage(mesh_obj)
                     else Note(NoteKind.MOVED_AS_AN_OBJECT, moved_as_an_object_note(mesh_obj, words.one)))
    return tuple(found)


# Causes (see :func:`diagnose`) the node group cannot see, so the add-on clears its "Enabled" input.
STOPPED_HERE = ("topology", "welded apart", "rest moved")
# Causes that are the artist's own choice, not a fault: the panel says them, the console does not, and the binding
# still gives its deformation (Save as Shape Key saves it).
ARTISTS_CHOICE = ("modifier off",)

# Vertices :func:`rest_moved` compares with their rest positions, spread over the mesh's order; and the rounding it
# allows, relative to the positions' magnitude: a few float32 ulps (the mesh's and its rest attribute's positions are
# float32, and the affine fit adds a little).
REST_SAMPLES = 16
FLOAT32_ROUNDING = 8 * float(np.finfo(np.float32).eps)
# And the share of the largest change the affine fit may leave unexplained: a move as a whole leaves only rounding; a
# stroke that pushed a few sampled vertices leaves most of their change (three quarters for one vertex of 16), even
# where it is within the rounding allowed far from the origin (a 0.01 stroke at x = 10⁴, a new user's finding).
UNEXPLAINED_SHARE = 0.1


def status(mesh_obj, depsgraph):
    """Whether a bound object's deformer can work, and if not, why.

    Returns
    -------
    (ok: bool, message: str)
    """
    cause, message = diagnose(mesh_obj, depsgraph)
    return cause is None, message


def held_off_warning(mesh_obj):
    """After a bind: why its deformer cannot work as the stack stands (e.g. a Rebind below a modifier that changes the
    vertex count, which Bind's own modifier, added at the top, never is), as a warning; None when it follows."""
    ok, message = status(mesh_obj, bpy.context.evaluated_depsgraph_get())
    return None if ok else f"bound, but the deformer is held off: {message[:1].lower()}{message[1:]}"


def diagnose(mesh_obj, depsgraph, cages=None):
    """Why a bound object's deformer cannot work: (cause, message), cause None when it works.

    ``cause`` is one of "modifier", "weights", "mesh vertices", "rest moved" (:func:`rest_moved`), "cage deleted",
    "cage type", "cage vertices", "topology", "welded apart", "modifier above" (one that can change the vertex
    count), "modifier error" (an error the node group raised for what only it sees), "modifier off" (switched off in
    the viewport by the artist). A cage with other vertices in renders still follows (cause None), its message says
    so. Only the causes in :data:`STOPPED_HERE` need the add-on to stop the deformer; the node group itself stops for
    the others.
    ``cages``: a dict keeping each cage's :func:`geometry.evaluated_cage` for the next bindings checked with the same
    depsgraph, so that the meshes bound to one cage (a body, its clothes, its eyes) evaluate and hash it once.
    """
    modifier = deformer.find_modifier(mesh_obj)
    found = (_mesh_fault(mesh_obj, modifier) or _cage_fault(mesh_obj.lbc, depsgraph, cages)
             or _modifier_fault(mesh_obj, modifier, depsgraph))
    if found is not None:
        return found
    cage = mesh_obj.lbc.cage
    difference = geometry.render_difference(cage)
    if difference is not None:
        return None, (f"Following '{cage.name}' in the viewport, but renders leave the mesh undeformed: the cage's "
                      f"{difference}. Make them the same and Rebind")
    return None, following_message(mesh_obj)


def following_message(mesh_obj):
    """The status line of a bound mesh that follows its cage: "Following 'Cage'", with the share of the mesh outside
    the cage where the cage is too small for it, a lasting state the cage's panel lists too."""
    settings = mesh_obj.lbc
    if not cage_too_small(settings, len(mesh_obj.data.vertices)):
        return f"Following '{settings.cage.name}'"
    share = settings.outside / (settings.mesh_vertex_count or len(mesh_obj.data.vertices))
    return f"Following '{settings.cage.name}', with {share:.0%} of the mesh outside it: the cage is too small"


def _mesh_fault(mesh_obj, modifier):
    """(cause, message) of what went wrong with the bound mesh itself, its modifier or its cached weights, or None."""
    settings = mesh_obj.lbc
    if modifier is None:
        return "modifier", (
            "The LBC modifier was removed or applied: Unbind to remove the weights it left in the mesh (the mesh keeps "
            "its shape), or Rebind"
        )
    count = len(mesh_obj.data.vertices)
    # 0: bound by a version of the add-on that did not record it. Checked first: a Join changes both the vertex count
    # and the slots stored, and the vertex count is what the artist did.
    if settings.mesh_vertex_count and count != settings.mesh_vertex_count:
        return "mesh vertices", (
            f"The mesh has {count} vertices, it was bound with {settings.mesh_vertex_count}: it stays undeformed. "
            "Rebind"
        )
    if storage.slot_count(mesh_obj.data) != settings.slots:
        return "weights", "The cached weights are missing from the mesh data: Rebind"
    if rest_moved(mesh_obj.data):
        return "rest moved", (
            "The mesh's vertices were moved as a whole since binding (Apply Transforms, or all of them moved in Edit "
            "Mode): it stays at rest, undeformed (following the cage it would jump). Undo the move, or put the cage "
            "in its rest pose and Rebind (Rebind binds to the cage as it is)"
        )
    return None


def _cage_fault(settings, depsgraph, cages):
    """(cause, message) of what went wrong with the cage of a binding (its ``settings``, Object.lbc): deleted, no
    longer a mesh, other vertices or topology, welded vertices posed apart; or None."""
    cage = settings.cage
    if cage is None:
        return "cage deleted", (
            "The cage was deleted: the mesh is back at rest. Select it, then a new cage (active), and Bind; or Unbind"
        )
    if cage.type != "MESH":
        return "cage type", f"The cage '{cage.name}' is no longer a mesh: Rebind with a mesh cage"
    topologies, positions = geometry.evaluated_cage_once(cage, depsgraph, cages)
    count = len(positions)
    if count != settings.cage_vertex_count:
        modifiers = geometry.cage_modifiers_note(cage)
        return "cage vertices", (
            f"The cage '{cage.name}' has {count} vertices{f' ({modifiers})' if modifiers else ''}, it was bound with "
            f"{settings.cage_vertex_count}: the mesh stays undeformed. Rebind"
        )
    if settings.cage_topology not in topologies:
        return "topology", (
            f"The topology of the cage '{cage.name}' changed since binding (same vertex count): the mesh stays "
            "undeformed. Rebind"
        )
    apart = welded_apart(settings.welded, positions)
    if apart is not None:
        return "welded apart", (
            f"Cage vertices {apart[0]} and {apart[1]} of '{cage.name}' were one point when bound and are now apart: "
            "the mesh stays at rest. Move them together again, or merge them (Merge by Distance) and Rebind"
        )
    return None


def _modifier_fault(mesh_obj, modifier, depsgraph):
    """(cause, message) of what holds the modifier back once mesh and cage are sound: a modifier above it that
    changes the vertex count, an error its node group raised, or the artist switching it off; or None."""
    # What only the modifier sees (Blender 4.3 and newer; the causes above are ruled out): the vertex count reaching
    # it differs. While the add-on holds the deformer off, its warning is the add-on's own, and the cause is gone.
    # The group's own warnings are looked up by their messages (node_group.warning_cause), never parsed.
    warnings = getattr(modifier, "node_warnings", ()) if deformer.is_enabled(modifier) else ()
    causes = [node_group.warning_cause(modifier.node_group, warning.message) for warning in warnings]
    causes = [cause for cause in causes if cause is not None]
    # Which modifier: one above that can change the count, as the modifier's error confirms (4.2 has no Warning node
    # to confirm it; there the modifier's type alone says so).
    above = _vertex_count_modifier_above(mesh_obj, modifier, depsgraph)
    if above is not None and (causes or not node_group.has_warning_nodes(modifier.node_group)):
        return "modifier above", (
            f"The modifier '{above.name}' above '{modifier.name}' changes the mesh's vertex count: the mesh stays "
            f"undeformed. Move '{modifier.name}' to the top of the stack"
        )
    if causes:
        settings = mesh_obj.lbc
        counts = settings.cage_vertex_count, settings.mesh_vertex_count or len(mesh_obj.data.vertices)
        message = node_group.stop_messages(*counts)[causes[0]]
        return "modifier error", message[:1].upper() + message[1:]
    if not modifier.show_viewport:
        return "modifier off", (
            f"The modifier '{modifier.name}' is switched off in the viewport (its screen icon): the mesh stays at rest "
            f"there{'' if modifier.show_render else ' and in renders'}. Switch it on to follow "
            f"'{mesh_obj.lbc.cage.name}'"
        )
    return None

def _vertex_count_modifier_above(mesh_obj, modifier, depsgraph):
    """The first modifier shown in the viewport above ``modifier`` that can change the vertex count, or None. A
    Geometry Nodes modifier (whose tree may keep the count) only where the evaluated mesh has another count than the
    mesh data and no modifier below could have changed it."""
    stack = list(mesh_obj.modifiers)
    position = stack.index(modifier)
    for other in filter(geometry.may_change_vertex_count, stack[:position]):
        if other.type != "NODES":
            return other
        if not any(map(geometry.may_change_vertex_count, stack[position + 1:])) and (
                len(mesh_obj.evaluated_get(depsgraph).data.vertices) != len(mesh_obj.data.vertices)):
            return other
    return None


def rest_moved(mesh):
    """Whether a bound mesh's vertices were moved as a whole since binding: a sample of them (:data:`REST_SAMPLES`)
    is an affine image, other than the identity, of the rest positions the weights reproduce. Apply Transforms does
    this to the mesh data, and the deformer would add the cage's displacement to a rest it no longer has: a jump.
    Edits of part of the mesh (sculpting) are no affine image. The weights of vertices outside the cage reproduce them
    too (they extrapolate from the closest points inside), so their rest is their own position."""
    rest_attribute = mesh.attributes.get(storage.REST_NAME)
    count = len(mesh.vertices)
    if rest_attribute is None or count < 4 or len(rest_attribute.data) != count:
        return False
    sample = np.unique(np.linspace(0, count - 1, min(count, REST_SAMPLES)).astype(int)).tolist()
    rest = np.array([rest_attribute.data[i].vector[:] for i in sample])
    now = np.array([mesh.vertices[i].co[:] for i in sample])
    return moved_affinely(rest, now)


def moved_affinely(before, after, tolerance=1e-5):
    """Whether (k, 3) points ``after`` are an affine image of ``before`` other than the identity, both to
    ``tolerance`` × the size of ``before`` plus the float32 rounding of the positions (far from the origin or scaled
    up, the rounding of the moved positions alone exceeds 1e-5 of the mesh's size), the fit leaving at most
    UNEXPLAINED_SHARE of the largest change unexplained."""
    size = float(np.linalg.norm(np.ptp(before, axis=0)))
    allowed = tolerance * size + FLOAT32_ROUNDING * (np.abs(before).max() + np.abs(after).max())
    change = np.abs(after - before).max()
    if change <= allowed:
        return False
    design = np.c_[before, np.ones(len(before))]
    fit, *_ = np.linalg.lstsq(design, after, rcond=None)
    unexplained = np.abs(design @ fit - after).max()
    return bool(unexplained <= allowed and unexplained <= UNEXPLAINED_SHARE * change)


def welded_apart(welded, positions):
    """The first (copy, kept) pair of cage vertices welded at bind time that are now apart, or None.

    ``welded``: the binding's "copy:kept,..." pairs; apart means farther than lbc_core's POSED_APART × the cage's size,
    the tolerance of ``lbc deform``.
    """
    pairs = read_welded(welded)
    if not len(pairs):
        return None
    size = float(np.linalg.norm(np.ptp(positions, axis=0)))
    offset = np.linalg.norm(positions[pairs[:, 0]] - positions[pairs[:, 1]], axis=1)
    apart = np.flatnonzero(offset > POSED_APART * size)
    return tuple(pairs[apart[0]].tolist()) if len(apart) else None


def edited_since_bind(settings):
    """Whether the cage's own vertex positions changed since the bind (``settings``: a bound mesh's ``Object.lbc``):
    an edit at rest, which the mesh follows as a pose until a Rebind makes it the rest (posing with bones, shape keys
    or the object's transform leaves them as they were). False while the deformer is stopped: an edit that stops it
    (a loop cut) is not followed, and the status already says why."""
    cage = settings.cage
    if settings.state != "FOLLOWING" or cage is None or cage.type != "MESH" or not settings.cage_shape:
        return False  # (no cage_shape: bound before the shape was recorded)
    shape = geometry.shape_fingerprint(cage.data)
    return bool(shape) and shape != settings.cage_shape


def moved_as_an_object(obj):
    """Whether a bound mesh was moved as an object since the bind, away from its cage: its own transform (location,
    rotation, scale: what G, R, S and their keys change) and its place relative to its cage both differ from the bind's.
    The deformer puts the mesh where its cage holds it, so such a move shows nothing. Moves that come from a parent
    (the cage, or a rig carrying both) leave its own transform as it was; a copy made with its cage (Shift+D of both)
    and moved with it keeps its place relative to the cage, and deforms where it is."""
    settings = obj.lbc
    then = np.array(settings.mesh_transform).reshape(4, 4)
    if not then.any():  # bound before the transform was recorded
        return False
    if _close(np.array(obj.matrix_basis), then):
        return False
    placed = np.array(settings.mesh_in_cage).reshape(4, 4)
    cage = settings.cage
    if not placed.any() or cage is None:  # bound before the place in the cage was recorded, or the cage deleted
        return True
    return not _close(np.array(mesh_in_cage(obj, cage)), placed)


def _close(matrix, then):
    """Whether two 4×4 transforms agree, to float32 rounding of their size."""
    return np.allclose(matrix, then, rtol=1e-5, atol=1e-5 * max(1.0, np.abs(then).max()))


def mesh_in_cage(mesh_obj, cage_obj):
    """The mesh object's world transform in its cage's frame (a ``mathutils.Matrix``): what moving both together
    keeps, and moving one alone changes."""
    return cage_obj.matrix_world.inverted_safe() @ mesh_obj.matrix_world


def outside_its_cage(obj):
    """Whether a bound mesh, where it is now (its vertices at rest under its own transform), lies wholly outside its
    cage's bounding box: a copy (Shift+D) moved away from the cage, which the cage still places, and which no Rebind
    can bind where it is. A bounding-box test, cheap enough for every redraw of the panel."""
    cage = obj.lbc.cage
    if cage is None or cage.type != "MESH" or not len(cage.data.vertices) or not len(obj.data.vertices):
        return False
    points = geometry.transform(obj.matrix_world, geometry.vertex_positions(obj.data))
    corners = geometry.transform(cage.matrix_world, np.array(cage.bound_box))
    low, high = corners.min(axis=0), corners.max(axis=0)
    return not np.any(np.all((points >= low) & (points <= high), axis=1))


def moved_as_an_object_note(obj, rebind):
    """What the panel and ``api.status`` say of a bound mesh :func:`moved_as_an_object` (``rebind``: how to rebind
    there)."""
    return (f"'{obj.name}' was moved as an object since the bind, which does not move it: its cage alone places it. "
            "Undo the move, then move the cage instead, or parent the mesh to the cage (Ctrl+P) to move both "
            f"together; or {rebind} to bind it where it is now")


def outside_its_cage_note(obj):
    """What the panel and ``api.status`` say of a mesh moved as an object out of its cage (:func:`outside_its_cage`):
    a Rebind there would find no vertex inside the cage."""
    cage = obj.lbc.cage.name
    return (f"'{obj.name}' was moved as an object out of its cage '{cage}', which still places it where the cage is. "
            f"Move it back into '{cage}' (or undo the move); or, to deform it where it is now, give it a cage there "
            f"(duplicate '{cage}' and move the copy around it) and bind it to that cage")


def edited_since_bind_note(rebind):
    """What ``api.status`` says of a bound mesh whose cage was :func:`edited_since_bind` (``rebind``: how)."""
    return f"the cage was edited since the bind, and the mesh follows the edit: {rebind} to make it the rest shape"
